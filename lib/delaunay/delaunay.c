/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Delaunay triangulation by radial sweep (sweep-hull): a seed triangle near
 * the centre of the points, the other points sorted by their distance from
 * its centroid and added one by one (lib/delaunay-mesh.c).
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "asph/delaunay.h"
#include "delaunay-internal.h"
#include "predicates.h"
#include "util-mem.h"

#define MAX_COORD 1e60

/* Buckets of the boundary hash: about as many as boundary vertices. */
static size_t hash_buckets(size_t n)
{
	return (size_t)ceil(sqrt((double)n));
}

struct asph_delaunay *asph_delaunay_alloc(size_t max_points)
{
	if (max_points > ASPH_DELAUNAY_MAX_POINTS) {
		errno = E2BIG;
		return NULL;
	}
	struct asph_delaunay *w = calloc(1, sizeof(*w));
	if (!w)
		return NULL;
	size_t n = max_points < 3 ? 3 : max_points;
	size_t max_tri = 2 * n;

	w->max_points = max_points;
	w->hash_cap = hash_buckets(n);
	w->stack_cap = 32;      /* grows when a legalization needs more */
	w->xy = malloc(2 * n * sizeof(*w->xy));
	w->ids = malloc(n * sizeof(*w->ids));
	w->sort_a = malloc(n * sizeof(*w->sort_a));
	w->sort_b = malloc(n * sizeof(*w->sort_b));
	w->tri = malloc(3 * max_tri * sizeof(*w->tri));
	w->adj = malloc(3 * max_tri * sizeof(*w->adj));
	w->hull_next = malloc(n * sizeof(*w->hull_next));
	w->hull_prev = malloc(n * sizeof(*w->hull_prev));
	w->hull_tri = malloc(n * sizeof(*w->hull_tri));
	w->hash = malloc(w->hash_cap * sizeof(*w->hash));
	w->stack = malloc(w->stack_cap * sizeof(*w->stack));
	if (!w->xy || !w->ids || !w->sort_a || !w->sort_b || !w->tri ||
	    !w->adj || !w->hull_next || !w->hull_prev || !w->hull_tri ||
	    !w->hash || !w->stack) {
		asph_delaunay_free(w);
		errno = ENOMEM;
		return NULL;
	}
	mem_advise_huge(w->xy, 2 * n * sizeof(*w->xy));
	mem_advise_huge(w->ids, n * sizeof(*w->ids));
	mem_advise_huge(w->sort_a, n * sizeof(*w->sort_a));
	mem_advise_huge(w->sort_b, n * sizeof(*w->sort_b));
	mem_advise_huge(w->tri, 3 * max_tri * sizeof(*w->tri));
	mem_advise_huge(w->adj, 3 * max_tri * sizeof(*w->adj));
	mem_advise_huge(w->hull_next, n * sizeof(*w->hull_next));
	mem_advise_huge(w->hull_prev, n * sizeof(*w->hull_prev));
	mem_advise_huge(w->hull_tri, n * sizeof(*w->hull_tri));
	mem_advise_huge(w->hash, w->hash_cap * sizeof(*w->hash));
	return w;
}

void asph_delaunay_free(struct asph_delaunay *w)
{
	if (!w)
		return;
	free(w->xy);
	free(w->ids);
	free(w->sort_a);
	free(w->sort_b);
	free(w->tri);
	free(w->adj);
	free(w->hull_next);
	free(w->hull_prev);
	free(w->hull_tri);
	free(w->hash);
	free(w->stack);
	free(w);
}

static int check_input(const double *xy, size_t n, struct asph_error *err)
{
	for (size_t i = 0; i < 2 * n; i++) {
		if (!(fabs(xy[i]) <= MAX_COORD))
			return asph_error_set(err, -EINVAL,
				"point %zu: coordinate %s is %g (must be finite, magnitude <= %g)",
				i / 2, i % 2 ? "y" : "x", xy[i], MAX_COORD);
	}
	return 0;
}

static inline double dist2(const double *p, double x, double y)
{
	double dx = p[0] - x, dy = p[1] - y;

	return dx * dx + dy * dy;
}

