/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Monte Carlo uncertainty against closed forms and independent
 * computations. Statistical tolerances are stated with the spread they
 * allow: the relative standard deviation of a standard deviation estimated
 * from M trials is about 1 / sqrt(2 (M - 1)). */
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
#include <gsl/gsl_errno.h>
#include <gsl/gsl_linalg.h>
#include <jansson.h>

#include "asph/fit.h"
#include "asph-mc/mc-runner.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "asph/tolerance.h"
#include "asph/uncertainty.h"
#include "custom-surface.h"

#define N_POINTS 160

static int under_valgrind(void)
{
	const char *v = getenv("ASPH_UNDER_VALGRIND");
	return v && *v && strcmp(v, "0") != 0;
}

/* 400 trials (100 under valgrind, which checks the memory, not the
 * statistics). */
static size_t trials(void)
{
	return under_valgrind() ? 100 : 400;
}

/* A band of z standard deviations of a standard deviation estimated from
 * the trials: z = 2.8 gives 10 % for 400 trials (20 % for 100). */
static double band(double z)
{
	return z / sqrt(2.0 * (double)(trials() - 1));
}

static struct asph_surface *lens(const char *name)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;

	assert_int_equal(asph_prescription_preset(name, &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/* A Fermat spiral of n points over 0.95 of the aperture, in scan order, on
 * the surface lifted by tz. */
static double *spiral(const struct asph_surface *s, size_t n, double tz)
{
	double a = 0.95 * asph_surface_aperture_radius(s), *xyz = malloc(3 * n * sizeof(double));

	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt((i + 0.5) / (double)n), t = 2.399963229728653 * (double)i;
		xyz[3 * i] = r * cos(t);
		xyz[3 * i + 1] = r * sin(t);
		xyz[3 * i + 2] = asph_surface_sag_xy(s, xyz[3 * i], xyz[3 * i + 1]) + tz;
	}
	return xyz;
}

struct run {
	struct asph_surface *s;
	double *xyz;
	size_t n;
	struct asph_fit_options fo;
	struct asph_fit_result ref;
	struct asph_mc *mc;
	struct asph_mc_result res;
};

static void reference_fit(struct run *r)
{
	struct asph_fit *w = NULL;
	struct asph_error err;

	assert_int_equal(asph_fit_alloc(r->s, r->n, &r->fo, &w, &err), 0);
	assert_int_equal(asph_fit_run(w, r->xyz, r->n, &r->ref, &err), 0);
	assert_true(r->ref.converged);
	asph_fit_free(w);
}

/* The trials on this thread through libasph's pieces alone: blocks as the
 * run asks for them, each in two halves, the later half first (any order
 * gives the same values). */
static int run_serial(struct asph_mc *mc, struct asph_mc_result *res)
{
	struct asph_mc_worker *w = NULL;
	struct asph_error err;
	size_t done = 0, first, count;

	asph_error_clear(&err);
	assert_int_equal(asph_mc_worker_alloc(mc, &w, &err), 0);
	while (asph_mc_next_block(mc, done, &first, &count)) {
		size_t half = count / 2;
		assert_int_equal(asph_mc_run_trials(mc, w, first + half, count - half), 0);
		assert_int_equal(asph_mc_run_trials(mc, w, first, half), 0);
		done = first + count;
	}
	assert_int_equal(asph_mc_run_trials(mc, w, asph_mc_planned(mc), 1 << 30), -EINVAL);
	asph_mc_worker_free(w);
	return asph_mc_finish(mc, done, 0, res, &err);
}

/* threads 0: run_serial(); else the threaded runner on that many. */
static int run_mc_threads(struct run *r, const struct asph_uncertainty_model *m,
			  const struct asph_mc_options *o, int threads)
{
	struct asph_mc_threads th = { .n_threads = threads };
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_mc_alloc(r->s, r->xyz, r->n, &r->fo, &r->ref, m, o, &r->mc, &err), 0);
	if (threads == 0)
		return run_serial(r->mc, &r->res);
	return asph_mc_run_threads(r->mc, &th, &r->res, &err);
}

