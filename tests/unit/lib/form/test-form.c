/* SPDX-License-Identifier: GPL-3.0-or-later */
/* ISO 14999-4 quantities against closed forms and an independent
 * computation (form-reference.h). */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>

#include "asph/form.h"
#include "asph/zernike.h"
#include "form-reference.h"

#define WAVELENGTH 632.8

struct field {
	size_t n;
	double *rho, *theta, *v;
};

/*
 * Concentric rings of equal area, each evenly spaced in angle with an
 * offset per ring (as the concentric plan samples a part), plus the centre.
 */
static void field_rings(struct field *f, int rings)
{
	size_t n = 1;

	for (int k = 1; k <= rings; k++)
		n += (size_t)(6 * k);
	f->n = n;
	f->rho = malloc(n * sizeof(double));
	f->theta = malloc(n * sizeof(double));
	f->v = calloc(n, sizeof(double));
	f->rho[0] = f->theta[0] = 0;
	n = 1;
	for (int k = 1; k <= rings; k++)
		for (int j = 0; j < 6 * k; j++, n++) {
			f->rho[n] = (double)k / rings;
			f->theta[n] = 2 * M_PI * (j + 0.37 * k) / (6 * k);
		}
}

static void field_free(struct field *f)
{
	free(f->rho);
	free(f->theta);
	free(f->v);
}

static void add_zernike(struct field *f, int j, double c)
{
	for (size_t i = 0; i < f->n; i++)
		f->v[i] += c * asph_zernike_noll(j, f->rho[i], f->theta[i]);
}

static void assert_rel(double got, double want, double rel)
{
	if (!(fabs(got - want) <= rel * fabs(want)))
		fail_msg("got %.12g, want %.12g (relative %.3g > %.3g)", got, want,
			 fabs(got - want) / fabs(want), rel);
}

static void compute(const struct field *f, struct asph_form *out)
{
	struct asph_form_options o = { .wavelength_nm = WAVELENGTH, .noise_nm = NAN };

	assert_int_equal(asph_form_compute(f->rho, f->theta, f->v, f->n, &o, out, NULL, NULL), 0);
}

/* Power in fringes, spherical aberration, astigmatism, trefoil and noise:
 * every quantity as the independent computation has it, to 1e-3. */
static void test_mixed_against_reference(void **state)
{
	struct field f;
	struct asph_form r;
	struct form_reference ref;
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	double fringes = 0.37, fringe = WAVELENGTH / 2;

	field_rings(&f, 30);
	gsl_rng_set(rng, 11);
	for (size_t i = 0; i < f.n; i++)
		f.v[i] = fringes * fringe * f.rho[i] * f.rho[i] + 3.1 +
			 0.7 * f.rho[i] * cos(f.theta[i]) + gsl_ran_gaussian_ziggurat(rng, 1.3);
	add_zernike(&f, 11, -17.3);    /* spherical aberration */
	add_zernike(&f, 6, 23.9);      /* astigmatism */
	add_zernike(&f, 9, 11.2);      /* trefoil */
	add_zernike(&f, 22, 4.1);      /* secondary spherical */
	compute(&f, &r);
	form_reference(f.rho, f.theta, f.v, f.n, ASPH_FORM_DEFAULT_RSI_ORDER, &ref);
	assert_rel(r.A.v, ref.A, 1e-3);
	assert_rel(r.B.v, ref.B, 1e-3);
	assert_rel(r.C.v, ref.C, 1e-3);
	assert_rel(r.rms_t.v, ref.rms_t, 1e-3);
	assert_rel(r.rms_i.v, ref.rms_i, 1e-3);
	assert_rel(r.rms_a.v, ref.rms_a, 1e-3);
	assert_rel(r.A_fringes, ref.A / fringe, 1e-3);
	assert_rel(r.B_fringes, ref.B / fringe, 1e-3);
	assert_rel(r.C_fringes, ref.C / fringe, 1e-3);
	/* The power comes back as injected, less what the Z11 and Z22 terms
	 * put into rho^2: none over the disk, a few percent over 30 rings
	 * (pure power comes back exactly: test_pure_power). */
	assert_rel(r.A_fringes, fringes, 0.06);
	assert_true(r.rms_t.v > r.rms_i.v && r.rms_i.v > r.rms_a.v);
	gsl_rng_free(rng);
	field_free(&f);
}

