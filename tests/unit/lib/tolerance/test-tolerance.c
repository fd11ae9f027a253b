/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The ISO 10110-5 call-out, the tolerance object and the ISO 14253-1
 * decision: every form, every refusal with its column, every branch. */
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

#include "asph/tolerance.h"

#define FRINGE (546.07 / 2)

static void parse_ok(const char *callout, struct asph_tolerance *t)
{
	struct asph_error err;
	int col = -1;

	asph_error_clear(&err);
	asph_tolerance_init(t);
	if (asph_tolerance_parse_callout(callout, t->wavelength_nm, t, &col, &err) < 0)
		fail_msg("'%s': column %d: %s", callout, col, err.message);
}

static void assert_near(double got, double want)
{
	if (!(fabs(got - want) <= 1e-12 * fabs(want)))
		fail_msg("got %.15g, want %.15g", got, want);
}

static void test_callout_forms(void **state)
{
	struct asph_tolerance t;

	parse_ok("3/2(0.5/0.3)", &t);
	assert_near(t.A.v, 2 * FRINGE);
	assert_near(t.B.v, 0.5 * FRINGE);
	assert_near(t.C.v, 0.3 * FRINGE);
	assert_true(isnan(t.rms_t.v) && isnan(t.rms_i.v) && isnan(t.rms_a.v));
	assert_string_equal(t.callout, "3/2(0.5/0.3)");

	parse_ok("3/-(1); RMSa < 0.1", &t);
	assert_true(isnan(t.A.v) && isnan(t.C.v));
	assert_near(t.B.v, FRINGE);
	assert_near(t.rms_a.v, 0.1 * FRINGE);

	parse_ok("3/ 2(1/0.5; RMSi < 0.05)", &t);
	assert_near(t.rms_i.v, 0.05 * FRINGE);

	parse_ok("3/- RMSt < 100 nm", &t);
	assert_near(t.rms_t.v, 100);

	parse_ok("3/\xe2\x80\x93; RMSt < 100 nm; RMSi < 30nm; \xce\xbb = 632.8 nm", &t);
	assert_near(t.rms_i.v, 30);
	assert_near(t.wavelength_nm, 632.8);

	parse_ok("3/2(1/0.5) lambda = 632.8", &t);
	assert_near(t.A.v, 2 * 316.4);       /* fringes of the call-out's lambda */
	assert_near(t.C.v, 0.5 * 316.4);

	parse_ok("3/0.4", &t);                 /* A alone */
	assert_near(t.A.v, 0.4 * FRINGE);
	assert_true(isnan(t.B.v));

	parse_ok("3/-(-/.25)", &t);
	assert_near(t.C.v, 0.25 * FRINGE);
	parse_ok("3/250nm(100 nm)", &t);
	assert_near(t.A.v, 250);
	assert_near(t.B.v, 100);
}

struct bad {
	const char *callout;
	int column;
	const char *reason;
};

static void test_callout_refused(void **state)
{
	static const struct bad cases[] = {
		{ "3/2(0.5", 8, "missing ')'" },
		{ "3/2(0.5/0.3", 12, "missing ')'" },
		{ "2/2(0.5)", 1, "starts with '3/'" },
		{ "", 1, "starts with '3/', found the end" },
		{ "3 2(0.5)", 3, "expected '/' after the code number 3" },
		{ "3/", 3, "expected a number for A" },
		{ "3/x", 3, "expected a number for A (sagitta deviation), found 'x'" },
		{ "3/2(", 5, "expected a number for B" },
		{ "3/2(0.5/)", 9, "expected a number for C" },
		{ "3/2(0.5/0.3]", 12, "expected '/', ';' or ')', found ']'" },
		{ "3/0(1)", 3, "A (sagitta deviation) must be greater than 0" },
		{ "3/2(0)", 5, "must be greater than 0" },
		{ "3/1.2.3", 3, "expected a number" },
		{ "3/2(1) RMSx < 1", 11, "RMS must be followed by t, i or a, found 'x'" },
		{ "3/2(1) RMSt 1", 13, "expected '<' after RMS" },
		{ "3/2(1) RMSt < 1; RMSt < 2", 18, "RMSt is given twice" },
		{ "3/2(1) RMSt <", 14, "expected a number for the RMS tolerance" },
		{ "3/2(1);", 8, "nothing follows ';'" },
		{ "3/2(1) foo", 8, "expected RMSt, RMSi, RMSa or lambda, found 'f'" },
		{ "3/2(1)x", 7, "expected ';' or a blank" },
		{ "3/2(1) lambda 632", 15, "expected '=' after lambda" },
		{ "3/-", 1, "tolerances nothing" },
		{ "3/-(-)", 1, "tolerances nothing" },
		{ "3/2(1; RMSq < 1)", 11, "RMS must be followed by t, i or a" },
	};

	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_tolerance t;
		struct asph_error err;
		int col = -1;

		asph_error_clear(&err);
		asph_tolerance_init(&t);
		assert_int_equal(asph_tolerance_parse_callout(cases[i].callout, 546.07, &t, &col, &err),
				 -EINVAL);
		if (col != cases[i].column || !strstr(err.message, cases[i].reason))
			fail_msg("'%s': column %d (want %d): '%s' (want '%s')", cases[i].callout, col,
				 cases[i].column, err.message, cases[i].reason);
	}
}

