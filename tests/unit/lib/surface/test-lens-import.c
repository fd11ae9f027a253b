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
#include "asph/surface.h"

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
	"  TYPE ODDASPHE\n"
	"  CURV -0.025\n"
	"  PARM 1 1.3e-3\n"
	"  PARM 3 -2.7e-6\n"
	"  DIAM 8\n"
	"SURF 8\n"                             /* 18 */
	"  TYPE GRID_SAG\n"
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
	assert_string_equal(s.type, "GRID_SAG");

	/* EVENASPH: PARM i multiplies r^(2i); DIAM is the semi-diameter */
	assert_int_equal(asph_lens_import_prescription(im, 1, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_EVEN_ASPHERE);
	assert_string_equal(p.name, "doublet-s1");
	assert_true(p.R == 1 / 4.975866e-2 && p.k == -1 && p.aperture_diameter == 40);
	assert_true(p.A[4] == -2.0868e-5 && p.A[6] == -3.9031e-9 && p.A[2] == 0 && p.A[8] == 0);
	/* ODDASPHE: PARM i multiplies r^i */
	assert_int_equal(asph_lens_import_prescription(im, 7, &p, &err), 0);
	assert_int_equal(p.type, ASPH_SURFACE_ODD_ASPHERE);
	assert_true(p.R == 1 / -0.025 && p.A[1] == 1.3e-3 && p.A[3] == -2.7e-6 && p.A[2] == 0);

	/* refusals: no aperture, a type not imported, no such surface, no choice */
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 0, &p, &err), -EINVAL);
	assert_true(err.line == 2 && err.column == 1);
	assert_string_equal(err.field, "DIAM");
	assert_non_null(strstr(err.message, "no positive semi-diameter"));
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 8, &p, &err), -EINVAL);
	assert_true(err.line == 19 && err.column == 8);
	assert_string_equal(err.field, "TYPE");
	assert_non_null(strstr(err.message, "GRID_SAG, which is not imported"));
	assert_string_equal(err.source, "/lab/doublet.v2.zmx");
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 9, &p, &err), -ENOENT);
	assert_non_null(strstr(err.message, "no surface 9 (the file has 0 to 8)"));
	assert_int_equal(asph_lens_import_prescription(im, -1, &p, &err), -ENOENT);
	asph_lens_import_free(im);
}

/* A refusal: the text, and where and what the error says. */
struct refusal {
	const char *text;
	int line, column;
	const char *field, *needle;
};

static void expect_refusal(const struct asph_error *err, const struct refusal *c,
			   const char *source)
{
	if (err->line != c->line || err->column != c->column ||
	    strcmp(err->field, c->field ? c->field : "") || !strstr(err->message, c->needle) ||
	    strcmp(err->source, source)) {
		print_error("%s:%d:%d: %s: %s\n  expected %d:%d: %s: ...%s...\n", err->source,
			    err->line, err->column, err->field, err->message, c->line, c->column,
			    c->field ? c->field : "", c->needle);
		fail();
	}
}

