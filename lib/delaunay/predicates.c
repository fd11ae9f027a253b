/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Robust orientation and in-circle predicates: a floating-point filter with
 * an exact fallback in floating-point expansion arithmetic.
 *
 * An expansion is a sum of doubles, stored from the smallest magnitude to
 * the largest, whose components do not overlap (the lowest set bit of each
 * is above the highest set bit of the previous one). Its sign is the sign
 * of its last component. The error-free transformations below (two_sum,
 * two_diff, two_product) return a rounded result and its exact rounding
 * error; built on them, sums and products of expansions are exact. The
 * method is J. R. Shewchuk, "Adaptive Precision Floating-Point Arithmetic
 * and Fast Robust Geometric Predicates", Discrete Comput. Geom. 18 (1997).
 *
 * Filter bounds (eps = 2^-53, the unit roundoff of double, round to nearest):
 *   orient2d: |det - det_exact| <= (3 + 16 eps) eps (|acx bcy| + |acy bcx|)
 *   incircle: |det - det_exact| <= (10 + 96 eps) eps * permanent
 * where the right-hand sides are evaluated with the same rounded differences
 * (they are the bounds of the paper above, stage A, which already absorb the
 * rounding of evaluating the bound itself). When |det| is not above the
 * bound, orient2d is decided exactly; incircle goes through two cheaper
 * stages first (incircle_adaptive) and is decided exactly when they fail.
 */
#include <float.h>
#include <math.h>
#include <string.h>

#include "predicates.h"

/* The error-free transformations need every operation rounded to double. */
#if FLT_EVAL_METHOD != 0
#error "exact predicates need double evaluation (FLT_EVAL_METHOD == 0, e.g. SSE2)"
#endif
#ifdef __FAST_MATH__
#error "exact predicates cannot be built with -ffast-math"
#endif

#define EPS 0x1p-53
#define ORIENT_BOUND ((3.0 + 16.0 * EPS) * EPS)
#define INCIRCLE_BOUND ((10.0 + 96.0 * EPS) * EPS)
#define INCIRCLE_BOUND_B ((4.0 + 48.0 * EPS) * EPS)
#define INCIRCLE_BOUND_C ((44.0 + 576.0 * EPS) * EPS * EPS)
#define RESULT_BOUND ((3.0 + 8.0 * EPS) * EPS)

/* a + b = x + y exactly, x = fl(a + b). */
static inline void two_sum(double a, double b, double *x, double *y)
{
	double s = a + b;
	double bv = s - a;
	double av = s - bv;

	*x = s;
	*y = (a - av) + (b - bv);
}

/* a - b = x + y exactly, x = fl(a - b). */
static inline void two_diff(double a, double b, double *x, double *y)
{
	double d = a - b;
	double bv = a - d;
	double av = d + bv;

	*x = d;
	*y = (a - av) + (bv - b);
}

/* a * b = x + y exactly, x = fl(a * b). Uses the hardware fused
 * multiply-add when the target has one, else Dekker's splitting (each
 * operand into two 26-bit halves whose products are exact). */
static inline void two_product(double a, double b, double *x, double *y)
{
	double p = a * b;

	*x = p;
#ifdef __FP_FAST_FMA
	*y = fma(a, b, -p);
#else
	const double splitter = 134217729.0; /* 2^27 + 1 */
	double ca = splitter * a, cb = splitter * b;
	double ahi = ca - (ca - a), bhi = cb - (cb - b);
	double alo = a - ahi, blo = b - bhi;
	double err = p - ahi * bhi;

	err -= alo * bhi;
	err -= ahi * blo;
	*y = alo * blo - err;
#endif
}

/* Appends a component unless it is zero; expansions keep at least one
 * component (a lone 0 for zero). */
static inline int push(double *h, int n, double v)
{
	if (v != 0.0)
		h[n++] = v;
	return n;
}

static inline int finish(double *h, int n, double q)
{
	if (q != 0.0 || n == 0)
		h[n++] = q;
	return n;
}

/* h = e + f. h has room for elen + flen components and differs from both. */
static int expansion_sum(const double *e, int elen, const double *f, int flen,
			 double *h)
{
	int i = 0, j = 0, n = 0;
	double q, g;

	/* Merge by magnitude and carry the running sum upward. */
	if (fabs(e[0]) < fabs(f[0]))
		q = e[i++];
	else
		q = f[j++];
	while (i < elen || j < flen) {
		if (j >= flen || (i < elen && fabs(e[i]) < fabs(f[j])))
			g = e[i++];
		else
			g = f[j++];
		double s, t;
		two_sum(q, g, &s, &t);
		n = push(h, n, t);
		q = s;
	}
	return finish(h, n, q);
}

/* h = b e. h has room for 2 elen components. */
static int scale_expansion(const double *e, int elen, double b, double *h)
{
	double q, t, p1, p0, s;
	int n = 0;

	two_product(e[0], b, &q, &t);
	n = push(h, n, t);
	for (int i = 1; i < elen; i++) {
		two_product(e[i], b, &p1, &p0);
		two_sum(q, p0, &s, &t);
		n = push(h, n, t);
		two_sum(p1, s, &q, &t);
		n = push(h, n, t);
	}
	return finish(h, n, q);
}