struct json_bad {
	const char *text;
	int line, column;
	const char *field, *reason;
};

static void test_json(void **state)
{
	static const char *good =
		"{\"iso10110_5\": \"3/2(0.5/0.3)\", \"wavelength_nm\": 546.07,\n"
		" \"rms_nm\": {\"t\": 60, \"i\": 40, \"a\": 25},\n"
		" \"slope_urad\": {\"rms\": 20, \"max\": 80, \"length_mm\": 1.0},\n"
		" \"R_mm\": 0.005}";
	static const struct json_bad cases[] = {
		/* the example, as a call-out alone */
		{ "\"3/2(0.5\"", 1, 9, "iso10110_5", "missing ')'" },
		{ "{\"iso10110_5\": \"3/2(0.5\"}", 1, 24, "iso10110_5", "missing ')'" },
		{ "{\n  \"iso10110_5\":\n    \"3/2(0.\\u0035/x)\"}", 3, 19, "iso10110_5",
		  "expected a number for C" },
		{ "{\"iso10110_5\": 3}", 1, 2, "iso10110_5", "must be a string" },
		{ "{\"rms_nm\": {\"t\": -1}}", 1, 13, "rms_nm.t", "must be greater than 0" },
		{ "{\"rms_nm\": {\"x\": 1}}", 1, 13, "rms_nm.x", "unknown member" },
		{ "{\"rms_nm\": [1]}", 1, 2, "rms_nm", "expected an object" },
		{ "{\"slope_urad\": {\"rms\": 20}}", 1, 2, "slope_urad", "length_mm" },
		{ "{\"slope_urad\": {\"length_mm\": 1}}", 1, 2, "slope_urad", "needs \"rms\" or \"max\"" },
		{ "{\"R_mm\": \"0.1\"}", 1, 2, "R_mm", "expected a number" },
		{ "{\"wavelength_nm\": 0.5461, \"R_mm\": 1}", 1, 2, "wavelength_nm", "outside" },
		{ "{\"wavelength_nm\": 600, \"iso10110_5\": \"3/1 lambda = 632.8\"}", 1, 2,
		  "wavelength_nm", "disagrees with the call-out's lambda" },
		{ "{\"iso10110_5\": \"3/-(-) RMSt < 0.2\", \"rms_nm\": {\"t\": 60}}", 1, 48, "rms_nm.t",
		  "disagrees with the call-out" },
		{ "{\"wavelength_nm\": 546.07}", 0, 0, "", "names no toleranced quantity" },
		{ "{\"R_mm\": 1, \"extra\": 2}", 1, 13, "extra", "unknown member" },
		{ "{\"R_mm\": 1,}", 1, 12, NULL, "" },
		{ "[1]", 1, 1, NULL, "an object or a call-out string" },
		{ "{\"R_mm\": 1, \"R_mm\": 2}", 1, 0, NULL, "duplicate" },
	};
	struct asph_tolerance t;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_tolerance_parse_json(good, strlen(good), "good.json", &t, &err), 0);
	assert_near(t.B.v, 0.5 * FRINGE);
	assert_near(t.rms_t.v, 60);
	assert_near(t.rms_a.v, 25);
	assert_near(t.slope_rms.v, 20);
	assert_near(t.slope_max.v, 80);
	assert_near(t.slope_length_mm, 1.0);
	assert_near(t.R_mm, 0.005);
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		const struct json_bad *c = &cases[i];
		asph_error_clear(&err);
		assert_int_equal(asph_tolerance_parse_json(c->text, strlen(c->text), "tol", &t, &err),
				 -EINVAL);
		if (!strstr(err.message, c->reason) || (c->line && err.line != c->line) ||
		    (c->column && err.column != c->column) ||
		    (c->field && strcmp(err.field, c->field)) || strcmp(err.source, "tol"))
			fail_msg("%s: got %s:%d:%d: %s: %s", c->text, err.source, err.line, err.column,
				 err.field, err.message);
	}
}

