/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph/prescription.h"

static const char good[] =
	"{\n"
	"  \"type\": \"even_asphere\",\n"
	"  \"name\": \"cam-1\",\n"
	"  \"R\": 20.097,\n"
	"  \"k\": -1,\n"
	"  \"A\": {\"4\": -2.0868e-5, \"6\": -3.9031e-9, \"8\": 3.4102e-11},\n"
	"  \"aperture_diameter\": 40\n"
	"}\n";

static void test_parse_good(void **state)
{
	struct asph_prescription p;
	struct asph_error err;
	assert_int_equal(asph_prescription_parse(good, strlen(good), "good.json", &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_EVEN_ASPHERE);
	assert_string_equal(p.name, "cam-1");
	assert_true(p.R == 20.097 && p.k == -1 && p.aperture_diameter == 40);
	assert_true(p.A[4] == -2.0868e-5 && p.A[6] == -3.9031e-9 && p.A[8] == 3.4102e-11);
	assert_true(p.A[10] == 0 && p.A[2] == 0);
}

/* Table 1 of the paper. */
static void test_presets(void **state)
{
	struct asph_prescription p;
	assert_int_equal(asph_prescription_preset("weak", &p), 0);
	assert_true(p.R == 40.6193 && p.k == 0 && p.A[12] == -4.4857e-20 && p.aperture_diameter == 39);
	assert_int_equal(asph_prescription_preset("strong", &p), 0);
	assert_true(p.R == 20.097 && p.k == -1 && p.A[4] == -2.0868e-5 && p.A[12] == 0 &&
		    p.aperture_diameter == 40);
	assert_int_equal(asph_prescription_preset("turning-point", &p), 0);
	assert_true(p.R == 94.6 && p.k == -23.2046 && p.A[10] == -8.06098e-14 &&
		    p.aperture_diameter == 60);
	assert_int_equal(asph_prescription_preset("medium", &p), -ENOENT);
	int n = 0;
	for (const char *const *name = asph_prescription_preset_names(); *name; name++, n++)
		assert_int_equal(asph_prescription_preset(*name, &p), 0);
	assert_int_equal(n, 3);
}

static void test_json_round_trip(void **state)
{
	const char *const *names = asph_prescription_preset_names();
	for (; *names; names++) {
		struct asph_prescription p, q;
		char *text = NULL;
		assert_int_equal(asph_prescription_preset(*names, &p), 0);
		assert_int_equal(asph_prescription_to_json(&p, &text), 0);
		assert_int_equal(asph_prescription_parse(text, strlen(text), "x", &q, NULL), 0);
		assert_memory_equal(&p, &q, sizeof(p));
		free(text);
	}
}

static void test_load_file_and_preset(void **state)
{
	char path[] = "/tmp/asph-test-presc-XXXXXX.json";
	int fd = mkstemps(path, 5);
	assert_true(fd >= 0);
	assert_int_equal(write(fd, good, strlen(good)), (ssize_t)strlen(good));
	close(fd);
	struct asph_prescription p;
	struct asph_error err;
	assert_int_equal(asph_prescription_load(path, &p, &err), 0);
	assert_string_equal(p.name, "cam-1");
	assert_int_equal(asph_prescription_load("strong", &p, &err), 0);
	assert_string_equal(p.name, "strong");
	unlink(path);
	assert_int_equal(asph_prescription_load(path, &p, &err), -ENOENT);
	assert_string_equal(err.source, path);
	assert_int_equal(asph_prescription_load("medium", &p, &err), -ENOENT);
	assert_non_null(strstr(err.message, "neither a preset"));
}

struct bad_case {
	const char *text;
	int line;                /* expected line, 0: not checked */
	const char *at;          /* the error points at the first occurrence of
				    this text (line and column), NULL: unchecked */
	const char *field;       /* "" when none */
	const char *needle;      /* must appear in the message */
};

#define HEAD "{\"type\": \"even_asphere\", "
#define QBFS "{\"type\": \"qbfs\", \"R\": 31.7, \"norm_radius\": 5, "
#define ODD "{\"type\": \"odd_asphere\", \"R\": 31.7, "
static const struct bad_case bad[] = {
	{ "", 1, NULL, "", "" },
	{ "{\"type\": \"even_asphere\", \"R\": 20", 1, NULL, "", "" },
	{ "[1, 2]", 1, "[", "", "JSON object" },
	{ "{\"R\": 20, \"aperture_diameter\": 10}", 0, NULL, "", "missing member \"type\"" },
	{ "{\"type\": 3, \"R\": 20, \"aperture_diameter\": 10}", 1, "\"type\"", "type", "expected a string" },
	{ "{\"type\": \"toroid\", \"R\": 20, \"aperture_diameter\": 10}", 1, "\"type\"", "type", "unknown surface type 'toroid'" },
	{ HEAD "\"aperture_diameter\": 10}", 0, NULL, "", "missing member \"R\" (vertex radius of curvature, mm) or \"c\"" },
	{ HEAD "\"R\": \"20\", \"aperture_diameter\": 10}", 1, "\"R\"", "R", "expected a radius in mm" },
	{ HEAD "\"R\": 20, \"c\": 0.05, \"aperture_diameter\": 10}", 1, "\"c\"", "c", "not both" },
	{ HEAD "\"c\": \"flat\", \"aperture_diameter\": 10}", 1, "\"c\"", "c", "expected a number" },
	{ HEAD "\"note\": [1], \"c\": 0, \"aperture_diameter\": 10}", 1, "\"note\"", "note", "expected a string" },
	{ HEAD "\n  \"R\": 0,\n  \"aperture_diameter\": 10}", 2, "\"R\"", "R", "R = 0" },
	{ HEAD "\"R\": 20, \"k\": \"x\", \"aperture_diameter\": 10}", 1, "\"k\"", "k", "expected a number" },
	{ HEAD "\"R\": 20, \"A\": [1e-5], \"aperture_diameter\": 10}", 1, "\"A\"", "A", "expected an object" },
	{ HEAD "\"R\": 20, \"A\": {\"five\": 1e-5}, \"aperture_diameter\": 10}", 1, "\"five\"", "A.five", "not a power" },
	{ HEAD "\"R\": 20, \"A\": {\"3\": 1e-5}, \"aperture_diameter\": 10}", 1, "\"3\"", "A.3", "powers 2, 4" },
	{ HEAD "\"R\": 20, \"A\": {\"22\": 1e-5}, \"aperture_diameter\": 10}", 1, "\"22\"", "A.22", "got 22" },
	{ HEAD "\"R\": 20, \"A\": {\"4\": 1e-5, \"04\": 2e-5}, \"aperture_diameter\": 10}", 1, "\"04\"", "A.04", "plain number" },
	{ HEAD "\"R\": 5e-324, \"aperture_diameter\": 10}", 1, "\"R\"", "R", "too small" },
	{ HEAD "\"R\": 20, \"A\": {\"4\": \"1e-5\"}, \"aperture_diameter\": 10}", 1, "\"4\"", "A.4", "expected a number" },
	{ HEAD "\"R\": 20}", 0, NULL, "", "missing member \"aperture_diameter\" (mm) or \"aperture\"" },
	{ HEAD "\"R\": 20, \"aperture_diameter\": 10,\n \"aperture\": {\"shape\": \"circular\", \"diameter\": 3}}", 0, NULL, "aperture_diameter", "not both" },
	{ HEAD "\"R\": 20,\n \"aperture\": {\"shape\": \"rectangular\", \"width\": 3}}", 2, "\"aperture\"", "aperture", "missing member \"height\"" },
	{ HEAD "\"R\": 20, \"aperture_diameter\": -3}", 1, "\"aperture_diameter\"", "aperture_diameter", "positive" },
	{ HEAD "\"R\": 20,\n \"aperture_diamter\": 10}", 2, "\"aperture_diamter\"", "aperture_diamter", "unknown member" },
	/* An empty key once hung the member check (found by fuzzing). */
	{ HEAD "\"\": 60, \"R\": 20, \"aperture_diameter\": 10}", 1, NULL, "", "unknown member ''" },
	{ HEAD "\"R\": 20, \"R\": 21, \"aperture_diameter\": 10}", 1, NULL, "", "duplicate" },
	{ HEAD "\"R\": 10,\n\"k\": 0, \"aperture_diameter\": 30}", 2, "\"k\"", "k", "r = 10 mm" },
	{ HEAD "\"R\": 1e400, \"aperture_diameter\": 10}", 1, NULL, "", "overflow" },
	{ HEAD "\"name\": 5, \"R\": 20, \"aperture_diameter\": 10}", 1, "\"name\"", "name", "expected a string" },
	{ HEAD "\"R\": 20, \"aperture_diameter\": 10} trailing", 1, NULL, "", "end of file expected" },
	{ "{\"type\": \"even_asphere\", \"R\": 20, \"aperture_diameter\": 10, \"A\": {\"6\": 1e-7, \"6\": 2e-7}}", 1, NULL, "", "duplicate" },
	/* The Q types and the odd asphere. */
	{ QBFS "\"k\": 2, \"a\": [1e-3], \"aperture_diameter\": 80}", 1, "\"k\"", "k", "reaches zero" },
	{ QBFS "\"A\": {\"4\": 1e-5}, \"aperture_diameter\": 10}", 1, "\"A\"", "A", "unknown member 'A'" },
	{ QBFS "\"a\": {\"0\": 1e-3}, \"aperture_diameter\": 10}", 1, "\"a\"", "a", "expected an array" },
	{ QBFS "\"a\": [1e-3, -2e-4,\n \"x\"], \"aperture_diameter\": 10}", 2, "\"x\"", "a.[2]", "expected a number" },
	{ "{\"type\": \"qcon\", \"R\": 31.7, \"a\": [1e-3], \"aperture_diameter\": 10}", 0, NULL, "", "missing member \"norm_radius\"" },
	{ "{\"type\": \"qcon\", \"R\": 31.7, \"norm_radius\": -5, \"aperture_diameter\": 10}", 1, "\"norm_radius\"", "norm_radius", "positive" },
	{ "{\"type\": \"qcon\", \"R\": 31.7, \"norm_radius\": 5, \"a\": [0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1], \"aperture_diameter\": 10}", 1, "\"a\"", "a", "at most 31" },
	{ HEAD "\"R\": 20, \"norm_radius\": 5, \"aperture_diameter\": 10}", 1, "\"norm_radius\"", "norm_radius", "unknown member" },
	{ ODD "\"A\": {\"0\": 1e-5}, \"aperture_diameter\": 10}", 1, "\"0\"", "A.0", "powers 1, 2" },
	{ ODD "\"A\": {\"21\": 1e-5}, \"aperture_diameter\": 10}", 1, "\"21\"", "A.21", "got 21" },
};

/* Whether err's line and column are those of the first occurrence of at,
 * counted independently of the parser. */
static int points_at(const char *text, const char *at, const struct asph_error *err)
{
	if (!at)
		return 1;
	const char *hit = strstr(text, at);
	assert_non_null(hit);
	int line = 1, col = 1;
	for (const char *c = text; c < hit; c++) {
		if (*c == '\n') {
			line++;
			col = 1;
		} else {
			col++;
		}
	}
	return err->line == line && err->column == col;
}

static void test_refusals(void **state)
{
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
		const struct bad_case *b = &bad[i];
		struct asph_prescription p;
		struct asph_error err;
		char buf[1024];
		asph_error_clear(&err);
		int r = asph_prescription_parse(b->text, strlen(b->text), "lens.json", &p, &err);
		asph_error_format(&err, buf, sizeof(buf));
		if (r != -EINVAL || strcmp(err.source, "lens.json") ||
		    (b->line && err.line != b->line) || !points_at(b->text, b->at, &err) ||
		    strcmp(err.field, b->field) || !strstr(err.message, b->needle)) {
			print_error("case %zu: r=%d '%s'\n", i, r, buf);
			fail();
		}
	}
}

