/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Predicates against exact integer arithmetic; triangulations checked with
 * the exact predicates (every triangle counter-clockwise, every interior
 * edge locally Delaunay, the boundary equal to the convex hull, Euler's
 * count) and, when Qhull is there, against Qhull's triangles.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "config.h"
#include "asph/delaunay.h"
#include "delaunay-internal.h"
#include "predicates.h"

#if HAVE_QHULL
#include <libqhull_r/qhull_ra.h>
#endif

/* ---- exact reference: 384-bit two's-complement integers ---- */

#define LIMBS 12

struct big {
	uint32_t d[LIMBS];
};

static struct big big_from(int64_t v)
{
	struct big r;
	uint64_t u = (uint64_t)v;

	r.d[0] = (uint32_t)u;
	r.d[1] = (uint32_t)(u >> 32);
	for (int i = 2; i < LIMBS; i++)
		r.d[i] = v < 0 ? UINT32_MAX : 0;
	return r;
}

static struct big big_add(struct big a, struct big b)
{
	struct big r;
	uint64_t carry = 0;

	for (int i = 0; i < LIMBS; i++) {
		uint64_t t = (uint64_t)a.d[i] + b.d[i] + carry;
		r.d[i] = (uint32_t)t;
		carry = t >> 32;
	}
	return r;
}

static struct big big_neg(struct big a)
{
	for (int i = 0; i < LIMBS; i++)
		a.d[i] = ~a.d[i];
	return big_add(a, big_from(1));
}

static struct big big_sub(struct big a, struct big b)
{
	return big_add(a, big_neg(b));
}

static struct big big_mul(struct big a, struct big b)
{
	struct big r;

	memset(&r, 0, sizeof(r));
	for (int i = 0; i < LIMBS; i++) {
		uint64_t carry = 0;
		for (int j = 0; i + j < LIMBS; j++) {
			uint64_t t = (uint64_t)r.d[i + j] +
				     (uint64_t)a.d[i] * b.d[j] + carry;
			r.d[i + j] = (uint32_t)t;
			carry = t >> 32;
		}
	}
	return r;
}

static int big_sign(struct big a)
{
	if (a.d[LIMBS - 1] & 0x80000000u)
		return -1;
	for (int i = 0; i < LIMBS; i++) {
		if (a.d[i])
			return 1;
	}
	return 0;
}

static struct big big_shl(struct big a, int s)
{
	struct big r;

	for (int i = LIMBS - 1; i >= 0; i--) {
		int from = i - s / 32;
		uint64_t hi = from >= 0 ? a.d[from] : 0;
		uint64_t lo = from >= 1 ? a.d[from - 1] : 0;
		r.d[i] = (uint32_t)(((hi << 32 | lo) << (s % 32)) >> 32);
	}
	return r;
}

/* x as an integer multiple of 2^-k; the test inputs are chosen so that
 * this is exact and fits (below 2^100). */
static struct big units(double x, int k)
{
	int e;
	int64_t m = (int64_t)ldexp(frexp(x, &e), 53);   /* x = m 2^(e - 53) */
	int shift = e - 53 + k;

	while (shift < 0 && m % 2 == 0 && m != 0) {
		m /= 2;
		shift++;
	}
	if (m == 0)
		return big_from(0);
	assert_true(shift >= 0 && e + k <= 100);
	return big_shl(big_from(m), shift);
}

static int exact_orient(const double *a, const double *b, const double *c,
			int k)
{
	struct big acx = big_sub(units(a[0], k), units(c[0], k));
	struct big acy = big_sub(units(a[1], k), units(c[1], k));
	struct big bcx = big_sub(units(b[0], k), units(c[0], k));
	struct big bcy = big_sub(units(b[1], k), units(c[1], k));

	return big_sign(big_sub(big_mul(acx, bcy), big_mul(acy, bcx)));
}

static int exact_incircle(const double *a, const double *b, const double *c,
			  const double *d, int k)
{
	const double *p[3] = { a, b, c };
	struct big x[3], y[3], lift[3];

	for (int i = 0; i < 3; i++) {
		x[i] = big_sub(units(p[i][0], k), units(d[0], k));
		y[i] = big_sub(units(p[i][1], k), units(d[1], k));
		lift[i] = big_add(big_mul(x[i], x[i]), big_mul(y[i], y[i]));
	}
	struct big det = big_from(0);
	for (int i = 0; i < 3; i++) {
		int j = (i + 1) % 3, l = (i + 2) % 3;
		struct big m = big_sub(big_mul(x[j], y[l]), big_mul(y[j], x[l]));
		det = big_add(det, big_mul(lift[i], m));
	}
	return big_sign(det);
}

static int sgn(double v)
{
	return (v > 0) - (v < 0);
}

