/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * lib/plansearch: the plan for a tolerance against a closed form. On a
 * plane fitted in tz, rx, ry with white probe noise sigma only, the points
 * of a plan centred on the axis give U(tz) = 2 sigma / sqrt(N) (k = 2), so
 * the fewest points meeting U <= r T are N* = (2 sigma / (r T))^2. The
 * chosen plan's N is within 10 % of N*; a fresh Monte Carlo with another
 * seed on it gives U/T within 10 % of r; half its points fail the ratio; a
 * tip radius (a floor that no number of points lowers: the whole plane
 * moves along its normal) below the ratio is reported impossible and
 * named; bad options are refused with the field. The model U^2 = a / N + b
 * against runs laid exactly on it, and the floor's stop on the plane: a tip
 * whose floor is beyond the ratio ends the search after three plans; one
 * below it moves the plan to N* / (1 - (floor / r T)^2), within 10 %.
 */
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

#include "asph/characterize.h"
#include "asph-mc/mc-runner.h"
#include "asph/plan-search.h"
#include "asph/prescription.h"
#include "plansearch-internal.h"

#define SIGMA_NM 25.0
#define RATIO 0.25
/* T of tz, mm: N* = (2 sigma / (r T))^2 = 150 (few points: the test runs
 * under valgrind) */
#define N_STAR 150.0
#define T_TZ_MM (2 * SIGMA_NM * 1e-6 / (RATIO * sqrt(N_STAR)))
/* A second of measuring per point: the search's time is the points'. */
#define SECONDS_PER_POINT 0.01

static struct asph_surface *plane(void)
{
	static const char text[] = "{\"type\": \"even_asphere\", \"name\": \"flat\", \"c\": 0, "
				    "\"aperture_diameter\": 20}";
	struct asph_prescription p;
	struct asph_surface *s;

	assert_int_equal(asph_prescription_parse(text, strlen(text), "flat", &p, NULL), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

static int run_mc(void *data, struct asph_mc *mc, struct asph_mc_result *out,
		  struct asph_error *err)
{
	const struct asph_mc_threads th = { .n_threads = 2 };

	(void)data;
	return asph_mc_run_threads(mc, &th, out, err);
}

static int plan_time(void *data, const struct asph_plan *plan, double *seconds,
		     struct asph_error *err)
{
	(void)data;
	(void)err;
	*seconds = SECONDS_PER_POINT * (double)plan->n;
	return 0;
}

/* The search on the plane: tz limited, fermat plans, probe noise (and
 * tip_um of tip radius). */
static void options(struct asph_plan_search_options *o, double tip_um)
{
	memset(o, 0, sizeof(*o));
	o->capability = RATIO;
	o->limit[ASPH_FIT_TZ] = T_TZ_MM;
	o->methods = 1u << ASPH_PLAN_FERMAT;
	o->min_points = 40;
	o->max_points = 20000;
	o->fit.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ) | ASPH_FIT_DOF_BIT(ASPH_FIT_RX) |
		     ASPH_FIT_DOF_BIT(ASPH_FIT_RY);
	o->fit.residual = ASPH_FIT_RESIDUAL_SAG;
	o->fit.n_zernike = 4;
	asph_uncertainty_model_init(&o->model);
	o->model.probe_noise_nm = SIGMA_NM;
	o->model.tip_radius_um = tip_um;
	o->mc.seed = 3;
	o->run_mc = run_mc;
	o->plan_time = plan_time;
}

static const struct asph_plan_search_result *search(struct asph_plan_search **ps,
						    const struct asph_surface *s,
						    const struct asph_plan_search_options *o)
{
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_plan_search_alloc(s, o, ps, &err), 0);
	int r = asph_plan_search_run(*ps, &err);
	if (r < 0)
		fail_msg("search: %s", err.message);
	return asph_plan_search_result(*ps);
}

