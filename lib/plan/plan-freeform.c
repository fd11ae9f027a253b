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

/* ---- the harmonic chart ------------------------------------------------------- */

struct asph_lb_chart {
	const struct asph_surface *s;
	struct grid_mesh mesh;  /* the aperture's grid and its Delaunay mesh */
	double *S;              /* the harmonic map at its nodes */
	uint32_t t;             /* the last triangle located: the next walk's start */
};

void asph_lb_chart_free(struct asph_lb_chart *c)
{
	if (!c)
		return;
	grid_mesh_clear(&c->mesh);
	free(c->S);
	free(c);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_lb_chart *, asph_lb_chart_free)

int asph_lb_chart_alloc(const struct asph_surface *s, double pitch, struct asph_lb_chart **out,
			struct asph_error *err)
{
	_cleanup_(asph_lb_chart_freep) struct asph_lb_chart *c = NULL;
	_cleanup_(plan_points_clear) struct plan_points grid = { 0 };
	int r;

	if (!(pitch > 0) || !isfinite(pitch))
		return asph_error_set(err, -EINVAL, "harmonic chart: pitch %g is not > 0", pitch);
	c = calloc(1, sizeof(*c));
	if (!c || plan_aperture_pattern(s, &plan_disk_grid, pitch, &grid, NULL) < 0 ||
	    !(c->S = malloc(2 * grid.n * sizeof(double))))
		return asph_error_set(err, -ENOMEM, "out of memory (%zu points)", grid.n);
	c->s = s;
	r = grid_mesh_build(grid.xyz, grid.n, &c->mesh, err);
	if (r == 0)
		r = asph_lb_fem_solve_graph(surface_gradient, (void *)s, c->mesh.xy, grid.n,
					    c->mesh.tri, c->mesh.ntri, c->S, err);
	if (r < 0)
		return r;
	for (size_t k = 0; k < c->mesh.ntri; k++)
		if (!(area2(c->S, c->mesh.tri + 3 * k) > 0))
			return asph_error_set(err, -ERANGE,
					      "the discrete Laplace-Beltrami map folds triangle %zu "
					      "of the grid: the surface is too steep for this density",
					      k);
	*out = c;
	c = NULL;
	return 0;
}

/* Maps p by `from` to `to`: the triangle of the mesh on `from` that holds
 * p, the same barycentric combination of the nodes of `to`. */
static int mesh_carry(struct asph_lb_chart *c, const double *from, const double *to,
		      const double p[2], double q[2])
{
	double b[3];

	if (asph_mesh_locate(from, c->mesh.tri, c->mesh.nb, c->mesh.ntri, &c->t, p, b) < 0)
		return -ENOENT;
	const uint32_t *v = c->mesh.tri + 3 * (size_t)c->t;
	q[0] = q[1] = 0;
	for (int k = 0; k < 3; k++) {
		q[0] += b[k] * to[2 * (size_t)v[k]];
		q[1] += b[k] * to[2 * (size_t)v[k] + 1];
	}
	return 0;
}

/* The affine map of triangle t of the mesh (from -> to) at p, for a point
 * just outside it. */
static void triangle_extend(const struct asph_lb_chart *c, uint32_t t, const double *from,
			    const double *to, const double p[2], double q[2])
{
	const uint32_t *v = c->mesh.tri + 3 * (size_t)t;
	const double *a = from + 2 * (size_t)v[0], *b = from + 2 * (size_t)v[1],
		     *d = from + 2 * (size_t)v[2];
	double det = (b[0] - a[0]) * (d[1] - a[1]) - (d[0] - a[0]) * (b[1] - a[1]);
	double l1 = ((p[0] - a[0]) * (d[1] - a[1]) - (d[0] - a[0]) * (p[1] - a[1])) / det;
	double l2 = ((b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1])) / det;
	double bc[3] = { 1 - l1 - l2, l1, l2 };

	q[0] = q[1] = 0;
	for (int k = 0; k < 3; k++) {
		q[0] += bc[k] * to[2 * (size_t)v[k]];
		q[1] += bc[k] * to[2 * (size_t)v[k] + 1];
	}
}

int asph_lb_chart_map(struct asph_lb_chart *c, double x, double y, double uv[2])
{
	double p[2] = { x, y };

	if (mesh_carry(c, c->mesh.xy, c->S, p, uv) == 0)
		return 0;
	/* Between a curved edge and the mesh's polygon (a sliver of
	 * O(pitch^2 / radius)): the boundary triangle the walk ended at,
	 * extended. */
	if (!asph_surface_contains(c->s, x, y, 1e-9 * fmax(1, hypot(x, y))))
		return -ENOENT;
	triangle_extend(c, c->t, c->mesh.xy, c->S, p, uv);
	return 0;
}

int plan_lb_freeform_map(const struct asph_surface *s, double p, double *xyz, size_t n,
			 struct asph_error *err)
{
	_cleanup_(asph_lb_chart_freep) struct asph_lb_chart *c = NULL;
	size_t n_edge = plan_outline_count(s, p);
	/* The elements: the aperture's grid at p / LB_REFINE. */
	int r = asph_lb_chart_alloc(s, p / LB_REFINE, &c, err);

	if (r < 0)
		return r;
	/* T = S^-1 at every grid point. The grid comes in scan order, so each
	 * walk starts next door. */
	for (size_t i = 0; i < n; i++) {
		double q[2] = { xyz[3 * i], xyz[3 * i + 1] }, T[2];
		if (i >= n - n_edge) {
			xyz[3 * i + 2] = asph_surface_sag_xy(s, q[0], q[1]);
			continue;
		}
		if (mesh_carry(c, c->S, c->mesh.xy, q, T) < 0)
			return asph_error_set(err, -ERANGE,
					      "grid point %zu is outside the image of the "
					      "Laplace-Beltrami map", i);
		xyz[3 * i] = T[0];
		xyz[3 * i + 1] = T[1];
		xyz[3 * i + 2] = asph_surface_sag_xy(s, T[0], T[1]);
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