static size_t nearest(const double *xy, size_t n, double x, double y,
		      size_t skip)
{
	size_t best = n;
	double best_d = INFINITY;

	for (size_t i = 0; i < n; i++) {
		const double *p = xy + 2 * i;
		if (i == skip || (skip < n && p[0] == xy[2 * skip] &&
				  p[1] == xy[2 * skip + 1]))
			continue;
		double d = dist2(p, x, y);
		if (d < best_d || best == n) {
			best_d = d;
			best = i;
		}
	}
	return best;
}

/* Squared circumradius of (a, b, c), +inf when they are (nearly) collinear. */
static double circumradius2(const double *a, const double *b, const double *c)
{
	double dx = b[0] - a[0], dy = b[1] - a[1];
	double ex = c[0] - a[0], ey = c[1] - a[1];
	double bl = dx * dx + dy * dy, cl = ex * ex + ey * ey;
	double d = dx * ey - dy * ex;

	if (d == 0)
		return INFINITY;
	double x = (ey * bl - dy * cl) * 0.5 / d;
	double y = (dx * cl - ex * bl) * 0.5 / d;
	double r = x * x + y * y;

	return isfinite(r) ? r : INFINITY;
}

/* The sweep centre: the centroid of the seed triangle. Returns whether it
 * lies strictly inside (star mode, see delaunay-mesh.c); it does unless the
 * triangle is so thin that no double lies inside it. */
static int sweep_centre(const double *a, const double *b, const double *c,
			double out[2])
{
	out[0] = (a[0] + b[0] + c[0]) / 3.0;
	out[1] = (a[1] + b[1] + c[1]) / 3.0;
	return orient2d(a, b, out) > 0 && orient2d(b, c, out) > 0 &&
	       orient2d(c, a, out) > 0;
}

/* The third seed point: the smallest circumcircle with i0 and i1, or any
 * point off their line when every circle is too large to compute. */
static size_t third_seed(const double *xy, size_t n, size_t i0, size_t i1)
{
	const double *a = xy + 2 * i0, *b = xy + 2 * i1;
	size_t best = n;
	double best_r = INFINITY;

	for (size_t i = 0; i < n; i++) {
		double r = circumradius2(a, b, xy + 2 * i);
		if (r < best_r && orient2d(a, b, xy + 2 * i) != 0) {
			best_r = r;
			best = i;
		}
	}
	for (size_t i = 0; best == n && i < n; i++) {
		if (orient2d(a, b, xy + 2 * i) != 0)
			best = i;
	}
	return best;
}

/* Returns 1 for star mode, 0 for convex mode, or a negative errno. */
static int choose_seed(const double *xy, size_t n, size_t seed[3],
		       double centre[2], struct asph_error *err)
{
	double lo[2] = { xy[0], xy[1] }, hi[2] = { xy[0], xy[1] };

	for (size_t i = 1; i < n; i++) {
		for (int k = 0; k < 2; k++) {
			lo[k] = fmin(lo[k], xy[2 * i + k]);
			hi[k] = fmax(hi[k], xy[2 * i + k]);
		}
	}
	size_t i0 = nearest(xy, n, 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), n);
	size_t i1 = nearest(xy, n, xy[2 * i0], xy[2 * i0 + 1], i0);
	if (i1 == n)
		return asph_error_set(err, -EINVAL,
			"all %zu points coincide: a triangulation needs 3 non-collinear points", n);
	size_t i2 = third_seed(xy, n, i0, i1);
	if (i2 == n)
		return asph_error_set(err, -EINVAL,
			"all %zu points are collinear: a triangulation needs 3 non-collinear points", n);
	if (orient2d(xy + 2 * i0, xy + 2 * i1, xy + 2 * i2) < 0) {
		size_t t = i1;
		i1 = i2;
		i2 = t;
	}
	seed[0] = i0;
	seed[1] = i1;
	seed[2] = i2;
	return sweep_centre(xy + 2 * i0, xy + 2 * i1, xy + 2 * i2, centre);
}

/* Float bits of a scaled squared distance in [0, 1]: monotone, 32 bits. */
static inline uint32_t sort_key(double d2)
{
	float f = (float)d2;
	uint32_t k;

	memcpy(&k, &f, sizeof(k));
	return k;
}

/* LSD radix sort of (key << 32 | index) by key, 11 bits a pass. Returns
 * the array that holds the result (a or b). */
