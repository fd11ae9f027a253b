/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include <cmocka.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_integration.h>
#include <gsl/gsl_rng.h>

#include "asph/zernike.h"

/* Noll's Table I, written out independently of the implementation. */
static double closed_form(int j, double r, double t)
{
	switch (j) {
	case 1: return 1.0;
	case 2: return 2 * r * cos(t);
	case 3: return 2 * r * sin(t);
	case 4: return sqrt(3) * (2 * r * r - 1);
	case 5: return sqrt(6) * r * r * sin(2 * t);
	case 6: return sqrt(6) * r * r * cos(2 * t);
	case 7: return sqrt(8) * (3 * pow(r, 3) - 2 * r) * sin(t);
	case 8: return sqrt(8) * (3 * pow(r, 3) - 2 * r) * cos(t);
	case 9: return sqrt(8) * pow(r, 3) * sin(3 * t);
	case 10: return sqrt(8) * pow(r, 3) * cos(3 * t);
	case 11: return sqrt(5) * (6 * pow(r, 4) - 6 * r * r + 1);
	case 12: return sqrt(10) * (4 * pow(r, 4) - 3 * r * r) * cos(2 * t);
	case 13: return sqrt(10) * (4 * pow(r, 4) - 3 * r * r) * sin(2 * t);
	case 14: return sqrt(10) * pow(r, 4) * cos(4 * t);
	case 15: return sqrt(10) * pow(r, 4) * sin(4 * t);
	default: return NAN;
	}
}

static void test_closed_forms(void **state)
{
	/* High-entropy points, including the centre and the rim. */
	const double pts[][2] = {
		{ 0.0, 0.3 }, { 0.137, 0.4121 }, { 0.5813, 2.7183 },
		{ 0.7719, -1.234 }, { 0.9371, 4.0187 }, { 1.0, 5.8803 },
	};

	for (int j = 1; j <= 15; j++)
		for (size_t i = 0; i < sizeof(pts) / sizeof(pts[0]); i++) {
			double want = closed_form(j, pts[i][0], pts[i][1]);
			double got = asph_zernike_noll(j, pts[i][0], pts[i][1]);
			assert_true(fabs(got - want) <= 1e-14 * (1 + fabs(want)));
		}
}

static void test_noll_index(void **state)
{
	/* (n, m) of j = 1..15 in Noll's order. */
	const int nm[15][2] = {
		{ 0, 0 }, { 1, 1 }, { 1, -1 }, { 2, 0 }, { 2, -2 },
		{ 2, 2 }, { 3, -1 }, { 3, 1 }, { 3, -3 }, { 3, 3 },
		{ 4, 0 }, { 4, 2 }, { 4, -2 }, { 4, 4 }, { 4, -4 },
	};
	int n, m;

	for (int j = 1; j <= 15; j++) {
		asph_zernike_noll_to_nm(j, &n, &m);
		assert_int_equal(n, nm[j - 1][0]);
		assert_int_equal(m, nm[j - 1][1]);
	}
	/* The mapping is a bijection onto the valid (n, m) up to the limit. */
	for (int j = 1; j <= ASPH_ZERNIKE_MAX_J; j++) {
		asph_zernike_noll_to_nm(j, &n, &m);
		assert_true(abs(m) <= n && (n - abs(m)) % 2 == 0);
		assert_int_equal(asph_zernike_nm_to_noll(n, m), j);
	}
	asph_zernike_noll_to_nm(0, &n, &m);
	assert_int_equal(n, -1);
	assert_int_equal(asph_zernike_nm_to_noll(3, 2), 0);
	assert_true(isnan(asph_zernike_noll(0, 0.5, 0.1)));
}

/* (1/pi) int_disk Z_i Z_j = delta_ij: Gauss-Legendre in rho (exact for the
 * polynomial degrees involved) times an equispaced rule in theta (exact for
 * trigonometric degree below the number of nodes). */
