/* SPDX-License-Identifier: GPL-3.0-or-later */
/* quantity.h: every quantity of the summary is formatted by one rule, and
 * the table's rows are the summary's keys: each path, uncertainty key and
 * verdict name is found in a summary asph_fit_result_to_json() makes (or
 * among the keys the Monte Carlo adds). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>
#include <jansson.h>

#include "asph/fit.h"
#include "asph/tolerance.h"
#include "asph/uncertainty.h"
#include "quantity.h"

static void test_format(void **state)
{
	const struct quantity *a = quantity_by_path("form.A_nm");
	const struct quantity *tx = quantity_by_path("dof.tx");
	const struct quantity *rms = quantity_by_path("rms_nm");
	const struct quantity *len = quantity_by_path("slope.length_mm");
	char buf[64];

	assert_non_null(a);
	assert_ptr_equal(quantity_by_verdict("A_nm"), a);
	assert_ptr_equal(quantity_by_u_key("A_nm"), a);
	assert_true(a->two_sided && a->sign);
	/* one value, one sign, one precision */
	assert_string_equal(quantity_format(a, -1.73558, QUANTITY_UNIT, buf, sizeof(buf)),
			    "-1.74 nm");
	assert_string_equal(quantity_format(a, 1.73558, 0, buf, sizeof(buf)), "+1.74");
	assert_string_equal(quantity_format(a, 1.73558, QUANTITY_NO_SIGN, buf, sizeof(buf)), "1.74");
	assert_string_equal(quantity_format(a, -0.004, 0, buf, sizeof(buf)), "0.00");
	assert_string_equal(quantity_format(a, NAN, QUANTITY_UNIT, buf, sizeof(buf)), "-");
	/* the pose in um from mm */
	assert_string_equal(quantity_format(tx, 0.0120076367, QUANTITY_UNIT, buf, sizeof(buf)),
			    "+12.0076 um");
	assert_string_equal(quantity_format(rms, 33.71342, QUANTITY_UNIT, buf, sizeof(buf)),
			    "33.71 nm");
	assert_string_equal(quantity_format(len, 1.0, QUANTITY_UNIT, buf, sizeof(buf)), "1 mm");
	assert_string_equal(quantity_format(NULL, 2.5, QUANTITY_UNIT, buf, sizeof(buf)), "2.5");
	/* the slope deviation and the Zernike fit's slope are two quantities */
	assert_ptr_equal(quantity_by_verdict("slope_rms_urad"), quantity_by_path("slope.rms_urad"));
	assert_true(strcmp(quantity_by_path("slope_rms_urad")->label,
			   quantity_by_path("slope.rms_urad")->label) != 0);
	assert_null(quantity_by_path("no.such"));
	assert_null(quantity_by_verdict(NULL));
}

static void figure_is(const char *path, double v, unsigned flags, const char *want)
{
	char buf[64];

	quantity_format(quantity_by_path(path), v, flags, buf, sizeof(buf));
	if (strcmp(buf, want))
		fail_msg("%s %.17g: '%s', want '%s'", path, v, buf, want);
}

/* The rule as the report and the text output meet it (docs/characterization.md,
 * "Figures"): nm to 0.01, fringes to 1e-4, R - R nominal to 1e-6 mm, the pose
 * in um to 1e-4. */
static void test_figures(void **state)
{
	figure_is("form.A_nm", -8.1963780952015224, 0, "-8.20");
	figure_is("form.A_nm", 141.7449, 0, "+141.74");
	figure_is("rms_nm", 133.77356728800095, 0, "133.77");
	figure_is("form.B_fringes", 0.51914, 0, "0.5191");
	figure_is("radius.deviation_mm", -0.0000004, 0, "0.000000");
	figure_is("dof.tx", -1.7729583e-5, 0, "-0.0177");
	/* what rounds to zero has no sign */
	figure_is("form.A_nm", -0.004, 0, "0.00");
	figure_is("form.B_nm", -0.004, 0, "0.00");
	figure_is("form.A_nm", 0.005000001, 0, "+0.01");
	figure_is("rms_nm", NAN, 0, "-");
	/* no figure of a measurement is this large */
	figure_is("rms_nm", 3.5e13, 0, "3.5e+13");
	figure_is("dof.tx", -2e9, QUANTITY_UNIT, "-2e+12 um");

	char small[8];
	quantity_format(quantity_by_path("rms_nm"), -123456.789, 0, small, sizeof(small));
	assert_string_equal(small, "-123456");   /* cut to the buffer, terminated */
}