static void test_zmx_refusals(void **state)
{
	static const struct refusal cases[] = {
		{ "SURF 1\n  TYPE EVENASPH\n  CURV 0.05\n  PARM 2 -2.1e-5q\n  DIAM 3\n",
		  4, 10, "PARM", "not a finite number" },
		{ "UNIT FT X W\nSURF 1\n", 1, 6, "UNIT", "the units read are MM, CM, IN and M" },
		{ "NAME x\n", 1, 0, NULL, "no SURF block" },
		{ "SURF 1\n  TYPE QED_TYPE\n  XDAT 0 1\n", 3, 0, "XDAT", "is not 1..250" },
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
		expect_refusal(&err, &cases[i], "bad.zmx");
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

/* ---- the freeform types ---------------------------------------------- */

static struct asph_lens_import *load(const char *file)
{
	const char *data = getenv("ASPH_TEST_DATA");
	struct asph_lens_import *im = NULL;
	struct asph_error err;
	char path[4096];

	assert_non_null(data);
	snprintf(path, sizeof(path), "%s/%s", data, file);
	asph_error_clear(&err);
	if (asph_lens_import_load(path, &im, &err) < 0) {
		print_error("%s:%d:%d: %s: %s\n", err.source, err.line, err.column, err.field,
			    err.message);
		fail();
	}
	return im;
}

static double conic(double c, double k, double r2)
{
	return c * r2 / (1 + sqrt(1 - (1 + k) * c * c * r2));
}

/* OpticStudio's sags, written from its manual (docs/prescriptions.md) with
 * the numbers of tests/data/lens-freeform.zmx typed in. */
static double biconic_sag(double x, double y)
{
	double cx = 1 / 41.37, cy = 0.019083969465648856, kx = -0.731, ky = -0.35;

	return (cx * x * x + cy * y * y) /
	       (1 + sqrt(1 - (1 + kx) * cx * cx * x * x - (1 + ky) * cy * cy * y * y));
}

static double toroidal_sag(double x, double y)
{
	double R = -71.3, u = x / 9.3, v = y / 9.3, rho2 = u * u + v * v;
	double zy = conic(0.01890359168241966, -0.613, y * y) - 1.77e-6 * pow(y, 4) +
		    4.1e-12 * pow(y, 8);
	double z = R + sqrt((R - zy) * (R - zy) - x * x);     /* R < 0 */

	/* Zernike Standard: Z2 2 rho cos, Z4 sqrt3 (2 rho^2 - 1), Z6 sqrt6 rho^2
	 * cos 2A, Z7 sqrt8 (3 rho^3 - 2 rho) sin A, Z10 sqrt8 rho^3 cos 3A */
	return z + 2.3e-4 * 2 * u - 3.4e-4 * sqrt(3) * (2 * rho2 - 1) +
	       5.6e-4 * sqrt(6) * (u * u - v * v) - 6.7e-4 * sqrt(8) * (3 * rho2 - 2) * v +
	       8.9e-4 * sqrt(8) * (u * u * u - 3 * u * v * v);
}

static double xpolynom_sag(double x, double y)
{
	double u = x / 11.3, v = y / 11.3;

	/* terms 1 x, 3 x^2, 5 y^2, 6 x^3, 7 x^2 y, 9 y^3, 12 x^2 y^2, 14 y^4, 20 y^5 */
	return conic(-0.01145475372279496, 0.37, x * x + y * y) + 1.3e-3 * u + 2.1e-1 * u * u -
	       1.3e-1 * v * v + 1.9e-2 * u * u * u + 4.1e-2 * u * u * v - 2.7e-2 * v * v * v -
	       3.3e-3 * u * u * v * v + 7.7e-4 * pow(v, 4) + 2.2e-4 * pow(v, 5);
}

static double szernsag_sag(double x, double y)
{
	double r2 = x * x + y * y, u = (x - 0.41) / 10.7, v = (y + 0.23) / 10.7;
	double rho2 = u * u + v * v;

	/* Z9 sqrt8 rho^3 sin 3A, Z11 sqrt5 (6 rho^4 - 6 rho^2 + 1), Z15 sqrt10
	 * rho^4 sin 4A */
	return conic(0.014025245441795233, -1.21, r2) - 2.2e-6 * r2 * r2 + 1.9e-9 * r2 * r2 * r2 +
	       1.1e-3 * 2 * u - 0.7e-3 * 2 * v + 2.4e-3 * sqrt(3) * (2 * rho2 - 1) -
	       1.5e-3 * sqrt(6) * (u * u - v * v) + 0.9e-3 * sqrt(8) * (3 * rho2 - 2) * v -
	       0.4e-3 * sqrt(8) * (3 * u * u * v - v * v * v) +
	       0.6e-3 * sqrt(8) * (u * u * u - 3 * u * v * v) +
	       1.2e-3 * sqrt(5) * (6 * rho2 * rho2 - 6 * rho2 + 1) -
	       0.3e-3 * sqrt(10) * (4 * u * u * u * v - 4 * u * v * v * v);
}

static void check_sag(const struct asph_prescription *p, double (*sag)(double, double),
		      double size)
{
	static const double f[][2] = { { 0, 0 }, { 0.31, -0.27 }, { -0.58, 0.41 },
				       { 0.69, 0.62 }, { -0.14, -0.93 }, { 0.95, -0.17 } };
	struct asph_surface *s = NULL;
	struct asph_aperture ap;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_surface_alloc(p, &s, &err), 0);
	asph_surface_aperture(s, &ap);
	for (size_t i = 0; i < sizeof(f) / sizeof(f[0]); i++) {
		double x = ap.offset[0] + size * f[i][0], y = ap.offset[1] + size * f[i][1];
		double got = asph_surface_sag_xy(s, x, y), want = sag(x, y);
		assert_true(asph_surface_contains(s, x, y, 0));
		if (!(fabs(got - want) <= 1e-12)) {
			print_error("%s at (%g, %g): %.17g, OpticStudio's formula %.17g\n",
				    p->name, x, y, got, want);
			fail();
		}
	}
	asph_surface_free(s);
}

/* The file as OpticStudio writes it, in UTF-8 and in UTF-16 LE with CR LF:
 * each surface against its OpticStudio sag formula. */
static void test_zmx_freeform(void **state)
{
	static const char *const files[] = { "lens-freeform.zmx", "lens-freeform-utf16.zmx" };
	struct asph_prescription p[2][4];
	struct asph_error err;

	for (int f = 0; f < 2; f++) {
		struct asph_lens_import *im = load(files[f]);
		assert_int_equal(asph_lens_import_count(im), 6);
		for (int i = 0; i < 4; i++) {
			asph_error_clear(&err);
			if (asph_lens_import_prescription(im, i + 1, &p[f][i], &err) < 0) {
				print_error("%s:%d:%d: %s: %s\n", err.source, err.line, err.column,
					    err.field, err.message);
				fail();
			}
		}
		asph_lens_import_free(im);
	}
	/* BICONICX: y from CURV and CONI, x from PARM 1 and 2; DIAM */
	assert_int_equal(p[0][0].type, ASPH_SURFACE_BICONIC);
	assert_true(p[0][0].Rx == 41.37 && p[0][0].kx == -0.731 && p[0][0].ky == -0.35);
	assert_true(p[0][0].aperture_diameter == 18);
	check_sag(&p[0][0], biconic_sag, 8.9);
	/* TOROIDAL: PARM 1 radius of rotation, PARM 2.. y^2, y^4, ...; the
	 * Zernike terms in extra data; SQAP half widths about OBDC */
	assert_int_equal(p[0][1].type, ASPH_SURFACE_TOROIDAL);
	assert_true(p[0][1].R_rotation == -71.3 && p[0][1].A[4] == -1.77e-6 && p[0][1].A[8] == 4.1e-12);
	assert_true(p[0][1].norm_radius == 9.3 && p[0][1].Zernike[9] == 8.9e-4);
	assert_int_equal(p[0][1].aperture.shape, ASPH_APERTURE_RECTANGULAR);
	assert_true(p[0][1].aperture.width == 14.2 && p[0][1].aperture.height == 11.7);
	assert_true(p[0][1].aperture.offset[0] == 0.37 && p[0][1].aperture.offset[1] == -0.81);
	check_sag(&p[0][1], toroidal_sag, 5.8);
	/* XPOLYNOM: term t is XDAT t + 2; ELAP about OBDC */
	assert_int_equal(p[0][2].type, ASPH_SURFACE_XY_POLYNOMIAL);
	assert_int_equal(p[0][2].aperture.shape, ASPH_APERTURE_ELLIPTICAL);
	check_sag(&p[0][2], xpolynom_sag, 7.4);
	/* SZERNSAG: PARM 1..8 r^2 .. r^16, PARM 9 and 10 the terms' centre;
	 * Extrapolate 0 is fine: the aperture stays inside the terms' circle */
	assert_int_equal(p[0][3].type, ASPH_SURFACE_ZERNIKE_SAG);
	assert_true(p[0][3].zernike_decenter[0] == 0.41 && p[0][3].zernike_decenter[1] == -0.23);
	check_sag(&p[0][3], szernsag_sag, 9.4);
	for (int i = 0; i < 4; i++) {
		assert_string_equal(p[1][i].name + strlen("lens-freeform-utf16"),
				    p[0][i].name + strlen("lens-freeform"));
		memset(p[0][i].name, 0, sizeof(p[0][i].name));
		memset(p[1][i].name, 0, sizeof(p[1][i].name));
		assert_memory_equal(&p[0][i], &p[1][i], sizeof(p[0][i]));
	}
}

/* ---- the files of other writers: Q types, units, segments, encodings ---- */

/* Forbes' Q^bfs_0 .. Q^bfs_3 (Opt. Express 15, 5218 (2007), Eq. A.2-A.4)
 * and Q^con_0 .. Q^con_3 = P_m^(0,4)(2x - 1), written out. */
static double qbfs_q(int m, double x)
{
	const double s2 = sqrt(2.0 / 95.0), s3 = sqrt(2.0 / 2545.0);
	const double q[4] = { 1, (13 - 16 * x) / sqrt(19.0), s2 * (29 - 4 * x * (25 - 19 * x)),
			      s3 * (207 - 4 * x * (315 - x * (577 - 320 * x))) };
	return q[m];
}

static double qcon_q(int m, double x)
{
	const double q[4] = { 1, 6 * x - 5, 15 - 14 * x * (3 - 2 * x),
			      -35 + x * (168 - x * (252 - 120 * x)) };
	return q[m];
}

/* OpticStudio's Q-type asphere: the base conic, then for Qbfs
 * u^2 (1 - u^2) sum a_m Q^bfs_m(u^2) times the secant of the conic's
 * normal sqrt((1 - k c^2 r^2) / (1 - (1 + k) c^2 r^2)), for Qcon
 * u^4 sum a_m Q^con_m(u^2); u = r / norm_radius. */
static double qtype_sag(int qcon, double c, double k, double rho, const double a[4], double r2)
{
	double u2 = r2 / (rho * rho), sum = 0;

	for (int m = 0; m < 4; m++)
		sum += a[m] * (qcon ? qcon_q(m, u2) : qbfs_q(m, u2));
	if (qcon)
		return conic(c, k, r2) + u2 * u2 * sum;
	return conic(c, k, r2) +
	       u2 * (1 - u2) * sqrt((1 - k * c * c * r2) / (1 - (1 + k) * c * c * r2)) * sum;
}

/* tests/data/lens-qtype-latin1.zmx */
static double condenser_qbfs_sag(double x, double y)
{
	const double a[4] = { -0.2913, -0.0871, 0.0231, -0.0067 };
	return qtype_sag(0, 8.712e-2, -0.5873, 13.5, a, x * x + y * y);
}

static double condenser_qcon_sag(double x, double y)
{
	const double a[4] = { 0.0417, -0.0123, 0.0051, -0.0019 };
	return qtype_sag(1, -1.9431e-2, -2.31, 12.7, a, x * x + y * y);
}

/* tests/data/lens-tma-inch-utf16.zmx, in inches: each sag z(x, y) in mm is
 * 25.4 z_in(x / 25.4, y / 25.4). */
#define IN 25.4
static double tma_primary_sag(double x, double y)
{
	double r2 = (x * x + y * y) / (IN * IN);
	return IN * (conic(-1.25e-2, -1.05, r2) + 3.1e-7 * r2 * r2 - 2.2e-10 * r2 * r2 * r2);
}

static double tma_secondary_sag(double x, double y)
{
	return IN * conic(-4.0e-2, -3.1, (x * x + y * y) / (IN * IN));
}

static double tma_tertiary_sag(double x, double y)
{
	double r2 = (x * x + y * y) / (IN * IN);
	return IN * (conic(-2.27e-2, -0.6, r2) - 1.3e-6 * r2 * r2);
}

static double tma_plate_sag(double x, double y)
{
	double r2 = (x * x + y * y) / (IN * IN);
	return IN * (1.7e-5 * r2 * r2 - 4.4e-8 * r2 * r2 * r2);
}

static void import_or_fail(const struct asph_lens_import *im, int number,
			   struct asph_prescription *p)
{
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_lens_import_prescription(im, number, p, &err) < 0) {
		print_error("%s:%d:%d: %s: %s\n", err.source, err.line, err.column, err.field,
			    err.message);
		fail();
	}
}