/* ---- deterministic random numbers (splitmix64) ---- */

static uint64_t rng_state = 0x9e3779b97f4a7c15u;

static uint64_t rng_next(void)
{
	uint64_t z = (rng_state += 0x9e3779b97f4a7c15u);

	z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9u;
	z = (z ^ (z >> 27)) * 0x94d049bb133111ebu;
	return z ^ (z >> 31);
}

static double rng_uniform(void)
{
	return (double)(rng_next() >> 11) * 0x1p-53;
}

/* ---- predicates ---- */

/* The classic near-line grid: a = (0.5 + i u, 0.5 + j u) against the line
 * through (12, 12) and (24, 24), u the spacing of doubles near 0.5. The
 * naive determinant gets many of these signs wrong. */
static void test_orient_near_line_grid(void **state)
{
	const double u = 0x1p-53;
	const double b[2] = { 12, 12 }, c[2] = { 24, 24 };
	int positive = 0, negative = 0, zero = 0;

	for (int i = 0; i < 256; i++) {
		for (int j = 0; j < 256; j++) {
			double a[2] = { 0.5 + i * u, 0.5 + j * u };
			int ref = exact_orient(a, b, c, 53);
			assert_int_equal(sgn(orient2d(a, b, c)), ref);
			assert_int_equal(sgn(orient2d_exact(a, b, c)), ref);
			assert_int_equal(sgn(orient2d(b, c, a)), ref);
			assert_int_equal(sgn(orient2d(c, b, a)), -ref);
			positive += ref > 0;
			negative += ref < 0;
			zero += ref == 0;
		}
	}
	/* The grid straddles the line: all three outcomes occur. */
	assert_int_equal(zero, 256);
	assert_true(positive > 1000 && negative > 1000);
}

/* Points a + t (b - a) rounded to doubles: collinear up to one rounding,
 * far from the origin and at 1e-15 scale perturbations. */
static void test_orient_random_near_collinear(void **state)
{
	for (int trial = 0; trial < 20000; trial++) {
		double a[2] = { 0.25 + 3 * rng_uniform(), 0.25 + 3 * rng_uniform() };
		double b[2] = { 0.25 + 3 * rng_uniform(), 0.25 + 3 * rng_uniform() };
		double t = 2 * rng_uniform() - 0.5;
		double c[2] = { a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]) };

		if (trial % 3 == 0)
			c[0] += ((int)(rng_next() % 7) - 3) * 1e-15;
		if (!(fabs(c[0]) >= 0.25 && fabs(c[0]) < 4 && fabs(c[1]) >= 0.25 &&
		      fabs(c[1]) < 4))
			continue;
		int ref = exact_orient(a, b, c, 60);
		assert_int_equal(sgn(orient2d(a, b, c)), ref);
		assert_int_equal(sgn(orient2d_exact(a, b, c)), ref);
		assert_int_equal(sgn(orient2d(c, a, b)), ref);
	}
}

/* Integer points of the circle x^2 + y^2 = 65^2 (exactly cocircular) at a
 * tiny unit on top of a large high-entropy offset, some moved by one unit
 * in or out. The signs follow from the integers alone: the determinant is
 * invariant under translation and scales as unit^4. */
static void test_incircle_cocircular_offset(void **state)
{
	static const int circle[][2] = {
		{ 16, 63 }, { -25, 60 }, { -33, -56 }, { 39, -52 }, { 63, 16 },
		{ -52, 39 }, { 0, -65 }, { 56, 33 }, { -60, -25 }, { 65, 0 },
	};
	const struct {
		double base;
		int k;
	} frames[] = {
		{ 0.7391085133, 45 }, { 1234.5678901, 42 }, { -377.21, 44 },
	};

	for (size_t f = 0; f < sizeof(frames) / sizeof(frames[0]); f++) {
		double unit = ldexp(1.0, -frames[f].k);
		double bx = ldexp(round(ldexp(frames[f].base, frames[f].k)), -frames[f].k);
		double by = ldexp(round(ldexp(-0.5 * frames[f].base, frames[f].k)), -frames[f].k);
		for (int trial = 0; trial < 1000; trial++) {
			double p[4][2];
			for (int i = 0; i < 4; i++) {
				int s = (int)(rng_next() % 10);
				int dx = 0, dy = 0;
				if (i == 3 && trial % 2) {
					dx = (int)(rng_next() % 3) - 1;
					dy = (int)(rng_next() % 3) - 1;
				}
				p[i][0] = bx + (circle[s][0] + dx) * unit;
				p[i][1] = by + (circle[s][1] + dy) * unit;
			}
			int ref = exact_incircle(p[0], p[1], p[2], p[3], frames[f].k);
			assert_int_equal(sgn(incircle(p[0], p[1], p[2], p[3])), ref);
			assert_int_equal(sgn(incircle_exact(p[0], p[1], p[2], p[3])), ref);
		}
	}
}

