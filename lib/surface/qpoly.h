/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Forbes' Q polynomials, evaluated by their recurrences (never by expanded
 * monomials, which lose precision at high order), with their first two
 * derivatives in x = u^2 by the differentiated recurrences. Internal to
 * lib/surface.c (and its tests).
 *
 * Q^bfs (Forbes, Opt. Express 15, 5218 (2007)): the polynomials whose
 * slopes d/du [u^2 (1 - u^2) Q_m(u^2)] are orthonormal in
 * <f, g> = (2/pi) int_0^1 f(u) g(u) / sqrt(1 - u^2) du.
 * Q^con: Q_m(x) = P_m^(0,4)(2x - 1), orthogonal in int_0^1 . x^4 dx.
 */
#ifndef ASPH_QPOLY_H
#define ASPH_QPOLY_H

/* Highest order m the tables hold. */
#define QPOLY_MAX_ORDER 30

/* The Q^bfs recurrence coefficients f_m, g_m, h_m for m <= QPOLY_MAX_ORDER. */
struct qbfs_coef {
	double f[QPOLY_MAX_ORDER + 1];
	double g[QPOLY_MAX_ORDER + 1];
	double h[QPOLY_MAX_ORDER + 1];
	double inv_f[QPOLY_MAX_ORDER + 1];
};

void qbfs_coef_init(struct qbfs_coef *c);

/* q[m][0..2] = Q_m(x), Q_m'(x), Q_m''(x) for m = 0 .. n-1 (n <= MAX + 1). */
void qbfs_eval(const struct qbfs_coef *c, int n, double x, double (*q)[3]);
void qcon_eval(int n, double x, double (*q)[3]);

/* s[0..2] = sum a_m Q_m(x) and its first two derivatives in x. */
void qbfs_sum(const struct qbfs_coef *c, const double *a, int n, double x,
	      double s[3]);
void qcon_sum(const double *a, int n, double x, double s[3]);

#endif
