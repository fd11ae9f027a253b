/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Forbes' Q polynomials and the Q-type and odd-asphere surfaces: the
 * polynomials against closed forms and exact rational evaluations, their
 * orthogonality by exact quadrature, the surfaces against independent
 * constructions, and the plans and the fit on them.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <gsl/gsl_integration.h>
#include <gsl/gsl_rng.h>

#include "asph/fit.h"
#include "asph/lb.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "qpoly.h"

/* High-entropy abscissae in [0, 1]. */
static const double xs[] = { 0.0, 0.0731, 0.2718, 0.4142, 0.5772, 0.6931, 0.8660, 0.9549, 1.0 };
#define N_XS (sizeof(xs) / sizeof(xs[0]))

static int close_rel(double got, double want, double tol)
{
	return fabs(got - want) <= tol * fmax(1.0, fabs(want));
}

/* ---- Q^bfs ----------------------------------------------------------------- */

/* Forbes (2007) Eq. (A.2)-(A.4): Q_0..Q_3 written out, with derivatives. */
static void qbfs_closed(int m, double x, double q[3])
{
	double s2 = sqrt(2.0 / 95.0), s3 = sqrt(2.0 / 2545.0);

	switch (m) {
	case 0:
		q[0] = 1, q[1] = 0, q[2] = 0;
		break;
	case 1:
		q[0] = (13 - 16 * x) / sqrt(19.0), q[1] = -16 / sqrt(19.0), q[2] = 0;
		break;
	case 2:
		q[0] = s2 * (29 - 4 * x * (25 - 19 * x));
		q[1] = s2 * (-100 + 152 * x);
		q[2] = s2 * 152;
		break;
	default:
		q[0] = s3 * (207 - 4 * x * (315 - x * (577 - 320 * x)));
		q[1] = s3 * (-1260 + 4616 * x - 3840 * x * x);
		q[2] = s3 * (4616 - 7680 * x);
		break;
	}
}

static void test_qbfs_closed_forms(void **state)
{
	struct qbfs_coef c;
	double q[QPOLY_MAX_ORDER + 1][3], want[3];

	qbfs_coef_init(&c);
	for (size_t i = 0; i < N_XS; i++) {
		qbfs_eval(&c, 4, xs[i], q);
		for (int m = 0; m < 4; m++) {
			qbfs_closed(m, xs[i], want);
			for (int d = 0; d < 3; d++)
				if (!close_rel(q[m][d], want[d], 1e-14))
					fail_msg("Q%d^(%d)(%g) = %.17g, closed form %.17g", m, d,
						 xs[i], q[m][d], want[d]);
		}
	}
}

/*
 * <f, g> = (2/pi) int_0^1 f'(u) g'(u) / sqrt(1 - u^2) du for the slopes of
 * f = u^2 (1 - u^2) Q_m(u^2). With u = sin t the integrand is an even trig
 * polynomial in t of degree <= 4m + 6, so the midpoint rule on [0, pi/2]
 * with n > 2m + 4 nodes is exact.
 */
static void test_qbfs_orthonormal(void **state)
{
	enum { M = 21, NODES = 96 };
	struct qbfs_coef c;
	static double gram[M][M];
	double q[QPOLY_MAX_ORDER + 1][3];

	qbfs_coef_init(&c);
	memset(gram, 0, sizeof(gram));
	for (int j = 0; j < NODES; j++) {
		double t = (j + 0.5) * (M_PI / 2) / NODES, u = sin(t), x = u * u;
		double slope[M];
		qbfs_eval(&c, M, x, q);
		for (int m = 0; m < M; m++)
			slope[m] = 2 * u * ((1 - 2 * x) * q[m][0] + x * (1 - x) * q[m][1]);
		for (int m = 0; m < M; m++)
			for (int n = 0; n < M; n++)
				gram[m][n] += slope[m] * slope[n] / NODES;
	}
	for (int m = 0; m < M; m++)
		for (int n = 0; n < M; n++)
			if (fabs(gram[m][n] - (m == n)) > 1e-12)
				fail_msg("<Q%d, Q%d> = %.3g", m, n, gram[m][n]);
}