/* Points on a circle rounded to doubles (nearly cocircular), plus a fourth
 * point 1e-15 off the circle in either direction. */
static void test_incircle_near_cocircular(void **state)
{
	int outcomes[3] = { 0, 0, 0 };

	for (int trial = 0; trial < 4000; trial++) {
		double cx = 1.5 + rng_uniform(), cy = 1.75 + rng_uniform();
		double r = 0.3 + 0.5 * rng_uniform();
		double p[4][2];
		for (int i = 0; i < 4; i++) {
			double th = 2 * M_PI * rng_uniform();
			double rr = r;
			if (i == 3)
				rr += ((int)(rng_next() % 5) - 2) * 1e-15;
			p[i][0] = cx + rr * cos(th);
			p[i][1] = cy + rr * sin(th);
		}
		int ref = exact_incircle(p[0], p[1], p[2], p[3], 60);
		assert_int_equal(sgn(incircle(p[0], p[1], p[2], p[3])), ref);
		assert_int_equal(sgn(incircle_exact(p[0], p[1], p[2], p[3])), ref);
		assert_int_equal(sgn(incircle(p[1], p[2], p[0], p[3])), ref);
		assert_int_equal(sgn(incircle(p[1], p[0], p[2], p[3])), -ref);
		outcomes[ref + 1]++;
	}
	assert_true(outcomes[0] > 20 && outcomes[2] > 20);
}

/* Isosceles trapezoids (x1, y1), (-x1, y1), (-x2, y2), (x2, y2) are exactly
 * cocircular for any doubles; with coordinates of very different
 * magnitudes their differences are not doubles, which defeats every stage
 * short of the exact one. Half of them get one coordinate moved by an ulp. */
static void test_incircle_trapezoids(void **state)
{
	int outcomes[3] = { 0, 0, 0 };

	for (int trial = 0; trial < 3000; trial++) {
		double v[4];
		for (int i = 0; i < 4; i++) {
			double m = 0.25 + rng_uniform();
			v[i] = ldexp(rng_next() % 2 ? m : -m, -(int)(rng_next() % 3) * 10);
		}
		double p[4][2] = { { v[0], v[1] }, { -v[0], v[1] },
				   { -v[2], v[3] }, { v[2], v[3] } };
		for (int i = 3; i > 0; i--) {
			int j = (int)(rng_next() % (uint64_t)(i + 1));
			for (int k = 0; k < 2; k++) {
				double t = p[i][k];
				p[i][k] = p[j][k];
				p[j][k] = t;
			}
		}
		if (trial % 2) {
			double *x = &p[rng_next() % 4][rng_next() % 2];
			*x = nextafter(*x, rng_next() % 2 ? 4.0 : -4.0);
		}
		int ref = exact_incircle(p[0], p[1], p[2], p[3], 76);
		assert_int_equal(sgn(incircle(p[0], p[1], p[2], p[3])), ref);
		assert_int_equal(sgn(incircle_exact(p[0], p[1], p[2], p[3])), ref);
		assert_int_equal(sgn(incircle(p[2], p[0], p[1], p[3])), ref);
		outcomes[ref + 1]++;
	}
	assert_true(outcomes[1] >= 1400);
	assert_true(outcomes[0] > 300 && outcomes[2] > 300);
}

/* Repeated points and points on a common line give exact zeros. */
static void test_predicates_exact_zero(void **state)
{
	for (int trial = 0; trial < 2000; trial++) {
		double a[2] = { 0.5 + rng_uniform(), 0.5 + rng_uniform() };
		double b[2] = { 0.5 + rng_uniform(), 0.5 + rng_uniform() };
		double c[2] = { 0.5 + rng_uniform(), 0.5 + rng_uniform() };
		assert_true(orient2d(a, b, a) == 0);
		assert_true(incircle(a, b, c, a) == 0);
		assert_true(incircle(a, b, c, c) == 0);
		/* mid-points of dyadic coordinates are exact */
		double m[2] = { 0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]) };
		assert_int_equal(sgn(orient2d(a, b, m)), exact_orient(a, b, m, 60));
	}
}

/* ---- triangulation checks ---- */

struct dedge {
	uint32_t a, b, t, k;
};

static int cmp_dedge(const void *x, const void *y)
{
	const struct dedge *p = x, *q = y;

	if (p->a != q->a)
		return p->a < q->a ? -1 : 1;
	if (p->b != q->b)
		return p->b < q->b ? -1 : 1;
	return 0;
}