/* Q-type aspheres (QED_TYPE), Qbfs over a conic past the vertex radius and
 * Qcon, in a Latin-1 file with unindented lines and no final newline. */
static void test_zmx_qtype_latin1(void **state)
{
	struct asph_lens_import *im = load("lens-qtype-latin1.zmx");
	struct asph_lens_surface ls;
	struct asph_prescription p;
	struct asph_error err;

	assert_int_equal(asph_lens_import_count(im), 4);
	asph_lens_import_surface(im, 1, &ls);
	assert_string_equal(ls.type, "QED_TYPE");
	import_or_fail(im, 1, &p);
	assert_int_equal(p.type, ASPH_SURFACE_QBFS);
	assert_true(p.norm_radius == 13.5 && p.k == -0.5873 && p.Q[3] == -0.0067 && p.Q[4] == 0);
	assert_true(p.aperture_diameter == 24.4 && p.note[0] == '\0');
	check_sag(&p, condenser_qbfs_sag, 12.2);
	import_or_fail(im, 2, &p);
	assert_int_equal(p.type, ASPH_SURFACE_QCON);
	assert_true(p.norm_radius == 12.7 && p.k == -2.31 && p.Q[0] == 0.0417);
	check_sag(&p, condenser_qcon_sag, 12.7);
	/* the last surface, its last line without a newline: a flat */
	import_or_fail(im, 3, &p);
	assert_true(isinf(p.R) && p.aperture_diameter == 6.2);
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_prescription(im, 0, &p, &err), -EINVAL);
	assert_string_equal(err.field, "DIAM");
	asph_lens_import_free(im);
}