/* The same recurrence carried in long double: m = 20 in double agrees. */
static void qbfs_eval_long(int n, long double x, long double (*q)[3])
{
	long double f[QPOLY_MAX_ORDER + 1], g[QPOLY_MAX_ORDER + 1], h[QPOLY_MAX_ORDER + 1];
	long double p[QPOLY_MAX_ORDER + 1][3];

	f[0] = 2, g[0] = -0.5L, f[1] = sqrtl(19.0L) / 2;
	for (int m = 2; m < n; m++) {
		h[m - 2] = -(long double)m * (m - 1) / (2 * f[m - 2]);
		g[m - 1] = -(1 + g[m - 2] * h[m - 2]) / f[m - 1];
		f[m] = sqrtl((long double)m * (m + 1) + 3 - g[m - 1] * g[m - 1] - h[m - 2] * h[m - 2]);
	}
	for (int m = 0; m < n; m++) {
		if (m == 0) {
			p[0][0] = 2, p[0][1] = 0, p[0][2] = 0;
		} else if (m == 1) {
			p[1][0] = 6 - 8 * x, p[1][1] = -8, p[1][2] = 0;
		} else {
			p[m][0] = (2 - 4 * x) * p[m - 1][0] - p[m - 2][0];
			p[m][1] = (2 - 4 * x) * p[m - 1][1] - 4 * p[m - 1][0] - p[m - 2][1];
			p[m][2] = (2 - 4 * x) * p[m - 1][2] - 8 * p[m - 1][1] - p[m - 2][2];
		}
		for (int d = 0; d < 3; d++) {
			long double v = p[m][d];
			if (m >= 1)
				v -= g[m - 1] * q[m - 1][d];
			if (m >= 2)
				v -= h[m - 2] * q[m - 2][d];
			q[m][d] = v / f[m];
		}
	}
}

static void test_qbfs_high_order(void **state)
{
	struct qbfs_coef c;
	double q[QPOLY_MAX_ORDER + 1][3];
	long double ql[QPOLY_MAX_ORDER + 1][3];

	qbfs_coef_init(&c);
	for (size_t i = 0; i < N_XS; i++) {
		qbfs_eval(&c, 21, xs[i], q);
		qbfs_eval_long(21, xs[i], ql);
		/* |Q_m| stays of order m; derivatives grow like m^2 and m^4. */
		for (int d = 0; d < 3; d++)
			assert_true(fabs(q[20][d] - (double)ql[20][d]) <=
				    1e-13 * (1.0 + fabsl(ql[20][d])));
		assert_true(fabs(q[20][0]) < 100);
	}
}

/* ---- Q^con ----------------------------------------------------------------- */

/* Exact integers wide enough for 16^20 times the largest binomial products. */
__extension__ typedef __int128 i128;

static i128 binom(int n, int k)
{
	i128 r = 1;

	if (k < 0 || k > n)
		return 0;
	for (int i = 1; i <= k; i++)
		r = r * (n - k + i) / i;
	return r;
}

/*
 * P_n^(alpha,beta)(2x - 1) = sum_s C(n+alpha, n-s) C(n+beta, s) (x-1)^s x^(n-s),
 * exactly, at x = p / 16: returns the numerator over 16^n.
 */
static i128 jacobi_exact(int n, int alpha, int beta, int p)
{
	i128 sum = 0;

	for (int s = 0; s <= n; s++) {
		i128 t = binom(n + alpha, n - s) * binom(n + beta, s);
		for (int i = 0; i < s; i++)
			t *= (p - 16);
		for (int i = 0; i < n - s; i++)
			t *= p;
		sum += t;
	}
	return sum;
}

static double jacobi_at(int n, int alpha, int beta, int p)
{
	if (n < 0)
		return 0;
	/* One correct rounding of the exact integer, then an exact scaling. */
	return ldexp((double)jacobi_exact(n, alpha, beta, p), -4 * n);
}