static const struct dedge *find_dedge(const struct dedge *e, size_t m,
				      uint32_t a, uint32_t b)
{
	struct dedge key = { a, b, 0, 0 };

	return bsearch(&key, e, m, sizeof(*e), cmp_dedge);
}

static const double *P(const double *xy, uint32_t i)
{
	return xy + 2 * (size_t)i;
}

static int cmp_point(const void *x, const void *y, void *ctx)
{
	const double *xy = ctx;
	const double *p = P(xy, *(const uint32_t *)x), *q = P(xy, *(const uint32_t *)y);

	if (p[0] != q[0])
		return p[0] < q[0] ? -1 : 1;
	if (p[1] != q[1])
		return p[1] < q[1] ? -1 : 1;
	return 0;
}

/* Number of distinct points; checks that exactly one point of each set of
 * equal points is a vertex. */
static size_t check_vertices(const double *xy, size_t n, const uint32_t *tri,
			     size_t nt)
{
	uint32_t *idx = malloc(n * sizeof(*idx));
	uint8_t *used = calloc(n, 1);
	size_t distinct = 0;

	assert_non_null(idx);
	assert_non_null(used);
	for (size_t h = 0; h < 3 * nt; h++) {
		assert_true(tri[h] < n);
		used[tri[h]] = 1;
	}
	for (size_t i = 0; i < n; i++)
		idx[i] = (uint32_t)i;
	qsort_r(idx, n, sizeof(*idx), cmp_point, (void *)xy);
	for (size_t i = 0; i < n;) {
		size_t j = i, in_mesh = 0;
		while (j < n && cmp_point(&idx[i], &idx[j], (void *)xy) == 0)
			in_mesh += used[idx[j++]];
		assert_int_equal(in_mesh, 1);
		distinct++;
		i = j;
	}
	free(idx);
	free(used);
	return distinct;
}

/* Everything a Delaunay triangulation of the points must satisfy, decided
 * with exact arithmetic. Returns the number of triangles checked. */
static size_t check_mesh(struct asph_delaunay *w, const double *xy, size_t n,
			 const uint32_t *tri, size_t nt)
{
	struct dedge *e = malloc(3 * nt * sizeof(*e));
	uint32_t *nbr = NULL, *hull = NULL;
	size_t nh = 0, boundary = 0;

	assert_non_null(e);
	for (uint32_t t = 0; t < nt; t++) {
		const uint32_t *v = tri + 3 * (size_t)t;
		assert_true(orient2d_exact(P(xy, v[0]), P(xy, v[1]), P(xy, v[2])) > 0);
		for (uint32_t k = 0; k < 3; k++)
			e[3 * t + k] = (struct dedge){ v[k], v[(k + 1) % 3], t, k };
	}
	qsort(e, 3 * nt, sizeof(*e), cmp_dedge);
	for (size_t i = 1; i < 3 * nt; i++)
		assert_true(cmp_dedge(&e[i - 1], &e[i]) != 0);

	assert_int_equal(asph_delaunay_neighbors(w, &nbr, NULL), 0);
	for (size_t i = 0; i < 3 * nt; i++) {
		const struct dedge *r = find_dedge(e, 3 * nt, e[i].b, e[i].a);
		uint32_t t = e[i].t;
		if (!r) {
			boundary++;
			assert_int_equal(nbr[3 * t + e[i].k], UINT32_MAX);
			continue;
		}
		assert_int_equal(nbr[3 * t + e[i].k], r->t);
		uint32_t c = tri[3 * t + (e[i].k + 2) % 3];
		uint32_t d = tri[3 * r->t + (r->k + 2) % 3];
		assert_true(incircle_exact(P(xy, e[i].a), P(xy, e[i].b), P(xy, c),
					   P(xy, d)) <= 0);
	}

	assert_int_equal(asph_delaunay_hull(w, &hull, &nh, NULL), 0);
	assert_int_equal(nh, boundary);
	for (size_t i = 0; i < nh; i++) {
		uint32_t a = hull[i], b = hull[(i + 1) % nh], c = hull[(i + 2) % nh];
		assert_non_null(find_dedge(e, 3 * nt, a, b));
		assert_true(orient2d_exact(P(xy, a), P(xy, b), P(xy, c)) >= 0);
	}
	size_t distinct = check_vertices(xy, n, tri, nt);
	assert_int_equal(nt, 2 * distinct - 2 - nh);
	free(e);
	free(nbr);
	free(hull);
	return nt;
}

/* The empty-circle property against every vertex (small meshes only; the
 * adaptive predicate, whose signs are checked against integers above). */
