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

/*
 * Forbes' freeform Q polynomials Q_n^m, m >= 1 (Opt. Express 20, 2483
 * (2012), Appendix A): the functions u^m Q_n^m(u^2) cos(m theta) (and sin)
 * have gradients orthonormal in
 *   <f, g> = (1/pi^2) int_0^2pi int_0^1 grad f . grad g / sqrt(1 - u^2) du dtheta.
 * Evaluated by the paper's recurrences: the auxiliary P_n^m by the
 * three-term recurrence (A.3) and Q_n^m = (P_n^m - g_{n-1} Q_{n-1}^m) / f_n
 * (A.18), with f, g from the Gram entries F, G (A.13, A.15).
 */
#define Q2D_MAX_N 20

struct q2d_coef {
	int m;
	double f[Q2D_MAX_N + 1], g[Q2D_MAX_N + 1], inv_f[Q2D_MAX_N + 1];
	/* P_n = (A[n] + B[n] x) P_{n-1} - C[n] P_{n-2} */
	double A[Q2D_MAX_N + 1], B[Q2D_MAX_N + 1], C[Q2D_MAX_N + 1];
};

/* m in 1 .. Q2D_MAX_N (the tables hold n = 0 .. Q2D_MAX_N). */
void q2d_coef_init(struct q2d_coef *c, int m);

/* q[n][0..2] = Q_n^m(x) and its first two derivatives, n = 0 .. count-1. */
void q2d_eval(const struct q2d_coef *c, int count, double x, double (*q)[3]);

/* s[0..2] = sum a_n Q_n^m(x), n < count, and its derivatives in x. */
void q2d_sum(const struct q2d_coef *c, const double *a, int count, double x,
	     double s[3]);

#endif