static void test_qcon_closed_forms(void **state)
{
	double q[QPOLY_MAX_ORDER + 1][3];

	for (size_t i = 0; i < N_XS; i++) {
		double x = xs[i];
		qcon_eval(4, x, q);
		double want[4][3] = {
			{ 1, 0, 0 },
			{ 6 * x - 5, 6, 0 },
			{ 15 - 14 * x * (3 - 2 * x), -42 + 56 * x, 56 },
			{ -35 + x * (168 - x * (252 - 120 * x)), 168 - 504 * x + 360 * x * x, -504 + 720 * x },
		};
		for (int m = 0; m < 4; m++)
			for (int d = 0; d < 3; d++)
				assert_true(close_rel(q[m][d], want[m][d], 1e-12));
	}
}

/* Q_m, Q_m' = (m+5) P_{m-1}^(1,5), Q_m'' = (m+5)(m+6) P_{m-2}^(2,6), all at
 * x = p/16 in exact integer arithmetic, up to m = 20. */
static void test_qcon_high_order(void **state)
{
	double q[QPOLY_MAX_ORDER + 1][3];

	for (int p = 1; p < 16; p += 2) {
		qcon_eval(21, p / 16.0, q);
		for (int m = 0; m <= 20; m++) {
			double want[3] = {
				jacobi_at(m, 0, 4, p),
				(m + 5) * jacobi_at(m - 1, 1, 5, p),
				(m + 5) * (m + 6) * jacobi_at(m - 2, 2, 6, p),
			};
			double scale[3] = { 1, 100, 1e4 };
			for (int d = 0; d < 3; d++)
				if (fabs(q[m][d] - want[d]) > 1e-12 * scale[d] * fmax(1, fabs(want[d])))
					fail_msg("Q%d^(%d)(%d/16) = %.17g, exact %.17g", m, d, p,
						 q[m][d], want[d]);
		}
	}
}

/* int_0^1 Q_m Q_n x^4 dx = delta_mn / (2m + 5), by 32-point Gauss-Legendre
 * (exact to degree 63 >= 2*20 + 4). */
static void test_qcon_orthogonal(void **state)
{
	enum { M = 21 };
	gsl_integration_glfixed_table *gl = gsl_integration_glfixed_table_alloc(32);
	static double gram[M][M];
	double q[QPOLY_MAX_ORDER + 1][3];

	memset(gram, 0, sizeof(gram));
	for (size_t j = 0; j < 32; j++) {
		double x, w;
		gsl_integration_glfixed_point(0, 1, j, &x, &w, gl);
		qcon_eval(M, x, q);
		for (int m = 0; m < M; m++)
			for (int n = 0; n < M; n++)
				gram[m][n] += w * pow(x, 4) * q[m][0] * q[n][0];
	}
	for (int m = 0; m < M; m++)
		for (int n = 0; n < M; n++) {
			double want = m == n ? 1.0 / (2 * m + 5) : 0;
			if (fabs(gram[m][n] - want) > 1e-13)
				fail_msg("(Q%d, Q%d) = %.17g, want %.17g", m, n, gram[m][n], want);
		}
	gsl_integration_glfixed_table_free(gl);
}

/* ---- surfaces ---------------------------------------------------------------- */

static const double qbfs_a[] = { 0.0213, -0.0071, 0.0032, -0.00118, 4.7e-4 };
static const double qcon_a[] = { 0.0371, -0.0128, 0.0049, -0.0017, 6.1e-4 };

static struct asph_prescription qbfs_lens(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_QBFS, .R = 31.7,
				       .aperture_diameter = 20, .norm_radius = 10.0 };
	snprintf(p.name, sizeof(p.name), "qbfs-test");
	memcpy(p.Q, qbfs_a, sizeof(qbfs_a));
	return p;
}

static struct asph_prescription qcon_lens(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_QCON, .R = -42.3, .k = -0.73,
				       .aperture_diameter = 20, .norm_radius = 10.5 };
	snprintf(p.name, sizeof(p.name), "qcon-test");
	memcpy(p.Q, qcon_a, sizeof(qcon_a));
	return p;
}

