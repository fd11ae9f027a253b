/* SPDX-License-Identifier: GPL-3.0-or-later */
/* lib/drift: the drift model against drifts written out here (linear in
 * time, vertical and lateral), the correction of the points, and the
 * acquisition's account. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <jansson.h>

#include "asph/drift.h"
#include "asph/prescription.h"

static struct asph_surface *strong(void)
{
	struct asph_prescription p;
	struct asph_surface *s;

	assert_int_equal(asph_prescription_preset("strong", &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/* The drift of the tests: linear in time, mm per s. */
static const double rate[3] = { 1.7e-6, -0.9e-6, 3.1e-6 };

static void drift_at(double t, double d[3])
{
	for (int k = 0; k < 3; k++)
		d[k] = rate[k] * t;
}

/* What a probe at machine (x, y) reads of the part drifted by d: the
 * part's height at (x - dx, y - dy), raised by dz. */
static struct asph_scanfile_point measured(const struct asph_surface *s, double x, double y,
					   double t, uint64_t index)
{
	double d[3];
	struct asph_scanfile_point p = { .plan_index = index, .x = x, .y = y };

	drift_at(t, d);
	p.z = asph_surface_sag(s, hypot(x - d[0], y - d[1])) + d[2];
	p.t_ns = (uint64_t)llround(t * 1e9);
	return p;
}

/* A scan of n points at times 0.5 s apart, with the references (x, y) of
 * refs measured in rounds at the times of rounds. */
static struct asph_scanfile *scan(const struct asph_surface *s, size_t n, const double (*refs)[2],
				  size_t n_refs, const double *rounds, size_t n_rounds)
{
	struct asph_scanfile *f = calloc(1, sizeof(*f));

	assert_non_null(f);
	f->n = n;
	f->points = calloc(n, sizeof(*f->points));
	f->n_references = n_refs * n_rounds;
	f->references = calloc(f->n_references ? f->n_references : 1, sizeof(*f->references));
	for (size_t i = 0; i < n; i++) {
		double a = 0.61 * (double)i, r = 15.0 * sqrt((double)(i + 1) / (double)n);
		f->points[i] = measured(s, r * cos(a), r * sin(a), 0.5 * (double)i + 0.25, i);
		f->points[i].position_source = (uint32_t)(1 + i % 4);
		if (i % 4 == 3)
			f->points[i].flags |= ASPH_SCANFILE_POINT_COMMANDED;
	}
	for (size_t k = 0; k < n_rounds; k++)
		for (size_t r = 0; r < n_refs; r++)
			f->references[k * n_refs + r] = measured(s, refs[r][0], refs[r][1], rounds[k], r);
	return f;
}

static void test_vertex_linear(void **state)
{
	struct asph_surface *s = strong();
	static const double refs[][2] = { { 0, 0 } };
	static const double rounds[] = { 0, 30.1, 61.7 };
	struct asph_scanfile *f = scan(s, 120, refs, 1, rounds, 3);
	struct asph_drift *d;
	struct asph_points *p;
	struct asph_drift_summary sum;
	double c[3];

	/* the points drift along z only; the vertex sees the lateral drift
	 * only through the curvature, H d^2 / 2 < 1e-9 mm here, the bound of
	 * the checks below */
	for (size_t i = 0; i < f->n; i++) {
		double t = (double)f->points[i].t_ns * 1e-9, dz = rate[2] * t;
		f->points[i].z = asph_surface_sag(s, hypot(f->points[i].x, f->points[i].y)) + dz;
	}
	assert_int_equal(asph_drift_fit(f, s, &d, NULL), 0);
	/* between rounds: the line through them, here the drift itself */
	asph_drift_at(d, 17500000000ull, c);
	assert_true(c[0] == 0 && c[1] == 0);
	assert_true(fabs(c[2] - rate[2] * 17.5) < 1e-9);
	/* before the first round and after the last: held */
	asph_drift_at(d, 70000000000ull, c);
	assert_true(fabs(c[2] - rate[2] * 61.7) < 1e-9);
	assert_int_equal(asph_drift_points(d, f, 0, &p, &sum, NULL), 0);
	assert_int_equal(sum.components, 1);
	assert_int_equal(sum.n_rounds, 3);
	assert_int_equal(sum.n_references, 1);
	assert_true(fabs(sum.span_s - 61.7) < 1e-12);
	/* the points measured up to the last round lie on the part again;
	 * later ones keep the drift after it */
	for (size_t i = 0; i < p->n; i++) {
		double t = (double)f->points[i].t_ns * 1e-9;
		double z = asph_surface_sag(s, hypot(p->xyz[3 * i], p->xyz[3 * i + 1]));
		double left = t > 61.7 ? rate[2] * (t - 61.7) : 0;
		assert_true(fabs(p->xyz[3 * i + 2] - z - left) < 1e-9);
	}
	/* the size of the correction, written out */
	double sq = 0, top = 0;
	for (size_t i = 0; i < f->n; i++) {
		double t = fmin((double)f->points[i].t_ns * 1e-9, 61.7);
		sq += rate[2] * t * rate[2] * t;
		top = fmax(top, rate[2] * t);
	}
	assert_true(fabs(sum.max_mm - top) < 1e-9);
	assert_true(fabs(sum.rms_mm - sqrt(sq / (double)f->n)) < 1e-9);
	asph_points_free(p);
	asph_drift_free(d);
	free(f->points);
	free(f->references);
	free(f);
	asph_surface_free(s);
}