static int run_mc(struct run *r, const struct asph_uncertainty_model *m,
		  const struct asph_mc_options *o)
{
	return run_mc_threads(r, m, o, 0);
}

static void run_free(struct run *r)
{
	asph_mc_free(r->mc);
	free(r->xyz);
	asph_surface_free(r->s);
}

static void assert_rel(double got, double want, double rel, const char *what)
{
	if (!(fabs(got - want) <= rel * fabs(want)))
		fail_msg("%s: got %.9g, want %.9g (relative %.3g > %.3g)", what, got, want,
			 fabs(got - want) / fabs(want), rel);
}

/* Piston only, sag residual: tz is the mean of z - S, so probe noise sigma
 * gives u(tz) = sigma / sqrt(N). The residual is the noise less its mean:
 * its RMS is sigma sqrt((N - 1) / N) on average and spreads by about
 * sigma / sqrt(2 N). */
static void test_piston_probe_noise(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct asph_mc_options o = { .n_trials = trials(), .fixed = 1, .seed = 11 };
	const double sigma_nm = 37.0;

	(void)state;
	r.s = custom(41.3, -0.6, 20);
	r.xyz = spiral(r.s, r.n, 0.0123);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ);
	r.fo.residual = ASPH_FIT_RESIDUAL_SAG;
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	m.probe_noise_nm = sigma_nm;
	assert_int_equal(run_mc(&r, &m, &o), 0);
	assert_int_equal(r.res.n_trials, trials());
	assert_int_equal(r.res.n_failed, 0);
	assert_true(r.res.covered[ASPH_FIT_TZ]);
	assert_false(r.res.covered[ASPH_FIT_TX]);
	assert_rel(r.res.u[ASPH_FIT_TZ], sigma_nm * 1e-6 / sqrt((double)r.n), band(2.8), "u(tz)");
	/* the mean: within 4 u / sqrt(M) of the reference */
	assert_true(fabs(r.res.mean[ASPH_FIT_TZ] - 0.0123) <
		    4 * r.res.u[ASPH_FIT_TZ] / sqrt((double)trials()));
	double n = (double)r.n;
	assert_rel(r.res.mean[ASPH_MC_RMS], sigma_nm * sqrt((n - 1) / n), 0.02, "mean RMS");
	assert_rel(r.res.u[ASPH_MC_RMS], sigma_nm / sqrt(2 * n), band(3.4), "u(RMS)");
	run_free(&r);
}

/* A linear least-squares case: on a nearly flat surface with the sag
 * residual, tz, rx, ry enter z linearly (z - tz + rx y - ry x to first
 * order), so their covariance is sigma^2 (J^T J)^-1 with J's rows
 * (1, y, x): the 10 % agreement, against GSL's Cholesky. */
static void test_linear_covariance(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct asph_mc_options o = { .n_trials = trials(), .fixed = 1, .seed = 5 };
	const double sigma_nm = 23.0;
	gsl_matrix *jtj = gsl_matrix_calloc(3, 3);

	(void)state;
	r.s = custom(1e7, 0, 30);
	r.xyz = spiral(r.s, r.n, 0.004);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ) | ASPH_FIT_DOF_BIT(ASPH_FIT_RX) |
		   ASPH_FIT_DOF_BIT(ASPH_FIT_RY);
	r.fo.residual = ASPH_FIT_RESIDUAL_SAG;
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	m.probe_noise_nm = sigma_nm;
	assert_int_equal(run_mc(&r, &m, &o), 0);
	for (size_t i = 0; i < r.n; i++) {
		double row[3] = { 1, r.xyz[3 * i + 1], r.xyz[3 * i] };
		for (int a = 0; a < 3; a++)
			for (int b = 0; b < 3; b++)
				*gsl_matrix_ptr(jtj, (size_t)a, (size_t)b) += row[a] * row[b];
	}
	assert_int_equal(gsl_linalg_cholesky_decomp1(jtj), 0);
	assert_int_equal(gsl_linalg_cholesky_invert(jtj), 0);
	double s2 = sigma_nm * 1e-6;
	assert_rel(r.res.u[ASPH_FIT_TZ], s2 * sqrt(gsl_matrix_get(jtj, 0, 0)), band(2.8), "u(tz)");
	assert_rel(r.res.u[ASPH_FIT_RX], s2 * sqrt(gsl_matrix_get(jtj, 1, 1)), band(2.8), "u(rx)");
	assert_rel(r.res.u[ASPH_FIT_RY], s2 * sqrt(gsl_matrix_get(jtj, 2, 2)), band(2.8), "u(ry)");
	gsl_matrix_free(jtj);
	run_free(&r);
}