/* The Q types and the odd asphere parse, and survive a round trip. */
static const char *const other_types[] = {
	"{\"type\": \"qbfs\", \"name\": \"q1\", \"R\": 31.7, \"norm_radius\": 10.25,\n"
	" \"a\": [0.0213, -0.0071, 0.0032], \"aperture_diameter\": 20}",
	"{\"type\": \"qbfs\", \"note\": \"a conic base\", \"c\": 0.0575, \"k\": -0.676,\n"
	" \"norm_radius\": 27, \"a\": [-0.81, -0.32], \"aperture_diameter\": 45.7}",
	"{\"type\": \"even_asphere\", \"c\": 0, \"A\": {\"4\": 2.1e-6},\n"
	" \"aperture\": {\"shape\": \"rectangular\", \"width\": 30, \"height\": 20, \"offset\": [0, 45]}}",
	"{\"type\": \"qcon\", \"R\": -42.3, \"k\": -0.73, \"norm_radius\": 10.5,\n"
	" \"a\": [0.0371, -0.0128, 0, 6.1e-4], \"aperture_diameter\": 20}",
	"{\"type\": \"odd_asphere\", \"R\": 27.9, \"k\": -0.41,\n"
	" \"A\": {\"1\": 1.3e-3, \"3\": -2.7e-6, \"4\": 3.1e-6, \"7\": 1.9e-11}, \"aperture_diameter\": 16}",
};

