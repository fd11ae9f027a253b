/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: Lloyd's iterations of the CVT plan (plan-cvt.c). */
#ifndef ASPH_PLAN_CVT_H
#define ASPH_PLAN_CVT_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/surface.h"

struct plan_cvt_info {
	int iterations;
	double last_move;       /* the largest distance of a moving site from its
				 * cell's centroid at the end / the spacing */
	size_t triangles;       /* the flat triangles the cells are cut from */
};

/*
 * Moves the n points xyz (on the surface, stride 3) until each is the
 * centroid of its Voronoi cell restricted to the surface, to 1e-3 of the
 * spacing sqrt(area / n) (at most 100 L-BFGS iterations on the CVT
 * energy); the points on the aperture's edge stay. The points must follow
 * the surface's area (the OT plan): their x-y Delaunay mesh, refined, is
 * the surface's mesh for the cells. p: the plan's x-y pitch (mm), the cell
 * of a bucket grid. info may be NULL. -EINVAL, -ENOMEM, -E2BIG.
 */
int plan_cvt_relax(const struct asph_surface *s, double p, double *xyz, size_t n,
		   struct plan_cvt_info *info, struct asph_error *err);

#endif