static struct asph_surface *build(const struct asph_prescription *p)
{
	struct asph_surface *s = NULL;
	struct asph_error err;

	if (asph_surface_alloc(p, &s, &err) != 0)
		fail_msg("surface: %s", err.message);
	return s;
}

/*
 * Sag of a Qbfs lens written out from the closed forms: the base conic
 * plus the departure times the secant of the conic's normal,
 * sqrt((1 - k c^2 r^2) / (1 - (1 + k) c^2 r^2)) (OpticStudio's Q-type
 * asphere; 1 / sqrt(1 - c^2 r^2), Forbes' sphere, for k = 0).
 */
static double qbfs_sag_closed(const struct asph_prescription *p, double r)
{
	double c = 1 / p->R, k = p->k, u2 = r * r / (p->norm_radius * p->norm_radius), sum = 0;
	double root = sqrt(1 - (1 + k) * c * c * r * r), q[3];

	for (int m = 0; m < 4; m++) {
		qbfs_closed(m, u2, q);
		sum += p->Q[m] * q[0];
	}
	return c * r * r / (1 + root) +
	       u2 * (1 - u2) * sqrt(1 - k * c * c * r * r) / root * sum;
}

/* A Qbfs departure over a conic, with an aperture past the vertex radius
 * (the sphere's secant would be undefined there): a condenser. */
static struct asph_prescription qbfs_conic_lens(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_QBFS, .R = 17.3729, .k = -0.67609,
				       .aperture_diameter = 45.72, .norm_radius = 27 };
	const double a[] = { -0.814837, -0.32311, 0.10591, -0.05058 };

	snprintf(p.name, sizeof(p.name), "qbfs-conic");
	memcpy(p.Q, a, sizeof(a));
	return p;
}

static void test_qbfs_surface(void **state)
{
	struct asph_prescription p[2] = { qbfs_lens(), qbfs_conic_lens() };
	p[0].Q[4] = 0;
	for (int k = 0; k < 2; k++) {
		struct asph_surface *s = build(&p[k]);
		double a = p[k].aperture_diameter / 2;
		for (int i = 0; i <= 40; i++) {
			double r = a * i / 40 * (1 - 0.013 * (i % 3)), want = qbfs_sag_closed(&p[k], r);
			if (!(fabs(asph_surface_sag(s, r) - want) < 1e-14 * fmax(1, fabs(want))))
				fail_msg("%s r = %g: %.17g, closed form %.17g", p[k].name, r,
					 asph_surface_sag(s, r), want);
		}
		asph_surface_free(s);
	}
}

/* All a_m = 0: the base sphere, to the last bits, with its tables. */
static void test_qbfs_zero_is_sphere(void **state)
{
	struct asph_prescription p = qbfs_lens();
	memset(p.Q, 0, sizeof(p.Q));
	struct asph_prescription e = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = p.R,
				       .aperture_diameter = p.aperture_diameter };
	struct asph_surface *s = build(&p), *t = build(&e);
	double a = 10, R = p.R;

	for (int i = 0; i <= 50; i++) {
		double r = a * i / 50 * 0.9973, d[3], w[3];
		asph_surface_sag_derivs(s, r, d);
		asph_surface_sag_derivs(t, r, w);
		double sph = R - sqrt(R * R - r * r);
		assert_true(fabs(d[0] - sph) < 1e-13);
		for (int k = 0; k < 3; k++)
			assert_true(d[k] == w[k]);
	}
	assert_true(fabs(asph_surface_area(s, a) - 2 * M_PI * R * (R - sqrt(R * R - a * a))) < 1e-11);
	asph_surface_free(s);
	asph_surface_free(t);
}