static void test_orthonormality(void **state)
{
	enum { NJ = 36, NT = 64, NR = 16 };
	gsl_integration_glfixed_table *gl = gsl_integration_glfixed_table_alloc(NR);
	static double gram[NJ][NJ];
	double z[NJ];

	for (size_t ir = 0; ir < NR; ir++) {
		double rho, wr;
		gsl_integration_glfixed_point(0, 1, ir, &rho, &wr, gl);
		for (int it = 0; it < NT; it++) {
			double th = 2 * M_PI * (it + 0.3) / NT;
			double wt = wr * rho * (2 * M_PI / NT) / M_PI;
			asph_zernike_noll_all(NJ, rho, th, z);
			for (int i = 0; i < NJ; i++)
				for (int j = 0; j < NJ; j++)
					gram[i][j] += wt * z[i] * z[j];
		}
	}
	for (int i = 0; i < NJ; i++)
		for (int j = 0; j < NJ; j++)
			assert_true(fabs(gram[i][j] - (i == j)) < 1e-12);
	gsl_integration_glfixed_table_free(gl);
}

static void test_all_and_gradient(void **state)
{
	double z[66];
	const double h = 1e-6;

	for (int k = 0; k < 7; k++) {
		double rho = 0.061 + 0.1537 * k, th = 0.7 + 1.93 * k;
		double u = rho * cos(th), v = rho * sin(th);

		asph_zernike_noll_all(66, rho, th, z);
		for (int j = 1; j <= 66; j++) {
			double g[2], fd[2];
			assert_true(fabs(z[j - 1] - asph_zernike_noll(j, rho, th)) < 1e-13);
			asph_zernike_noll_gradient(j, rho, th, g);
			/* Central differences in Cartesian coordinates. */
			fd[0] = (asph_zernike_noll(j, hypot(u + h, v), atan2(v, u + h)) -
				 asph_zernike_noll(j, hypot(u - h, v), atan2(v, u - h))) / (2 * h);
			fd[1] = (asph_zernike_noll(j, hypot(u, v + h), atan2(v + h, u)) -
				 asph_zernike_noll(j, hypot(u, v - h), atan2(v - h, u))) / (2 * h);
			assert_true(fabs(g[0] - fd[0]) < 1e-6 * (1 + fabs(fd[0])));
			assert_true(fabs(g[1] - fd[1]) < 1e-6 * (1 + fabs(fd[1])));
		}
	}
	/* At the centre, among the first 15 only Z2, Z3 (slope 2) and Z7, Z8
	 * (slope -2 sqrt 8) have a gradient. */
	for (int j = 1; j <= 15; j++) {
		double g[2];
		double gx = j == 2 ? 2 : j == 8 ? -2 * sqrt(8) : 0;
		double gy = j == 3 ? 2 : j == 7 ? -2 * sqrt(8) : 0;
		asph_zernike_noll_gradient(j, 0.0, 1.1, g);
		assert_true(fabs(g[0] - gx) < 1e-13 && fabs(g[1] - gy) < 1e-13);
	}
}

static void test_series(void **state)
{
	double coef[21], g[2], want = 0, gw[2] = { 0, 0 };

	for (int j = 0; j < 21; j++)
		coef[j] = sin(1.3 * j + 0.2);
	for (int j = 1; j <= 21; j++) {
		double gj[2];
		want += coef[j - 1] * asph_zernike_noll(j, 0.6123, -2.05);
		asph_zernike_noll_gradient(j, 0.6123, -2.05, gj);
		gw[0] += coef[j - 1] * gj[0];
		gw[1] += coef[j - 1] * gj[1];
	}
	assert_true(fabs(asph_zernike_series(coef, 21, 0.6123, -2.05, g) - want) < 1e-13);
	assert_true(fabs(g[0] - gw[0]) < 1e-12 && fabs(g[1] - gw[1]) < 1e-12);
}

static void random_disk(gsl_rng *rng, size_t n, double *rho, double *th)
{
	for (size_t i = 0; i < n; i++) {
		rho[i] = sqrt(gsl_rng_uniform(rng));
		th[i] = 2 * M_PI * gsl_rng_uniform(rng);
	}
}

