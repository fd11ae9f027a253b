/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <math.h>

#include "qpoly.h"

/*
 * Q^bfs: the auxiliary P_0 = 2, P_1 = 6 - 8x, P_m = (2 - 4x) P_{m-1} - P_{m-2}
 * have a pentadiagonal Gram matrix in the slope inner product (diagonal
 * m(m+1) + 3, except 4 for m = 0; first off-diagonal -1; second
 * -m(m-1)/2). Its banded Cholesky factor gives the orthonormal Q_m:
 *   P_m = f_m Q_m + g_{m-1} Q_{m-1} + h_{m-2} Q_{m-2}.
 */
void qbfs_coef_init(struct qbfs_coef *c)
{
	c->f[0] = 2.0;
	c->g[0] = -0.5;
	c->h[0] = 0;
	c->f[1] = sqrt(19.0) / 2.0;
	for (int m = 2; m <= QPOLY_MAX_ORDER; m++) {
		c->h[m - 2] = -(double)m * (m - 1) / (2.0 * c->f[m - 2]);
		c->g[m - 1] = -(1.0 + c->g[m - 2] * c->h[m - 2]) / c->f[m - 1];
		c->f[m] = sqrt((double)m * (m + 1) + 3.0 -
			       c->g[m - 1] * c->g[m - 1] -
			       c->h[m - 2] * c->h[m - 2]);
	}
	c->g[QPOLY_MAX_ORDER] = c->h[QPOLY_MAX_ORDER] = 0;
	c->h[QPOLY_MAX_ORDER - 1] = 0;
	for (int m = 0; m <= QPOLY_MAX_ORDER; m++)
		c->inv_f[m] = 1.0 / c->f[m];
}

/* P_m (and its derivatives) from P_{m-1} in p and P_{m-2} in pm1, in place:
 * afterwards p holds P_m and pm1 holds P_{m-1}. */
static void qbfs_p_advance(int m, double x, double p[3], double pm1[3])
{
	double prev[3] = { p[0], p[1], p[2] };

	if (m == 0) {
		p[0] = 2, p[1] = 0, p[2] = 0;
	} else if (m == 1) {
		p[0] = 6.0 - 8.0 * x, p[1] = -8.0, p[2] = 0;
	} else {
		/* (2 - 4x) P_{m-1} - P_{m-2}, differentiated twice. */
		const double lin = 2.0 - 4.0 * x;
		p[2] = lin * prev[2] - 8.0 * prev[1] - pm1[2];
		p[1] = lin * prev[1] - 4.0 * prev[0] - pm1[1];
		p[0] = lin * prev[0] - pm1[0];
	}
	for (int d = 0; d < 3; d++)
		pm1[d] = prev[d];
}

/* Q_m from P_m, Q_{m-1} (q1) and Q_{m-2} (q2). */
static void qbfs_form(const struct qbfs_coef *c, int m, const double p[3],
		      const double q1[3], const double q2[3], double q[3])
{
	for (int d = 0; d < 3; d++) {
		double v = p[d];
		if (m >= 1)
			v -= c->g[m - 1] * q1[d];
		if (m >= 2)
			v -= c->h[m - 2] * q2[d];
		q[d] = v * c->inv_f[m];
	}
}

void qbfs_eval(const struct qbfs_coef *c, int n, double x, double (*q)[3])
{
	double p[3] = { 0, 0, 0 }, pm1[3] = { 0, 0, 0 };
	static const double zero[3] = { 0, 0, 0 };

	for (int m = 0; m < n; m++) {
		qbfs_p_advance(m, x, p, pm1);
		qbfs_form(c, m, p, m >= 1 ? q[m - 1] : zero, m >= 2 ? q[m - 2] : zero, q[m]);
	}
}

/*
 * Jacobi P_m^(0,4)(y), y = 2x - 1: with s = 2m + 4,
 *   2m (m+4) (s-2) P_m = (s-1) [s (s-2) y - 16] P_{m-1} - 2 (m-1)(m+3) s P_{m-2},
 * written as P_m = (alpha x + beta) P_{m-1} - gamma P_{m-2}.
 */
static void qcon_form(int m, double x, const double q1[3], const double q2[3],
		      double q[3])
{
	if (m == 0) {
		q[0] = 1, q[1] = 0, q[2] = 0;
		return;
	}
	if (m == 1) {
		q[0] = 6.0 * x - 5.0, q[1] = 6.0, q[2] = 0;
		return;
	}
	double s = 2.0 * m + 4.0, inv = 1.0 / (2.0 * m * (m + 4.0) * (s - 2.0));
	double alpha = 2.0 * (s - 1.0) * s * (s - 2.0) * inv;
	double beta = -(s - 1.0) * (s * (s - 2.0) + 16.0) * inv;
	double gamma = 2.0 * (m - 1.0) * (m + 3.0) * s * inv;
	double lin = alpha * x + beta;
	q[0] = lin * q1[0] - gamma * q2[0];
	q[1] = lin * q1[1] + alpha * q1[0] - gamma * q2[1];
	q[2] = lin * q1[2] + 2.0 * alpha * q1[1] - gamma * q2[2];
}