static void check_empty_circles(const double *xy, const uint32_t *tri,
				size_t nt, const uint32_t *verts, size_t nv)
{
	for (size_t t = 0; t < nt; t++) {
		const uint32_t *v = tri + 3 * t;
		for (size_t i = 0; i < nv; i++)
			assert_true(incircle(P(xy, v[0]), P(xy, v[1]), P(xy, v[2]),
					     P(xy, verts[i])) <= 0);
	}
}

static size_t triangulate_and_check(struct asph_delaunay *w, const double *xy,
				    size_t n, int brute_force)
{
	uint32_t *tri = NULL;
	size_t nt = 0;
	struct asph_error err = { 0 };

	int r = asph_delaunay_triangulate(w, xy, n, &tri, &nt, &err);
	if (r)
		fail_msg("triangulate: %d %s", r, err.message);
	check_mesh(w, xy, n, tri, nt);
	if (brute_force) {
		uint32_t *all = malloc(n * sizeof(*all));
		assert_non_null(all);
		for (size_t i = 0; i < n; i++)
			all[i] = (uint32_t)i;
		check_empty_circles(xy, tri, nt, all, n);
		free(all);
	}
	free(tri);
	return nt;
}

static double *random_points(size_t n, double x0, double y0, double sx,
			     double sy)
{
	double *xy = malloc(2 * n * sizeof(*xy));

	assert_non_null(xy);
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = x0 + sx * rng_uniform();
		xy[2 * i + 1] = y0 + sy * rng_uniform();
	}
	return xy;
}

static void shuffle_points(double *xy, size_t n)
{
	for (size_t i = n - 1; i > 0; i--) {
		size_t j = rng_next() % (i + 1);
		double tx = xy[2 * i], ty = xy[2 * i + 1];
		xy[2 * i] = xy[2 * j];
		xy[2 * i + 1] = xy[2 * j + 1];
		xy[2 * j] = tx;
		xy[2 * j + 1] = ty;
	}
}

static void test_random(void **state)
{
	struct asph_delaunay *w = asph_delaunay_alloc(5000);

	assert_non_null(w);
	for (int k = 0; k < 4; k++) {
		size_t n = k == 0 ? 200 : 1000 + 1300 * (size_t)k;
		double *xy = random_points(n, -3.71 + k, 1.93, 7.3, 2.9 + k);
		triangulate_and_check(w, xy, n, n <= 200);
		free(xy);
	}
	asph_delaunay_free(w);
}

/* A lattice with a high-entropy spacing and offset: every unit square is
 * cocircular, and so are many larger sets. */
static void test_grid(void **state)
{
	const size_t side = 31, n = side * side;
	struct asph_delaunay *w = asph_delaunay_alloc(n);
	double *xy = malloc(2 * n * sizeof(*xy));

	assert_non_null(w);
	assert_non_null(xy);
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = 17.3125 + 0.375 * (double)(i % side);
		xy[2 * i + 1] = -4.8125 + 0.375 * (double)(i / side);
	}
	size_t nt = triangulate_and_check(w, xy, n, 1);
	assert_int_equal(nt, 2 * (side - 1) * (side - 1));
	shuffle_points(xy, n);
	nt = triangulate_and_check(w, xy, n, 0);
	assert_int_equal(nt, 2 * (side - 1) * (side - 1));
	free(xy);
	asph_delaunay_free(w);
}

/* Points on one circle (all cocircular) and concentric rings. */
static void test_circles(void **state)
{
	const size_t n = 720;
	struct asph_delaunay *w = asph_delaunay_alloc(n);
	double *xy = malloc(2 * n * sizeof(*xy));

	assert_non_null(w);
	assert_non_null(xy);
	/* x^2 + y^2 = 65^2 has 12 integer points per quadrant pair; scaled by
	 * a power of two they stay exactly cocircular */
	static const int q[][2] = { { 16, 63 }, { 25, 60 }, { 33, 56 }, { 39, 52 },
				    { 52, 39 }, { 56, 33 }, { 60, 25 }, { 63, 16 },
				    { 65, 0 }, { 0, 65 } };
	size_t m = 0;
	for (size_t i = 0; i < 10; i++) {
		for (int sx = -1; sx <= 1; sx += 2) {
			for (int sy = -1; sy <= 1; sy += 2) {
				xy[2 * m] = 3.25 + sx * q[i][0] * 0x1p-5;
				xy[2 * m + 1] = -1.5 + sy * q[i][1] * 0x1p-5;
				m++;
			}
		}
	}
	triangulate_and_check(w, xy, m, 1);

	for (size_t i = 0; i < n; i++) {
		double r = 0.7 + 0.3 * (double)(i / 60);
		double th = 2 * M_PI * (double)(i % 60) / 60.0;
		xy[2 * i] = 1.234 + r * cos(th);
		xy[2 * i + 1] = -0.567 + r * sin(th);
	}
	triangulate_and_check(w, xy, n, 1);
	free(xy);
	asph_delaunay_free(w);
}