/* U(tz) of a fresh Monte Carlo on the fermat plan of n points. */
static double U_tz(const struct asph_surface *s, const struct asph_plan_search_options *o,
		   size_t n, unsigned long seed, size_t trials)
{
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, (double)n };
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	struct asph_characterize_options co = {
		.fit = o->fit, .uncertainty = &o->model,
		.mc = { .n_trials = trials, .fixed = 1, .seed = seed }, .run_mc = run_mc,
	};
	struct asph_plan *plan;
	struct asph_points *p;
	struct asph_characterization *c;

	assert_int_equal(asph_plan_compute_opts(s, ASPH_PLAN_FERMAT, d, &po, &plan, NULL), 0);
	p = asph_points_alloc(plan->n);
	assert_non_null(p);
	memcpy(p->xyz, plan->xyz, 3 * plan->n * sizeof(double));
	assert_int_equal(asph_characterize_alloc(s, &co, &c, NULL), 0);
	assert_int_equal(asph_characterize_points(c, p, NULL), 0);
	const struct asph_characterize_result *r = asph_characterize_result(c);
	assert_true(r->mc_done && r->mc.covered[ASPH_FIT_TZ]);
	double U = r->mc.U[ASPH_FIT_TZ];
	asph_characterize_free(c);
	asph_points_free(p);
	asph_plan_free(plan);
	return U;
}

static void test_closed_form(void **state)
{
	struct asph_surface *s = plane();
	struct asph_plan_search_options o;
	struct asph_plan_search *ps;

	(void)state;
	options(&o, 0);
	const struct asph_plan_search_result *r = search(&ps, s, &o);
	assert_true(r->found);
	assert_int_equal(r->method, ASPH_PLAN_FERMAT);
	print_message("chosen %zu points (N* = %.0f), %zu characterizations\n", r->points, N_STAR,
		      r->characterizations);
	assert_true(fabs((double)r->points - N_STAR) <= 0.10 * N_STAR);
	assert_true(fabs(r->seconds - SECONDS_PER_POINT * (double)r->points) < 1e-9);
	assert_int_equal(r->n_quantities, 1);
	assert_int_equal(r->quantity[0].q, ASPH_FIT_TZ);
	assert_true(r->quantity[0].ratio <= RATIO);
	assert_true(r->characterizations <= 5000);

	/* the chosen plan holds with another seed: U/T within 10 % of r
	 * (800 trials: U's relative standard error is 2.5 %). Under valgrind,
	 * which checks the memory and not the statistics, the runs are those
	 * of the search: this one is left out, and half the points (U/T 41 %
	 * above r) are told apart on 100 trials (7 %). */
	const char *vg = getenv("ASPH_UNDER_VALGRIND");
	size_t trials = vg && strcmp(vg, "0") ? 100 : 800;
	double ratio;
	if (trials == 800) {
		ratio = U_tz(s, &o, (size_t)r->density.value, 77, trials) / T_TZ_MM;
		print_message("another seed: U/T %.4f\n", ratio);
		assert_true(fabs(ratio - RATIO) <= 0.10 * RATIO);
	}
	/* half the points fail the ratio */
	ratio = U_tz(s, &o, (size_t)(r->density.value / 2), 78, trials) / T_TZ_MM;
	print_message("half the points: U/T %.4f\n", ratio);
	assert_true(ratio > RATIO);

	char *json;
	assert_int_equal(asph_plan_search_result_to_json(r, &json), 0);
	assert_non_null(strstr(json, "\"found\":true"));
	assert_non_null(strstr(json, "\"method\":\"fermat\""));
	free(json);
	asph_plan_search_free(ps);
	asph_surface_free(s);
}

/* A tip radius of u_tip moves the plane by u_tip along z whatever the
 * points: U(tz) >= 2 u_tip. With 2 u_tip at twice r T no plan meets the
 * ratio, and the tip is named as what dominates. */