/* Integer monomial coefficients of Q_m^con: Q_m(x) = sum_j coef[j] x^j. */
static void qcon_monomials(int m, double coef[])
{
	i128 acc[QPOLY_MAX_ORDER + 1] = { 0 };

	for (int s = 0; s <= m; s++) {
		i128 b = binom(m, m - s) * binom(m + 4, s);
		/* (x - 1)^s x^(m-s) */
		for (int i = 0; i <= s; i++) {
			i128 t = b * binom(s, i);
			if ((s - i) % 2)
				t = -t;
			acc[i + m - s] += t;
		}
	}
	for (int j = 0; j <= m; j++)
		coef[j] = (double)acc[j];
}

static void test_qcon_as_even_asphere(void **state)
{
	struct asph_prescription p = qcon_lens();
	const double extra[] = { -2.3e-4, 9.7e-5, -3.1e-5, 1.37e-5 };
	memcpy(p.Q + 5, extra, sizeof(extra));
	struct asph_prescription e = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = p.R, .k = p.k,
				       .aperture_diameter = p.aperture_diameter };
	double rho = p.norm_radius, coef[QPOLY_MAX_ORDER + 1];

	/* u^4 sum a_m Q_m(u^2) = sum_j (sum_m a_m coef_mj) r^(4+2j) / rho^(4+2j) */
	for (int m = 0; m <= 8; m++) {
		qcon_monomials(m, coef);
		for (int j = 0; j <= m; j++)
			e.A[4 + 2 * j] += p.Q[m] * coef[j] / pow(rho, 4 + 2 * j);
	}
	struct asph_surface *s = build(&p), *t = build(&e);
	for (int i = 0; i <= 60; i++) {
		double r = 10.0 * i / 60 * (1 - 0.0071 * (i % 5)), d[3], w[3];
		asph_surface_sag_derivs(s, r, d);
		asph_surface_sag_derivs(t, r, w);
		if (fabs(d[0] - w[0]) > 1e-12)
			fail_msg("r = %g: qcon %.17g, even asphere %.17g", r, d[0], w[0]);
		assert_true(fabs(d[1] - w[1]) < 1e-11 && fabs(d[2] - w[2]) < 1e-10);
	}
	assert_true(fabs(asph_surface_area(s, 10) - asph_surface_area(t, 10)) < 1e-10);
	asph_surface_free(s);
	asph_surface_free(t);
}

/* Z' and Z'' of every new type against 4th-order central differences of
 * Z (and of Z'), at radii away from the vertex. */
static void check_derivs(const struct asph_surface *s)
{
	double a = asph_surface_aperture_radius(s), h = 1e-3;

	for (int i = 1; i <= 30; i++) {
		double r = a * (0.02 + 0.95 * i / 30.0), d[3], z[4], dz[4];
		double off[4] = { -2 * h, -h, h, 2 * h };
		asph_surface_sag_derivs(s, r, d);
		for (int k = 0; k < 4; k++) {
			double e[3];
			asph_surface_sag_derivs(s, r + off[k], e);
			z[k] = e[0];
			dz[k] = e[1];
		}
		double fd1 = (z[0] - 8 * z[1] + 8 * z[2] - z[3]) / (12 * h);
		double fd2 = (dz[0] - 8 * dz[1] + 8 * dz[2] - dz[3]) / (12 * h);
		if (fabs(fd1 - d[1]) > 1e-9 * (1 + fabs(d[1])) ||
		    fabs(fd2 - d[2]) > 1e-8 * (1 + fabs(d[2])))
			fail_msg("%s r = %g: Z' %.12g (fd %.12g), Z'' %.12g (fd %.12g)",
				 asph_surface_prescription(s)->name, r, d[1], fd1, d[2], fd2);
	}
}

static void test_derivatives(void **state)
{
	struct asph_prescription p[4] = { qbfs_lens(), qcon_lens(),
		{ .type = ASPH_SURFACE_ODD_ASPHERE, .R = 27.9, .k = -0.41, .aperture_diameter = 16 },
		qbfs_conic_lens() };

	/* High orders too: a_20 of either family. */
	p[0].Q[20] = 3.3e-5;
	p[1].Q[17] = -2.9e-5;
	p[2].A[1] = 1.3e-3, p[2].A[3] = -2.7e-6, p[2].A[4] = 3.1e-6, p[2].A[7] = 1.9e-11;
	snprintf(p[2].name, sizeof(p[2].name), "odd");
	p[3].Q[20] = 2.1e-5;
	for (int i = 0; i < 4; i++) {
		struct asph_surface *s = build(&p[i]);
		check_derivs(s);
		asph_surface_free(s);
	}
}

