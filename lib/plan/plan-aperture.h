/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: the vertex-plane patterns laid over a
 * freeform's aperture, whatever its shape (docs/sampling-plans.md,
 * "Freeform surfaces"). */
#ifndef ASPH_PLAN_APERTURE_H
#define ASPH_PLAN_APERTURE_H

#include <stdbool.h>
#include <stddef.h>

#include "asph/error.h"
#include "asph/plan.h"
#include "asph/surface.h"
#include "plan-patterns.h"

/*
 * A growing list of points (x, y and a third slot) in the part's frame. The
 * patterns below append to it; plan_points_push() returns -ENOMEM.
 */
struct plan_points {
	double *xyz;
	size_t n, cap;
};

int plan_points_push(struct plan_points *pp, double x, double y, double z);
void plan_points_clear(struct plan_points *pp);

/*
 * The aperture's edge sampled at equal steps of at most p, counter-clockwise,
 * starting with the sample nearest to (x0, y0): a circle at equal angles, an
 * ellipse at equal arc length, a rectangle with its corners and each side
 * divided equally. Every sample lies in the aperture (asph_surface_contains
 * with tol 0), on its edge to rounding.
 */
size_t plan_outline_count(const struct asph_surface *s, double p);
int plan_outline_append(const struct asph_surface *s, double p, double x0,
			double y0, struct plan_points *pp);

/*
 * A vertex-plane pattern (plan-patterns.h) at pitch p over the aperture, in
 * scan order, z = 0: on a circle (centred or not) the pattern of the
 * circle, moved to its centre; on a rectangle or an ellipse the disk grid
 * and the spirals and circles laid over the disk about the aperture's
 * centre, kept where they are at least p/2 inside, then the outline; a
 * pattern of rows (the raster) has its rows end on the edge (and a
 * rectangle's top and bottom sides are rows). *n_edge (may be NULL) is the
 * number of trailing points on the edge: the outline, or on a circle the
 * pattern's rim (the disk grid's ring); 0 for the other patterns of a
 * circle and for rows.
 */
int plan_aperture_pattern(const struct asph_surface *s, const struct plan_pattern *pat,
			  double p, struct plan_points *pp, size_t *n_edge);

/* Moves (x, y) towards the aperture's centre by an ulp at a time until the
 * aperture holds it (a point computed on the edge may round outside). */
void plan_aperture_nudge_in(const struct asph_surface *s, double *x, double *y);

#endif