static void test_impossible(void **state)
{
	struct asph_surface *s = plane();
	struct asph_plan_search_options o;
	struct asph_plan_search *ps;

	(void)state;
	options(&o, RATIO * T_TZ_MM * 1e3);     /* u_tip in um: U = 2 r T */
	o.max_points = 4000;
	const struct asph_plan_search_result *r = search(&ps, s, &o);
	assert_false(r->found);
	assert_int_equal(r->methods[ASPH_PLAN_FERMAT].outcome, ASPH_PLAN_SEARCH_IMPOSSIBLE);
	assert_int_equal(r->failing, ASPH_FIT_TZ);
	assert_int_equal(r->dominant, ASPH_PLAN_SEARCH_TIP);
	assert_true(r->contribution_U[ASPH_PLAN_SEARCH_TIP] >
		    r->contribution_U[ASPH_PLAN_SEARCH_PROBE]);
	print_message("impossible: U/T %.3f, tip alone U %.3g mm, %zu plans, %zu "
		      "characterizations\n", r->quantity[0].ratio,
		      r->contribution_U[ASPH_PLAN_SEARCH_TIP], r->evaluations,
		      r->characterizations);
	assert_true(r->quantity[0].ratio > RATIO);
	/* the floor is told by the model from the coarsest plan and one or
	 * two finer (a floor twice the threshold), not by plans up to the
	 * finest */
	assert_true(r->evaluations <= 3);
	asph_plan_search_free(ps);
	asph_surface_free(s);
}

/* Runs of a synthetic U^2 = a / N + b at the n[] points, m trials each. */
static void synthetic(struct ps_eval *e, const double *n, size_t count, double a, double b,
		      size_t m)
{
	memset(e, 0, count * sizeof(*e));
	for (size_t i = 0; i < count; i++) {
		for (int q = 0; q < NQ; q++)
			e[i].U[q] = NAN;
		e[i].n = e[i].request = (size_t)n[i];
		e[i].trials = m;
		e[i].computed = 1;
		e[i].U[ASPH_FIT_TZ] = sqrt(a / n[i] + b);
	}
}

/* The model on runs laid exactly on it (800 trials: U to 2.5 %): the root
 * a / (L^2 - b) to 1e-9; a floor 1.5x the limit stops, one 0.6x the limit
 * or one run alone does not; nor does a floor the finest run contradicts.
 * Runs 4x apart need the floor beyond by three of its errors, not two. */
static void test_model(void **state)
{
	const double L = 1.0, a = 400.0;
	struct ps_eval e[3];
	double U, root;
	int beyond;

	(void)state;
	/* no floor: b = 0, the root a / L^2 */
	synthetic(e, (const double[]){ 100, 400, 1600 }, 3, a, 0, 800);
	assert_int_equal(ps_model(e, 3, ASPH_FIT_TZ, 400, L, &U, &root, &beyond), 0);
	assert_false(beyond);
	assert_true(fabs(root - a / (L * L)) <= 1e-9 * a);
	assert_true(fabs(U - 1.0) <= 1e-9);
	/* a floor below the limit: the root moves to a / (L^2 - b) */
	double b = 0.6 * 0.6 * L * L;
	synthetic(e, (const double[]){ 100, 1600 }, 2, a, b, 800);
	assert_int_equal(ps_model(e, 2, ASPH_FIT_TZ, 1600, L, &U, &root, &beyond), 0);
	assert_false(beyond);
	assert_true(fabs(root - a / (L * L - b)) <= 1e-9 * root);
	/* a floor 1.5x the limit: two runs 16x apart tell it, a and b
	 * from the coarser and the finer */
	b = 1.5 * 1.5 * L * L;
	synthetic(e, (const double[]){ 100, 1600 }, 2, a, b, 800);
	assert_int_equal(ps_model(e, 2, ASPH_FIT_TZ, 1600, L, &U, &root, &beyond), 0);
	assert_true(beyond);
	assert_true(isinf(root));
	/* one run cannot tell a floor from 1 / sqrt(N) */
	assert_int_equal(ps_model(e, 1, ASPH_FIT_TZ, 100, L, &U, &root, &beyond), 0);
	assert_false(beyond);
	assert_true(isfinite(root));
	/* the finest run meets the limit: no floor stops the method */
	synthetic(e, (const double[]){ 100, 200, 6400 }, 3, a, b, 800);
	e[2].U[ASPH_FIT_TZ] = 0.9 * L;
	assert_int_equal(ps_model(e, 3, ASPH_FIT_TZ, 6400, L, &U, &root, &beyond), 0);
	assert_false(beyond);
	/* nor a floor within 10 % of the limit (the margin) */
	b = 1.05 * 1.05 * L * L;
	synthetic(e, (const double[]){ 100, 1600 }, 2, a, b, 800);
	assert_int_equal(ps_model(e, 2, ASPH_FIT_TZ, 1600, L, &U, &root, &beyond), 0);
	assert_false(beyond);
	/* 100 trials a run: a floor 1.5x the limit is told by runs 16x apart
	 * (b 2.25 +- 0.34, at twice its error) and not yet by runs 4x apart
	 * (+- 0.46, at three times); one twice the limit is (4 +- 0.80) */
	b = 1.5 * 1.5 * L * L;
	synthetic(e, (const double[]){ 100, 1600 }, 2, 40, b, 100);
	assert_int_equal(ps_model(e, 2, ASPH_FIT_TZ, 1600, L, &U, &root, &beyond), 0);
	assert_true(beyond);
	synthetic(e, (const double[]){ 100, 400 }, 2, 40, b, 100);
	assert_int_equal(ps_model(e, 2, ASPH_FIT_TZ, 400, L, &U, &root, &beyond), 0);
	assert_false(beyond);
	synthetic(e, (const double[]){ 100, 400 }, 2, 40, 4 * L * L, 100);
	assert_int_equal(ps_model(e, 2, ASPH_FIT_TZ, 400, L, &U, &root, &beyond), 0);
	assert_true(beyond);
}