/* h = e f. h has room for 2 elen flen components; work for
 * 2 elen + 2 elen flen. */
static int expansion_product(const double *e, int elen, const double *f,
			     int flen, double *h, double *work)
{
	double *s = work, *t = work + 2 * elen;
	int hlen = scale_expansion(e, elen, f[0], h);

	for (int i = 1; i < flen; i++) {
		int slen = scale_expansion(e, elen, f[i], s);
		int tlen = expansion_sum(h, hlen, s, slen, t);
		memcpy(h, t, (size_t)tlen * sizeof(*h));
		hlen = tlen;
	}
	return hlen;
}

static void negate(double *e, int n)
{
	for (int i = 0; i < n; i++)
		e[i] = -e[i];
}

/* a - b as an expansion of at most two components. */
static int difference(double a, double b, double *h)
{
	double x, y;

	two_diff(a, b, &x, &y);
	return finish(h, push(h, 0, y), x);
}

/* h = p q - r s for two-component expansions; h has room for 16. */
static int cross(const double *p, int plen, const double *q, int qlen,
		 const double *r, int rlen, const double *s, int slen,
		 double *h)
{
	double pq[8], rs[8], work[16];
	int n1 = expansion_product(p, plen, q, qlen, pq, work);
	int n2 = expansion_product(r, rlen, s, slen, rs, work);

	negate(rs, n2);
	return expansion_sum(pq, n1, rs, n2, h);
}

double orient2d_exact(const double *a, const double *b, const double *c)
{
	double acx[2], acy[2], bcx[2], bcy[2], det[16];
	int nacx = difference(a[0], c[0], acx);
	int nacy = difference(a[1], c[1], acy);
	int nbcx = difference(b[0], c[0], bcx);
	int nbcy = difference(b[1], c[1], bcy);
	int n = cross(acx, nacx, bcy, nbcy, acy, nacy, bcx, nbcx, det);

	return det[n - 1];
}

double orient2d(const double *a, const double *b, const double *c)
{
	double left = (a[0] - c[0]) * (b[1] - c[1]);
	double right = (a[1] - c[1]) * (b[0] - c[0]);
	double det = left - right;
	double sum;

	/* Opposite signs (or a zero, which is exact) cannot cancel. */
	if (left > 0.0) {
		if (right <= 0.0)
			return det;
		sum = left + right;
	} else if (left < 0.0) {
		if (right >= 0.0)
			return det;
		sum = -left - right;
	} else {
		return det;
	}
	if (fabs(det) >= ORIENT_BOUND * sum)
		return det;
	return orient2d_exact(a, b, c);
}

struct diffs {
	double v[6][2];   /* adx, ady, bdx, bdy, cdx, cdy */
	int n[6];
};

/* One term of the in-circle determinant: (px^2 + py^2) (qx ry - qy rx). */
static int incircle_term(const struct diffs *d, int p, int q, int r,
			 double *h)
{
	double xx[8], yy[8], lift[16], det[16], work[2 * 16 + 2 * 16 * 16];
	const double *px = d->v[2 * p], *py = d->v[2 * p + 1];
	const double *qx = d->v[2 * q], *qy = d->v[2 * q + 1];
	const double *rx = d->v[2 * r], *ry = d->v[2 * r + 1];
	int npx = d->n[2 * p], npy = d->n[2 * p + 1];
	int nqx = d->n[2 * q], nqy = d->n[2 * q + 1];
	int nrx = d->n[2 * r], nry = d->n[2 * r + 1];
	int nxx = expansion_product(px, npx, px, npx, xx, work);
	int nyy = expansion_product(py, npy, py, npy, yy, work);
	int nlift = expansion_sum(xx, nxx, yy, nyy, lift);
	int ndet = cross(qx, nqx, ry, nry, qy, nqy, rx, nrx, det);

	return expansion_product(lift, nlift, det, ndet, h, work);
}

double incircle_exact(const double *a, const double *b, const double *c,
		      const double *d)
{
	struct diffs df;
	double ta[512], tb[512], tc[512], ab[1024], det[1536];
	const double *pts[3] = { a, b, c };

	for (int i = 0; i < 3; i++) {
		/* df.v[k] is where difference() writes: not read uninitialized. */
		// cppcheck-suppress uninitvar
		df.n[2 * i] = difference(pts[i][0], d[0], df.v[2 * i]);
		df.n[2 * i + 1] = difference(pts[i][1], d[1], df.v[2 * i + 1]);
	}
	int na = incircle_term(&df, 0, 1, 2, ta);
	int nb = incircle_term(&df, 1, 2, 0, tb);
	int nc = incircle_term(&df, 2, 0, 1, tc);
	int nab = expansion_sum(ta, na, tb, nb, ab);
	int n = expansion_sum(ab, nab, tc, nc, det);

	return det[n - 1];
}