/* The member at a path of the summary: "rms_nm" or "form.A_nm", or in
 * the first element of an array ("profiles.rms_nm"; the table's deeper
 * paths are outside the summary). */
static json_t *member(json_t *root, const char *path)
{
	const char *dot = strchr(path, '.');
	char head[32];
	json_t *o;

	if (!dot)
		return json_object_get(root, path);
	snprintf(head, sizeof(head), "%.*s", (int)(dot - path), path);
	o = json_object_get(root, head);
	return json_object_get(json_is_array(o) ? json_array_get(o, 0) : o, dot + 1);
}

/* A key the Monte Carlo adds to uncertainty_k2. */
static int is_mc_key(const char *key)
{
	for (int q = 0; q < ASPH_MC_N_QUANTITIES; q++)
		if (!strcmp(asph_mc_quantity_key((enum asph_mc_quantity)q), key))
			return 1;
	return 0;
}

static void test_keys(void **state)
{
	static const char *const outside[] = { "band_rms.", "acquisition.", NULL };
	struct asph_fit_result r = { .dof = ASPH_FIT_DOF_RIGID6 | ASPH_FIT_DOF_BIT(ASPH_FIT_R) |
					    ASPH_FIT_DOF_BIT(ASPH_FIT_K),
				     .n_zernike = 1, .profile = 1, .n_profiles = 1 };
	char *text = NULL;
	json_t *root;
	size_t n;
	const struct quantity *q = quantity_table(&n);

	r.verdict.present = 1;
	assert_int_equal(asph_fit_result_to_json(&r, "x", 0, &text), 0);
	root = json_loads(text, 0, NULL);
	assert_non_null(root);
	for (size_t i = 0; i < n; i++) {
		int skip = 0;
		for (const char *const *o = outside; *o; o++)
			skip |= !strncmp(q[i].path, *o, strlen(*o));
		if (!skip && !member(root, q[i].path))
			fail_msg("%s is not a key of the summary", q[i].path);
		if (q[i].u_key && !json_object_get(json_object_get(root, "uncertainty_k2"), q[i].u_key) &&
		    !is_mc_key(q[i].u_key))
			fail_msg("%s: %s is not a key of uncertainty_k2", q[i].path, q[i].u_key);
		assert_ptr_equal(quantity_by_path(q[i].path), &q[i]);
	}
	json_decref(root);
	free(text);
}

/* Every verdict item names a row; A and R - R nominal are the two-sided
 * ones. */
static void test_verdict_names(void **state)
{
	struct asph_tolerance t;
	struct asph_form f = { .wavelength_nm = 546.07 };
	struct asph_slope sl = { .length_mm = 1 };
	struct asph_uncertainty_k2 u;
	struct asph_verdict_report v;

	assert_int_equal(asph_tolerance_parse_callout("3/1(0.5/0.2) RMSt < 1 RMSi < 1 RMSa < 1",
						      546.07, &t, NULL, NULL), 0);
	t.slope_rms.v = t.slope_max.v = 10;
	t.R_mm = 0.001;
	asph_uncertainty_k2_clear(&u);
	asph_verdict_evaluate(&t, &f, &sl, 0.0005, &u, &v);
	assert_int_equal(v.n_items, 9);
	for (size_t i = 0; i < v.n_items; i++) {
		const struct quantity *q = quantity_by_verdict(v.items[i].quantity);
		assert_non_null(q);
		assert_int_equal(q->two_sided, !strcmp(v.items[i].quantity, "A_nm") ||
						    !strcmp(v.items[i].quantity, "R_deviation_mm"));
	}
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_format),
		cmocka_unit_test(test_figures),
		cmocka_unit_test(test_keys),
		cmocka_unit_test(test_verdict_names),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
