/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The circle involute on any surface of revolution z = Z(r) given by its
 * profile, so that tests can feed an exact plane. Internal. */
#ifndef ASPH_INVOLUTE_PROFILE_H
#define ASPH_INVOLUTE_PROFILE_H

#include <stddef.h>

#include "asph/error.h"

struct involute_profile {
	/* d[0] = Z(r), d[1] = Z'(r), d[2] = Z''(r) */
	void (*derivs)(const void *ctx, double r, double d[3]);
	const void *ctx;
	double a;               /* aperture radius, mm */
};

/* As asph_involute_points(), for the profile p. */
int involute_points_profile(const struct involute_profile *p,
			    double spacing_mm, size_t max_points,
			    double **xyz, size_t *n, struct asph_error *err);

#endif
