/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The interpolant of a residual at scattered points: linear on the
 * triangles of their Delaunay triangulation, defined only in triangles whose
 * edges are all short enough (the measured region).
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_statistics_double.h>

#include "asph/areal.h"
#include "asph/delaunay.h"
#include "areal-internal.h"
#include "util-mem.h"

#define DEFAULT_EDGE_FACTOR 3.0

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_delaunay *, asph_delaunay_free)

void asph_scatter_free(struct asph_scatter *s)
{
	if (!s)
		return;
	free(s->xy);
	free(s->value);
	free(s->tri);
	free(s->adj);
	free(s->kept);
	free(s);
}

static double edge_length(const struct asph_scatter *s, uint32_t a, uint32_t b)
{
	return hypot(s->xy[2 * a] - s->xy[2 * b], s->xy[2 * a + 1] - s->xy[2 * b + 1]);
}

/* Median edge length (selected, not sorted: the same element, in linear
 * time), then which triangles stay inside. */
static int mark_kept(struct asph_scatter *s, const struct asph_scatter_options *o,
		     struct asph_error *err)
{
	_cleanup_free_ double *len = malloc(3 * s->n_tri * sizeof(double));
	double factor = o->max_edge_factor > 0 ? o->max_edge_factor : DEFAULT_EDGE_FACTOR;

	s->kept = malloc(s->n_tri + 1);
	if (!len || !s->kept)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(len, 3 * s->n_tri * sizeof(double));
	for (size_t t = 0; t < s->n_tri; t++)
		for (int k = 0; k < 3; k++)
			len[3 * t + k] = edge_length(s, s->tri[3 * t + k], s->tri[3 * t + (k + 1) % 3]);
	s->median_edge = gsl_stats_select(len, 1, 3 * s->n_tri, 3 * s->n_tri / 2);
	s->max_edge = o->max_edge_mm > 0 ? o->max_edge_mm : factor * s->median_edge;
	for (size_t t = 0; t < s->n_tri; t++) {
		s->kept[t] = 1;
		for (int k = 0; k < 3; k++)
			if (edge_length(s, s->tri[3 * t + k], s->tri[3 * t + (k + 1) % 3]) > s->max_edge)
				s->kept[t] = 0;
	}
	return 0;
}

/* Bits of a cell's x or y: at most 1024 x 1024 cells, about two triangles
 * in each. */
#define MORTON_MAX_BITS 10

/* x (below 2^16) with a zero bit after each of its bits. */
static uint32_t spread_bits(uint32_t x)
{
	x = (x | (x << 8)) & 0x00ff00ffu;
	x = (x | (x << 4)) & 0x0f0f0f0fu;
	x = (x | (x << 2)) & 0x33333333u;
	x = (x | (x << 1)) & 0x55555555u;
	return x;
}

/* The cell of triangle t's centroid along a Z-order curve. */
static uint32_t morton_cell(const struct asph_scatter *s, size_t t, const double lo[2],
			    const double scale[2], int bits)
{
	uint32_t c[2], top = ((uint32_t)1 << bits) - 1;

	for (int d = 0; d < 2; d++) {
		double x = (s->xy[2 * s->tri[3 * t] + d] + s->xy[2 * s->tri[3 * t + 1] + d] +
			    s->xy[2 * s->tri[3 * t + 2] + d]) / 3;
		double f = (x - lo[d]) * scale[d];
		c[d] = f <= 0 ? 0 : f >= top ? top : (uint32_t)f;
	}
	return spread_bits(c[0]) | (spread_bits(c[1]) << 1);
}

/* Renumbers the triangles along a Z-order curve of their centroids (a
 * counting sort by cell, stable), so that searches at nearby positions
 * read nearby memory: in the triangulation's own order, neighbours in the
 * plane are far apart in the arrays, and a search's steps wait for memory.
 * Each triangle keeps its vertices in their order, and its neighbours
 * stay its neighbours: a search visits the same triangles. */
