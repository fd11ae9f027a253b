/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The form quantities, slope, radius deviation and verdict of a fit, end to
 * end from synthetic measurements: against the independent computation of
 * tests/unit/lib/form/form-reference.h on the residual the fit leaves, and
 * against closed forms where the fit leaves the form error unchanged. */
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

#include "asph/fit.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "asph/zernike.h"
#include "../form/form-reference.h"

static struct asph_surface *lens(const char *name)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;

	assert_int_equal(asph_prescription_preset(name, &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/* Concentric rings evenly spaced in angle (the concentric plan's
 * sampling), the rim included. */
static double *rings(const struct asph_surface *s, int n_rings, size_t *n_out)
{
	double a = asph_surface_aperture_radius(s);
	size_t total = 1, k = 1;
	double *xyz;

	for (int j = 1; j <= n_rings; j++)
		total += (size_t)(6 * j);
	xyz = calloc(3 * total, sizeof(double));
	xyz[2] = asph_surface_sag(s, 0);
	for (int j = 1; j <= n_rings; j++)
		for (int i = 0; i < 6 * j; i++, k++) {
			double r = a * j / n_rings, t = 2 * M_PI * (i + 0.31 * j) / (6 * j);
			xyz[3 * k] = r * cos(t);
			xyz[3 * k + 1] = r * sin(t);
			xyz[3 * k + 2] = asph_surface_sag(s, r);
		}
	*n_out = total;
	return xyz;
}

static void assert_rel(double got, double want, double rel)
{
	if (!(fabs(got - want) <= rel * fabs(want)))
		fail_msg("got %.12g, want %.12g (relative %.3g > %.3g)", got, want,
			 fabs(got - want) / fabs(want), rel);
}

static void run_fit(const struct asph_surface *s, const double *xyz, size_t n,
		    const struct asph_fit_options *o, struct asph_fit **w,
		    struct asph_fit_result *r)
{
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_fit_alloc(s, n, o, w, &err), 0);
	if (asph_fit_run(*w, xyz, n, r, &err) < 0)
		fail_msg("%s", err.message);
	assert_true(r->converged);
}

/* The residual map of the fit, in the form module's coordinates. */
static void residual_field(const struct asph_fit *w, const struct asph_fit_result *r,
			   double a, double **rho, double **theta, double **v)
{
	double *xy = malloc(2 * r->n_used * sizeof(double));

	*rho = malloc(r->n_used * sizeof(double));
	*theta = malloc(r->n_used * sizeof(double));
	*v = malloc(r->n_used * sizeof(double));
	assert_int_equal(asph_fit_residual_map(w, xy, *v), r->n_used);
	for (size_t k = 0; k < r->n_used; k++) {
		(*rho)[k] = hypot(xy[2 * k], xy[2 * k + 1]) / a;
		(*theta)[k] = atan2(xy[2 * k + 1], xy[2 * k]);
	}
	free(xy);
}

/* Power (in fringes), spherical aberration, astigmatism, trefoil and noise
 * on a misaligned part: the quantities agree with the independent
 * computation on the residual, to 1e-3. */
static void test_against_reference(void **state)
{
	const char *names[] = { "weak", "turning-point" };

	for (size_t L = 0; L < 2; L++) {
		struct asph_surface *s = lens(names[L]);
		double a = asph_surface_aperture_radius(s), *rho, *theta, *v;
		/* 0.4 fringes of 546.07 nm of power as Z4: A = 2 sqrt(3) c4. */
		double c4 = 0.4 * 546.07 / 2 / (2 * sqrt(3));
		struct asph_synth_term terms[] = { { 4, c4 }, { 11, -14.2 }, { 6, 21.5 }, { 9, 9.7 } };
		struct asph_synth_options so = {
			.pose = { { 0.02, -0.013, 0.031 }, 2e-4, -3e-4 },
			.terms = terms, .n_terms = 4, .noise_nm = 1.5, .seed = 5,
		};
		struct asph_fit *w = NULL;
		struct asph_fit_result r;
		struct form_reference ref;
		size_t n;
		double *xyz = rings(s, 24, &n);

		assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, xyz, NULL), 0);
		run_fit(s, xyz, n, NULL, &w, &r);
		assert_true(r.form_valid && r.slope_valid);
		residual_field(w, &r, a, &rho, &theta, &v);
		form_reference(rho, theta, v, r.n_used, ASPH_FORM_DEFAULT_RSI_ORDER, &ref);
		assert_rel(r.form.A.v, ref.A, 1e-3);
		assert_rel(r.form.B.v, ref.B, 1e-3);
		assert_rel(r.form.C.v, ref.C, 1e-3);
		assert_rel(r.form.rms_t.v, ref.rms_t, 1e-3);
		assert_rel(r.form.rms_i.v, ref.rms_i, 1e-3);
		assert_rel(r.form.rms_a.v, ref.rms_a, 1e-3);
		assert_rel(r.form.A_fringes, ref.A / (546.07 / 2), 1e-3);
		assert_int_equal(r.uncertainty_k2.method, ASPH_UNCERTAINTY_COVARIANCE);
		assert_true(r.uncertainty_k2.A.v > 0 && r.uncertainty_k2.B.v > 0);
		/* No tolerance, no verdict; R not fitted, no radius deviation. */
		assert_false(r.verdict.present);
		assert_true(isnan(r.R_deviation_mm));
		free(rho);
		free(theta);
		free(v);
		free(xyz);
		asph_fit_free(w);
		asph_surface_free(s);
	}
}

/* Astigmatism has |m| = 2: the rigid fit leaves it as it is on rings, so
 * C = 0, RMSa = RMSi, and RMSi is the term's RMS over the points. */