static uint64_t *radix_sort(uint64_t *a, uint64_t *b, size_t m)
{
	enum { BITS = 11, BUCKETS = 1 << BITS, PASSES = 3 };
	uint32_t count[PASSES][BUCKETS];

	memset(count, 0, sizeof(count));
	for (size_t i = 0; i < m; i++) {
		uint32_t k = (uint32_t)(a[i] >> 32);
		for (int p = 0; p < PASSES; p++)
			count[p][(k >> (BITS * p)) & (BUCKETS - 1)]++;
	}
	for (int p = 0; p < PASSES; p++) {
		unsigned shift = 32 + BITS * (unsigned)p;
		if (m == 0 || count[p][(a[0] >> shift) & (BUCKETS - 1)] == m)
			continue;       /* one bucket: the pass changes nothing */
		uint32_t sum = 0;
		for (int j = 0; j < BUCKETS; j++) {
			uint32_t c = count[p][j];
			count[p][j] = sum;
			sum += c;
		}
		for (size_t i = 0; i < m; i++)
			b[count[p][(a[i] >> shift) & (BUCKETS - 1)]++] = a[i];
		uint64_t *t = a;
		a = b;
		b = t;
	}
	return a;
}

struct tie_ctx {
	const double *xy;
	double cx, cy;
};

/* By distance, then by x and y, so that equal points end up adjacent. */
static int cmp_distance(const void *x, const void *y, void *arg)
{
	const struct tie_ctx *c = arg;
	const double *p = c->xy + 2 * (uint32_t)*(const uint64_t *)x;
	const double *q = c->xy + 2 * (uint32_t)*(const uint64_t *)y;
	double a = dist2(p, c->cx, c->cy), b = dist2(q, c->cx, c->cy);

	if (a != b)
		return a < b ? -1 : 1;
	if (p[0] != q[0])
		return p[0] < q[0] ? -1 : 1;
	return (p[1] > q[1]) - (p[1] < q[1]);
}

/* Orders each run of equal float keys by the double distance: insertion
 * sort for the short runs of ordinary inputs, qsort for the long runs of
 * cocircular ones. */
static void break_ties(uint64_t *s, size_t m, const double *xy, double cx,
		       double cy)
{
	struct tie_ctx c = { xy, cx, cy };

	for (size_t i = 0; i < m;) {
		size_t j = i + 1;
		while (j < m && (s[j] >> 32) == (s[i] >> 32))
			j++;
		if (j - i > 16) {
			qsort_r(s + i, j - i, sizeof(*s), cmp_distance, &c);
		} else {
			for (size_t k = i + 1; k < j; k++) {
				for (size_t l = k; l > i && cmp_distance(&s[l - 1], &s[l], &c) > 0; l--) {
					uint64_t t = s[l];
					s[l] = s[l - 1];
					s[l - 1] = t;
				}
			}
		}
		i = j;
	}
}

/* Numbers the points in insertion order: the seed, then by distance. */
static void order_points(struct asph_delaunay *w, const double *xy, size_t n,
			 const size_t seed[3])
{
	size_t m = 0;
	double far = 0;

	/* Keys relative to the largest distance cannot overflow a float. */
	for (size_t i = 0; i < n; i++)
		far = fmax(far, dist2(xy + 2 * i, w->cx, w->cy));
	double scale = 1.0 / far;
	if (!isfinite(scale))
		scale = 1.0;
	for (size_t i = 0; i < n; i++) {
		if (i == seed[0] || i == seed[1] || i == seed[2])
			continue;
		uint64_t k = sort_key(scale * dist2(xy + 2 * i, w->cx, w->cy));
		w->sort_a[m++] = k << 32 | (uint64_t)i;
	}
	uint64_t *s = w->sort_a;
	if (!(w->debug_flags & DELAUNAY_KEEP_ORDER)) {
		s = radix_sort(w->sort_a, w->sort_b, m);
		break_ties(s, m, xy, w->cx, w->cy);
	}
	for (size_t k = 0; k < 3; k++)
		w->ids[k] = (uint32_t)seed[k];
	for (size_t k = 0; k < m; k++)
		w->ids[3 + k] = (uint32_t)s[k];
	for (size_t k = 0; k < n; k++) {
		const double *p = xy + 2 * (size_t)w->ids[k];
		w->xy[2 * k] = p[0];
		w->xy[2 * k + 1] = p[1];
		w->hull_next[k] = NONE;
	}
}