static void test_other_types(void **state)
{
	struct asph_prescription p[5], q;
	struct asph_error err;

	for (int i = 0; i < 5; i++) {
		const char *t = other_types[i];
		char *json = NULL;
		if (asph_prescription_parse(t, strlen(t), "t.json", &p[i], &err) != 0)
			fail_msg("case %d: %s", i, err.message);
		assert_int_equal(asph_prescription_to_json(&p[i], &json), 0);
		assert_int_equal(asph_prescription_parse(json, strlen(json), "rt", &q, &err), 0);
		assert_memory_equal(&p[i], &q, sizeof(q));
		free(json);
	}
	assert_int_equal(p[0].type, ASPH_SURFACE_QBFS);
	assert_true(p[0].norm_radius == 10.25 && p[0].Q[1] == -0.0071 && p[0].Q[3] == 0 && p[0].k == 0);
	/* Qbfs on a conic base; the curvature c for R */
	assert_int_equal(p[1].type, ASPH_SURFACE_QBFS);
	assert_true(p[1].R == 1 / 0.0575 && p[1].k == -0.676 && p[1].Q[1] == -0.32);
	assert_string_equal(p[1].note, "a conic base");
	/* a plate: a plane base, an off-centre aperture */
	assert_true(isinf(p[2].R) && p[2].A[4] == 2.1e-6 && p[2].aperture_diameter == 0);
	assert_true(p[2].aperture.shape == ASPH_APERTURE_RECTANGULAR && p[2].aperture.offset[1] == 45);
	assert_int_equal(p[3].type, ASPH_SURFACE_QCON);
	assert_true(p[3].k == -0.73 && p[3].Q[3] == 6.1e-4 && p[3].Q[2] == 0);
	assert_int_equal(p[4].type, ASPH_SURFACE_ODD_ASPHERE);
	assert_true(p[4].A[1] == 1.3e-3 && p[4].A[3] == -2.7e-6 && p[4].A[7] == 1.9e-11);
	/* the plane is written as its curvature */
	char *json = NULL;
	assert_int_equal(asph_prescription_to_json(&p[2], &json), 0);
	assert_non_null(strstr(json, "\"c\": 0.0"));
	assert_null(strstr(json, "\"R\""));
	free(json);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_parse_good),
		cmocka_unit_test(test_presets),
		cmocka_unit_test(test_json_round_trip),
		cmocka_unit_test(test_load_file_and_preset),
		cmocka_unit_test(test_refusals),
		cmocka_unit_test(test_other_types),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