/* The odd asphere is the conic plus sum A_i r^i, written out. */
static void test_odd_asphere(void **state)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_ODD_ASPHERE, .R = 27.9, .k = -0.41,
				       .aperture_diameter = 16 };
	p.A[1] = 1.3e-3, p.A[2] = 2.1e-4, p.A[3] = -2.7e-6, p.A[5] = 4.3e-9;
	struct asph_surface *s = build(&p);

	for (int i = 0; i <= 20; i++) {
		double r = 8.0 * i / 20 * 0.991, c = 1 / p.R;
		double want = c * r * r / (1 + sqrt(1 - (1 + p.k) * c * c * r * r)) + p.A[1] * r +
			      p.A[2] * r * r + p.A[3] * pow(r, 3) + p.A[5] * pow(r, 5);
		assert_true(fabs(asph_surface_sag(s, r) - want) < 1e-14);
	}
	asph_surface_free(s);
}

static void test_refusals(void **state)
{
	struct asph_prescription ok = qbfs_lens(), p;
	struct asph_error err;

	/* a conic base whose root vanishes inside the aperture */
	p = ok, p.k = 10;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "k");
	p = ok, p.norm_radius = 0;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "norm_radius");
	p = ok, p.A[4] = 1e-5;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "A.4");
	p = ok, p.Q[7] = NAN;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "a.[7]");
	p = qcon_lens(), p.norm_radius = INFINITY;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	p = (struct asph_prescription){ .type = ASPH_SURFACE_EVEN_ASPHERE, .R = 20, .aperture_diameter = 10 };
	p.Q[0] = 1e-3;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "a.[0]");
	p.Q[0] = 0, p.norm_radius = 5;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	p.norm_radius = 0, p.type = ASPH_SURFACE_ODD_ASPHERE, p.A[0] = 1e-3;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "A.0");
	p.A[0] = 0, p.A[1] = 1e-3;
	assert_int_equal(asph_prescription_check(&p, &err), 0);
	p.type = ASPH_SURFACE_EVEN_ASPHERE;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "A.1");
	p.type = (enum asph_surface_type)17;
	assert_int_equal(asph_prescription_check(&p, &err), -EINVAL);
	assert_string_equal(err.field, "type");
}

/* ---- plans on Q surfaces ------------------------------------------------------ */

static struct asph_plan *plan(const struct asph_surface *s, enum asph_plan_method m)
{
	struct asph_plan *p = NULL;
	struct asph_error err;

	if (asph_plan_compute(s, m, (struct asph_plan_density){ ASPH_DENSITY_H, 0.04 }, 0, &p, &err) < 0)
		fail_msg("%s: %s", asph_plan_method_name(m), err.message);
	return p;
}

static double signed_area_xy(const double *p0, const double *p1, const double *p2)
{
	return (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p1[1] - p0[1]) * (p2[0] - p0[0]);
}

/* Every point on the surface and inside the aperture; the grid methods are
 * one-to-one (no folded triangle) and move the disk grid radially by a
 * monotone map that keeps the rim; OT solves its area equation. */