/* Tip radius alone on a sphere: every point moves by d along the normal,
 * which is the concentric sphere of radius R - d with its vertex at z = d.
 * So each trial's R + tz is R exactly, and u(R) = u(tz) = sigma_tip. */
static void test_tip_radius_sphere(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct asph_mc_options o = { .n_trials = trials(), .fixed = 1, .seed = 3 };
	const double R = 37.9, sigma_um = 0.8;
	size_t nt;

	(void)state;
	r.s = custom(R, 0, 24);
	r.xyz = spiral(r.s, r.n, 0);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ) | ASPH_FIT_DOF_BIT(ASPH_FIT_R);
	r.fo.xtol = 1e-13;
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	m.tip_radius_um = sigma_um;
	assert_int_equal(run_mc(&r, &m, &o), 0);
	const double *v = asph_mc_values(r.mc, &nt);
	assert_int_equal(nt, trials());
	for (size_t t = 0; t < nt; t++) {
		const double *q = v + t * ASPH_MC_N_QUANTITIES;
		/* the trials vary the curvature c = 1/R */
		if (!(fabs(1 / q[ASPH_FIT_R] + q[ASPH_FIT_TZ] - R) < 1e-9))
			fail_msg("trial %zu: R %.12f + tz %.12f != %g", t, 1 / q[ASPH_FIT_R],
				 q[ASPH_FIT_TZ], R);
	}
	/* u(R) = u(c) R^2, to first order in u(R) / R (2e-5 here) */
	assert_rel(r.res.u[ASPH_FIT_R] * R * R, sigma_um * 1e-3, band(2.8), "u(R)");
	assert_rel(r.res.u[ASPH_FIT_TZ], sigma_um * 1e-3, band(2.8), "u(tz)");
	run_free(&r);
}

/* Drift alone, piston only: z gains d i / (N - 1), whose mean is d / 2, so
 * each trial's tz moves by exactly half the drift and u(tz) = sigma_d / 2. */
static void test_drift_piston(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct asph_mc_options o = { .n_trials = trials(), .fixed = 1, .seed = 8 };
	const double sigma_nm = 120;

	(void)state;
	r.s = custom(-52.0, 0.3, 18);
	r.xyz = spiral(r.s, r.n, -0.002);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ);
	r.fo.residual = ASPH_FIT_RESIDUAL_SAG;
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	m.drift_residual_nm = sigma_nm;
	assert_int_equal(run_mc(&r, &m, &o), 0);
	assert_rel(r.res.u[ASPH_FIT_TZ], sigma_nm * 1e-6 / 2, band(2.8), "u(tz)");
	run_free(&r);
}

/* A whole characterization with every contribution: a rigid fit of the
 * weak lens with form error. */
static void full_run(struct run *r, int threads, size_t trials, unsigned long seed)
{
	struct asph_synth_term terms[] = { { 4, 31.0 }, { 5, -12.5 }, { 11, 8.25 } };
	struct asph_synth_options so = {
		.pose = { { 0.013, -0.021, 0.007 }, 2.1e-4, -1.3e-4, 0 },
		.terms = terms, .n_terms = 3, .noise_nm = 3, .seed = 2,
	};
	struct asph_uncertainty_model m = {
		.probe_noise_nm = 6, .position_noise_um = 0.2, .position_resolution_um = 0.05,
		.latency_us = 40, .scan_speed_mm_s = 4, .drift_residual_nm = 5,
		.tip_radius_um = 0.3,
	};
	struct asph_mc_options o = { .n_trials = trials, .fixed = 1, .seed = seed };

	r->n = 400;
	r->s = lens("weak");
	r->xyz = spiral(r->s, r->n, 0);
	assert_int_equal(asph_fit_synthesize(r->s, r->xyz, r->n, &so, r->xyz, NULL), 0);
	reference_fit(r);
	assert_int_equal(run_mc_threads(r, &m, &o, threads), 0);
}