/* Every branch of the decision, and the values exactly on a limit (all
 * chosen exactly representable, so "exactly" is exact). */
static void test_decide(void **state)
{
	assert_int_equal(asph_verdict_decide(0.5, 0.25, 1.0), ASPH_VERDICT_PASS);
	assert_int_equal(asph_verdict_decide(0.75, 0.25, 1.0), ASPH_VERDICT_PASS);   /* on */
	assert_int_equal(asph_verdict_decide(0.875, 0.25, 1.0), ASPH_VERDICT_UNDECIDED);
	assert_int_equal(asph_verdict_decide(1.0, 0.25, 1.0), ASPH_VERDICT_UNDECIDED); /* value on */
	assert_int_equal(asph_verdict_decide(1.25, 0.25, 1.0), ASPH_VERDICT_UNDECIDED); /* on */
	assert_int_equal(asph_verdict_decide(1.5, 0.25, 1.0), ASPH_VERDICT_FAIL);
	assert_int_equal(asph_verdict_decide(1.0, 0.0, 1.0), ASPH_VERDICT_PASS);
	assert_int_equal(asph_verdict_decide(1.0000000000000002, 0.0, 1.0), ASPH_VERDICT_FAIL);
	assert_int_equal(asph_verdict_decide(NAN, 0.1, 1.0), ASPH_VERDICT_UNDECIDED);
	assert_int_equal(asph_verdict_decide(0.1, NAN, 1.0), ASPH_VERDICT_UNDECIDED);
	assert_int_equal(asph_verdict_decide(0.1, -1, 1.0), ASPH_VERDICT_UNDECIDED);
	assert_string_equal(asph_verdict_name(ASPH_VERDICT_PASS), "pass");
	assert_string_equal(asph_verdict_name(ASPH_VERDICT_FAIL), "fail");
	assert_string_equal(asph_verdict_name(ASPH_VERDICT_UNDECIDED), "undecided");
}

/* The overall decision: fail wins over undecided, which wins over pass;
 * only toleranced quantities get items; A keeps its sign in the item (as
 * in the form quantities) and |A| is what is decided. */
static void test_evaluate(void **state)
{
	struct asph_tolerance t;
	struct asph_form f = { .wavelength_nm = 546.07 };
	struct asph_slope sl = { .length_mm = 1 };
	struct asph_uncertainty_k2 u;
	struct asph_verdict_report v;

	asph_tolerance_init(&t);
	asph_uncertainty_k2_clear(&u);
	t.A.v = 100;
	t.rms_i.v = 10;
	f.A.v = -75;
	u.A.v = 25;
	f.rms_i.v = 5;
	u.rms_i.v = 1;
	asph_verdict_evaluate(&t, &f, &sl, NAN, &u, &v);
	assert_int_equal(v.n_items, 2);
	assert_string_equal(v.items[0].quantity, "A_nm");
	assert_true(v.items[0].value == -75);
	assert_int_equal(v.items[0].verdict, ASPH_VERDICT_PASS);
	assert_int_equal(v.overall, ASPH_VERDICT_PASS);

	f.rms_i.v = 10.5;                                  /* undecided */
	asph_verdict_evaluate(&t, &f, &sl, NAN, &u, &v);
	assert_int_equal(v.items[1].verdict, ASPH_VERDICT_UNDECIDED);
	assert_int_equal(v.overall, ASPH_VERDICT_UNDECIDED);

	f.A.v = 126;                                        /* fails */
	asph_verdict_evaluate(&t, &f, &sl, NAN, &u, &v);
	assert_int_equal(v.items[0].verdict, ASPH_VERDICT_FAIL);
	assert_int_equal(v.overall, ASPH_VERDICT_FAIL);
	f.A.v = -126;                                       /* on either side */
	asph_verdict_evaluate(&t, &f, &sl, NAN, &u, &v);
	assert_true(v.items[0].value == -126);
	assert_int_equal(v.items[0].verdict, ASPH_VERDICT_FAIL);
	f.A.v = -80;                                        /* -80 - 25 < -100 */
	asph_verdict_evaluate(&t, &f, &sl, NAN, &u, &v);
	assert_int_equal(v.items[0].verdict, ASPH_VERDICT_UNDECIDED);

	t.R_mm = 0.01;                                      /* R not fitted */
	t.slope_max.v = 50;                                 /* no slope */
	asph_verdict_evaluate(&t, &f, NULL, NAN, &u, &v);
	assert_int_equal(v.n_items, 4);
	assert_string_equal(v.items[2].quantity, "slope_max_urad");
	assert_int_equal(v.items[2].verdict, ASPH_VERDICT_UNDECIDED);
	assert_int_equal(v.items[3].verdict, ASPH_VERDICT_UNDECIDED);
}

