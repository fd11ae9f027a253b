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