/* Copies of points (up to four of each), shuffled: one of each enters. */
static void test_duplicates(void **state)
{
	const size_t base = 400;
	double *xy = random_points(4 * base, 0.61, -2.2, 3.3, 1.7);
	size_t n = base;
	struct asph_delaunay *w = asph_delaunay_alloc(4 * base);

	assert_non_null(w);
	for (size_t i = 0; i < base; i++) {
		size_t copies = rng_next() % 4;
		for (size_t c = 0; c < copies; c++) {
			xy[2 * n] = xy[2 * i];
			xy[2 * n + 1] = xy[2 * i + 1];
			n++;
		}
	}
	shuffle_points(xy, n);
	triangulate_and_check(w, xy, n, 0);

	/* a grid given twice */
	for (size_t i = 0; i < 2 * 400; i++) {
		xy[2 * i] = 0.5 * (double)(i % 20) + 0.11;
		xy[2 * i + 1] = 0.5 * (double)((i / 20) % 20) - 7.9;
	}
	shuffle_points(xy, 800);
	assert_int_equal(triangulate_and_check(w, xy, 800, 0), 2 * 19 * 19);
	free(xy);
	asph_delaunay_free(w);
}

/* Collinear runs: on the hull, across the interior, and near-collinear
 * points 1e-15 off a line. */
static void test_collinear(void **state)
{
	const size_t n = 301;
	double *xy = malloc(2 * n * sizeof(*xy));
	struct asph_delaunay *w = asph_delaunay_alloc(n);

	assert_non_null(xy);
	assert_non_null(w);
	/* 300 points on a line and one off it: a fan, every point on the hull */
	for (size_t i = 0; i < n - 1; i++) {
		xy[2 * i] = 1.125 + 0.0625 * (double)i;
		xy[2 * i + 1] = 2.375 - 0.03125 * (double)i;
	}
	xy[2 * (n - 1)] = 5.7;
	xy[2 * (n - 1) + 1] = 9.1;
	shuffle_points(xy, n);
	assert_int_equal(triangulate_and_check(w, xy, n, 1), n - 2);

	/* three crossing lines through a common point */
	for (size_t i = 0; i < n; i++) {
		double t = (double)(i / 3) * 0.125 - 6.25;
		switch (i % 3) {
		case 0: xy[2 * i] = t; xy[2 * i + 1] = 0.75; break;
		case 1: xy[2 * i] = 0.5; xy[2 * i + 1] = t; break;
		default: xy[2 * i] = t + 0.5; xy[2 * i + 1] = t + 0.75; break;
		}
	}
	triangulate_and_check(w, xy, n, 1);

	/* a line with one point a unit in the last place off it: the only
	 * triangles are needles too thin to hold a double inside */
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = 0.25 * (double)i + 3.0;
		xy[2 * i + 1] = 0.5 * (double)i + 6.0;
	}
	xy[2 * 17 + 1] = nextafter(xy[2 * 17 + 1], 100.0);
	shuffle_points(xy, n);
	assert_int_equal(triangulate_and_check(w, xy, n, 1), n - 2);

	/* a line of points with 1e-15 perturbations */
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = 0.3 + 0.01 * (double)i;
		xy[2 * i + 1] = 0.7 + 0.02 * (double)i +
				((int)(rng_next() % 3) - 1) * 1e-15;
	}
	triangulate_and_check(w, xy, n, 1);
	free(xy);
	asph_delaunay_free(w);
}

/* A lattice perturbed at the 1e-15 level: almost cocircular everywhere. */
static void test_perturbed_grid(void **state)
{
	const size_t side = 25, n = side * side;
	double *xy = malloc(2 * n * sizeof(*xy));
	struct asph_delaunay *w = asph_delaunay_alloc(n);

	assert_non_null(xy);
	assert_non_null(w);
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = 0.7 + 0.01 * (double)(i % side) +
			    ((int)(rng_next() % 5) - 2) * 1e-15;
		xy[2 * i + 1] = 0.9 + 0.01 * (double)(i / side) +
				((int)(rng_next() % 5) - 2) * 1e-15;
	}
	triangulate_and_check(w, xy, n, 1);
	free(xy);
	asph_delaunay_free(w);
}

/* The layout of a sampling plan: the planar circle involute (paper Eq. 5)
 * at equal arc length 2 pi s0, inside a disk. */
