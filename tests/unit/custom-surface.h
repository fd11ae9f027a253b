/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * An even asphere of the given R, k and aperture diameter, for the tests
 * that fit points to one (the fit's, the line profiles', the Monte
 * Carlo's). Include after <cmocka.h>.
 */
#ifndef ASPH_TEST_CUSTOM_SURFACE_H
#define ASPH_TEST_CUSTOM_SURFACE_H

#include <stdio.h>

#include "asph/prescription.h"
#include "asph/surface.h"

static inline struct asph_surface *custom(double R, double k, double diameter)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE };
	struct asph_surface *s = NULL;

	snprintf(p.name, sizeof(p.name), "custom");
	p.R = R;
	p.k = k;
	p.aperture_diameter = diameter;
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

#endif