static void test_lateral(void **state)
{
	struct asph_surface *s = strong();
	/* the vertex and two points on slopes: the lateral drift shows */
	static const double refs[][2] = { { 0, 0 }, { 11.3, 0.7 }, { -1.9, 12.1 } };
	static const double rounds[] = { 0, 25, 50, 75 };
	struct asph_scanfile *f = scan(s, 140, refs, 3, rounds, 4);
	struct asph_drift *d;
	struct asph_points *p;
	struct asph_drift_summary sum;
	double c[3];

	assert_int_equal(asph_drift_fit(f, s, &d, NULL), 0);
	asph_drift_at(d, 50000000000ull, c);
	/* the model is first order in the drift: the surface's curvature
	 * leaves H d^2 / 2, below 1e-10 mm here */
	for (int k = 0; k < 3; k++)
		if (fabs(c[k] - rate[k] * 50) > 1e-9)
			fail_msg("component %d: %.6g mm, drift %.6g mm", k, c[k], rate[k] * 50);
	assert_int_equal(asph_drift_points(d, f, 0, &p, &sum, NULL), 0);
	assert_int_equal(sum.components, 3);
	/* points before the last round: back on the part, at their place */
	for (size_t i = 0; i < p->n; i++) {
		double t = (double)f->points[i].t_ns * 1e-9;
		if (t > 75)
			break;
		const double *q = p->xyz + 3 * i;
		if (fabs(q[2] - asph_surface_sag(s, hypot(q[0], q[1]))) > 1e-9)
			fail_msg("point %zu at %g s: %.3g mm off the part", i, t,
				 q[2] - asph_surface_sag(s, hypot(q[0], q[1])));
	}
	asph_points_free(p);
	asph_drift_free(d);
	free(f->points);
	free(f->references);
	free(f);
	asph_surface_free(s);
}

static void test_none_and_invalid(void **state)
{
	struct asph_surface *s = strong();
	static const double refs[][2] = { { 0, 0 } };
	static const double rounds[] = { 0, 30, 60 };
	struct asph_scanfile *f = scan(s, 40, refs, 1, rounds, 1);
	struct asph_drift *d;
	struct asph_points *p;
	struct asph_drift_summary sum;

	/* one round: nothing to model, the points as recorded */
	assert_int_equal(asph_drift_fit(f, s, &d, NULL), 0);
	assert_int_equal(asph_drift_points(d, f, 0, &p, &sum, NULL), 0);
	assert_int_equal(sum.n_rounds, 0);
	assert_int_equal(sum.components, 0);
	for (size_t i = 0; i < p->n; i++)
		assert_true(p->xyz[3 * i + 2] == f->points[i].z);
	asph_points_free(p);
	asph_drift_free(d);
	free(f->points);
	free(f->references);
	free(f);

	/* a round whose reference was invalid stays out of the model */
	f = scan(s, 40, refs, 1, rounds, 3);
	f->references[1].flags = ASPH_SCANFILE_POINT_INVALID;
	f->references[1].z = NAN;
	assert_int_equal(asph_drift_fit(f, s, &d, NULL), 0);
	assert_int_equal(asph_drift_points(d, f, ASPH_SCANFILE_POINT_COMMANDED, &p, &sum, NULL), 0);
	assert_int_equal(sum.n_rounds, 2);
	assert_int_equal(p->n, 30);     /* the commanded ones left out as asked */
	double c[3];
	asph_drift_at(d, 30000000000ull, c);
	assert_true(fabs(c[2] - rate[2] * 30) < 1e-9);
	asph_points_free(p);

	/* the account */
	char *text;
	assert_int_equal(asph_drift_report_json(f, &sum, 1, &text), 0);
	json_t *j = json_loads(text, 0, NULL);
	assert_non_null(j);
	assert_int_equal(json_integer_value(json_object_get(j, "commanded_points")), 10);
	json_t *pos = json_object_get(j, "positions");
	assert_int_equal(json_integer_value(json_object_get(pos, "latched")), 10);
	assert_int_equal(json_integer_value(json_object_get(pos, "commanded")), 10);
	assert_int_equal(json_integer_value(json_object_get(pos, "unknown")), 0);
	json_t *dr = json_object_get(j, "drift");
	assert_true(json_is_true(json_object_get(dr, "corrected")));
	assert_string_equal(json_string_value(json_object_get(dr, "components")), "z");
	assert_int_equal(json_array_size(json_object_get(j, "warnings")), 1);
	json_decref(j);
	free(text);
	asph_drift_free(d);
	free(f->points);
	free(f->references);
	free(f);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_vertex_linear),
		cmocka_unit_test(test_lateral),
		cmocka_unit_test(test_none_and_invalid),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
