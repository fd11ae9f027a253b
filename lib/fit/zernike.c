/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_blas.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_linalg.h>
#include <gsl/gsl_matrix.h>
#include <gsl/gsl_vector.h>

#include "asph/zernike.h"
#include "util-mem.h"

#define MAX_N 20

/* Rows of points per block: big enough for BLAS to run at speed and for the
 * (P+1) rows of R that QR carries along to be a small overhead, small
 * enough to stay in cache. */
#define DECOMPOSE_BLOCK 1024

void asph_zernike_noll_to_nm(int j, int *n, int *m)
{
	int nn = 0, k, am;

	if (j < 1 || j > ASPH_ZERNIKE_MAX_J) {
		*n = -1;
		*m = -1;
		return;
	}
	while ((nn + 1) * (nn + 2) / 2 < j)
		nn++;
	k = j - nn * (nn + 1) / 2 - 1;   /* 0-based position in row nn */
	/* Noll orders a row by increasing |m|; each m != 0 comes as a pair,
	 * the even j carrying cos (m > 0) and the odd j sin (m < 0). */
	am = (nn % 2 == 0) ? 2 * ((k + 1) / 2) : 2 * (k / 2) + 1;
	*n = nn;
	*m = (am == 0 || j % 2 == 0) ? am : -am;
}

int asph_zernike_nm_to_noll(int n, int m)
{
	int am = abs(m);

	if (n < 0 || n > MAX_N || am > n || (n - am) % 2)
		return 0;
	for (int j = n * (n + 1) / 2 + 1; j <= (n + 1) * (n + 2) / 2; j++) {
		int jn, jm;
		asph_zernike_noll_to_nm(j, &jn, &jm);
		if (jm == m)
			return j;
	}
	return 0;
}

/* What evaluating one term needs, worked out once per call rather than once
 * per point: its (n, m), normalization and radial coefficients. */
struct term {
	int n, m, am, ns;
	double norm;
	double c[MAX_N / 2 + 1];  /* R_n^am = sum_s c[s] rho^(n - 2s) */
};

/* c_0 = binomial(n, (n - am) / 2), then the ratio of consecutive terms of
 * the factorial formula: no factorial overflows. */
static void term_init(int j, struct term *t)
{
	int hp, hm;
	double c0 = 1.0;

	asph_zernike_noll_to_nm(j, &t->n, &t->m);
	t->am = abs(t->m);
	hp = (t->n + t->am) / 2;
	hm = (t->n - t->am) / 2;
	t->ns = hm + 1;
	t->norm = t->m == 0 ? sqrt((double)(t->n + 1)) : sqrt(2.0 * (double)(t->n + 1));
	for (int i = 1; i <= hm; i++)
		c0 = c0 * (double)(t->n - hm + i) / (double)i;
	t->c[0] = c0;
	for (int s = 0; s + 1 < t->ns; s++)
		t->c[s + 1] = -t->c[s] * (double)(hp - s) * (double)(hm - s) /
			      ((double)(s + 1) * (double)(t->n - s));
}

static void table_init(int n_terms, struct term *t)
{
	for (int j = 1; j <= n_terms; j++)
		term_init(j, &t[j - 1]);
}

/* The point's powers of rho and harmonics cos(k th), sin(k th). */
struct point {
	double pw[MAX_N + 1], cm[MAX_N + 1], sm[MAX_N + 1];
	double ct, st;
};

static void point_init(double rho, double theta, int nmax, struct point *p)
{
	p->ct = cos(theta);
	p->st = sin(theta);
	p->pw[0] = p->cm[0] = 1.0;
	p->sm[0] = 0.0;
	for (int k = 1; k <= nmax; k++) {
		p->pw[k] = p->pw[k - 1] * rho;
		p->cm[k] = p->cm[k - 1] * p->ct - p->sm[k - 1] * p->st;
		p->sm[k] = p->sm[k - 1] * p->ct + p->cm[k - 1] * p->st;
	}
}