static void test_involute(void **state)
{
	const double R = 20.0;
	const size_t n = 3000;
	double s0 = R / sqrt(4 * M_PI * (double)n + 1);
	double *xy = malloc(2 * n * sizeof(*xy));
	struct asph_delaunay *w = asph_delaunay_alloc(n);

	assert_non_null(xy);
	assert_non_null(w);
	for (size_t k = 0; k < n; k++) {
		double t = 2 * s0 * sqrt(M_PI * (double)k), phi = t / s0;
		xy[2 * k] = s0 * cos(phi) + t * sin(phi);
		xy[2 * k + 1] = s0 * sin(phi) - t * cos(phi);
	}
	triangulate_and_check(w, xy, n, 0);
	free(xy);
	asph_delaunay_free(w);
}

static int cmp_triangle(const void *x, const void *y)
{
	const uint32_t *a = x, *b = y;

	for (int i = 0; i < 3; i++) {
		if (a[i] != b[i])
			return a[i] < b[i] ? -1 : 1;
	}
	return 0;
}

/* Sorts each triangle's vertices, then the triangles. */
static void canonical(uint32_t *tri, size_t nt)
{
	for (size_t t = 0; t < nt; t++) {
		uint32_t *v = tri + 3 * t;
		for (int pass = 0; pass < 2; pass++) {
			for (int i = 0; i < 2; i++) {
				if (v[i] > v[i + 1]) {
					uint32_t s = v[i];
					v[i] = v[i + 1];
					v[i + 1] = s;
				}
			}
		}
	}
	qsort(tri, nt, 3 * sizeof(*tri), cmp_triangle);
}

/* Insertion in input order (most points then fall inside the mesh and are
 * located by a walk) and the convex-front mode, on every kind of input;
 * random points must give the same triangles as the sorted sweep. */
static void test_other_insertion_paths(void **state)
{
	const unsigned modes[] = { DELAUNAY_KEEP_ORDER, DELAUNAY_CONVEX,
				   DELAUNAY_KEEP_ORDER | DELAUNAY_CONVEX };
	const size_t n = 900;
	struct asph_delaunay *w = asph_delaunay_alloc(n);
	double *xy = malloc(2 * n * sizeof(*xy));

	assert_non_null(w);
	assert_non_null(xy);
	for (size_t m = 0; m < sizeof(modes) / sizeof(modes[0]); m++) {
		double *rnd = random_points(n, -1.37, 2.71, 3.9, 2.2);
		uint32_t *ref = NULL, *tri = NULL;
		size_t nref = 0, nt = 0;

		w->debug_flags = 0;
		assert_int_equal(asph_delaunay_triangulate(w, rnd, n, &ref, &nref, NULL), 0);
		w->debug_flags = modes[m];
		triangulate_and_check(w, rnd, n, 0);
		assert_int_equal(asph_delaunay_triangulate(w, rnd, n, &tri, &nt, NULL), 0);
		assert_int_equal(nt, nref);
		canonical(ref, nref);
		canonical(tri, nt);
		assert_memory_equal(ref, tri, 3 * nt * sizeof(*tri));
		free(ref);
		free(tri);
		free(rnd);

		/* a lattice, shuffled, with a third of it repeated */
		for (size_t i = 0; i < n; i++) {
			size_t j = i < 600 ? i : i - 600;
			xy[2 * i] = 2.5 + 0.125 * (double)(j % 25);
			xy[2 * i + 1] = -1.0 + 0.25 * (double)(j / 25);
		}
		shuffle_points(xy, n);
		assert_int_equal(triangulate_and_check(w, xy, n, 1), 2 * 24 * 23);

		/* concentric rings */
		for (size_t i = 0; i < n; i++) {
			double r = 0.4 + 0.2 * (double)(i / 90);
			double th = 2 * M_PI * (double)(i % 90) / 90.0;
			xy[2 * i] = -3.3 + r * cos(th);
			xy[2 * i + 1] = 0.8 + r * sin(th);
		}
		triangulate_and_check(w, xy, n, 1);
	}
	asph_delaunay_free(w);
	free(xy);
}