/* A three-mirror telescope in inches, UTF-16 LE with CR LF: off-axis
 * segments (SQAP and ELAP about OBDC), a standard surface without TYPE, an
 * aspheric plate, every length converted to mm. */
static void test_zmx_segments_inches(void **state)
{
	struct asph_lens_import *im = load("lens-tma-inch-utf16.zmx");
	struct asph_lens_surface ls;
	struct asph_prescription p;

	assert_int_equal(asph_lens_import_count(im), 6);
	asph_lens_import_surface(im, 2, &ls);
	assert_string_equal(ls.type, "STANDARD");
	assert_true(ls.R == IN / -4.0e-2 && ls.aperture_diameter == 2 * 1.2 * IN);

	import_or_fail(im, 1, &p);
	assert_int_equal(p.type, ASPH_SURFACE_EVEN_ASPHERE);
	assert_int_equal(p.aperture.shape, ASPH_APERTURE_RECTANGULAR);
	assert_true(p.aperture.width == 6 * IN && p.aperture.height == 4 * IN);
	assert_true(p.aperture.offset[0] == 0 && p.aperture.offset[1] == 4.5 * IN);
	assert_non_null(strstr(p.note, "inches (UNIT IN) converted to mm"));
	check_sag(&p, tma_primary_sag, 1.9 * IN);
	import_or_fail(im, 2, &p);
	assert_true(p.aperture_diameter == 2.4 * IN);
	check_sag(&p, tma_secondary_sag, 1.2 * IN);
	import_or_fail(im, 3, &p);
	assert_int_equal(p.aperture.shape, ASPH_APERTURE_ELLIPTICAL);
	assert_true(p.aperture.offset[0] == 0.4 * IN && p.aperture.offset[1] == -3.1 * IN);
	check_sag(&p, tma_tertiary_sag, 1.5 * IN);
	import_or_fail(im, 4, &p);
	assert_true(isinf(p.R));
	check_sag(&p, tma_plate_sag, 1.5 * IN);
	asph_lens_import_free(im);
}