/* The result does not depend on how many threads ran the trials: the
 * runner on 1 and on 3 threads and the library's pieces on this thread
 * alone give the same values bit for bit. */
static void test_thread_independence(void **state)
{
	struct run a = { 0 }, b = { 0 }, c = { 0 };
	size_t na, nb, nc;

	(void)state;
	full_run(&a, 1, 24, 77);
	full_run(&b, 3, 24, 77);
	full_run(&c, 0, 24, 77);
	const double *va = asph_mc_values(a.mc, &na), *vb = asph_mc_values(b.mc, &nb);
	const double *vc = asph_mc_values(c.mc, &nc);
	assert_int_equal(na, 24);
	assert_int_equal(na, nb);
	assert_int_equal(na, nc);
	assert_memory_equal(va, vb, na * ASPH_MC_N_QUANTITIES * sizeof(double));
	assert_memory_equal(va, vc, na * ASPH_MC_N_QUANTITIES * sizeof(double));
	assert_memory_equal(a.res.u, b.res.u, sizeof(a.res.u));
	assert_memory_equal(a.res.u, c.res.u, sizeof(a.res.u));
	run_free(&c);
	/* every quantity of the summary is covered, with a positive u */
	int want[] = { ASPH_FIT_TX, ASPH_FIT_TY, ASPH_FIT_TZ, ASPH_FIT_RX, ASPH_FIT_RY,
		       ASPH_MC_RMS, ASPH_MC_PV, ASPH_MC_PVR, ASPH_MC_A, ASPH_MC_B, ASPH_MC_C,
		       ASPH_MC_RMS_T, ASPH_MC_RMS_I, ASPH_MC_RMS_A, ASPH_MC_SLOPE_RMS,
		       ASPH_MC_SLOPE_MAX };
	for (size_t i = 0; i < sizeof(want) / sizeof(want[0]); i++) {
		assert_true(a.res.covered[want[i]]);
		if (!(a.res.u[want[i]] > 0))
			fail_msg("%s: u %g", asph_mc_quantity_key((enum asph_mc_quantity)want[i]),
				 a.res.u[want[i]]);
	}
	/* a different seed draws differently */
	run_free(&b);
	memset(&b, 0, sizeof(b));
	full_run(&b, 2, 24, 78);
	vb = asph_mc_values(b.mc, &nb);
	assert_true(memcmp(va, vb, na * ASPH_MC_N_QUANTITIES * sizeof(double)) != 0);
	run_free(&a);
	run_free(&b);
}

/* U = k u with k = 2, in the result, the fit's uncertainty_k2 (fringes at
 * lambda / 2 per fringe) and the JSON; and the verdict uses U. */