static void test_pure_astigmatism(void **state)
{
	struct asph_surface *s = lens("strong");
	struct asph_synth_term terms[] = { { 6, 27.0 } };
	struct asph_synth_options so = { .pose = { { 0.01, 0.02, -0.01 }, 1e-4, 2e-4 },
					 .terms = terms, .n_terms = 1, .seed = 1 };
	struct asph_fit *w = NULL;
	struct asph_fit_result r;
	size_t n;
	double *xyz = rings(s, 20, &n), s2;

	assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, xyz, NULL), 0);
	run_fit(s, xyz, n, NULL, &w, &r);
	assert_true(fabs(r.form.C.v) < 1e-3 * r.form.B.v);
	assert_rel(r.form.rms_a.v, r.form.rms_i.v, 1e-3);
	/* 27 Z6 has RMS 27 over the disk; over equal-angle rings at
	 * radii k / 20, sqrt(mean(6 rho^4 cos^2)) = 27 sqrt(3 mean rho^4). */
	double m4 = 0, cnt = 1;
	for (int jj = 1; jj <= 20; jj++) {
		m4 += 6.0 * jj * pow(jj / 20.0, 4);
		cnt += 6.0 * jj;
	}
	s2 = 27.0 * sqrt(3 * m4 / cnt);
	assert_rel(r.form.rms_i.v, s2, 1e-3);
	free(xyz);
	asph_fit_free(w);
	asph_surface_free(s);
}

/* Pure power along z with sag residuals and the part in place: the rigid
 * fit takes the piston only, A is the power, B = C = 0. */
static void test_pure_power(void **state)
{
	struct asph_surface *s = lens("strong");
	struct asph_fit_options o = { .residual = ASPH_FIT_RESIDUAL_SAG };
	double a = asph_surface_aperture_radius(s), power_nm = 0.6 * 546.07 / 2;
	struct asph_fit *w = NULL;
	struct asph_fit_result r;
	size_t n;
	double *xyz = rings(s, 20, &n);

	for (size_t k = 0; k < n; k++) {
		double rr = hypot(xyz[3 * k], xyz[3 * k + 1]) / a;
		xyz[3 * k + 2] += power_nm * 1e-6 * rr * rr;
	}
	run_fit(s, xyz, n, &o, &w, &r);
	assert_rel(r.form.A.v, power_nm, 1e-6);
	assert_rel(r.form.A_fringes, 0.6, 1e-6);
	assert_true(fabs(r.form.B.v) < 1e-6 * power_nm);
	assert_true(fabs(r.form.C.v) < 1e-6 * power_nm);
	free(xyz);
	asph_fit_free(w);
	asph_surface_free(s);
}

/* R fitted: the deviation from the nominal radius and its uncertainty,
 * and a tolerance decides on every item given. */
static void test_radius_and_verdict(void **state)
{
	struct asph_surface *s = lens("weak");
	struct asph_tolerance t;
	struct asph_error err;
	struct asph_fit_options o = { .dof = ASPH_FIT_DOF_RIGID | ASPH_FIT_DOF_BIT(ASPH_FIT_R),
				      .tolerance = &t };
	struct asph_synth_term terms[] = { { 6, 15.0 } };
	struct asph_synth_options so = { .terms = terms, .n_terms = 1, .noise_nm = 1, .seed = 2 };
	struct asph_fit *w = NULL;
	struct asph_fit_result r;
	size_t n;
	double *xyz = rings(s, 16, &n);
	const char *tol = "{\"iso10110_5\": \"3/-(0.5/0.2); RMSa < 0.1\", \"R_mm\": 0.001,"
			  "\"slope_urad\": {\"rms\": 1000, \"length_mm\": 2}}";

	asph_error_clear(&err);
	assert_int_equal(asph_tolerance_parse_json(tol, strlen(tol), "t", &t, &err), 0);
	assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, xyz, NULL), 0);
	run_fit(s, xyz, n, &o, &w, &r);
	assert_true(fabs(r.R_deviation_mm) < 5 * r.uncertainty[ASPH_FIT_R] + 1e-9);
	assert_true(r.uncertainty_k2.R_mm > 0);
	assert_true(r.verdict.present);
	assert_int_equal(r.verdict.n_items, 5);
	assert_string_equal(r.verdict.items[0].quantity, "B_nm");
	assert_string_equal(r.verdict.items[2].quantity, "rms_a_nm");
	assert_string_equal(r.verdict.items[3].quantity, "slope_rms_urad");
	assert_string_equal(r.verdict.items[4].quantity, "R_deviation_mm");
	assert_rel(r.slope.length_mm, 2, 0);
	/* 15 nm of astigmatism: B about 73 nm < 136.5 nm; RMSa 15 nm < 27.3 */
	assert_int_equal(r.verdict.items[0].verdict, ASPH_VERDICT_PASS);
	assert_int_equal(r.verdict.items[2].verdict, ASPH_VERDICT_PASS);
	assert_int_equal(r.verdict.overall, ASPH_VERDICT_PASS);
	char *json = NULL;
	assert_int_equal(asph_fit_result_to_json(&r, "weak", 0, &json), 0);
	assert_non_null(strstr(json, "\"verdict\":{\"overall\":\"pass\""));
	assert_non_null(strstr(json, "\"deviation_mm\""));
	free(json);
	free(xyz);
	asph_fit_free(w);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_against_reference),
		cmocka_unit_test(test_pure_astigmatism),
		cmocka_unit_test(test_pure_power),
		cmocka_unit_test(test_radius_and_verdict),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