static int order_triangles(struct asph_scatter *s, struct asph_error *err)
{
	int bits = 1;

	while (bits < MORTON_MAX_BITS && ((size_t)2 << (2 * bits)) < s->n_tri)
		bits++;
	size_t nc = (size_t)1 << (2 * bits);
	_cleanup_free_ uint32_t *start = calloc(nc + 1, sizeof(uint32_t));
	_cleanup_free_ uint32_t *to = malloc(s->n_tri * sizeof(uint32_t) + 1);
	uint32_t *tri = malloc(3 * s->n_tri * sizeof(uint32_t) + 1);
	uint32_t *adj = malloc(3 * s->n_tri * sizeof(uint32_t) + 1);
	double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY }, scale[2];

	if (!start || !to || !tri || !adj) {
		free(tri);
		free(adj);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	mem_advise_huge(start, (nc + 1) * sizeof(uint32_t));
	mem_advise_huge(to, s->n_tri * sizeof(uint32_t));
	mem_advise_huge(tri, 3 * s->n_tri * sizeof(uint32_t));
	mem_advise_huge(adj, 3 * s->n_tri * sizeof(uint32_t));
	for (size_t i = 0; i < s->n; i++)
		for (int d = 0; d < 2; d++) {
			lo[d] = fmin(lo[d], s->xy[2 * i + d]);
			hi[d] = fmax(hi[d], s->xy[2 * i + d]);
		}
	for (int d = 0; d < 2; d++)
		scale[d] = hi[d] > lo[d] ? (double)((size_t)1 << bits) / (hi[d] - lo[d]) : 0;
	for (size_t t = 0; t < s->n_tri; t++) {
		to[t] = morton_cell(s, t, lo, scale, bits);
		start[to[t] + 1]++;
	}
	for (size_t c = 0; c < nc; c++)
		start[c + 1] += start[c];
	for (size_t t = 0; t < s->n_tri; t++)
		to[t] = start[to[t]]++;
	for (size_t t = 0; t < s->n_tri; t++)
		for (int k = 0; k < 3; k++) {
			uint32_t nb = s->adj[3 * t + k];
			tri[3 * (size_t)to[t] + k] = s->tri[3 * t + k];
			adj[3 * (size_t)to[t] + k] = nb == UINT32_MAX ? UINT32_MAX : to[nb];
		}
	free(s->tri);
	free(s->adj);
	s->tri = tri;
	s->adj = adj;
	return 0;
}

static int check_values(const double *value, size_t n, struct asph_error *err)
{
	for (size_t i = 0; i < n; i++)
		if (!isfinite(value[i]))
			return asph_error_set(err, -EINVAL, "point %zu: value is not finite", i);
	return 0;
}

int asph_scatter_set_values(struct asph_scatter *s, const double *value,
			    struct asph_error *err)
{
	int r = check_values(value, s->n, err);

	if (r == 0)
		memcpy(s->value, value, s->n * sizeof(double));
	return r;
}

int asph_scatter_alloc(const double *xy, const double *value, size_t n,
		       const struct asph_scatter_options *opts,
		       struct asph_scatter **out, struct asph_error *err)
{
	struct asph_scatter_options o = { 0 };
	_cleanup_(asph_delaunay_freep) struct asph_delaunay *d = NULL;
	struct asph_scatter *s;
	int r;