static void check_plans(const struct asph_surface *s)
{
	double a = asph_surface_aperture_radius(s);
	struct asph_plan *pl[ASPH_PLAN_CI + 1];

	for (int m = ASPH_PLAN_OP; m <= ASPH_PLAN_CI; m++) {
		pl[m] = plan(s, (enum asph_plan_method)m);
		assert_true(pl[m]->n > 100);
		for (size_t k = 0; k < pl[m]->n; k++) {
			const double *q = pl[m]->xyz + 3 * k;
			double r = hypot(q[0], q[1]);
			assert_true(r <= a);
			assert_true(fabs(q[2] - asph_surface_sag(s, r)) <= 1e-11 * a);
		}
	}
	for (int m = ASPH_PLAN_OP; m <= ASPH_PLAN_LB; m++) {
		const struct asph_plan *p = pl[m], *op = pl[ASPH_PLAN_OP];
		assert_true(p->n_triangles > 0);
		for (size_t t = 0; t < p->n_triangles; t++) {
			const uint32_t *v = p->triangles + 3 * t;
			assert_true(signed_area_xy(p->xyz + 3 * v[0], p->xyz + 3 * v[1],
						   p->xyz + 3 * v[2]) > 0);
		}
		assert_int_equal(p->n, op->n);
		double prev = 0;
		for (size_t k = 0; k < p->n; k++) {
			const double *q = p->xyz + 3 * k, *d = op->xyz + 3 * k;
			double r = hypot(q[0], q[1]), rho = hypot(d[0], d[1]);
			if (rho >= a * (1 - 1e-15)) {
				assert_true(fabs(r - a) <= 1e-14 * a);
				continue;
			}
			assert_true(r > prev && r < a);
			prev = r;
		}
	}
	double area_a = asph_surface_area(s, a);
	for (int j = 1; j < 40; j++) {
		double rho = a * j / 40.0 * (1 - 0.01 * (j % 3)), r = asph_plan_ot_radius(s, rho);
		assert_true(fabs(asph_surface_area(s, r) / area_a - (rho / a) * (rho / a)) < 1e-12);
	}
	for (int m = ASPH_PLAN_OP; m <= ASPH_PLAN_CI; m++)
		asph_plan_free(pl[m]);
}

static void test_plans(void **state)
{
	struct asph_prescription p[2] = { qbfs_lens(), qcon_lens() };

	for (int i = 0; i < 2; i++) {
		struct asph_surface *s = build(&p[i]);
		check_plans(s);
		asph_surface_free(s);
	}
}

/* ---- the fit on Q surfaces ---------------------------------------------------- */

static double *ring_points(const struct asph_surface *s, size_t *n_out)
{
	double a = asph_surface_aperture_radius(s);
	size_t rings = 18, total = 1, k = 1;

	for (size_t j = 1; j <= rings; j++)
		total += (size_t)(2 * M_PI * j) + 3;
	double *xyz = calloc(3 * total, sizeof(double));
	for (size_t j = 1; j <= rings; j++) {
		double r = a * sqrt((j - 0.5 * (j < rings)) / (double)rings);
		size_t m = (size_t)(2 * M_PI * j) + 3;
		for (size_t i = 0; i < m; i++, k++) {
			double t = 2.399963229728653 * (double)j + 2 * M_PI * (double)i / (double)m;
			xyz[3 * k] = r * cos(t);
			xyz[3 * k + 1] = r * sin(t);
			xyz[3 * k + 2] = asph_surface_sag(s, r);
		}
	}
	*n_out = total;
	return xyz;
}

static int fit(const struct asph_surface *s, const double *xyz, size_t n, unsigned dof,
	       struct asph_fit_result *res, struct asph_error *err)
{
	struct asph_fit_options o = { .dof = dof };
	struct asph_fit *w = NULL;
	int r = asph_fit_alloc(s, n, &o, &w, err);

	if (r == 0)
		r = asph_fit_run(w, xyz, n, res, err);
	asph_fit_free(w);
	return r;
}

static void expect_pose(const struct asph_fit_result *r, const struct asph_pose *p)
{
	for (int k = 0; k < 3; k++)
		assert_true(fabs(r->value[ASPH_FIT_TX + k] - p->t[k]) < 1e-9);
	assert_true(fabs(r->value[ASPH_FIT_RX] - p->rx) < 1e-9);
	assert_true(fabs(r->value[ASPH_FIT_RY] - p->ry) < 1e-9);
}