/* Pure power, with piston and tilt: A is the power, B = C = 0. */
static void test_pure_power(void **state)
{
	struct field f;
	struct asph_form r;
	double power = 0.83 * WAVELENGTH / 2;

	field_rings(&f, 20);
	for (size_t i = 0; i < f.n; i++)
		f.v[i] = -power * f.rho[i] * f.rho[i] + 40 - 2.5 * f.rho[i] * sin(f.theta[i]);
	compute(&f, &r);
	assert_rel(r.A.v, -power, 1e-12);
	assert_rel(r.A_fringes, -0.83, 1e-12);
	assert_true(fabs(r.B.v) < 1e-9 * power);
	assert_true(fabs(r.C.v) < 1e-9 * power);
	assert_true(r.rms_i.v < 1e-9 * power && r.rms_a.v < 1e-9 * power);
	/* RMSt of power alone: RMS of p (rho^2 - mean) over the points. */
	double mean = 0, s2 = 0;
	for (size_t i = 0; i < f.n; i++)
		mean += f.rho[i] * f.rho[i] / (double)f.n;
	for (size_t i = 0; i < f.n; i++)
		s2 += pow(power * (f.rho[i] * f.rho[i] - mean), 2) / (double)f.n;
	assert_rel(r.rms_t.v, sqrt(s2), 1e-9);
	field_free(&f);
}

/* Pure astigmatism on rings: C = 0, RMSa = RMSi = RMSt = the term's RMS,
 * B its PV over the points. */
static void test_pure_astigmatism(void **state)
{
	struct field f;
	struct asph_form r;
	double c = 31.7, s2 = 0, lo = INFINITY, hi = -INFINITY;

	field_rings(&f, 20);
	add_zernike(&f, 5, c);
	for (size_t i = 0; i < f.n; i++) {
		s2 += f.v[i] * f.v[i] / (double)f.n;
		lo = fmin(lo, f.v[i]);
		hi = fmax(hi, f.v[i]);
	}
	compute(&f, &r);
	assert_true(fabs(r.C.v) < 1e-9 * c);
	assert_true(fabs(r.A.v) < 1e-9 * c);
	assert_rel(r.rms_a.v, r.rms_i.v, 1e-12);
	assert_rel(r.rms_i.v, sqrt(s2), 1e-9);
	assert_rel(r.rms_t.v, sqrt(s2), 1e-9);
	assert_rel(r.B.v, hi - lo, 1e-9);
	field_free(&f);
}

/* Pure spherical aberration: C = B (all irregularity is rotationally
 * symmetric), RMSa = 0. */
static void test_pure_spherical(void **state)
{
	struct field f;
	struct asph_form r;

	field_rings(&f, 20);
	add_zernike(&f, 11, 13.3);
	compute(&f, &r);
	assert_rel(r.C.v, r.B.v, 1e-9);
	assert_true(r.rms_a.v < 1e-9 * 13.3);
	field_free(&f);
}

/* The propagated uncertainty of A against the spread of A over repeated
 * noise (a small Monte Carlo: 60 draws, so 30 % covers it many times over). */
static void test_uncertainty_of_A(void **state)
{
	struct field f;
	struct asph_form r;
	struct asph_uncertainty_k2 u;
	struct asph_form_options o = { .noise_nm = 2.0 };
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	double sum = 0, sum2 = 0;
	const int draws = 60;

	field_rings(&f, 12);
	for (int k = 0; k < draws; k++) {
		for (size_t i = 0; i < f.n; i++)
			f.v[i] = 50 * f.rho[i] * f.rho[i] + gsl_ran_gaussian_ziggurat(rng, 2.0);
		asph_uncertainty_k2_clear(&u);
		assert_int_equal(asph_form_compute(f.rho, f.theta, f.v, f.n, &o, &r, &u, NULL), 0);
		sum += r.A.v;
		sum2 += r.A.v * r.A.v;
	}
	double sd = sqrt((sum2 - sum * sum / draws) / (draws - 1));
	assert_int_equal(u.method, ASPH_UNCERTAINTY_COVARIANCE);
	assert_rel(u.A.v / 2, sd, 0.3);
	assert_rel(u.rms_t.v, 2 * 2.0 / sqrt((double)f.n), 1e-12);
	gsl_rng_free(rng);
	field_free(&f);
}

static void test_bad_input(void **state)
{
	struct field f;
	struct asph_form r;
	struct asph_error err;
	struct asph_form_options o = { .rsi_order = 7 };

	field_rings(&f, 3);
	asph_error_clear(&err);
	assert_int_equal(asph_form_compute(f.rho, f.theta, f.v, f.n, &o, &r, NULL, &err), -EINVAL);
	assert_non_null(strstr(err.message, "order 7"));
	o.rsi_order = 0;
	f.v[4] = NAN;
	assert_int_equal(asph_form_compute(f.rho, f.theta, f.v, f.n, &o, &r, NULL, &err), -EINVAL);
	assert_non_null(strstr(err.message, "point 4"));
	f.v[4] = 0;
	/* 19 points cannot determine 13 terms at 4 radii. */
	assert_int_equal(asph_form_compute(f.rho, f.theta, f.v, f.n, &o, &r, NULL, &err), -EDOM);
	assert_int_equal(asph_form_compute(f.rho, f.theta, f.v, 10, &o, &r, NULL, &err), -EDOM);
	field_free(&f);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_mixed_against_reference),
		cmocka_unit_test(test_pure_power),
		cmocka_unit_test(test_pure_astigmatism),
		cmocka_unit_test(test_pure_spherical),
		cmocka_unit_test(test_uncertainty_of_A),
		cmocka_unit_test(test_bad_input),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