/* (x^2 + y^2) e exactly, for an expansion e of at most 4 components. */
static int lift_times(const double *e, int n, double x, double y, double *h)
{
	double ex[8], exx[16], ey[8], eyy[16];
	int nx = scale_expansion(e, n, x, ex);
	int nxx = scale_expansion(ex, nx, x, exx);
	int ny = scale_expansion(e, n, y, ey);
	int nyy = scale_expansion(ey, ny, y, eyy);

	return expansion_sum(exx, nxx, eyy, nyy, h);
}

static double estimate(const double *e, int n)
{
	double s = 0;

	for (int i = 0; i < n; i++)
		s += e[i];
	return s;
}

/*
 * Between the filter and the exact path: the determinant of the rounded
 * differences computed exactly (exact outright when the differences were,
 * as on a lattice), then corrected to first order in the rounding errors
 * of the differences. Bounds as in the paper cited at the top (stages B
 * and C):
 *   B: |det_B - det_exact| <= (4 + 48 eps) eps permanent
 *   C: |det_C - det_exact| <= (44 + 576 eps) eps^2 permanent
 *                             + (3 + 8 eps) eps |det_B|
 */
static double incircle_adaptive(const double *a, const double *b,
				const double *c, const double *d,
				double permanent)
{
	double adx, ady, bdx, bdy, cdx, cdy;
	double adxt, adyt, bdxt, bdyt, cdxt, cdyt;
	double bc[4], ca[4], ab[4], ta[32], tb[32], tc[32], tab[64], fin[96];

	two_diff(a[0], d[0], &adx, &adxt);
	two_diff(a[1], d[1], &ady, &adyt);
	two_diff(b[0], d[0], &bdx, &bdxt);
	two_diff(b[1], d[1], &bdy, &bdyt);
	two_diff(c[0], d[0], &cdx, &cdxt);
	two_diff(c[1], d[1], &cdy, &cdyt);
	int nbc = cross(&bdx, 1, &cdy, 1, &bdy, 1, &cdx, 1, bc);
	int nca = cross(&cdx, 1, &ady, 1, &cdy, 1, &adx, 1, ca);
	int nab = cross(&adx, 1, &bdy, 1, &ady, 1, &bdx, 1, ab);
	int na = lift_times(bc, nbc, adx, ady, ta);
	int nb = lift_times(ca, nca, bdx, bdy, tb);
	int nc = lift_times(ab, nab, cdx, cdy, tc);
	int ntab = expansion_sum(ta, na, tb, nb, tab);
	int nfin = expansion_sum(tab, ntab, tc, nc, fin);
	double det = estimate(fin, nfin);

	if (fabs(det) >= INCIRCLE_BOUND_B * permanent)
		return det;
	if (adxt == 0 && adyt == 0 && bdxt == 0 && bdyt == 0 && cdxt == 0 &&
	    cdyt == 0)
		return det;
	double bound = INCIRCLE_BOUND_C * permanent + RESULT_BOUND * fabs(det);
	det += ((adx * adx + ady * ady) * ((bdx * cdyt + cdy * bdxt) -
					    (bdy * cdxt + cdx * bdyt)) +
		2.0 * (adx * adxt + ady * adyt) * (bdx * cdy - bdy * cdx)) +
	       ((bdx * bdx + bdy * bdy) * ((cdx * adyt + ady * cdxt) -
					    (cdy * adxt + adx * cdyt)) +
		2.0 * (bdx * bdxt + bdy * bdyt) * (cdx * ady - cdy * adx)) +
	       ((cdx * cdx + cdy * cdy) * ((adx * bdyt + bdy * adxt) -
					    (ady * bdxt + bdx * adyt)) +
		2.0 * (cdx * cdxt + cdy * cdyt) * (adx * bdy - ady * bdx));
	if (fabs(det) >= bound)
		return det;
	return incircle_exact(a, b, c, d);
}

double incircle(const double *a, const double *b, const double *c,
		const double *d)
{
	double adx = a[0] - d[0], ady = a[1] - d[1];
	double bdx = b[0] - d[0], bdy = b[1] - d[1];
	double cdx = c[0] - d[0], cdy = c[1] - d[1];
	double bdxcdy = bdx * cdy, cdxbdy = cdx * bdy;
	double cdxady = cdx * ady, adxcdy = adx * cdy;
	double adxbdy = adx * bdy, bdxady = bdx * ady;
	double alift = adx * adx + ady * ady;
	double blift = bdx * bdx + bdy * bdy;
	double clift = cdx * cdx + cdy * cdy;
	double det = alift * (bdxcdy - cdxbdy) + blift * (cdxady - adxcdy) +
		     clift * (adxbdy - bdxady);
	double permanent = (fabs(bdxcdy) + fabs(cdxbdy)) * alift +
			   (fabs(cdxady) + fabs(adxcdy)) * blift +
			   (fabs(adxbdy) + fabs(bdxady)) * clift;

	if (fabs(det) > INCIRCLE_BOUND * permanent)
		return det;
	return incircle_adaptive(a, b, c, d, permanent);
}
