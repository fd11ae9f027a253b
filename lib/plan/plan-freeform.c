/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The maps of the grid methods on freeform surfaces. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "asph/delaunay.h"
#include "asph/lb.h"
#include "asph/ot.h"
#include "plan-aperture.h"
#include "plan-freeform.h"
#include "util-mem.h"

/* The elements of LB are LB_REFINE times finer than the plan's grid: P1's
 * O(h^2) error is what the plan inherits. */
#define LB_REFINE 2

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_delaunay *, asph_delaunay_free)

static void surface_gradient(void *ctx, double x, double y, double grad[2])
{
	double g[3];

	asph_surface_sag_grad_xy(ctx, x, y, g);
	grad[0] = g[1];
	grad[1] = g[2];
}

/* The points' x, y, their Delaunay triangulation (every triangle: the FEM
 * needs the whole domain) and its adjacency. */
struct grid_mesh {
	double *xy;
	uint32_t *tri, *nb;
	size_t ntri;
};

static void grid_mesh_clear(struct grid_mesh *m)
{
	free(m->xy);
	free(m->tri);
	free(m->nb);
}

static int grid_mesh_build(const double *xyz, size_t n, struct grid_mesh *m,
			   struct asph_error *err)
{
	_cleanup_(asph_delaunay_freep) struct asph_delaunay *w = asph_delaunay_alloc(n);
	int r;

	m->xy = malloc(2 * n * sizeof(double));
	if (!w || !m->xy)
		return asph_error_set(err, -ENOMEM, "out of memory (a mesh of %zu points)", n);
	for (size_t i = 0; i < n; i++) {
		m->xy[2 * i] = xyz[3 * i];
		m->xy[2 * i + 1] = xyz[3 * i + 1];
	}
	r = asph_delaunay_triangulate(w, m->xy, n, &m->tri, &m->ntri, err);
	if (r == 0)
		r = asph_delaunay_neighbors(w, &m->nb, err);
	return r;
}

/* Twice the signed area of triangle v of the points xy. */
static double area2(const double *xy, const uint32_t *v)
{
	const double *p0 = xy + 2 * (size_t)v[0], *p1 = xy + 2 * (size_t)v[1];
	const double *p2 = xy + 2 * (size_t)v[2];

	return (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (p1[1] - p0[1]);
}

int plan_lb_freeform_map(const struct asph_surface *s, double p, double *xyz, size_t n,
			 struct asph_error *err)
{
	_cleanup_(grid_mesh_clear) struct grid_mesh m = { 0 };
	_cleanup_(plan_points_clear) struct plan_points fine = { 0 };
	_cleanup_free_ double *S = NULL;
	size_t n_edge = plan_outline_count(s, p);
	uint32_t t = 0;
	int r;

	/* The elements: the aperture's grid at p / LB_REFINE. */
	if (plan_aperture_pattern(s, ASPH_PLAN_OP, p / LB_REFINE, &fine, NULL) < 0 ||
	    !(S = malloc(2 * fine.n * sizeof(double))))
		return asph_error_set(err, -ENOMEM, "out of memory (%zu points)", fine.n);
	r = grid_mesh_build(fine.xyz, fine.n, &m, err);
	if (r == 0)
		r = asph_lb_fem_solve_graph(surface_gradient, (void *)s, m.xy, fine.n, m.tri,
					    m.ntri, S, err);
	if (r < 0)
		return r;
	for (size_t k = 0; k < m.ntri; k++)
		if (!(area2(S, m.tri + 3 * k) > 0))
			return asph_error_set(err, -ERANGE,
					      "the discrete Laplace-Beltrami map folds triangle %zu "
					      "of the grid: the surface is too steep for this density",
					      k);
	/* T = S^-1 at every grid point: the triangle of the image mesh that
	 * holds it, the same barycentric combination of the source points.
	 * The grid comes in scan order, so each walk starts next door. */
	for (size_t i = 0; i < n; i++) {
		double q[2] = { xyz[3 * i], xyz[3 * i + 1] }, b[3];
		if (i >= n - n_edge) {
			xyz[3 * i + 2] = asph_surface_sag_xy(s, q[0], q[1]);
			continue;
		}
		if (asph_mesh_locate(S, m.tri, m.nb, m.ntri, &t, q, b) < 0)
			return asph_error_set(err, -ERANGE,
					      "grid point %zu is outside the image of the "
					      "Laplace-Beltrami map", i);
		const uint32_t *v = m.tri + 3 * (size_t)t;
		double x = 0, y = 0;
		for (int k = 0; k < 3; k++) {
			x += b[k] * m.xy[2 * (size_t)v[k]];
			y += b[k] * m.xy[2 * (size_t)v[k] + 1];
		}
		xyz[3 * i] = x;
		xyz[3 * i + 1] = y;
		xyz[3 * i + 2] = asph_surface_sag_xy(s, x, y);
	}
	return 0;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_ot_map *, asph_ot_map_free)

/* The map keeps the aperture and its edge, to its tables' interpolation
 * (~1e-9 of the aperture): T back inside, and onto the edge for a point of
 * the edge. In the aperture's reference coordinates (the unit disk or the
 * square [-1, 1]^2). */
static void snap_to_aperture(const struct asph_surface *s, const struct asph_aperture *ap,
			     bool edge, double T[2])
{
	double hx = 0.5 * ap->width, hy = 0.5 * ap->height;
	double u = (T[0] - ap->offset[0]) / hx, v = (T[1] - ap->offset[1]) / hy;

	if (ap->shape == ASPH_APERTURE_RECTANGULAR) {
		u = fmax(-1, fmin(1, u));
		v = fmax(-1, fmin(1, v));
		if (edge && fmax(fabs(u), fabs(v)) < 1) {
			if (1 - fabs(u) < 1 - fabs(v))
				u = copysign(1, u);
			else
				v = copysign(1, v);
		}
	} else if (edge || hypot(u, v) > 1) {
		/* on the edge as asph_surface_aperture_edge() traces it */
		double t = atan2(v, u);
		u = cos(t);
		v = sin(t);
	}
	T[0] = ap->offset[0] + hx * u;
	T[1] = ap->offset[1] + hy * v;
	plan_aperture_nudge_in(s, &T[0], &T[1]);
}

int plan_ot_freeform_map(const struct asph_surface *s, double p, double *xyz, size_t n,
			 struct asph_error *err)
{
	_cleanup_(asph_ot_map_freep) struct asph_ot_map *m = NULL;
	size_t n_edge = plan_outline_count(s, p);
	struct asph_aperture ap;
	int r = asph_ot_map_solve(s, NULL, &m, err);

	if (r < 0)
		return r;
	asph_surface_aperture(s, &ap);
	for (size_t i = 0; i < n; i++) {
		double T[2];
		asph_ot_map_apply(m, xyz[3 * i], xyz[3 * i + 1], T, NULL);
		snap_to_aperture(s, &ap, i >= n - n_edge, T);
		xyz[3 * i] = T[0];
		xyz[3 * i + 1] = T[1];
		xyz[3 * i + 2] = asph_surface_sag_xy(s, T[0], T[1]);
	}
	return 0;
}