/* Value and, when gu is not NULL, Cartesian gradient of one term. */
static double term_eval(const struct term *t, const struct point *p,
			double *gu, double *gv)
{
	double r = 0, dr = 0, ro = 0, tv, dt;

	for (int s = 0; s < t->ns; s++) {
		int e = t->n - 2 * s;
		/* e >= |m| >= 0: term_init sets ns = (n - |m|) / 2 + 1. */
		r += t->c[s] * p->pw[e]; // NOLINT(clang-analyzer-core.UndefinedBinaryOperatorResult)
		if (gu && e >= 1) {
			dr += t->c[s] * (double)e * p->pw[e - 1];
			ro += t->c[s] * p->pw[e - 1];
		}
	}
	tv = t->m > 0 ? p->cm[t->am] : t->m < 0 ? p->sm[t->am] : 1.0;
	if (gu) {
		/* d/du = cos(th) d/drho - sin(th)/rho d/dth, with R/rho kept
		 * as a polynomial (ro) so that rho = 0 is exact. */
		dt = t->m > 0 ? -t->am * p->sm[t->am] : t->m < 0 ? t->am * p->cm[t->am] : 0.0;
		double ro_dt = t->am >= 1 ? ro * dt : 0.0;
		*gu = t->norm * (p->ct * dr * tv - p->st * ro_dt);
		*gv = t->norm * (p->st * dr * tv + p->ct * ro_dt);
	}
	return t->norm * r * tv;
}

static int max_order(const struct term *t, int n_terms)
{
	return n_terms > 0 ? t[n_terms - 1].n : 0;   /* n grows with j */
}

static void table_eval(const struct term *t, int n_terms, double rho,
		       double theta, double *values, double *gu, double *gv)
{
	struct point p;

	point_init(rho, theta, max_order(t, n_terms), &p);
	for (int j = 0; j < n_terms; j++)
		values[j] = term_eval(&t[j], &p, gu ? &gu[j] : NULL, gv ? &gv[j] : NULL);
}

static double single_term(int j, double rho, double theta, double grad[2])
{
	struct term t;
	struct point p;

	term_init(j, &t);
	point_init(rho, theta, t.n, &p);
	return term_eval(&t, &p, grad ? &grad[0] : NULL, grad ? &grad[1] : NULL);
}

double asph_zernike_noll(int j, double rho, double theta)
{
	if (j < 1 || j > ASPH_ZERNIKE_MAX_J)
		return NAN;
	return single_term(j, rho, theta, NULL);
}

void asph_zernike_noll_gradient(int j, double rho, double theta,
				double grad[2])
{
	if (j < 1 || j > ASPH_ZERNIKE_MAX_J) {
		grad[0] = grad[1] = NAN;
		return;
	}
	single_term(j, rho, theta, grad);
}

void asph_zernike_noll_all(int n_terms, double rho, double theta,
			   double *values)
{
	struct term t[ASPH_ZERNIKE_MAX_J];

	if (n_terms > ASPH_ZERNIKE_MAX_J)
		n_terms = ASPH_ZERNIKE_MAX_J;
	table_init(n_terms, t);
	table_eval(t, n_terms, rho, theta, values, NULL, NULL);
}

static double series_eval(const struct term *t, const double *coef, int n_terms,
			  double rho, double theta, double grad[2])
{
	struct point p;
	double sum = 0, su = 0, sv = 0;

	point_init(rho, theta, max_order(t, n_terms), &p);
	for (int j = 0; j < n_terms; j++) {
		double gu, gv;
		if (coef[j] == 0)
			continue;
		sum += coef[j] * term_eval(&t[j], &p, grad ? &gu : NULL, &gv);
		if (grad) {
			su += coef[j] * gu;
			sv += coef[j] * gv;
		}
	}
	if (grad) {
		grad[0] = su;
		grad[1] = sv;
	}
	return sum;
}

double asph_zernike_series(const double *coef, int n_terms, double rho,
			   double theta, double grad[2])
{
	struct term t[ASPH_ZERNIKE_MAX_J];

	if (n_terms > ASPH_ZERNIKE_MAX_J)
		n_terms = ASPH_ZERNIKE_MAX_J;
	table_init(n_terms, t);
	return series_eval(t, coef, n_terms, rho, theta, grad);
}