static void test_expanded_and_verdict(void **state)
{
	struct run r = { 0 };
	struct asph_tolerance t;
	char *text = NULL;
	json_error_t jerr;

	(void)state;
	full_run(&r, 2, 16, 4);
	for (int q = 0; q < ASPH_MC_N_QUANTITIES; q++)
		if (r.res.covered[q])
			assert_true(r.res.U[q] == 2 * r.res.u[q]);
		else
			assert_true(isnan(r.res.U[q]));
	assert_int_equal(asph_mc_result_to_json(&r.res, r.ref.form.wavelength_nm, &text), 0);
	json_t *root = json_loads(text, 0, &jerr);
	assert_non_null(root);
	json_t *k2 = json_object_get(root, "uncertainty_k2");
	json_t *st = json_object_get(root, "uncertainty_standard");
	json_t *model = json_object_get(root, "uncertainty_model");
	assert_true(json_is_object(k2) && json_is_object(st) && json_is_object(model));
	assert_int_equal(json_object_size(k2), json_object_size(st));
	const char *key;
	json_t *v;
	json_object_foreach(k2, key, v) {
		double ku = json_real_value(json_object_get(st, key));
		assert_true(json_real_value(v) == 2 * ku);
	}
	assert_true(fabs(json_real_value(json_object_get(k2, "B_fringes")) -
			 r.res.U[ASPH_MC_B] / (r.ref.form.wavelength_nm / 2)) < 1e-12);
	assert_string_equal(json_string_value(json_object_get(model, "method")), "monte-carlo");
	assert_true(json_real_value(json_object_get(model, "tip_radius_um")) == 0.3);
	assert_int_equal(json_integer_value(json_object_get(model, "trials")), 16);
	json_decref(root);
	free(text);

	/* RMSt: a limit between value + U and value - U is undecided, one
	 * above value + U passes; the covariance's U would decide otherwise */
	double val = r.ref.form.rms_t.v, U = r.res.U[ASPH_MC_RMS_T];
	asph_tolerance_init(&t);
	t.rms_t.v = val + 0.5 * U;
	r.ref.verdict.present = 1;
	asph_mc_apply(&r.res, &t, &r.ref);
	assert_int_equal(r.ref.uncertainty_k2.method, ASPH_UNCERTAINTY_MONTE_CARLO);
	assert_true(r.ref.uncertainty_k2.rms_t.v == U);
	assert_true(r.ref.uncertainty_k2.A_fringes ==
		    r.res.U[ASPH_MC_A] * 2 / r.ref.form.wavelength_nm);
	assert_int_equal(r.ref.verdict.n_items, 1);
	assert_true(r.ref.verdict.items[0].U == U);
	assert_int_equal(r.ref.verdict.overall, ASPH_VERDICT_UNDECIDED);
	t.rms_t.v = val + 1.5 * U;
	asph_mc_apply(&r.res, &t, &r.ref);
	assert_int_equal(r.ref.verdict.overall, ASPH_VERDICT_PASS);
	t.rms_t.v = val - 1.5 * U;
	asph_mc_apply(&r.res, &t, &r.ref);
	assert_int_equal(r.ref.verdict.overall, ASPH_VERDICT_FAIL);
	run_free(&r);
}

/* GUM S1 7.9.4, computed here from the trials' values: the spread of h
 * block means and block standard deviations, s / sqrt(h), against half a
 * unit of the first significant digit of u. */
static int criterion(const double *v, size_t n, size_t block, const int *covered)
{
	size_t h = n / block;

	for (int q = 0; q < ASPH_MC_N_QUANTITIES; q++) {
		double ym[64], um[64], all = 0, all2 = 0;
		if (!covered[q])
			continue;
		for (size_t t = 0; t < h * block; t++)
			all += v[t * ASPH_MC_N_QUANTITIES + (size_t)q];
		all /= (double)(h * block);
		for (size_t t = 0; t < h * block; t++)
			all2 += pow(v[t * ASPH_MC_N_QUANTITIES + (size_t)q] - all, 2);
		double u = sqrt(all2 / (double)(h * block - 1));
		if (!(u > 0))
			continue;
		for (size_t b = 0; b < h; b++) {
			double s = 0, s2 = 0;
			for (size_t t = b * block; t < (b + 1) * block; t++)
				s += v[t * ASPH_MC_N_QUANTITIES + (size_t)q];
			ym[b] = s / (double)block;
			for (size_t t = b * block; t < (b + 1) * block; t++)
				s2 += pow(v[t * ASPH_MC_N_QUANTITIES + (size_t)q] - ym[b], 2);
			um[b] = sqrt(s2 / (double)(block - 1));
		}
		double delta = 0.5 * pow(10, floor(log10(u)));
		double my = 0, mu = 0, sy = 0, su = 0;
		for (size_t b = 0; b < h; b++)
			my += ym[b] / (double)h, mu += um[b] / (double)h;
		for (size_t b = 0; b < h; b++)
			sy += pow(ym[b] - my, 2), su += pow(um[b] - mu, 2);
		sy = sqrt(sy / ((double)h * (double)(h - 1)));
		su = sqrt(su / ((double)h * (double)(h - 1)));
		if (!(2 * sy <= delta && 2 * su <= delta))
			return 0;
	}
	return 1;
}

/* The adaptive stop ends, and where it ends the criterion holds and one
 * block earlier it did not. */