void qcon_eval(int n, double x, double (*q)[3])
{
	static const double zero[3] = { 0, 0, 0 };

	for (int m = 0; m < n; m++)
		qcon_form(m, x, m >= 1 ? q[m - 1] : zero, m >= 2 ? q[m - 2] : zero, q[m]);
}

/* The sums keep only the last two polynomials. */
static void accumulate(double s[3], double a, const double q[3], double q1[3], double q2[3])
{
	for (int d = 0; d < 3; d++) {
		s[d] += a * q[d];
		q2[d] = q1[d];
		q1[d] = q[d];
	}
}

void qbfs_sum(const struct qbfs_coef *c, const double *a, int n, double x,
	      double s[3])
{
	double p[3] = { 0, 0, 0 }, pm1[3] = { 0, 0, 0 };
	double q[3], q1[3] = { 0, 0, 0 }, q2[3] = { 0, 0, 0 };

	s[0] = s[1] = s[2] = 0;
	for (int m = 0; m < n; m++) {
		qbfs_p_advance(m, x, p, pm1);
		qbfs_form(c, m, p, q1, q2, q);
		accumulate(s, a[m], q, q1, q2);
	}
}

void qcon_sum(const double *a, int n, double x, double s[3])
{
	double q[3], q1[3] = { 0, 0, 0 }, q2[3] = { 0, 0, 0 };

	s[0] = s[1] = s[2] = 0;
	for (int m = 0; m < n; m++) {
		qcon_form(m, x, q1, q2, q);
		accumulate(s, a[m], q, q1, q2);
	}
}

/* ---- freeform Q_n^m, m >= 1 ------------------------------------------- */

/* (2k - 1)!! for k >= 0, with (-1)!! = 1. */
static double double_factorial_odd(int k)
{
	double v = 1;

	for (int i = 2 * k - 1; i > 1; i -= 2)
		v *= i;
	return v;
}

/* gamma_n^m of (A.14), n >= 1, m >= 2. */
static double q2d_gamma(int n, int m)
{
	double g = 3.0 / 8.0;   /* gamma_1^2 */

	for (int mm = 3; mm <= m; mm++)
		g *= (2.0 * mm - 1.0) / (2.0 * (mm - 2.0));
	for (int nn = 2; nn <= n; nn++)
		g *= nn * (2.0 * m + 2.0 * nn - 3.0) / ((m + nn - 3.0) * (2.0 * nn - 1.0));
	return g;
}

/* The Gram entries F_n^m (A.13) and G_n^m (A.15). */
static double q2d_F(int n, int m)
{
	double fact = 1;

	if (n == 0) {
		for (int i = 2; i < m; i++)
			fact *= i;
		return (double)m * m * double_factorial_odd(m - 1) / (ldexp(1.0, m + 1) * fact);
	}
	if (m == 1)
		return (4.0 * (n - 1.0) * (n - 1.0) * n * n + 1.0) / (8.0 * (2.0 * n - 1.0) * (2.0 * n - 1.0)) +
		       (n == 1 ? 11.0 / 32.0 : 0.0);
	double chi = m + n - 2.0;
	double num = 2.0 * n * chi * (3.0 - 5.0 * m + 4.0 * n * chi) +
		     (double)m * m * (3.0 - m + 4.0 * n * chi);
	double den = (m + 2.0 * n - 3.0) * (m + 2.0 * n - 2.0) * (m + 2.0 * n - 1.0) * (2.0 * n - 1.0);
	return num / den * q2d_gamma(n, m);
}

static double q2d_G(int n, int m)
{
	double fact = 1;

	if (n == 0) {
		for (int i = 2; i < m; i++)
			fact *= i;
		return double_factorial_odd(m) / (ldexp(1.0, m + 1) * fact);
	}
	if (m == 1)
		return -(2.0 * n * n - 1.0) * (n * n - 1.0) / (8.0 * (4.0 * n * n - 1.0)) -
		       (n == 1 ? 1.0 / 24.0 : 0.0);
	double num = (2.0 * n * (m + n - 1.0) - m) * (n + 1.0) * (2.0 * m + 2.0 * n - 1.0);
	double den = (m + 2.0 * n - 2.0) * (m + 2.0 * n - 1.0) * (m + 2.0 * n) * (2.0 * n + 1.0);
	return -num / den * q2d_gamma(n, m);
}