static void convert(const char *text, struct asph_prescription *p, struct asph_error *err,
		    int expect)
{
	struct asph_lens_import *im = NULL;

	asph_error_clear(err);
	assert_int_equal(asph_lens_import_parse(text, strlen(text), "ff.zmx", &im, err), 0);
	assert_int_equal(asph_lens_import_prescription(im, -1, p, err), expect);
	asph_lens_import_free(im);
}

/* Defaults and edges: a radius parameter of 0 is a plane, a toroid needs
 * no Zernike terms, terms past the count are OpticStudio's to ignore. */
static void test_zmx_freeform_edges(void **state)
{
	struct asph_prescription p;
	struct asph_error err;

	convert("SURF 8\n  TYPE TOROIDAL\n  CURV 0.01\n  XDAT 1 0\n  XDAT 2 7\n  DIAM 8\n", &p, &err,
		0);
	assert_true(p.R == 100 && isinf(p.R_rotation) && p.norm_radius == 0);
	convert("SURF 1\n  TYPE BICONICX\n  CURV 0\n  PARM 1 25\n  DIAM 4\n", &p, &err, 0);
	assert_true(isinf(p.Ry) && p.Rx == 25);
	convert("SURF 1\n  TYPE XPOLYNOM\n  CURV 0.01\n  XDAT 1 2\n  XDAT 2 5\n  XDAT 4 1e-3\n"
		"  XDAT 5 2e-3\n  DIAM 4\n", &p, &err, 0);
	assert_true(p.C[2] == 1e-3 && p.C[3] == 0);
	convert("SURF 1\n  TYPE SZERNSAG\n  CURV 0.01\n  CLAP 0 4.5\n  OBDC 0.5 -0.25\n"
		"  XDAT 1 1\n  XDAT 2 6\n  XDAT 3 1e-3\n  DIAM 9\n", &p, &err, 0);
	assert_int_equal(p.aperture.shape, ASPH_APERTURE_CIRCULAR);
	assert_true(p.aperture.width == 9 && p.aperture.offset[0] == 0.5);
	assert_true(p.Zernike[0] == 1e-3);
	/* a CLAP without a decenter is the centred circle of any type */
	convert("SURF 1\n  TYPE EVENASPH\n  CURV 0.02\n  CLAP 0 3.5\n  DIAM 5\n", &p, &err, 0);
	assert_true(p.aperture_diameter == 7);
	/* off-axis segments of a rotationally symmetric parent: any aperture
	 * about its decenter */
	convert("SURF 1\n  TYPE EVENASPH\n  CURV 0.02\n  CLAP 0 3\n  OBDC 1 0\n  DIAM 4\n", &p, &err,
		0);
	assert_true(p.aperture.shape == ASPH_APERTURE_CIRCULAR && p.aperture.width == 6 &&
		    p.aperture.offset[0] == 1 && p.aperture_diameter == 0);
	convert("SURF 1\n  TYPE ODDASPHE\n  CURV 0.02\n  SQAP 3 2\n  DIAM 4\n", &p, &err, 0);
	assert_true(p.aperture.shape == ASPH_APERTURE_RECTANGULAR && p.aperture.height == 4 &&
		    p.aperture.offset[1] == 0);
	/* a plate: CURV 0 is a plane base; no TYPE line is STANDARD */
	convert("SURF 1\n  TYPE EVENASPH\n  CURV 0\n  PARM 2 1.7e-5\n  DIAM 4\n", &p, &err, 0);
	assert_true(isinf(p.R) && p.A[4] == 1.7e-5);
	convert("SURF 1\n  CURV -0.04\n  CONI -3.1\n  DIAM 1.2\n", &p, &err, 0);
	assert_true(p.type == ASPH_SURFACE_EVEN_ASPHERE && p.R == 1 / -0.04 && p.k == -3.1);
	/* OpticStudio's older short name of the odd asphere */
	convert("SURF 1\n  TYPE ODDASPH\n  CURV 0.02\n  PARM 3 1e-6\n  DIAM 4\n", &p, &err, 0);
	assert_true(p.type == ASPH_SURFACE_ODD_ASPHERE && p.A[3] == 1e-6);
	/* lens units in centimetres and metres: lengths in mm, r^i terms by
	 * (10 mm)^(1-i) */
	convert("UNIT CM\nSURF 1\n  TYPE EVENASPH\n  CURV 0.5\n  PARM 2 2e-3\n  DIAM 1.5\n", &p,
		&err, 0);
	assert_true(p.R == 20 && p.aperture_diameter == 30 && fabs(p.A[4] - 2e-6) < 1e-21);
	assert_non_null(strstr(p.note, "UNIT CM"));
	convert("UNIT M\nSURF 1\n  TYPE QED_TYPE\n  CURV 10\n  XDAT 1 1\n  XDAT 2 1\n"
		"  XDAT 3 0.012\n  XDAT 4 2e-5\n  DIAM 0.01\n", &p, &err, 0);
	assert_true(p.R == 100 && p.norm_radius == 12 && p.Q[0] == 2e-2 && p.aperture_diameter == 20);
}