static void test_errors(void **state)
{
	struct asph_delaunay *w = asph_delaunay_alloc(10);
	struct asph_error err = { 0 };
	uint32_t *tri = NULL;
	size_t nt = 0;
	double xy[22];

	assert_non_null(w);
	for (int i = 0; i < 11; i++) {
		xy[2 * i] = 0.25 * i + 1.5;
		xy[2 * i + 1] = -0.5 * i + 2.75;
	}
	assert_int_equal(asph_delaunay_triangulate(w, xy, 11, &tri, &nt, &err), -E2BIG);
	assert_int_equal(err.code, -E2BIG);
	assert_int_equal(asph_delaunay_triangulate(w, xy, 2, &tri, &nt, &err), -EINVAL);
	assert_int_equal(asph_delaunay_triangulate(w, xy, 10, &tri, &nt, &err), -EINVAL);
	assert_non_null(strstr(err.message, "collinear"));
	assert_null(tri);
	assert_int_equal(asph_delaunay_hull(w, &tri, &nt, NULL), -EINVAL);
	for (int i = 0; i < 10; i++) {
		xy[2 * i] = 3.5;
		xy[2 * i + 1] = -1.25;
	}
	assert_int_equal(asph_delaunay_triangulate(w, xy, 10, &tri, &nt, &err), -EINVAL);
	assert_non_null(strstr(err.message, "coincide"));
	xy[7] = NAN;
	assert_int_equal(asph_delaunay_triangulate(w, xy, 10, &tri, &nt, &err), -EINVAL);
	assert_non_null(strstr(err.message, "point 3"));
	xy[7] = 1e300;
	assert_int_equal(asph_delaunay_triangulate(w, xy, 10, &tri, &nt, &err), -EINVAL);
	/* three points, given twice each: one triangle */
	double t[] = { 0.1, 0.2, 1.3, 0.2, 0.1, 0.2, 0.4, 1.9, 1.3, 0.2, 0.4, 1.9 };
	assert_int_equal(asph_delaunay_triangulate(w, t, 6, &tri, &nt, &err), 0);
	assert_int_equal(nt, 1);
	free(tri);
	asph_delaunay_free(w);
	assert_null(asph_delaunay_alloc(ASPH_DELAUNAY_MAX_POINTS + 1));
	asph_delaunay_free(NULL);
}

#if HAVE_QHULL
static uint32_t *qhull_triangles(const double *xy, size_t n, size_t *nt)
{
	qhT qh_qh;
	qhT *qh = &qh_qh;
	char flags[] = "qhull d Qt Qbb Qc Qz Q12";
	double *pts = malloc(2 * n * sizeof(*pts));
	uint32_t *out = NULL;
	size_t m = 0;

	assert_non_null(pts);
	memcpy(pts, xy, 2 * n * sizeof(*pts));
	qh_zero(qh, stderr);
	int exitcode = qh_new_qhull(qh, 2, (int)n, pts, False, flags, NULL, stderr);
	assert_int_equal(exitcode, 0);
	facetT *facet;
	vertexT *vertex, **vertexp;
	FORALLfacets {
		if (!facet->upperdelaunay)
			m++;
	}
	out = malloc(3 * m * sizeof(*out));
	assert_non_null(out);
	m = 0;
	FORALLfacets {
		if (facet->upperdelaunay)
			continue;
		int k = 0;
		FOREACHvertex_(facet->vertices) {
			assert_true(k < 3);
			out[3 * m + k++] = (uint32_t)qh_pointid(qh, vertex->point);
		}
		m++;
	}
	qh_freeqhull(qh, !qh_ALL);
	int curlong, totlong;
	qh_memfreeshort(qh, &curlong, &totlong);
	free(pts);
	*nt = m;
	return out;
}

/* Random points are in general position: the Delaunay triangulation is
 * unique and must equal Qhull's triangle for triangle. */
static void test_against_qhull(void **state)
{
	struct asph_delaunay *w = asph_delaunay_alloc(3000);

	assert_non_null(w);
	for (int k = 0; k < 3; k++) {
		size_t n = 500 + 1000 * (size_t)k;
		double *xy = random_points(n, 2.71 * k - 1.1, -0.37, 4.1 + k, 3.3);
		uint32_t *ours = NULL;
		size_t nt = 0, nq = 0;
		assert_int_equal(asph_delaunay_triangulate(w, xy, n, &ours, &nt, NULL), 0);
		uint32_t *ref = qhull_triangles(xy, n, &nq);
		assert_int_equal(nt, nq);
		canonical(ours, nt);
		canonical(ref, nq);
		assert_memory_equal(ours, ref, 3 * nt * sizeof(*ours));
		free(ours);
		free(ref);
		free(xy);
	}
	asph_delaunay_free(w);
}
#else
static void test_against_qhull(void **state)
{
	skip();
}
#endif

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_orient_near_line_grid),
		cmocka_unit_test(test_orient_random_near_collinear),
		cmocka_unit_test(test_incircle_cocircular_offset),
		cmocka_unit_test(test_incircle_near_cocircular),
		cmocka_unit_test(test_incircle_trapezoids),
		cmocka_unit_test(test_predicates_exact_zero),
		cmocka_unit_test(test_random),
		cmocka_unit_test(test_grid),
		cmocka_unit_test(test_circles),
		cmocka_unit_test(test_duplicates),
		cmocka_unit_test(test_collinear),
		cmocka_unit_test(test_perturbed_grid),
		cmocka_unit_test(test_involute),
		cmocka_unit_test(test_other_insertion_paths),
		cmocka_unit_test(test_errors),
		cmocka_unit_test(test_against_qhull),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