static void test_adaptive_stop(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct asph_mc_options o = { .n_trials = 40, .block_size = 20, .max_trials = 1200,
				     .seed = 21 };
	size_t nt;

	(void)state;
	r.s = custom(41.3, -0.6, 20);
	r.xyz = spiral(r.s, r.n, 0.01);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ);
	r.fo.residual = ASPH_FIT_RESIDUAL_SAG;
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	m.probe_noise_nm = 41;
	assert_int_equal(run_mc(&r, &m, &o), 0);
	const double *v = asph_mc_values(r.mc, &nt);
	assert_true(r.res.stable);
	assert_false(r.res.fixed);
	assert_int_equal(nt, r.res.n_trials);
	assert_true(nt >= 40 && nt <= 1200 && nt % 20 == 0);
	assert_true(criterion(v, nt, 20, r.res.covered));
	if (nt > 40)
		assert_false(criterion(v, nt - 20, 20, r.res.covered));
	/* the runner's blocks on 2 threads stop at the same trial with the
	 * same values */
	struct asph_mc_threads th = { .n_threads = 2 };
	struct asph_mc_result res2;
	struct asph_error err;
	double *v1 = malloc(nt * ASPH_MC_N_QUANTITIES * sizeof(double));
	size_t nt2;
	assert_non_null(v1);
	memcpy(v1, v, nt * ASPH_MC_N_QUANTITIES * sizeof(double));
	assert_int_equal(asph_mc_run_threads(r.mc, &th, &res2, &err), 0);
	const double *v2 = asph_mc_values(r.mc, &nt2);
	assert_int_equal(nt2, nt);
	assert_true(res2.stable);
	assert_memory_equal(v1, v2, nt * ASPH_MC_N_QUANTITIES * sizeof(double));
	assert_memory_equal(r.res.u, res2.u, sizeof(res2.u));
	free(v1);
	run_free(&r);
}

struct progress {
	size_t calls, last_done, cancel_at;
	int monotonic;
};

static int on_progress(void *data, size_t done, size_t planned)
{
	struct progress *p = data;

	p->calls++;
	p->monotonic &= done >= p->last_done && done <= planned;
	p->last_done = done;
	return p->cancel_at && done >= p->cancel_at;
}

/* Progress is reported, and a cancellation stops the run between trials
 * with the statistics of the trials done. */
static void test_progress_cancel(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct progress p = { .monotonic = 1 };
	struct asph_mc_options o = { .n_trials = 60, .fixed = 1, .seed = 1 };
	struct asph_mc_threads th = { .n_threads = 2, .progress = on_progress,
				      .progress_data = &p };
	struct asph_error err;
	size_t nt;

	(void)state;
	r.s = custom(41.3, -0.6, 20);
	r.xyz = spiral(r.s, r.n, 0);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ);
	r.fo.residual = ASPH_FIT_RESIDUAL_SAG;
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	m.probe_noise_nm = 10;
	asph_error_clear(&err);
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, &o, &r.mc, &err), 0);
	assert_int_equal(asph_mc_run_threads(r.mc, &th, &r.res, &err), 0);
	assert_true(p.calls >= 1 && p.monotonic);
	assert_int_equal(p.last_done, 60);

	/* again with the same workspace, cancelled after 10 */
	p = (struct progress){ .monotonic = 1, .cancel_at = 10 };
	asph_error_clear(&err);
	assert_int_equal(asph_mc_run_threads(r.mc, &th, &r.res, &err), -ECANCELED);
	asph_mc_values(r.mc, &nt);
	assert_true(nt >= 10 && nt < 60);
	assert_int_equal(r.res.n_trials, nt);
	assert_true(r.res.u[ASPH_FIT_TZ] > 0);
	assert_non_null(strstr(err.message, "cancelled"));
	run_free(&r);
}

