/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: Lloyd's iterations of the CVT plan (plan-cvt.c). */
#ifndef ASPH_PLAN_CVT_H
#define ASPH_PLAN_CVT_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/surface.h"

struct plan_cvt_info {
	int iterations;
	double last_move;       /* the largest move of the last iteration / p */
	size_t samples;
};

/*
 * Moves the n points xyz (on the surface, stride 3) to the centroids of
 * their Voronoi cells restricted to the surface, until none moves more than
 * 1e-3 p (at most 100 iterations); the points on the aperture's edge stay.
 * p: the plan's pitch (mm), which sets the samples' lattice. info may be
 * NULL. -EINVAL, -ENOMEM.
 */
int plan_cvt_relax(const struct asph_surface *s, double p, double *xyz, size_t n,
		   struct plan_cvt_info *info, struct asph_error *err);

#endif