/* What cannot be imported, each with its line, column and keyword. */
static void test_zmx_freeform_refusals(void **state)
{
	static const struct refusal cases[] = {
		{ "SURF 1\n  TYPE BICONICX\n  CURV 0.02\n  PARM 1 40\n  PARM 3 1.5e-3\n  DIAM 5\n",
		  5, 10, "PARM 3", "the Biconic surface has no parameter 3" },
		{ "SURF 1\n  TYPE BICONICX\n  CURV 0.02\n  XDAT 1 4\n  DIAM 5\n",
		  4, 10, "XDAT 1", "the Biconic surface has no extra data" },
		{ "SURF 1\n  TYPE TOROIDAL\n  CURV 0.02\n  PARM 9 2e-9\n  DIAM 5\n",
		  4, 10, "PARM 9", "the Toroidal surface has no parameter 9" },
		{ "SURF 2\n  TYPE XPOLYNOM\n  CURV 0.01\n  XDAT 1 231\n  XDAT 2 10\n  DIAM 5\n",
		  4, 10, "XDAT 1", "a whole number from 0 to 230" },
		{ "SURF 2\n  TYPE XPOLYNOM\n  CURV 0.01\n  XDAT 1 3\n  XDAT 3 1e-3\n  DIAM 5\n",
		  2, 8, "XDAT 2", "normalization radius is 0" },
		{ "SURF 2\n  TYPE XPOLYNOM\n  CURV 0.01\n  PARM 2 0.5\n  XDAT 2 10\n  DIAM 5\n",
		  4, 10, "PARM 2", "the Extended Polynomial surface has no parameter 2" },
		{ "SURF 2\n  TYPE SZERNSAG\n  CURV 0.01\n  XDAT 1 232\n  XDAT 2 10\n  DIAM 5\n",
		  4, 10, "XDAT 1", "a whole number from 0 to 231" },
		{ "SURF 4\n  TYPE SZERNSAG\n  CURV 0.01\n  PARM 0 0\n  XDAT 1 4\n  XDAT 2 5\n"
		  "  XDAT 6 1e-3\n  DIAM 6\n", 4, 10, "PARM 0", "Extrapolate is 0" },
		{ "SURF 4\n  TYPE TOROIDAL\n  CURV 0.01\n  PARM 0 0\n  PARM 1 -30\n  XDAT 1 4\n"
		  "  XDAT 2 5\n  XDAT 6 1e-3\n  DIAM 6\n", 4, 10, "PARM 0", "Extrapolate is 0" },
		{ "SURF 4\n  TYPE TOROIDAL\n  CURV 0.01\n  XDAT 1 2.5\n  XDAT 2 5\n  DIAM 6\n",
		  4, 10, "XDAT 1", "2.5 terms" },
		{ "SURF 1\n  TYPE BICONICX\n  CURV 0.02\n  PARM 1 10\n  PARM 2 40\n  DIAM 5\n",
		  5, 10, "PARM 2", "kx: the biconic square root" },
		{ "SURF 1\n  TYPE TOROIDAL\n  CURV 0.02\n  PARM 1 4\n  DIAM 6\n",
		  4, 10, "PARM 1", "R_rotation: the circle of rotation" },
		{ "SURF 1\n  TYPE FZERNSAG\n  CURV 0.02\n  DIAM 5\n",
		  2, 8, "TYPE", "FZERNSAG, which is not imported" },
		/* the Q-type asphere's extra data */
		{ "SURF 1\n  TYPE QED_TYPE\n  CURV 0.02\n  XDAT 1 2\n  XDAT 3 5\n  DIAM 4\n",
		  4, 10, "XDAT 1", "Q type 2 (0 is Qbfs, 1 is Qcon)" },
		{ "SURF 1\n  TYPE QED_TYPE\n  CURV 0.02\n  XDAT 2 2.5\n  XDAT 3 5\n  DIAM 4\n",
		  4, 10, "XDAT 2", "2.5 Q terms" },
		{ "SURF 1\n  TYPE QED_TYPE\n  CURV 0.02\n  XDAT 2 33\n  XDAT 3 5\n"
		  "  XDAT 35 1e-6\n  DIAM 4\n", 6, 11, "XDAT", "term a31 is 1e-06" },
		{ "SURF 1\n  TYPE QED_TYPE\n  CURV 0.02\n  XDAT 2 1\n  XDAT 4 1e-3\n  DIAM 4\n",
		  2, 8, "XDAT 3", "norm_radius" },
		{ "SURF 1\n  TYPE QED_TYPE\n  CURV 0.02\n  PARM 2 1e-5\n  XDAT 3 5\n  DIAM 4\n",
		  4, 10, "PARM 2", "the Q-Type Asphere surface has no parameter 2" },
		{ "SURF 1\n  TYPE EVENASPH\n  CURV 0.02\n  XDAT 1 3\n  DIAM 4\n",
		  4, 10, "XDAT 1", "the Even Asphere surface has no extra data" },
		{ "SURF 1\n  CURV 0.02\n  PARM 2 1e-5\n  DIAM 4\n",
		  3, 10, "PARM 2", "the Standard surface has no parameter 2" },
		/* a segment whose parent's conic ends inside the aperture */
		{ "SURF 1\n  TYPE EVENASPH\n  CURV 0.02\n  CONI 0.5\n  SQAP 3 2\n  OBDC 0 40\n"
		  "  DIAM 4\n", 4, 8, "CONI", "reaches zero" },
		{ "SURF 1\n  TYPE XPOLYNOM\n  CURV 0.02\n  XDAT 2 5\n  UDAD 0 0\n  DIAM 4\n",
		  5, 1, "UDAD", "user-defined aperture" },
		{ "SURF 1\n  TYPE XPOLYNOM\n  CURV 0.02\n  XDAT 2 5\n  CLAP 1.5 4\n  DIAM 4\n",
		  5, 8, "CLAP", "hole" },
		{ "SURF 1\n  TYPE XPOLYNOM\n  CURV 0.02\n  XDAT 2 5\n  SQAP 3 2\n  ELAP 3 2\n"
		  "  DIAM 4\n", 6, 1, "ELAP", "2 aperture lines" },
		{ "SURF 1\n  TYPE XPOLYNOM\n  CURV 0.02\n  XDAT 2 5\n  ELAP 3 0\n  DIAM 4\n",
		  5, 10, "ELAP", "half widths must be positive" },
	};
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_prescription p;
		struct asph_error err;

		convert(cases[i].text, &p, &err, -EINVAL);
		expect_refusal(&err, &cases[i], "ff.zmx");
	}
	/* an extra-data number out of range refuses the file as it is read */
	struct asph_lens_import *im = NULL;
	struct asph_error err;
	const char *bad = "SURF 1\n  TYPE XPOLYNOM\n  XDAT 251 1\n";
	asph_error_clear(&err);
	assert_int_equal(asph_lens_import_parse(bad, strlen(bad), "ff.zmx", &im, &err), -EINVAL);
	assert_true(err.line == 3 && !strcmp(err.field, "XDAT"));
	assert_non_null(strstr(err.message, "extra data number 251 is not 1..250"));
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
		cmocka_unit_test(test_zmx_freeform),
		cmocka_unit_test(test_zmx_freeform_edges),
		cmocka_unit_test(test_zmx_freeform_refusals),
		cmocka_unit_test(test_zmx_qtype_latin1),
		cmocka_unit_test(test_zmx_segments_inches),
		cmocka_unit_test(test_csv),
		cmocka_unit_test(test_load),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
