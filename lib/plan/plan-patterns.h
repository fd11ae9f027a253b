/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: the planar point patterns every method starts
 * from, and the lattice constants the density relations use. */
#ifndef ASPH_PLAN_PATTERNS_H
#define ASPH_PLAN_PATTERNS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/plan.h"

/*
 * Each method lays out a lattice of pitch p (the disk grid, the vertex-plane
 * patterns, or for CI the 3-D step along the curve). On a flat part of
 * area A the lattice has about A / (area_per_pitch2 p^2) points and a
 * triangulation of it has mean edge length edge_per_pitch * p. Both
 * constants were measured on large flat patterns (docs/sampling-plans.md).
 */
struct plan_lattice {
	double area_per_pitch2;
	double edge_per_pitch;
};

/*
 * A planar pattern: its lattice, its exact count and its points (below) on
 * the disk of radius a, and how it lies over an aperture that is not a
 * circle (plan-aperture.h): the disk pattern kept inside with the outline,
 * or (rows) rows that end on the edge. rim_count, where not NULL, is the
 * number of its trailing points on the circle r = a.
 */
struct plan_pattern {
	struct plan_lattice lattice;
	size_t (*count)(double a, double p);
	int (*fill)(double a, double p, double *xyr);
	size_t (*rim_count)(double a, double p);
	bool rows;
};

extern const struct plan_pattern plan_disk_grid, plan_raster, plan_concentric, plan_spiral,
	plan_fermat;

/* The pattern a method lays (CI: the disk grid's lattice, laid on the
 * surface), and its lattice. */
const struct plan_pattern *plan_pattern_of(enum asph_plan_method m);
const struct plan_lattice *plan_lattice_of(enum asph_plan_method m);

/*
 * The pattern generators write, per point and in scan order, x and y in the
 * plane and in the third slot the radius sqrt(x^2 + y^2) as the generator
 * knows it (exactly a on the aperture circle), so that the lift to the
 * surface needs no square root and never sees a radius above a.
 * count() is exact: fill() writes exactly that many points; it returns 0
 * or -ENOMEM.
 */

/* Disk grid of paper 5.1: the circle involute of Eq. (5) with base radius
 * s0 = p / (2 pi) sampled at arc length 2 pi s0 = p while its radius stays
 * <= a - p/2, then a ring of ceil(2 pi a / p) points on the circle r = a. */
size_t plan_disk_grid_count(double a, double p);
size_t plan_disk_grid_spiral_count(double a, double p);   /* involute samples */
size_t plan_disk_grid_rim_count(double a, double p);      /* the ring */
int plan_disk_grid_fill(double a, double p, double *xyr);

/* k-th involute sample: t_k = 2 s0 sqrt(pi k), the arc length being
 * t^2 / (2 s0) = 2 pi s0 k. */
void plan_involute_point(double s0, size_t k, double xy[2], double *rho);

/* x-y raster: rows y = j p, lattice columns x = i p at least p/2 inside the
 * rim, and both row ends on the rim; serpentine order from y = -a up. */
size_t plan_raster_count(double a, double p);
int plan_raster_fill(double a, double p, double *xyr);

/* One raster row over the chord |x| <= c: its point count (1 for a chord
 * shorter than p/2: the single point x = 0), and its lattice columns
 * x = i p, |i| <= cols, at least p/2 inside the chord (-1: none); the
 * other two points are the chord's ends. */
size_t plan_raster_row_count(double c, double p);
long plan_raster_cols(double c, double p);

/* Concentric circles: the centre, then M = ceil(a/p) rings at radii
 * j a / M with ceil(2 pi r_j / p) points each, ring after ring, each ring
 * counter-clockwise from the angle where the previous one ended. */
size_t plan_concentric_count(double a, double p);
int plan_concentric_fill(double a, double p, double *xyr);

/* Archimedean spiral r = p theta / (2 pi) from the vertex to r = a,
 * sampled at equal arc length (<= p, the last sample exactly on the rim). */
size_t plan_spiral_count(double a, double p);
int plan_spiral_fill(double a, double p, double *xyr);

/* Fermat spiral: n points r_i = a sqrt(i / (n - 1)), theta_i = i times the
 * golden angle, n = round(pi a^2 / p^2); visited in annular bands of
 * width ~p, each counter-clockwise by angle. */
size_t plan_fermat_count(double a, double p);
int plan_fermat_fill(double a, double p, double *xyr);   /* -ENOMEM */

/*
 * Inverting a monotone F (F' = f > 0, f' = g) at increasing targets, one
 * sample after the other: a second-order prediction from the previous
 * sample, the increment of F over the step by the trapezoid rule with its
 * end correction (error h^5 f''''/720), and one Newton correction. When the
 * end correction is not negligible (the step is not small against the
 * scale of f), or the Newton correction is too large for one step to
 * converge, the step is refused and the caller inverts F exactly (so near
 * the vertex, where steps are large against the radius).
 * Plans of 1e6 points are thus generated with one evaluation of f, g per
 * point instead of a full inversion.
 */
struct inverse_step {
	double x, F, f, g;
	double inv_f;            /* 1 / f, kept to spare divisions */
};

static inline void inverse_step_set(struct inverse_step *st, double x,
				    double F, double f, double g)
{
	*st = (struct inverse_step){ x, F, f, g, f > 0 ? 1.0 / f : 0.0 };
}

/* Newton's step on the quadratic model F + f h + g h^2 / 2, expanded to
 * second order in the increment (its O(h^3) error is what the Newton
 * correction of inverse_step_finish removes). At f = 0 (a vertex) it
 * returns x, and finish refuses the step. */
static inline double inverse_step_predict(const struct inverse_step *st,
					  double target)
{
	double h = (target - st->F) * st->inv_f;

	return st->x + h * (1.0 - 0.5 * st->g * h * st->inv_f);
}

/* x0 from inverse_step_predict(), f0 > 0 and g0 at x0. On success (0) *x1
 * is the solution and st moves to it; -1: compute this sample exactly. */
static inline int inverse_step_finish(struct inverse_step *st, double target,
				      double x0, double f0, double g0,
				      double *x1)
{
	double h = x0 - st->x, corr = h * h * (1.0 / 12.0) * (g0 - st->g);
	double inc = 0.5 * h * (st->f + f0) - corr, inv_f0 = 1.0 / f0;

	double newton = (st->F + inc - target) * inv_f0;

	/* Refused: a quadrature whose next error term may show, or a
	 * prediction so far off that one Newton step (error ~ g/(2f) times
	 * its square) does not reach the last bit. */
	if (!(h > 0 && __builtin_fabs(corr) <= 1e-6 * __builtin_fabs(inc)) ||
	    !(newton * newton * __builtin_fabs(g0) * inv_f0 <= 1e-17 * x0))
		return -1;
	double x = x0 - newton;
	st->x = x;
	st->F = target;
	st->f = f0 + g0 * (x - x0);
	st->g = g0;
	st->inv_f = inv_f0;
	*x1 = x;
	return 0;
}

/* Samples between exact inversions, so rounding cannot accumulate. */
#define INVERSE_STEP_ANCHOR 256

/* q of Eq. (1) for a planar triangle. */
double plan_triangle_q_2d(const double *p0, const double *p1,
			  const double *p2);

/* Triangulates the disk points (stride 3: x, y, radius), drops triangles
 * with q < 0.75 (paper 5.1). Triangles are counter-clockwise. */
int plan_disk_mesh(const double *xyr, size_t n, uint32_t **triangles,
		   size_t *n_triangles, struct asph_error *err);

#endif