/* A tip floor 0.6 r T below the ratio: U(tz)^2 = 4 sigma^2 / N + (0.6 r T)^2,
 * the fewest points N* / (1 - 0.36). The search still finds a plan, whose
 * closed-form U is within 10 % of r T (as the chosen plan holds with
 * another seed); in N within 25 %: near the floor U falls as N^-0.32, so
 * the Monte Carlo's few % in U are three times as many in N. */
static void test_floor_below(void **state)
{
	struct asph_surface *s = plane();
	struct asph_plan_search_options o;
	struct asph_plan_search *ps;
	const double n_floor = N_STAR / (1 - 0.6 * 0.6);

	(void)state;
	options(&o, 0.6 * RATIO * T_TZ_MM * 1e3 / 2);  /* u_tip in um: 2 u_tip = 0.6 r T */
	const struct asph_plan_search_result *r = search(&ps, s, &o);
	assert_true(r->found);
	print_message("floor 0.6 r T: chosen %zu points (N = %.0f), %zu plans, %zu "
		      "characterizations\n", r->points, n_floor, r->evaluations,
		      r->characterizations);
	double U = 2 * sqrt(pow(SIGMA_NM * 1e-6, 2) / (double)r->points +
			    pow(0.6 * RATIO * T_TZ_MM / 2, 2));
	print_message("closed-form U/T there %.4f\n", U / T_TZ_MM);
	assert_true(fabs(U / T_TZ_MM - RATIO) <= 0.10 * RATIO);
	assert_true(fabs((double)r->points - n_floor) <= 0.25 * n_floor);
	assert_true(r->quantity[0].ratio <= RATIO);
	asph_plan_search_free(ps);
	asph_surface_free(s);
}

static void refused(const struct asph_surface *s, const struct asph_plan_search_options *o,
		    const char *field)
{
	struct asph_plan_search *ps = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_plan_search_alloc(s, o, &ps, &err), -EINVAL);
	assert_null(ps);
	assert_true(err.message[0]);
	if (field)
		assert_string_equal(err.field, field);
}

static void test_bad_options(void **state)
{
	struct asph_surface *s = plane();
	struct asph_plan_search_options o;

	(void)state;
	options(&o, 0);
	o.capability = 1.5;
	refused(s, &o, "capability");
	o.capability = -0.1;
	refused(s, &o, "capability");
	options(&o, 0);
	o.limit[ASPH_FIT_TZ] = 0;
	refused(s, &o, "limit");
	o.limit[ASPH_FIT_TZ] = NAN;
	refused(s, &o, "limit");
	options(&o, 0);
	asph_uncertainty_model_init(&o.model);
	refused(s, &o, "model");
	options(&o, 0);
	o.min_points = 500;
	o.max_points = 100;
	refused(s, &o, "min_points");
	options(&o, 0);
	o.run_mc = NULL;
	refused(s, &o, NULL);

	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_bad_options),
		cmocka_unit_test(test_closed_form),
		cmocka_unit_test(test_impossible),
		cmocka_unit_test(test_model),
		cmocka_unit_test(test_floor_below),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