/* The model: names, units, bad values, what a latency needs. */
static void test_model(void **state)
{
	struct asph_uncertainty_model m;
	struct asph_error err;
	size_t n;
	char *text = NULL;

	(void)state;
	asph_uncertainty_model_init(&m);
	assert_true(asph_uncertainty_model_is_empty(&m));
	const struct asph_uncertainty_field *f = asph_uncertainty_model_fields(&n);
	assert_int_equal(n, 7);
	for (size_t i = 0; i < n; i++)
		assert_int_equal(asph_uncertainty_model_set(&m, f[i].name, 1.5 + (double)i, &err), 0);
	assert_true(m.probe_noise_nm == 1.5 && m.tip_radius_um == 7.5 && m.scan_speed_mm_s == 5.5);
	assert_false(asph_uncertainty_model_is_empty(&m));
	assert_int_equal(asph_uncertainty_model_check(&m, &err), 0);
	assert_int_equal(asph_uncertainty_model_set(&m, "probe_noise", 1, &err), -ENOENT);
	assert_non_null(strstr(err.message, "probe_noise_nm"));
	assert_int_equal(asph_uncertainty_model_set(&m, "latency_us", -1, &err), -EINVAL);
	assert_int_equal(asph_uncertainty_model_set(&m, "latency_us", NAN, &err), -EINVAL);
	m.scan_speed_mm_s = 0;
	asph_error_clear(&err);
	assert_int_equal(asph_uncertainty_model_check(&m, &err), -EINVAL);
	assert_string_equal(err.field, "scan_speed_mm_s");
	m.scan_speed_mm_s = 2;
	m.drift_residual_nm = INFINITY;
	assert_int_equal(asph_uncertainty_model_check(&m, &err), -EINVAL);
	assert_string_equal(err.field, "drift_residual_nm");
	m.drift_residual_nm = 3;
	assert_int_equal(asph_uncertainty_model_to_json(&m, &text), 0);
	json_t *o = json_loads(text, 0, NULL);
	assert_true(json_real_value(json_object_get(o, "drift_residual_nm")) == 3);
	assert_int_equal(json_object_size(o), 7);
	json_decref(o);
	free(text);
}

/* Bad options and a bad reference are refused, never run. */
static void test_bad_options(void **state)
{
	struct run r = { .n = N_POINTS };
	struct asph_uncertainty_model m;
	struct asph_mc *mc = NULL;
	struct asph_error err;
	struct asph_mc_options o = { .n_trials = 30, .block_size = 20 };

	(void)state;
	r.s = custom(41.3, -0.6, 20);
	r.xyz = spiral(r.s, r.n, 0);
	r.fo.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ);
	reference_fit(&r);
	asph_uncertainty_model_init(&m);
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, &o, &mc, &err), -EINVAL);
	o = (struct asph_mc_options){ .n_trials = 1, .fixed = 1 };
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, &o, &mc, &err), -EINVAL);
	o = (struct asph_mc_options){ .n_trials = 200, .max_trials = 100 };
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, &o, &mc, &err), -EINVAL);
	/* the runner refuses a bad number of threads before any trial */
	struct asph_mc_threads th = { .n_threads = -2 };
	struct asph_mc_result res;
	m.probe_noise_nm = 1;
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, NULL, &mc, &err), 0);
	assert_int_equal(asph_mc_run_threads(mc, &th, &res, &err), -EINVAL);
	th.n_threads = 257;
	assert_int_equal(asph_mc_run_threads(mc, &th, &res, &err), -EINVAL);
	asph_mc_free(mc);
	mc = NULL;
	m.probe_noise_nm = -1;
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, NULL, &mc, &err), -EINVAL);
	m.probe_noise_nm = 1;
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n - 1, &r.fo, &r.ref, &m, NULL, &mc, &err),
			 -EINVAL);
	r.ref.converged = 0;
	assert_int_equal(asph_mc_alloc(r.s, r.xyz, r.n, &r.fo, &r.ref, &m, NULL, &mc, &err), -EINVAL);
	assert_null(mc);
	run_free(&r);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_model),
		cmocka_unit_test(test_bad_options),
		cmocka_unit_test(test_piston_probe_noise),
		cmocka_unit_test(test_linear_covariance),
		cmocka_unit_test(test_tip_radius_sphere),
		cmocka_unit_test(test_drift_piston),
		cmocka_unit_test(test_thread_independence),
		cmocka_unit_test(test_expanded_and_verdict),
		cmocka_unit_test(test_adaptive_stop),
		cmocka_unit_test(test_progress_cancel),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