/* The recurrence (A.3) for P_{n+1} from P_n and P_{n-1}, stored at n + 1. */
static void q2d_abc(int n, int m, double *A, double *B, double *C)
{
	double D = (4.0 * n * n - 1.0) * (m + n - 2.0) * (m + 2.0 * n - 3.0);

	*A = (2.0 * n - 1.0) * (m + 2.0 * n - 2.0) *
	     (4.0 * n * (m + n - 2.0) + (m - 3.0) * (2.0 * m - 1.0)) / D;
	*B = -2.0 * (2.0 * n - 1.0) * (m + 2.0 * n - 3.0) * (m + 2.0 * n - 2.0) *
	     (m + 2.0 * n - 1.0) / D;
	*C = n * (2.0 * n - 3.0) * (m + 2.0 * n - 1.0) * (2.0 * m + 2.0 * n - 3.0) / D;
}

void q2d_coef_init(struct q2d_coef *c, int m)
{
	c->m = m;
	c->f[0] = sqrt(q2d_F(0, m));
	c->g[0] = q2d_G(0, m) / c->f[0];
	for (int n = 1; n <= Q2D_MAX_N; n++) {
		c->f[n] = sqrt(q2d_F(n, m) - c->g[n - 1] * c->g[n - 1]);
		c->g[n] = q2d_G(n, m) / c->f[n];
	}
	for (int n = 0; n <= Q2D_MAX_N; n++) {
		c->inv_f[n] = 1.0 / c->f[n];
		c->A[n] = c->B[n] = c->C[n] = 0;
	}
	/* m = 1 has explicit P_1 .. P_3 (the recurrence's D vanishes at n = 1);
	 * m >= 2 recurs from P_2 on. */
	for (int n = m == 1 ? 4 : 2; n <= Q2D_MAX_N; n++)
		q2d_abc(n - 1, m, &c->A[n], &c->B[n], &c->C[n]);
}

/* P_n^m(x) with derivatives, from P_{n-1} (p1) and P_{n-2} (p2). */
static void q2d_p(const struct q2d_coef *c, int n, double x, const double p1[3],
		  const double p2[3], double p[3])
{
	const int m = c->m;

	if (n == 0) {
		p[0] = 0.5, p[1] = 0, p[2] = 0;
	} else if (n == 1 && m == 1) {
		p[0] = 1.0 - 0.5 * x, p[1] = -0.5, p[2] = 0;
	} else if (n == 1) {
		p[0] = (m - 0.5) + (1.0 - m) * x, p[1] = 1.0 - m, p[2] = 0;
	} else if (n == 2 && m == 1) {
		p[0] = (3.0 - x * (12.0 - 8.0 * x)) / 6.0;
		p[1] = (-12.0 + 16.0 * x) / 6.0;
		p[2] = 16.0 / 6.0;
	} else if (n == 3 && m == 1) {
		p[0] = (5.0 - x * (60.0 - x * (120.0 - 64.0 * x))) / 10.0;
		p[1] = (-60.0 + x * (240.0 - 192.0 * x)) / 10.0;
		p[2] = (240.0 - 384.0 * x) / 10.0;
	} else {
		double lin = c->A[n] + c->B[n] * x;
		p[0] = lin * p1[0] - c->C[n] * p2[0];
		p[1] = lin * p1[1] + c->B[n] * p1[0] - c->C[n] * p2[1];
		p[2] = lin * p1[2] + 2.0 * c->B[n] * p1[1] - c->C[n] * p2[2];
	}
}

void q2d_eval(const struct q2d_coef *c, int count, double x, double (*q)[3])
{
	double p[3] = { 0, 0, 0 }, p1[3] = { 0, 0, 0 }, p2[3] = { 0, 0, 0 };

	for (int n = 0; n < count; n++) {
		q2d_p(c, n, x, p1, p2, p);
		for (int d = 0; d < 3; d++) {
			double v = p[d];
			if (n >= 1)
				v -= c->g[n - 1] * q[n - 1][d];
			q[n][d] = v * c->inv_f[n];
			p2[d] = p1[d];
			p1[d] = p[d];
		}
	}
}

void q2d_sum(const struct q2d_coef *c, const double *a, int count, double x,
	     double s[3])
{
	double p[3] = { 0, 0, 0 }, p1[3] = { 0, 0, 0 }, p2[3] = { 0, 0, 0 };
	double q[3] = { 0, 0, 0 };

	s[0] = s[1] = s[2] = 0;
	for (int n = 0; n < count; n++) {
		q2d_p(c, n, x, p1, p2, p);
		for (int d = 0; d < 3; d++) {
			double v = p[d];
			if (n >= 1)
				v -= c->g[n - 1] * q[d];
			q[d] = v * c->inv_f[n];
			s[d] += a[n] * q[d];
			p2[d] = p1[d];
			p1[d] = p[d];
		}
	}
}