static void test_decompose(void **state)
{
	enum { N = 3000, P = 36 };
	static double rho[N], th[N], val[N], w[N];
	double truth[P], coef[P];
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	struct asph_error err;

	gsl_rng_set(rng, 20261121);
	random_disk(rng, N, rho, th);
	for (int j = 0; j < P; j++)
		truth[j] = 40 * cos(0.77 * j + 0.4);
	for (size_t i = 0; i < N; i++) {
		val[i] = asph_zernike_series(truth, P, rho[i], th[i], NULL);
		w[i] = 0.5 + gsl_rng_uniform(rng);
	}
	/* One point far off the model with weight 0 must not count. */
	val[17] += 1e6;
	w[17] = 0;
	assert_int_equal(asph_zernike_decompose(rho, th, val, w, N, P, coef, &err), 0);
	for (int j = 0; j < P; j++)
		assert_true(fabs(coef[j] - truth[j]) < 1e-9);

	/* Fewer terms than the data holds: the least-squares projection of
	 * an orthogonal set on a uniform random sample is close to truth. */
	val[17] -= 1e6;
	assert_int_equal(asph_zernike_decompose(rho, th, val, NULL, N, 15, coef, &err), 0);
	for (int j = 0; j < 15; j++)
		assert_true(fabs(coef[j] - truth[j]) < 15);

	gsl_rng_free(rng);
}

/* Points crowded into a thin ring near the rim: the terms are nearly
 * dependent there, the normal equations refuse, QR still solves. */
static void test_decompose_ill_conditioned(void **state)
{
	enum { N = 4000, P = 21 };
	static double rho[N], th[N], val[N], grad[2 * N];
	double truth[P], coef[P];
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);

	gsl_rng_set(rng, 31);
	for (int i = 0; i < N; i++) {
		rho[i] = 0.99 + 0.01 * gsl_rng_uniform(rng);
		th[i] = 2 * M_PI * gsl_rng_uniform(rng);
	}
	for (int j = 0; j < P; j++)
		truth[j] = 3.3 * sin(0.91 * j + 0.2);
	asph_zernike_series_many(truth, P, rho, th, N, val, grad);
	for (int i = 0; i < N; i += 97) {
		double g[2];
		assert_true(fabs(val[i] - asph_zernike_series(truth, P, rho[i], th[i], g)) < 1e-13);
		assert_true(fabs(grad[2 * i] - g[0]) < 1e-12 && fabs(grad[2 * i + 1] - g[1]) < 1e-12);
	}
	assert_int_equal(asph_zernike_decompose(rho, th, val, NULL, N, P, coef, NULL), 0);
	for (int j = 0; j < P; j++)
		assert_true(fabs(coef[j] - truth[j]) < 1e-6);
	gsl_rng_free(rng);
}

static void test_decompose_bad(void **state)
{
	enum { N = 200 };
	double rho[N], th[N], val[N], coef[36];
	struct asph_error err;

	for (int i = 0; i < N; i++) {
		rho[i] = 0.9 * i / N;
		th[i] = 0.4;          /* every point on one diameter */
		val[i] = 0.3 * i;
	}
	assert_int_equal(asph_zernike_decompose(rho, th, val, NULL, N, 36, coef, &err), -EDOM);
	assert_int_equal(asph_zernike_decompose(rho, th, val, NULL, 10, 36, coef, &err), -EDOM);
	assert_int_equal(asph_zernike_decompose(rho, th, val, NULL, N, 0, coef, &err), -EINVAL);
	val[3] = NAN;
	assert_int_equal(asph_zernike_decompose(rho, th, val, NULL, N, 4, coef, &err), -EINVAL);
	assert_int_equal(err.code, -EINVAL);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_closed_forms),
		cmocka_unit_test(test_noll_index),
		cmocka_unit_test(test_orthonormality),
		cmocka_unit_test(test_all_and_gradient),
		cmocka_unit_test(test_series),
		cmocka_unit_test(test_decompose),
		cmocka_unit_test(test_decompose_ill_conditioned),
		cmocka_unit_test(test_decompose_bad),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
