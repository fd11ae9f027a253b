/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph/lens-import.h: .zmx and CSV lens files as prescriptions. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph/lens-import.h"

static const char zmx[] =
	"UNIT MM X W X CM MR CPMM\n"           /* 1 */
	"SURF 0\n"                             /* 2 */
	"  TYPE STANDARD\n"
	"  CURV 0.0 0 0 0 0 \"\"\n"
	"SURF 1\n"                             /* 5 */
	"  TYPE EVENASPH\n"
	"  CURV 4.975866e-2 0 0 0 0 \"\"\n"
	"  PARM 2 -2.0868E-005\n"
	"  PARM 3 -3.9031E-009\n"
	"  CONI -1\n"
	"  DIAM 20 1 0 0 1 \"\"\n"
	"SURF 7\n"                             /* 12 */
	"  TYPE ODDASPH\n"
	"  CURV -0.025\n"
	"  PARM 1 1.3e-3\n"
	"  PARM 3 -2.7e-6\n"
	"  DIAM 8\n"
	"SURF 8\n"                             /* 18 */
	"  TYPE TOROIDAL\n"
	"  CURV 0.01\n"
	"  DIAM 8\n";

static struct asph_lens_import *parse(const char *text, const char *name)
{
	struct asph_lens_import *im = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_parse(text, strlen(text), name, &im, &err), 0);
	assert_non_null(im);
	return im;
}

static void test_zmx(void **state)
{
	struct asph_lens_import *im = parse(zmx, "/lab/doublet.v2.zmx");
	struct asph_lens_surface s;
	struct asph_prescription p;
	struct asph_error err;

	assert_int_equal(asph_lens_import_format(im), ASPH_LENS_ZMX);
	assert_int_equal(asph_lens_import_count(im), 4);
	asph_lens_import_surface(im, 0, &s);
	assert_true(s.number == 0 && isinf(s.R) && s.aperture_diameter == 0 && s.line == 2);
	assert_string_equal(s.type, "STANDARD");
	asph_lens_import_surface(im, 1, &s);
	assert_true(s.number == 1 && s.R == 1 / 4.975866e-2 && s.k == -1 && s.line == 5);
	assert_true(s.aperture_diameter == 40);
	asph_lens_import_surface(im, 3, &s);
	assert_true(s.number == 8 && s.line == 18);
	assert_string_equal(s.type, "TOROIDAL");

	/* EVENASPH: PARM i multiplies r^(2i); DIAM is the semi-diameter */
	assert_int_equal(asph_lens_import_prescription(im, 1, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_EVEN_ASPHERE);
	assert_string_equal(p.name, "doublet-s1");
	assert_true(p.R == 1 / 4.975866e-2 && p.k == -1 && p.aperture_diameter == 40);
	assert_true(p.A[4] == -2.0868e-5 && p.A[6] == -3.9031e-9 && p.A[2] == 0 && p.A[8] == 0);
	/* ODDASPH: PARM i multiplies r^i */
	assert_int_equal(asph_lens_import_prescription(im, 7, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_ODD_ASPHERE);
	assert_true(p.R == 1 / -0.025 && p.A[1] == 1.3e-3 && p.A[3] == -2.7e-6 && p.A[2] == 0);

	/* refusals: a plane, a type not imported, no such surface, no choice */
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 0, &p, &err), -EINVAL);
	assert_string_equal(err.field, "CURV");
	assert_non_null(strstr(err.message, "flat"));
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 8, &p, &err), -EINVAL);
	assert_true(err.line == 19 && err.column == 8);
	assert_string_equal(err.field, "TYPE");
	assert_string_equal(err.source, "/lab/doublet.v2.zmx");
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 9, &p, &err), -ENOENT);
	assert_non_null(strstr(err.message, "no surface 9 (the file has 0 to 8)"));
	assert_int_equal(asph_lens_import_prescription(im, -1, &p, &err), -ENOENT);
	asph_lens_import_free(im);
}

static void test_zmx_refusals(void **state)
{
	static const struct {
		const char *text;
		int line, column;
		const char *field, *needle;
	} cases[] = {
		{ "SURF 1\n  TYPE EVENASPH\n  CURV 0.05\n  PARM 2 -2.1e-5q\n  DIAM 3\n",
		  4, 10, "PARM", "not a finite number" },
		{ "UNIT IN X W\nSURF 1\n", 1, 6, "UNIT", "millimetres" },
		{ "SURF 1\n  TYPE STANDARD\n  CURV 0.05", 3, 12, NULL, "truncated" },
		{ "SURF 1\n  CURV 0.05\n", 1, 1, NULL, "no TYPE line" },
		{ "NAME x\n", 1, 0, NULL, "no SURF block" },
		{ "SURF 1\n\0\n", 0, 0, NULL, "NUL bytes" },
		/* found by the lens-zmx fuzz target: a number past int */
		{ "SURF 09999999999999999999\n  TYPE STANDARD\n", 1, 1, "SURF",
		  "bad surface number" },
		{ "SURF -1\n", 1, 1, "SURF", "bad surface number" },
	};
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_lens_import *im = NULL;
		struct asph_error err;
		size_t len = !strcmp(cases[i].needle, "NUL bytes") ? 9 : strlen(cases[i].text);

		asph_error_clear(&err);
		assert_int_equal(asph_lens_import_parse(cases[i].text, len, "bad.zmx", &im, &err),
				 -EINVAL);
		assert_null(im);
		assert_int_equal(err.line, cases[i].line);
		assert_int_equal(err.column, cases[i].column);
		assert_string_equal(err.field, cases[i].field ? cases[i].field : "");
		assert_string_equal(err.source, "bad.zmx");
		assert_non_null(strstr(err.message, cases[i].needle));
	}
}