void asph_zernike_series_many(const double *coef, int n_terms,
			      const double *rho, const double *theta, size_t n,
			      double *value, double *grad)
{
	struct term t[ASPH_ZERNIKE_MAX_J];

	if (n_terms > ASPH_ZERNIKE_MAX_J)
		n_terms = ASPH_ZERNIKE_MAX_J;
	table_init(n_terms, t);
	for (size_t i = 0; i < n; i++)
		value[i] = series_eval(t, coef, n_terms, rho[i], theta[i],
				       grad ? grad + 2 * i : NULL);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(gsl_matrix *, gsl_matrix_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(gsl_vector *, gsl_vector_free)

static int decompose_check(const double *rho, const double *theta,
			   const double *value, const double *w, size_t n,
			   size_t *n_used, struct asph_error *err)
{
	*n_used = 0;
	for (size_t i = 0; i < n; i++) {
		if (!isfinite(rho[i]) || !isfinite(theta[i]) || !isfinite(value[i]) ||
		    (w && (!isfinite(w[i]) || w[i] < 0)))
			return asph_error_set(err, -EINVAL,
					      "Zernike decomposition: point %zu is not finite",
					      i + 1);
		*n_used += !w || w[i] > 0;
	}
	return 0;
}

/* The rows [sqrt(w) Z_1 .. sqrt(w) Z_P, sqrt(w) value] of the points from
 * *next on, into m from row `row` until m is full or the points end.
 * Returns the row after the last one filled. */
struct rows_src {
	const struct term *t;
	int p;
	const double *rho, *theta, *value, *w;
	size_t n, next;
};

static size_t fill_rows(struct rows_src *src, gsl_matrix *m, size_t row)
{
	double z[ASPH_ZERNIKE_MAX_J];

	for (; src->next < src->n && row < m->size1; src->next++) {
		size_t i = src->next;
		double sw = src->w ? sqrt(src->w[i]) : 1.0;
		double *r = gsl_matrix_ptr(m, row, 0);
		if (sw == 0.0)
			continue;
		table_eval(src->t, src->p, src->rho[i], src->theta[i], z, NULL, NULL);
		for (int j = 0; j < src->p; j++)
			r[j] = sw * z[j];
		r[src->p] = sw * src->value[i];
		row++;
	}
	return row;
}

/*
 * g += B^T B on g's lower triangle, B the first `rows` rows of blk: the
 * sums of the block are formed in t (packed lower triangle) a row at a time,
 * then added to g. Each element sums its products in the order the
 * reference BLAS dsyrk does (down the block from zero, then into g), so the
 * result is the same to the bit; but the rows are read where they lie
 * instead of striding down every pair of columns, and the inner loop runs
 * over contiguous memory.
 */
static void add_gram_lower(const gsl_matrix *blk, size_t rows, gsl_matrix *g, double *t)
{
	size_t p1 = g->size1;

	memset(t, 0, p1 * (p1 + 1) / 2 * sizeof(*t));
	for (size_t l = 0; l < rows; l++) {
		const double *r = gsl_matrix_const_ptr(blk, l, 0);
		double *ti = t;
		for (size_t i = 0; i < p1; i++) {
			double ri = r[i];
			for (size_t j = 0; j <= i; j++)
				ti[j] += ri * r[j];
			ti += i + 1;
		}
	}
	for (size_t i = 0; i < p1; i++, t += i) {
		double *gi = gsl_matrix_ptr(g, i, 0);
		for (size_t j = 0; j <= i; j++)
			gi[j] += t[j];
	}
}

/*
 * Normal equations, (Z^T W Z) c = Z^T W v, accumulated by blocks (a
 * rank-k update, add_gram_lower) and solved by Cholesky. The Noll terms are orthonormal over the
 * disk, so for points spread over it Z^T W Z is close to a multiple of the
 * identity and squaring its condition number costs nothing. Returns 1 when
 * the matrix is not safely conditioned (the caller then uses QR).
 */
static int solve_normal(struct rows_src *src, double *coef)
{
	size_t p = (size_t)src->p, p1 = p + 1, rows;
	_cleanup_(gsl_matrix_freep) gsl_matrix *blk = gsl_matrix_alloc(DECOMPOSE_BLOCK, p1);
	_cleanup_(gsl_matrix_freep) gsl_matrix *g = gsl_matrix_calloc(p1, p1);
	_cleanup_(gsl_vector_freep) gsl_vector *work = gsl_vector_alloc(3 * p);
	_cleanup_free_ double *t = malloc(p1 * (p1 + 1) / 2 * sizeof(double));
	double rcond = 0;

	if (!blk || !g || !work || !t)
		return -ENOMEM;
	while ((rows = fill_rows(src, blk, 0)) > 0)
		add_gram_lower(blk, rows, g, t);
	gsl_matrix_view a = gsl_matrix_submatrix(g, 0, 0, p, p);
	gsl_vector_view rhs = gsl_matrix_subrow(g, p, 0, p);   /* lower triangle */
	gsl_vector_view x = gsl_vector_view_array(coef, p);
	for (size_t i = 0; i < p; i++)          /* symmetric: fill the upper part */
		for (size_t j = i + 1; j < p; j++)
			gsl_matrix_set(&a.matrix, i, j, gsl_matrix_get(&a.matrix, j, i));
	if (gsl_linalg_cholesky_decomp1(&a.matrix) != 0 ||
	    gsl_linalg_cholesky_rcond(&a.matrix, &rcond, work) != 0 || !(rcond > 1e-8))
		return 1;
	gsl_linalg_cholesky_solve(&a.matrix, &rhs.vector, &x.vector);
	return 0;
}

/*
 * Streaming QR for what the normal equations cannot take: M holds the
 * triangle R of [A b] so far in its top P+1 rows and a block of new rows
 * below; a Householder QR of M leaves the updated triangle on top (Q is
 * never needed: the last column carries Q^T b).
 */
static void qr_fold_block(gsl_matrix *m, size_t rows, gsl_vector *tau)
{
	size_t cols = m->size2;
	gsl_matrix_view mv = gsl_matrix_submatrix(m, 0, 0, rows, cols);

	gsl_linalg_QR_decomp(&mv.matrix, tau);
	/* Only the triangle's rows survive; the rest is overwritten next. */
	for (size_t i = 1; i < cols; i++)
		for (size_t k = 0; k < i; k++)
			gsl_matrix_set(m, i, k, 0.0);
}

static int solve_triangle(gsl_matrix *m, int p, double *coef,
			  struct asph_error *err)
{
	double dmax = 0;
	gsl_matrix_view r = gsl_matrix_submatrix(m, 0, 0, (size_t)p, (size_t)p);
	gsl_vector_view b = gsl_vector_view_array(coef, (size_t)p);

	for (int i = 0; i < p; i++)
		dmax = fmax(dmax, fabs(gsl_matrix_get(m, (size_t)i, (size_t)i)));
	/* Each Z_j has RMS 1 over the disk, so a well spread set of points
	 * gives diagonal entries of order sqrt(n); a tiny one means a term
	 * the points cannot see. */
	for (int i = 0; i < p; i++)
		if (!(fabs(gsl_matrix_get(m, (size_t)i, (size_t)i)) > 1e-9 * dmax))
			return asph_error_set(err, -EDOM,
					      "Zernike decomposition: the points do not determine term Z%d (rank deficient: all on a line or too few)",
					      i + 1);
	for (int i = 0; i < p; i++)
		coef[i] = gsl_matrix_get(m, (size_t)i, (size_t)p);
	gsl_blas_dtrsv(CblasUpper, CblasNoTrans, CblasNonUnit, &r.matrix,
		       &b.vector);
	return 0;
}

static int solve_qr(struct rows_src *src, double *coef, struct asph_error *err)
{
	size_t p1 = (size_t)src->p + 1, row;
	_cleanup_(gsl_matrix_freep) gsl_matrix *m = gsl_matrix_calloc(p1 + DECOMPOSE_BLOCK, p1);
	_cleanup_(gsl_vector_freep) gsl_vector *tau = gsl_vector_alloc(p1);

	if (!m || !tau)
		return asph_error_set(err, -ENOMEM, "out of memory");
	while ((row = fill_rows(src, m, p1)) > p1)
		qr_fold_block(m, row, tau);
	return solve_triangle(m, src->p, coef, err);
}

int asph_zernike_decompose(const double *rho, const double *theta,
			   const double *value, const double *w, size_t n,
			   int n_terms, double *coef, struct asph_error *err)
{
	struct term t[ASPH_ZERNIKE_MAX_J];
	struct rows_src src = { t, n_terms, rho, theta, value, w, n, 0 };
	size_t n_used;
	int r;

	if (n_terms < 1 || n_terms > ASPH_ZERNIKE_MAX_J)
		return asph_error_set(err, -EINVAL,
				      "Zernike decomposition: %d terms (1..%d)",
				      n_terms, ASPH_ZERNIKE_MAX_J);
	r = decompose_check(rho, theta, value, w, n, &n_used, err);
	if (r < 0)
		return r;
	if (n_used < (size_t)n_terms)
		return asph_error_set(err, -EDOM,
				      "Zernike decomposition: %zu points for %d terms",
				      n_used, n_terms);
	table_init(n_terms, t);
	r = solve_normal(&src, coef);
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	if (r == 0)
		return 0;
	src.next = 0;
	return solve_qr(&src, coef, err);
}