static void test_load(void **state)
{
	struct asph_tolerance t;
	struct asph_error err;
	char path[] = "/tmp/asph-tolerance-XXXXXX";
	int fd = mkstemp(path);
	FILE *f = fdopen(fd, "w");

	fputs("{\"iso10110_5\": \"3/1(0.5)\",\n \"R_mm\": -2}\n", f);
	fclose(f);
	asph_error_clear(&err);
	assert_int_equal(asph_tolerance_load(path, &t, &err), -EINVAL);
	assert_string_equal(err.source, path);
	assert_int_equal(err.line, 2);
	assert_string_equal(err.field, "R_mm");
	asph_error_clear(&err);
	assert_int_equal(asph_tolerance_load("  {\"R_mm\": 0.5}", &t, &err), 0);
	assert_near(t.R_mm, 0.5);
	assert_int_equal(asph_tolerance_load("/nonexistent/tol.json", &t, &err), -ENOENT);
	remove(path);
}

/* What a tolerance argument is (the rule of asph, asphctl and the web
 * page), and a bare call-out read as the call-out string in JSON is. */
static void test_arg_kind(void **state)
{
	struct asph_tolerance t, j;
	struct asph_error err;
	char buf[600];

	assert_int_equal(asph_tolerance_arg_kind(" {\"R_mm\": 1}"), ASPH_TOLERANCE_ARG_JSON);
	assert_int_equal(asph_tolerance_arg_kind("\"3/2\""), ASPH_TOLERANCE_ARG_JSON);
	assert_int_equal(asph_tolerance_arg_kind("3/2(0.5/0.3)"), ASPH_TOLERANCE_ARG_CALLOUT);
	assert_int_equal(asph_tolerance_arg_kind(" 3 /- RMSt < 100 nm"), ASPH_TOLERANCE_ARG_CALLOUT);
	assert_int_equal(asph_tolerance_arg_kind("3.json"), ASPH_TOLERANCE_ARG_FILE);
	assert_int_equal(asph_tolerance_arg_kind("./3/tol.json"), ASPH_TOLERANCE_ARG_FILE);
	assert_int_equal(asph_tolerance_arg_kind("tol.json"), ASPH_TOLERANCE_ARG_FILE);
	assert_int_equal(asph_tolerance_arg_kind("-"), ASPH_TOLERANCE_ARG_FILE);

	asph_error_clear(&err);
	assert_int_equal(asph_tolerance_load("3/2(0.5/0.3); lambda = 632.8 nm", &t, &err), 0);
	assert_int_equal(asph_tolerance_load("\"3/2(0.5/0.3); lambda = 632.8 nm\"", &j, &err), 0);
	assert_true(t.A.v == j.A.v && t.B.v == j.B.v && t.C.v == j.C.v);
	assert_near(t.A.v, 632.8);         /* 2 fringes of lambda / 2 */
	assert_near(t.wavelength_nm, 632.8);
	assert_string_equal(t.callout, "3/2(0.5/0.3); lambda = 632.8 nm");

	/* the column in the argument; no line or column of a file */
	assert_int_equal(asph_tolerance_load("3/2(0.5/x)", &t, &err), -EINVAL);
	asph_error_format(&err, buf, sizeof(buf));
	assert_non_null(strstr(buf, "'3/2(0.5/x)', column 9: "));
	assert_int_equal(err.line, 0);
	assert_int_equal(err.column, 0);
	assert_null(strstr(buf, "-1"));
	assert_int_equal(asph_tolerance_load(" ", &t, &err), -EINVAL);
	assert_non_null(strstr(err.message, "empty"));
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_callout_forms),
		cmocka_unit_test(test_callout_refused),
		cmocka_unit_test(test_json),
		cmocka_unit_test(test_decide),
		cmocka_unit_test(test_evaluate),
		cmocka_unit_test(test_load),
		cmocka_unit_test(test_arg_kind),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
