/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: Lloyd's iterations of the CVT plan (plan-cvt.c). */
#ifndef ASPH_PLAN_CVT_H
#define ASPH_PLAN_CVT_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/progress.h"
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
 * of a bucket grid. progress (may be NULL) hears of each iteration, of
 * at most ASPH_PLAN_CVT_MAX_ITERATIONS. info may be NULL. -EINVAL,
 * -ENOMEM, -E2BIG, -ECANCELED when progress cancelled.
 */
int plan_cvt_relax(const struct asph_surface *s, double p, double *xyz, size_t n,
		   const struct asph_progress *progress, struct plan_cvt_info *info,
		   struct asph_error *err);

/*
 * The step (x-y) at which the CVT's starting sites sample the aperture's
 * outline for n sites: the outline lifted onto the surface divided into
 * steps as long as the lattice's, sqrt(2 area / (sqrt 3 n)).
 */
double plan_cvt_edge_step(const struct asph_surface *s, size_t n);

/*
 * The CVT's n starting sites in the x-y plane, in scan order, for the OT
 * map to move onto the surface: the n - m points of a hexagonal lattice
 * (one per n-th of the aperture's area) deepest inside the aperture, in
 * spiral order about its centre, then the m = plan_outline_count(s,
 * plan_cvt_edge_step(s, n)) samples of its outline. The third slot holds
 * the distance from the aperture's centre (the radius of the aperture on
 * the edge). -EINVAL when n is too small to fill the aperture, -ENOMEM.
 */
int plan_cvt_seed(const struct asph_surface *s, size_t n, double *xyz, struct asph_error *err);

/*
 * The scan order of the n relaxed sites xyz (on the surface) that
 * plan_cvt_seed() started: the inner sites along a spiral about the
 * aperture's centre whose turns are a row of the lattice apart on the
 * surface (the distance from the centre measured along the meridian on a
 * surface of revolution, as the 3-D chord on a freeform), then the outline
 * from its sample nearest to the last of them. -ENOMEM.
 */
int plan_cvt_order(const struct asph_surface *s, double *xyz, size_t n, struct asph_error *err);

#endif