static int mesh_error(const struct asph_delaunay *w, int r, uint32_t p,
		      struct asph_error *err)
{
	if (r == -ENOMEM)
		return asph_error_set(err, r, "triangulation: out of memory");
	return asph_error_set(err, r,
		"triangulation: mesh found inconsistent at point %u", w->ids[p]);
}

static int sweep(struct asph_delaunay *w, size_t n, int star,
		 struct asph_error *err)
{
	mesh_init(w, star);
	for (uint32_t p = 3; p < n; p++) {
		const double *a = w->xy + 2 * (size_t)p;
		if (a[0] == a[-2] && a[1] == a[-1])
			continue;       /* duplicate of the point before */
		int r = mesh_insert(w, p);
		if (r < 0)
			return mesh_error(w, r, p, err);
	}
	int r = mesh_finish(w);
	if (r < 0)
		return mesh_error(w, r, 0, err);
	return 0;
}

int asph_delaunay_triangulate(struct asph_delaunay *w, const double *xy,
			      size_t n, uint32_t **triangles,
			      size_t *n_triangles, struct asph_error *err)
{
	size_t seed[3] = { 0, 1, 2 };
	double centre[2] = { 0, 0 };
	int r;

	if (!w || !triangles || !n_triangles || (!xy && n > 0))
		return asph_error_set(err, -EINVAL, "triangulation: missing argument");
	w->valid = 0;
	*triangles = NULL;
	*n_triangles = 0;
	if (n > w->max_points)
		return asph_error_set(err, -E2BIG,
			"triangulation: %zu points, the workspace holds %zu", n,
			w->max_points);
	if (n < 3)
		return asph_error_set(err, -EINVAL,
			"triangulation: %zu points, a triangle needs 3 non-collinear points", n);
	r = check_input(xy, n, err);
	if (r < 0)
		return r;
	int star = choose_seed(xy, n, seed, centre, err);
	if (star < 0)
		return star;
	if (w->debug_flags & DELAUNAY_CONVEX)
		star = 0;
	w->cx = centre[0];
	w->cy = centre[1];
	w->hash_size = hash_buckets(n);
	order_points(w, xy, n, seed);
	r = sweep(w, n, star, err);
	if (r < 0)
		return r;

	uint32_t *out = malloc(3 * w->n_tri * sizeof(*out));
	if (!out)
		return asph_error_set(err, -ENOMEM, "triangulation: out of memory");
	mem_advise_huge(out, 3 * w->n_tri * sizeof(*out));
	for (size_t h = 0; h < 3 * w->n_tri; h++)
		out[h] = w->ids[w->tri[h]];
	w->n_points = n;
	w->valid = 1;
	*triangles = out;
	*n_triangles = w->n_tri;
	return 0;
}

int asph_delaunay_neighbors(const struct asph_delaunay *w,
			    uint32_t **neighbors, struct asph_error *err)
{
	if (!w || !neighbors || !w->valid)
		return asph_error_set(err, -EINVAL,
			"triangulation neighbours: no successful triangulation");
	uint32_t *out = malloc(3 * w->n_tri * sizeof(*out));
	if (!out)
		return asph_error_set(err, -ENOMEM, "triangulation: out of memory");
	mem_advise_huge(out, 3 * w->n_tri * sizeof(*out));
	for (size_t h = 0; h < 3 * w->n_tri; h++)
		out[h] = w->adj[h] == NONE ? UINT32_MAX : w->adj[h] / 3;
	*neighbors = out;
	return 0;
}

int asph_delaunay_hull(const struct asph_delaunay *w, uint32_t **hull,
		       size_t *n_hull, struct asph_error *err)
{
	if (!w || !hull || !n_hull || !w->valid)
		return asph_error_set(err, -EINVAL,
			"triangulation hull: no successful triangulation");
	size_t m = 0;
	uint32_t v = w->hull_start;
	do {
		m++;
		v = w->hull_next[v];
	} while (v != w->hull_start);
	uint32_t *out = malloc(m * sizeof(*out));
	if (!out)
		return asph_error_set(err, -ENOMEM, "triangulation: out of memory");
	for (size_t k = 0; k < m; k++) {
		out[k] = w->ids[v];
		v = w->hull_next[v];
	}
	*hull = out;
	*n_hull = m;
	return 0;
}