/* An injected misalignment is recovered on both Q types. */
static void test_fit_pose(void **state)
{
	struct asph_prescription p[2] = { qbfs_lens(), qcon_lens() };
	const struct asph_pose poses[2] = { { { 0.043, -0.027, 0.0113 }, 4.1e-4, -2.7e-4 },
					    { { -0.061, 0.019, -0.0087 }, -3.3e-4, 5.9e-4 } };

	for (int i = 0; i < 2; i++) {
		struct asph_surface *s = build(&p[i]);
		size_t n;
		double *xyz = ring_points(s, &n), *meas = malloc(3 * n * sizeof(double));
		struct asph_synth_options so = { .pose = poses[i], .seed = 3 };
		struct asph_fit_result res;
		struct asph_error err;

		assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
		if (fit(s, meas, n, ASPH_FIT_DOF_RIGID, &res, &err) != 0)
			fail_msg("fit: %s", err.message);
		assert_true(res.converged);
		expect_pose(&res, &poses[i]);
		assert_true(res.rms.v < 0.01);
		assert_int_equal(res.n_used, n);
		free(xyz);
		free(meas);
		asph_surface_free(s);
	}
}

/*
 * R and k are those of the base conic, the departure kept as it is: for
 * Qcon (whose departure does not depend on R or k) a part made with
 * another R and k is exactly that, and the fit finds them. On Qbfs the
 * fit finds the nominal R and k of a part made to them.
 */
static void test_fit_radius_conic(void **state)
{
	struct asph_prescription nom = qcon_lens(), made = qcon_lens();
	made.R *= 1 + 2.7e-4;
	made.k += 1.9e-3;
	struct asph_surface *s = build(&nom), *part = build(&made);
	size_t n;
	double *xyz = ring_points(part, &n), *meas = malloc(3 * n * sizeof(double));
	struct asph_synth_options so = { .pose = { { 0.021, 0.033, -0.0071 }, 2.2e-4, 1.7e-4 } };
	struct asph_fit_result res;
	struct asph_error err;
	unsigned rk = ASPH_FIT_DOF_BIT(ASPH_FIT_R) | ASPH_FIT_DOF_BIT(ASPH_FIT_K);

	assert_int_equal(asph_fit_synthesize(part, xyz, n, &so, meas, NULL), 0);
	if (fit(s, meas, n, ASPH_FIT_DOF_RIGID | rk, &res, &err) != 0)
		fail_msg("fit: %s", err.message);
	expect_pose(&res, &so.pose);
	assert_true(fabs(res.value[ASPH_FIT_R] - made.R) < 1e-8);
	assert_true(fabs(res.value[ASPH_FIT_K] - made.k) < 1e-8);
	asph_surface_free(s);
	asph_surface_free(part);
	free(xyz);

	struct asph_prescription qb = qbfs_lens();
	s = build(&qb);
	xyz = ring_points(s, &n);
	assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
	if (fit(s, meas, n, ASPH_FIT_DOF_RIGID | rk, &res, &err) != 0)
		fail_msg("fit: %s", err.message);
	expect_pose(&res, &so.pose);
	assert_true(fabs(res.value[ASPH_FIT_R] - qb.R) < 1e-8);
	assert_true(fabs(res.value[ASPH_FIT_K] - qb.k) < 1e-8);
	asph_surface_free(s);
	free(xyz);
	free(meas);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_qbfs_closed_forms),
		cmocka_unit_test(test_qbfs_orthonormal),
		cmocka_unit_test(test_qbfs_high_order),
		cmocka_unit_test(test_qcon_closed_forms),
		cmocka_unit_test(test_qcon_high_order),
		cmocka_unit_test(test_qcon_orthogonal),
		cmocka_unit_test(test_qbfs_surface),
		cmocka_unit_test(test_qbfs_zero_is_sphere),
		cmocka_unit_test(test_qcon_as_even_asphere),
		cmocka_unit_test(test_derivatives),
		cmocka_unit_test(test_odd_asphere),
		cmocka_unit_test(test_refusals),
		cmocka_unit_test(test_plans),
		cmocka_unit_test(test_fit_pose),
		cmocka_unit_test(test_fit_radius_conic),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