	if (opts)
		o = *opts;
	if (!isfinite(o.max_edge_mm) || o.max_edge_mm < 0 || !isfinite(o.max_edge_factor) ||
	    o.max_edge_factor < 0)
		return asph_error_set(err, -EINVAL, "the longest edge must be a positive number");
	r = check_values(value, n, err);
	if (r < 0)
		return r;
	d = asph_delaunay_alloc(n);
	s = calloc(1, sizeof(*s));
	if (!d || !s) {
		free(s);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	s->n = n;
	s->xy = malloc(2 * n * sizeof(double) + 1);
	s->value = malloc(n * sizeof(double) + 1);
	if (!s->xy || !s->value) {
		asph_scatter_free(s);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	mem_advise_huge(s->xy, 2 * n * sizeof(double));
	mem_advise_huge(s->value, n * sizeof(double));
	memcpy(s->xy, xy, 2 * n * sizeof(double));
	memcpy(s->value, value, n * sizeof(double));
	r = asph_delaunay_triangulate(d, xy, n, &s->tri, &s->n_tri, err);
	if (r == 0)
		r = asph_delaunay_neighbors(d, &s->adj, err);
	/* the workspace's memory is not needed for the rest */
	asph_delaunay_free(steal_ptr(d));
	if (r == 0)
		r = order_triangles(s, err);
	if (r == 0)
		r = mark_kept(s, &o, err);
	if (r < 0) {
		asph_scatter_free(s);
		return r;
	}
	*out = s;
	return 0;
}

size_t asph_scatter_n_points(const struct asph_scatter *s)
{
	return s->n;
}

const double *asph_scatter_xy(const struct asph_scatter *s)
{
	return s->xy;
}

const double *asph_scatter_values(const struct asph_scatter *s)
{
	return s->value;
}

double asph_scatter_median_edge(const struct asph_scatter *s)
{
	return s->median_edge;
}

double asph_scatter_max_edge(const struct asph_scatter *s)
{
	return s->max_edge;
}

/* > 0 when p is left of a -> b. */
static double orient(const double *a, const double *b, double x, double y)
{
	return (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]);
}

/* Barycentric weights of (x, y) in triangle t; 1 when all >= 0. */
static int barycentric(const struct asph_scatter *s, size_t t, double x, double y,
		       double w[3])
{
	const double *a = s->xy + 2 * s->tri[3 * t], *b = s->xy + 2 * s->tri[3 * t + 1];
	const double *c = s->xy + 2 * s->tri[3 * t + 2];
	double area = orient(a, b, c[0], c[1]);

	w[0] = orient(b, c, x, y) / area;
	w[1] = orient(c, a, x, y) / area;
	w[2] = 1 - w[0] - w[1];
	return w[0] >= -1e-12 && w[1] >= -1e-12 && w[2] >= -1e-12;
}

/* The triangle holding (x, y) by a visibility walk from *hint; a walk that
 * does not end (it cannot on a Delaunay triangulation, but rounding) falls
 * back to a scan. -1 outside the hull. */
static long locate(const struct asph_scatter *s, double x, double y, uint32_t *hint)
{
	size_t t = *hint < s->n_tri ? *hint : 0;

	for (size_t step = 0; step < s->n_tri + 3; step++) {
		int moved = 0;
		for (int e = 0; e < 3; e++) {
			int k = (int)((e + step) % 3);
			const double *a = s->xy + 2 * s->tri[3 * t + k];
			const double *b = s->xy + 2 * s->tri[3 * t + (k + 1) % 3];
			if (orient(a, b, x, y) < 0) {
				uint32_t nb = s->adj[3 * t + k];
				if (nb == UINT32_MAX)
					return -1;
				t = nb;
				moved = 1;
				break;
			}
		}
		if (!moved) {
			*hint = (uint32_t)t;
			return (long)t;
		}
	}
	for (size_t u = 0; u < s->n_tri; u++) {
		double w[3];
		if (barycentric(s, u, x, y, w)) {
			*hint = (uint32_t)u;
			return (long)u;
		}
	}
	return -1;
}

int asph_scatter_eval(const struct asph_scatter *s, double x, double y,
		      uint32_t *hint, double *value, uint32_t idx[3],
		      double w[3])
{
	uint32_t h0 = 0;
	double ww[3];
	long t;

	*value = NAN;
	if (!isfinite(x) || !isfinite(y))
		return -EDOM;
	t = locate(s, x, y, hint ? hint : &h0);
	if (t < 0 || !s->kept[t])
		return -EDOM;
	barycentric(s, (size_t)t, x, y, ww);
	*value = 0;
	for (int k = 0; k < 3; k++) {
		uint32_t i = s->tri[3 * (size_t)t + k];
		*value += ww[k] * s->value[i];
		if (idx)
			idx[k] = i;
		if (w)
			w[k] = ww[k];
	}
	return 0;
}