/* UTF-16 with a byte-order mark reads as the same text in UTF-8. */
static void test_utf16(void **state)
{
	const char *text = "SURF 3\n  TYPE STANDARD\n  CURV -0.02\n  CONI 0.37\n  DIAM 4\n";
	size_t n = strlen(text);
	unsigned char le[256], be[256];
	struct asph_prescription p;
	struct asph_error err;

	assert_true(2 * n + 2 <= sizeof(le));
	le[0] = 0xff, le[1] = 0xfe, be[0] = 0xfe, be[1] = 0xff;
	for (size_t i = 0; i < n; i++) {
		le[2 + 2 * i] = (unsigned char)text[i], le[3 + 2 * i] = 0;
		be[2 + 2 * i] = 0, be[3 + 2 * i] = (unsigned char)text[i];
	}
	for (int big = 0; big < 2; big++) {
		struct asph_lens_import *im = NULL;
		asph_error_clear(&err);
		assert_int_equal(asph_lens_import_parse(big ? be : le, 2 * n + 2, "w.zmx", &im, &err),
				 0);
		assert_int_equal(asph_lens_import_prescription(im, -1, &p, &err), 0);
		assert_true(p.R == 1 / -0.02 && p.k == 0.37 && p.aperture_diameter == 8);
		assert_string_equal(p.name, "w-s3");
		asph_lens_import_free(im);
	}
	/* an odd byte count is a cut file */
	struct asph_lens_import *im = NULL;
	assert_int_equal(asph_lens_import_parse(le, 2 * n + 1, "w.zmx", &im, &err), -EINVAL);
	assert_non_null(strstr(err.message, "odd number of bytes"));
}

static void test_csv(void **state)
{
	struct asph_lens_import *im =
		parse("R,k,A1,A4,aperture_diameter\n"
		      "31.7,-0.5,,2e-6,22\n"
		      "\n"
		      "-45,0,1e-3,,30\n", "t.csv");
	struct asph_lens_surface s;
	struct asph_prescription p;
	struct asph_error err;

	assert_int_equal(asph_lens_import_format(im), ASPH_LENS_CSV);
	assert_int_equal(asph_lens_import_count(im), 2);
	asph_lens_import_surface(im, 1, &s);
	assert_true(s.number == 2 && s.R == -45 && s.aperture_diameter == 30 && s.line == 4);
	assert_string_equal(s.type, "");
	assert_int_equal(asph_lens_import_prescription(im, 1, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_EVEN_ASPHERE);
	assert_true(p.R == 31.7 && p.k == -0.5 && p.A[4] == 2e-6 && p.A[1] == 0);
	assert_string_equal(p.name, "t-s1");
	/* an odd power makes an odd asphere */
	assert_int_equal(asph_lens_import_prescription(im, 2, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_ODD_ASPHERE);
	assert_true(p.A[1] == 1e-3);
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 3, &p, &err), -ENOENT);
	assert_non_null(strstr(err.message, "no row 3 (the file has 2)"));
	asph_lens_import_free(im);

	/* read as CSV by its first bytes whatever its name */
	im = parse("R,aperture_diameter\n12,5\n", "table.txt");
	assert_int_equal(asph_lens_import_format(im), ASPH_LENS_CSV);
	asph_lens_import_free(im);

	asph_error_clear(&err);
	im = NULL;
	const char *bad = "R,k,A4,aperture_diameter\n31.7,-0.5,x1,22\n";
	assert_int_equal(asph_lens_import_parse(bad, strlen(bad), "bad.csv", &im, &err), -EINVAL);
	assert_true(err.line == 2 && err.column == 11);
	const char *unknown = "R,k,B4,aperture_diameter\n31.7,-0.5,1,22\n";
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_parse(unknown, strlen(unknown), "u.csv", &im, &err),
			 -EINVAL);
	assert_true(err.line == 1 && err.column == 5);
	assert_string_equal(err.field, "B4");
}

static void test_load(void **state)
{
	const char *data = getenv("ASPH_TEST_DATA");
	struct asph_lens_import *im = NULL;
	struct asph_prescription p;
	struct asph_error err;
	char path[4096];

	assert_non_null(data);
	snprintf(path, sizeof(path), "%s/lens-doublet-utf16.zmx", data);
	assert_int_equal(asph_lens_import_load(path, &im, &err), 0);
	assert_int_equal(asph_lens_import_count(im), 7);
	assert_int_equal(asph_lens_import_prescription(im, 4, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_QCON);
	assert_true(p.norm_radius == 10.5 && p.k == -0.73 && p.Q[4] == 6.1e-4);
	asph_lens_import_free(im);

	im = NULL;
	snprintf(path, sizeof(path), "%s/no-such-lens.zmx", data);
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_load(path, &im, &err), -ENOENT);
	assert_null(im);
	assert_string_equal(err.source, path);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_zmx),
		cmocka_unit_test(test_zmx_refusals),
		cmocka_unit_test(test_utf16),
		cmocka_unit_test(test_csv),
		cmocka_unit_test(test_load),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
