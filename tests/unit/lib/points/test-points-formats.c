/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The readers of measured data, on files this test writes from the formats'
 * public documents: delimited text as profilometers and spreadsheets export
 * it, X3P (ISO 25178-72 and the openGPS ISO 5436-2 schema), SDF (ISO
 * 25178-71), Zygo MetroPro .dat (the MetroPro Reference Guide's layout) and
 * .datx (HDF5, as Zygo lays it out). Each carries the quirks real writers
 * have; every value read is compared with the one written.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>
#include <hdf5.h>
#include <nettle/md5.h>
#include <zip.h>

#include "asph/areal.h"
#include "asph/points.h"
#include "asph/x3p.h"
#include "rmtree.h"

static char dir[] = "/tmp/asph-test-points-formats-XXXXXX";

static int setup(void **state)
{
	return mkdtemp(dir) ? 0 : -1;
}

static int teardown(void **state)
{
	return rmtree(dir);
}

static const char *path_of(const char *name)
{
	static char path[512];

	snprintf(path, sizeof(path), "%s/%s", dir, name);
	return path;
}

static void write_file(const char *name, const void *data, size_t len)
{
	FILE *f = fopen(path_of(name), "wb");

	assert_non_null(f);
	assert_int_equal(fwrite(data, 1, len, f), len);
	assert_int_equal(fclose(f), 0);
}

/* Reads name (found from the content unless o says otherwise); fails the
 * test with the message when it is refused. */
static struct asph_points *read_ok(const char *name, const struct asph_points_read_options *o,
				   struct asph_points_read_info *info)
{
	struct asph_points *p = NULL;
	struct asph_error err;
	char buf[1024];

	asph_error_clear(&err);
	if (asph_points_read_as(path_of(name), o, &p, info, &err) < 0) {
		print_error("%s: %s\n", name, asph_error_format(&err, buf, sizeof(buf)));
		fail();
	}
	return p;
}

/* Reads name and expects a refusal whose message holds needle; returns
 * the error for more checks. */
static struct asph_error read_bad(const char *name, const char *needle)
{
	struct asph_points *p = NULL;
	struct asph_error err;
	char buf[1024];

	asph_error_clear(&err);
	if (asph_points_read_as(path_of(name), NULL, &p, NULL, &err) >= 0 || p ||
	    !strstr(err.message, needle)) {
		print_error("%s: expected '%s', got '%s'\n", name, needle,
			    asph_error_format(&err, buf, sizeof(buf)));
		fail();
	}
	return err;
}

static void expect_point(const struct asph_points *p, size_t i, double x, double y, double z)
{
	if (p->xyz[3 * i] != x || p->xyz[3 * i + 1] != y || p->xyz[3 * i + 2] != z) {
		print_error("point %zu: (%.17g, %.17g, %.17g), expected (%.17g, %.17g, %.17g)\n", i,
			    p->xyz[3 * i], p->xyz[3 * i + 1], p->xyz[3 * i + 2], x, y, z);
		fail();
	}
}

/* ---- delimited text ---- */

static void test_text_variants(void **state)
{
	struct asph_points_read_info info;
	struct asph_points *p;

	/* a European spreadsheet: semicolons, decimal commas, units */
	static const char semi[] = "X [mm];Y [mm];Z [\xc2\xb5m]\r\n1,5;-2,25;125,5\r\n3;4;-0,5\r\n";
	write_file("semi.csv", semi, strlen(semi));
	p = read_ok("semi.csv", NULL, &info);
	assert_int_equal(info.format, ASPH_POINTS_TEXT);
	assert_int_equal(p->n, 2);
	expect_point(p, 0, 1.5, -2.25, 125.5 * 1e-3);
	expect_point(p, 1, 3, 4, -0.5 * 1e-3);
	assert_string_equal(info.units[2], "\xc2\xb5m");
	asph_points_free(p);

	/* a profilometer's tab-separated export with a preamble */
	static const char tab[] = "Instrument:\tForm Talysurf PGI\nDate:\t2024-03-01\n\n"
				  "x(mm)\ty(mm)\tz(nm)\n0.25\t0\t12.5\n0.5\t0\t-3\n";
	write_file("tab.txt", tab, strlen(tab));
	p = read_ok("tab.txt", NULL, &info);
	assert_int_equal(p->n, 2);
	assert_int_equal(info.n_preamble, 2);
	assert_true(info.has_header);
	expect_point(p, 0, 0.25, 0, 12.5 * 1e-6);
	expect_point(p, 1, 0.5, 0, -3 * 1e-6);
	asph_points_free(p);

	/* "Z/nm" and a slash for each, blanks between, any case and order */
	static const char slash[] = "z/nm  X/um  Y/um\n100 2000 -1000\n";
	write_file("slash.txt", slash, strlen(slash));
	p = read_ok("slash.txt", NULL, &info);
	expect_point(p, 0, 2000 * 1e-3, -1000 * 1e-3, 100 * 1e-6);
	asph_points_free(p);

	/* blank separated, the units apart from the names */
	static const char spaced[] = "X [mm]   Y [mm]   Z [um]\n 1.25  -2  3.5\n";
	write_file("spaced.txt", spaced, strlen(spaced));
	p = read_ok("spaced.txt", NULL, &info);
	expect_point(p, 0, 1.25, -2, 3.5 * 1e-3);
	assert_null(p->value);
	asph_points_free(p);

	/* an asphere machine's whitespace columns without a header, in um */
	static const char plain[] = "# exported by the machine\n  1.5   -2  0.125\n  3e1 4 5\n";
	write_file("plain.xyz", plain, strlen(plain));
	struct asph_points_read_options um = { .unit_mm = 1e-3 };
	assert_int_equal(asph_points_unit_parse("um", &um.unit_mm), 0);
	p = read_ok("plain.xyz", &um, &info);
	assert_false(info.has_header);
	assert_int_equal(p->n, 2);
	expect_point(p, 0, 1.5 * 1e-3, -2 * 1e-3, 0.125 * 1e-3);
	expect_point(p, 1, 3e1 * 1e-3, 4 * 1e-3, 5 * 1e-3);
	asph_points_free(p);

	/* no header, semicolons and decimal commas, a trailing separator */
	static const char semi_short[] = "1,25;2;\n";
	write_file("semi-short.csv", semi_short, strlen(semi_short));
	struct asph_error err = read_bad("semi-short.csv", "three columns");
	assert_int_equal(err.line, 1);
	static const char semi_plain2[] = "1,25;2;3,5;\n-4;0,5;6;\n";
	write_file("semi-plain2.csv", semi_plain2, strlen(semi_plain2));
	p = read_ok("semi-plain2.csv", NULL, NULL);
	expect_point(p, 0, 1.25, 2, 3.5);
	expect_point(p, 1, -4, 0.5, 6);
	asph_points_free(p);

	/* a header's units beat --units; columns it gives none take it */
	static const char mixed[] = "x,y,z [nm]\n1,2,3\n";
	write_file("mixed.csv", mixed, strlen(mixed));
	p = read_ok("mixed.csv", &um, NULL);
	expect_point(p, 0, 1 * 1e-3, 2 * 1e-3, 3 * 1e-6);
	asph_points_free(p);
}

/* ---- X3P ---- */

static void md5_hex(const void *data, size_t len, char hex[33])
{
	struct md5_ctx c;
	uint8_t d[MD5_DIGEST_SIZE];

	md5_init(&c);
	md5_update(&c, len, data);
	md5_digest(&c, sizeof(d), d);
	for (int i = 0; i < MD5_DIGEST_SIZE; i++)
		snprintf(hex + 2 * i, 3, "%02x", d[i]);
}

struct x3p_axis_spec {
	const char *type, *data;   /* "I"/"A", NULL or "I", "L", "F", "D" */
	const char *increment, *offset;
};

struct x3p_spec {
	const char *feature;
	struct x3p_axis_spec ax[3];
	size_t nx, ny, list;       /* list > 0: ListDimension */
	const void *data;          /* bindata/data.bin, or NULL: inline */
	size_t len;
	const char *datum_list;    /* the <Datum> elements when inline */
	const uint8_t *valid;      /* bindata/valid.bin or NULL */
	size_t valid_len;
	const char *bad_data_md5;  /* a wrong MD5ChecksumPointData */
	int no_checksum_file;
	const char *folder;        /* the members in this folder ("part/") */
	const char *root;          /* the root element; NULL: p:ISO5436_2 */
};

static void axis_xml(char *out, size_t size, const char *name, const struct x3p_axis_spec *a)
{
	char data[64] = "", inc[96] = "", off[96] = "";

	if (a->data)
		snprintf(data, sizeof(data), "<DataType>%s</DataType>", a->data);
	if (a->increment)
		snprintf(inc, sizeof(inc), "<Increment>%s</Increment>", a->increment);
	if (a->offset)
		snprintf(off, sizeof(off), "<Offset>%s</Offset>", a->offset);
	snprintf(out, size, "<%s><AxisType>%s</AxisType>%s%s%s</%s>", name, a->type, data, inc,
		 off, name);
}

/* An X3P container as ISO 25178-72 lays it out, main.xml written by hand
 * from the schema (the elements unqualified below the namespaced root). */
static void write_x3p(const char *name, const struct x3p_spec *s)
{
	char ax[3][256], dims[256], link[512], data_md5[33], valid_md5[33], xml_md5[33];
	static char xml[1 << 16];
	static char hexfile[128];

	for (int k = 0; k < 3; k++)
		axis_xml(ax[k], sizeof(ax[k]), k == 0 ? "CX" : k == 1 ? "CY" : "CZ", &s->ax[k]);
	if (s->list)
		snprintf(dims, sizeof(dims), "<ListDimension>%zu</ListDimension>", s->list);
	else
		snprintf(dims, sizeof(dims),
			 "<MatrixDimension><SizeX>%zu</SizeX><SizeY>%zu</SizeY><SizeZ>1</SizeZ></MatrixDimension>",
			 s->nx, s->ny);
	if (s->data) {
		md5_hex(s->data, s->len, data_md5);
		char valid[256] = "";
		if (s->valid) {
			md5_hex(s->valid, s->valid_len, valid_md5);
			snprintf(valid, sizeof(valid),
				 "<ValidPointsLink>bindata/valid.bin</ValidPointsLink>"
				 "<MD5ChecksumValidPoints>%s</MD5ChecksumValidPoints>", valid_md5);
		}
		snprintf(link, sizeof(link),
			 "<DataLink><PointDataLink>bindata/data.bin</PointDataLink>"
			 "<MD5ChecksumPointData>%s</MD5ChecksumPointData>%s</DataLink>",
			 s->bad_data_md5 ? s->bad_data_md5 : data_md5, valid);
	}
	snprintf(xml, sizeof(xml),
		 "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
		 "<%s>\n"
		 "<Record1><Revision>ISO5436 - 2000</Revision><FeatureType>%s</FeatureType>"
		 "<Axes>%s%s%s</Axes></Record1>\n"
		 "<Record2><Date>2024-03-01T10:00:00+01:00</Date><Instrument><Manufacturer>Lab</Manufacturer>"
		 "<Model>Test</Model><Serial>1</Serial><Version>1</Version></Instrument>"
		 "<CalibrationDate>2024-01-01T10:00:00+01:00</CalibrationDate>"
		 "<ProbingSystem><Type>NonContacting</Type><Identification>-</Identification></ProbingSystem>"
		 "</Record2>\n"
		 "<Record3>%s%s%s%s%s</Record3>\n"
		 "<Record4><ChecksumFile>md5checksum.hex</ChecksumFile></Record4>\n"
		 "</%s>\n",
		 s->root ? s->root : "p:ISO5436_2 xmlns:p=\"http://www.opengps.eu/2008/ISO5436_2\"",
		 s->feature, ax[0], ax[1], ax[2], dims, s->data ? link : "",
		 s->data ? "" : "<DataList>", s->data ? "" : s->datum_list, s->data ? "" : "</DataList>",
		 s->root ? s->root : "p:ISO5436_2");
	md5_hex(xml, strlen(xml), xml_md5);
	snprintf(hexfile, sizeof(hexfile), "%s *main.xml\n", xml_md5);

	int zerr = 0;
	char member[4][64];
	const char *f = s->folder ? s->folder : "";
	zip_t *z = zip_open(path_of(name), ZIP_CREATE | ZIP_TRUNCATE, &zerr);
	assert_non_null(z);
	snprintf(member[0], sizeof(member[0]), "%smain.xml", f);
	snprintf(member[1], sizeof(member[1]), "%sbindata/data.bin", f);
	snprintf(member[2], sizeof(member[2]), "%sbindata/valid.bin", f);
	snprintf(member[3], sizeof(member[3]), "%smd5checksum.hex", f);
	assert_true(zip_file_add(z, member[0], zip_source_buffer(z, xml, strlen(xml), 0), 0) >= 0);
	if (s->data)
		assert_true(zip_file_add(z, member[1], zip_source_buffer(z, s->data, s->len, 0), 0) >= 0);
	if (s->valid)
		assert_true(zip_file_add(z, member[2],
					 zip_source_buffer(z, s->valid, s->valid_len, 0), 0) >= 0);
	if (!s->no_checksum_file)
		assert_true(zip_file_add(z, member[3],
					 zip_source_buffer(z, hexfile, strlen(hexfile), 0), 0) >= 0);
	assert_int_equal(zip_close(z), 0);
}

static void put_le(uint8_t *p, uint64_t v, int n)
{
	for (int i = 0; i < n; i++)
		p[i] = (uint8_t)(v >> (8 * i));
}

static void put_le_float(uint8_t *p, float f)
{
	uint32_t u;

	memcpy(&u, &f, 4);
	put_le(p, u, 4);
}

static void put_le_double(uint8_t *p, double d)
{
	uint64_t u;

	memcpy(&u, &d, 8);
	put_le(p, u, 8);
}

/* A matrix of float32 heights with a scale (Increment) and offset,
 * incremental axes with their offsets, and invalid points both ways: a
 * valid-points file and NaN. */
static void test_x3p_matrix_float_scaled(void **state)
{
	enum { NX = 5, NY = 4 };
	uint8_t data[NX * NY * 4], valid[(NX * NY + 7) / 8];
	float raw[NX * NY];

	memset(valid, 0xff, sizeof(valid));
	for (int k = 0; k < NX * NY; k++) {
		raw[k] = (float)(k * 37 % 11) - 4.75f;
		put_le_float(data + 4 * k, raw[k]);
	}
	valid[7 / 8] &= (uint8_t)~(1u << 7);          /* node 7 invalid by the mask */
	put_le_float(data + 4 * 12, NAN);           /* node 12 invalid by NaN */
	struct x3p_spec s = {
		.feature = "SUR",
		.ax = { { "I", NULL, "2.5e-6", "-1.0e-3" }, { "I", NULL, "3e-6", "2e-4" },
			{ "A", "F", "1e-9", "5e-7" } },
		.nx = NX, .ny = NY, .data = data, .len = sizeof(data),
		.valid = valid, .valid_len = sizeof(valid),
	};
	write_x3p("float.x3p", &s);
	struct asph_points_read_info info;
	struct asph_points *p = read_ok("float.x3p", NULL, &info);
	assert_int_equal(info.format, ASPH_POINTS_X3P);
	assert_int_equal(info.nx, NX);
	assert_int_equal(info.ny, NY);
	assert_int_equal(info.n_invalid, 2);
	assert_int_equal(p->n, NX * NY - 2);
	size_t n = 0;
	for (int k = 0; k < NX * NY; k++) {
		if (k == 7 || k == 12)
			continue;
		/* metres from the schema's Xreal = Xoffset + Xinteger x XIncrement */
		double x = ((k % NX) * 2.5e-6 + -1.0e-3) * 1000;
		double y = ((k / NX) * 3e-6 + 2e-4) * 1000;
		double z = ((double)raw[k] * 1e-9 + 5e-7) * 1000;
		expect_point(p, n++, x, y, z);
	}
	asph_points_free(p);
}

/* Integer heights (int16, int32) with their scales, and a matrix of
 * doubles with NaN for invalid points and no md5checksum.hex. */
static void test_x3p_matrix_integer_types(void **state)
{
	enum { N = 6 };
	uint8_t i16[2 * N], i32[4 * N], f64[8 * N];
	int32_t v[N] = { -32768, -5, 0, 7, 1200, 32767 };

	for (int k = 0; k < N; k++) {
		put_le(i16 + 2 * k, (uint16_t)(int16_t)v[k], 2);
		put_le(i32 + 4 * k, (uint32_t)(v[k] * 1000), 4);
		put_le_double(f64 + 8 * k, k == 2 ? NAN : v[k] * 1e-9);
	}
	struct x3p_spec s = {
		.feature = "SUR",
		.ax = { { "I", NULL, "1e-5", NULL }, { "I", NULL, "1e-5", NULL }, { "A", "I", "2e-10", NULL } },
		.nx = 3, .ny = 2, .data = i16, .len = sizeof(i16),
	};
	write_x3p("i16.x3p", &s);
	s.ax[2] = (struct x3p_axis_spec){ "A", "L", "2e-13", "-1e-6" };
	s.data = i32;
	s.len = sizeof(i32);
	write_x3p("i32.x3p", &s);
	s.ax[2] = (struct x3p_axis_spec){ "A", "D", NULL, NULL };
	s.data = f64;
	s.len = sizeof(f64);
	s.no_checksum_file = 1;
	write_x3p("f64.x3p", &s);

	struct asph_points_read_info info;
	struct asph_points *a = read_ok("i16.x3p", NULL, NULL), *b = read_ok("i32.x3p", NULL, NULL);
	struct asph_points *c = read_ok("f64.x3p", NULL, &info);
	assert_int_equal(a->n, N);
	assert_int_equal(c->n, N - 1);
	assert_int_equal(info.n_invalid, 1);
	for (int k = 0; k < N; k++) {
		double x = (k % 3) * 1e-5 * 1000, y = (k / 3) * 1e-5 * 1000;
		expect_point(a, (size_t)k, x, y, v[k] * 2e-10 * 1000);
		expect_point(b, (size_t)k, x, y, ((double)(v[k] * 1000) * 2e-13 + -1e-6) * 1000);
		if (k != 2)
			expect_point(c, (size_t)(k < 2 ? k : k - 1), x, y, v[k] * 1e-9 * 1000);
	}
	asph_points_free(a);
	asph_points_free(b);
	asph_points_free(c);

	/* as other writers make them: the members in a folder of the ZIP,
	 * the root without its namespace, an empty Offset for "none" */
	s.folder = "part/";
	s.root = "ISO5436";
	s.ax[2] = (struct x3p_axis_spec){ "A", "D", "1", "" };
	write_x3p("folder.x3p", &s);
	c = read_ok("folder.x3p", NULL, &info);
	assert_int_equal(c->n, N - 1);
	expect_point(c, 4, 2e-5 * 1000, 1e-5 * 1000, v[5] * 1e-9 * 1000);
	asph_points_free(c);
}

/* The list layout inline in main.xml (DataList), X and Y absolute floats,
 * an empty Datum for an invalid point; and a profile (PRF) of Z alone. */
static void test_x3p_inline(void **state)
{
	struct x3p_spec s = {
		.feature = "PCL",
		.ax = { { "A", "D", NULL, "1e-3" }, { "A", "D", NULL, NULL }, { "A", "D", NULL, NULL } },
		.list = 3,
		.datum_list = "<Datum>1e-4;2e-4;3e-6</Datum><Datum/><Datum> -5e-4 ; 0 ; -1.5e-6 </Datum>",
	};
	write_x3p("inline.x3p", &s);
	struct asph_points_read_info info;
	struct asph_points *p = read_ok("inline.x3p", NULL, &info);
	assert_int_equal(p->n, 2);
	assert_int_equal(info.n_invalid, 1);
	expect_point(p, 0, (1e-4 + 1e-3) * 1000, 2e-4 * 1000, 3e-6 * 1000);
	expect_point(p, 1, (-5e-4 + 1e-3) * 1000, 0, -1.5e-6 * 1000);
	asph_points_free(p);

	struct x3p_spec prf = {
		.feature = "PRF",
		.ax = { { "I", NULL, "1e-6", NULL }, { "I", NULL, "1e-6", NULL }, { "A", "D", NULL, NULL } },
		.nx = 4, .ny = 1, .datum_list = "<Datum>1e-7</Datum><Datum>2e-7</Datum><Datum>3e-7</Datum>"
						"<Datum>4e-7</Datum>",
	};
	write_x3p("prf.x3p", &prf);
	p = read_ok("prf.x3p", NULL, NULL);
	assert_int_equal(p->n, 4);
	expect_point(p, 3, 3e-6 * 1000, 0, 4e-7 * 1000);
	asph_points_free(p);
}

static void test_x3p_errors(void **state)
{
	uint8_t data[8 * 4];
	for (int k = 0; k < 4; k++)
		put_le_double(data + 8 * k, k * 1e-6);
	struct x3p_spec s = {
		.feature = "SUR",
		.ax = { { "I", NULL, "1e-6", NULL }, { "I", NULL, "1e-6", NULL }, { "A", "D", NULL, NULL } },
		.nx = 2, .ny = 2, .data = data, .len = sizeof(data),
		.bad_data_md5 = "0123456789abcdef0123456789abcdef",
	};
	write_x3p("md5.x3p", &s);
	struct asph_error err = read_bad("md5.x3p", "does not match its MD5 sum");
	assert_string_equal(err.field, "Record3/DataLink/MD5ChecksumPointData");
	s.bad_data_md5 = NULL;
	s.len = 3 * 8;
	write_x3p("short.x3p", &s);
	read_bad("short.x3p", "holds 24 bytes; 4 points of 8 bytes take 32");
	s.len = sizeof(data);
	s.ax[2].data = "Q";
	write_x3p("type.x3p", &s);
	err = read_bad("type.x3p", "expected I, L, F or D");
	assert_string_equal(err.field, "Record1/Axes/CZ/DataType");
	s.ax[2] = (struct x3p_axis_spec){ "I", NULL, "1", NULL };
	write_x3p("zinc.x3p", &s);
	read_bad("zinc.x3p", "must be absolute");
}

/* asph's own exports read back: the list layout gives the points written
 * to within the one rounding of mm to m (and, written again, the same
 * file bits); the matrix layout the grid's nodes and heights as stored. */
static void test_x3p_own_exports(void **state)
{
	enum { N = 4000 };
	struct asph_points *p0 = asph_points_alloc(N);
	size_t differ = 0;

	for (size_t i = 0; i < N; i++) {
		p0->xyz[3 * i] = sin(1.37 * (double)i + 0.1) * 19.7;
		p0->xyz[3 * i + 1] = cos(2.91 * (double)i) * 23.3;
		p0->xyz[3 * i + 2] = exp(-(double)i / 700.0) / 3.0 - 0.171;
	}
	struct asph_error err;
	assert_int_equal(asph_x3p_write_points(path_of("own1.x3p"), p0->xyz, N, NULL, &err), 0);
	struct asph_points *p1 = read_ok("own1.x3p", NULL, NULL);
	assert_int_equal(p1->n, N);
	for (size_t i = 0; i < 3 * N; i++) {
		double a = p0->xyz[i], b = p1->xyz[i];
		differ += a != b;
		assert_true(a == b || nextafter(a, b) == b);
	}
	assert_int_equal(asph_x3p_write_points(path_of("own2.x3p"), p1->xyz, N, NULL, &err), 0);
	struct asph_points *p2 = read_ok("own2.x3p", NULL, NULL);
	assert_memory_equal(p1->xyz, p2->xyz, 3 * N * sizeof(double));
	/* most values come back as they were; about one in a hundred is one
	 * ulp off (a division by 1000 maps some pairs of mm onto one metre) */
	print_message("x3p list: %zu of %d coordinates one ulp off after mm -> m -> mm\n", differ,
		      3 * N);
	assert_true(differ < 3 * N / 20);
	asph_points_free(p0);
	asph_points_free(p1);
	asph_points_free(p2);

	enum { GX = 7, GY = 5 };
	double z[GX * GY];
	for (int k = 0; k < GX * GY; k++)
		z[k] = k % 9 == 4 ? NAN : 31.7 * sin(0.9 * k) - 2.5;
	struct asph_grid g = { .nx = GX, .ny = GY, .dx = 0.0625, .x0 = -0.1875, .y0 = -0.125, .z = z };
	assert_int_equal(asph_x3p_write_grid(path_of("grid.x3p"), &g, NULL, &err), 0);
	struct asph_points_read_info info;
	struct asph_points *m = read_ok("grid.x3p", NULL, &info);
	assert_int_equal(info.nx, GX);
	assert_int_equal(info.ny, GY);
	size_t n = 0, invalid = 0;
	for (int k = 0; k < GX * GY; k++) {
		if (isnan(z[k])) {
			invalid++;
			continue;
		}
		/* the file's metres: Offset + i Increment, and the height */
		double x = ((k % GX) * (g.dx * 1e-3) + g.x0 * 1e-3) * 1000;
		double y = ((k / GX) * (g.dx * 1e-3) + g.y0 * 1e-3) * 1000;
		expect_point(m, n++, x, y, z[k] * 1e-9 * 1000);
	}
	assert_int_equal(info.n_invalid, invalid);
	assert_int_equal(m->n, n);
	asph_points_free(m);
}

/* ---- SDF ---- */

static void test_sdf(void **state)
{
	static const char ascii[] =
		"aBCR-1.0\nManufacID   = Lab\nCreateDate  = 010320241000\nModDate     = 010320241000\n"
		"NumPoints   = 3\nNumProfiles = 2\nXscale      = 2.0E-06\nYscale      = 4.0E-06\n"
		"Zscale      = 1.0E-09\nZresolution = -1\nCompression = 0\nDataType    = 5\n"
		"CheckType   = 0\n; a comment\n*\n10 -20 30\n40 50\n-60\n*\nOPERATOR = me\n*\n";
	write_file("a.sdf", ascii, strlen(ascii));
	struct asph_points_read_info info;
	struct asph_points *p = read_ok("a.sdf", NULL, &info);
	assert_int_equal(info.format, ASPH_POINTS_SDF);
	assert_int_equal(p->n, 6);
	double dx = 2.0e-6 * 1000, dy = 4.0e-6 * 1000;
	/* centred: the middle node at 0, the first profile lowest */
	expect_point(p, 0, -1 * dx, -0.5 * dy, 10 * 1e-9 * 1000);
	expect_point(p, 5, 1 * dx, 0.5 * dy, -60 * 1e-9 * 1000);
	asph_points_free(p);

	uint8_t bin[81 + 4 * 4];
	memset(bin, 0, sizeof(bin));
	memcpy(bin, "bBCR-1.0", 8);
	memcpy(bin + 8, "Lab", 3);
	put_le(bin + 42, 2, 2);
	put_le(bin + 44, 2, 2);
	put_le_double(bin + 46, 1e-5);
	put_le_double(bin + 54, 1e-5);
	put_le_double(bin + 62, 1e-6);
	put_le_double(bin + 70, -1);
	bin[79] = 3; /* float */
	float v[4] = { 0.5f, NAN, -1.25f, 2 };
	for (int k = 0; k < 4; k++)
		put_le_float(bin + 81 + 4 * k, v[k]);
	write_file("b.sdf", bin, sizeof(bin));
	p = read_ok("b.sdf", NULL, &info);
	assert_int_equal(p->n, 3);
	assert_int_equal(info.n_invalid, 1);
	expect_point(p, 2, 0.5 * 1e-5 * 1000, 0.5 * 1e-5 * 1000, 2 * 1e-6 * 1000);
	asph_points_free(p);

	write_file("short.sdf", bin, sizeof(bin) - 1);
	read_bad("short.sdf", "after the header at byte offset 81");
	bin[79] = 9;
	write_file("type.sdf", bin, sizeof(bin));
	struct asph_error err = read_bad("type.sdf", "data type 9");
	assert_string_equal(err.field, "DataType");
	static const char few[] = "aBCR-1.0\nNumPoints = 2\nNumProfiles = 2\nXscale = 1e-6\n"
				  "Yscale = 1e-6\nZscale = 1e-9\nDataType = 7\n*\n1 2 3\n*\n";
	write_file("few.sdf", few, strlen(few));
	read_bad("few.sdf", "3 values; NumPoints x NumProfiles give 4");
}

/* ---- Zygo MetroPro .dat ---- */

static void put_be(uint8_t *p, uint64_t v, int n)
{
	for (int i = 0; i < n; i++)
		p[i] = (uint8_t)(v >> (8 * (n - 1 - i)));
}

static void put_be_float(uint8_t *p, float f)
{
	uint32_t u;

	memcpy(&u, &f, 4);
	put_be(p, u, 4);
}

/* A MetroPro file: header format (1-3) and its size, intensity frames,
 * the phase map. */
static size_t metropro(uint8_t *buf, int format, int w, int h, const int32_t *phase, int sign,
		       int phase_res)
{
	static const uint32_t magic[] = { 0, 0x881B036F, 0x881B0370, 0x881B0371 };
	size_t header = format == 3 ? 4096 : 834, ac = (size_t)w * h * 2;

	memset(buf, 0, header);
	put_be(buf, magic[format], 4);
	put_be(buf + 4, (uint64_t)format, 2);
	put_be(buf + 6, header, 4);
	put_be(buf + 52, (uint64_t)w, 2);        /* intensity: one bucket */
	put_be(buf + 54, (uint64_t)h, 2);
	put_be(buf + 56, 1, 2);
	put_be(buf + 60, ac, 4);
	put_be(buf + 68, (uint64_t)w, 2);
	put_be(buf + 70, (uint64_t)h, 2);
	put_be(buf + 72, (uint64_t)w * h * 4, 4);
	put_be_float(buf + 164, 0.5f);           /* interferometric scale factor */
	put_be_float(buf + 168, 632.8e-9f);      /* wavelength */
	put_be_float(buf + 176, 1.0f);           /* obliquity */
	put_be_float(buf + 184, 1.25e-4f);       /* lateral resolution */
	put_be(buf + 218, (uint64_t)phase_res, 2);
	put_be(buf + 232, (uint64_t)sign, 2);
	for (size_t i = 0; i < (size_t)w * h; i++)
		put_be(buf + header + 2 * i, 1000 + i, 2);
	for (size_t i = 0; i < (size_t)w * h; i++)
		put_be(buf + header + ac + 4 * i, (uint32_t)phase[i], 4);
	return header + ac + (size_t)w * h * 4;
}

static void test_metropro(void **state)
{
	static uint8_t buf[4096 + 6 * 6];
	int32_t phase[6] = { 100, -2500, 2147483640, 0, 31000, 2147483647 };
	const double res[] = { 4096, 32768, 131072 };

	for (int format = 1; format <= 3; format++) {
		int pr = format - 1, sign = format == 2;
		size_t len = metropro(buf, format, 3, 2, phase, sign, pr);
		char name[32];
		snprintf(name, sizeof(name), "f%d.dat", format);
		write_file(name, buf, len);
		struct asph_points_read_info info;
		struct asph_points *p = read_ok(name, NULL, &info);
		assert_int_equal(info.format, ASPH_POINTS_METROPRO);
		assert_int_equal(info.n_invalid, 2);
		assert_int_equal(p->n, 4);
		/* heights: value x S x O x wavelength / R, in mm */
		double q = (double)0.5f * (double)1.0f * (double)632.8e-9f / res[pr] * 1000 *
			   (sign ? -1 : 1);
		double lat = (double)1.25e-4f * 1000;
		/* row 0 is the top: y = +lat/2 */
		expect_point(p, 0, -lat, 0.5 * lat, 100 * q);
		expect_point(p, 1, 0, 0.5 * lat, -2500 * q);
		expect_point(p, 2, -lat, -0.5 * lat, 0 * q);
		expect_point(p, 3, 0, -0.5 * lat, 31000 * q);
		asph_points_free(p);
	}
	size_t len = metropro(buf, 1, 3, 2, phase, 0, 0);
	put_be(buf + 4, 2, 2);
	write_file("fmt.dat", buf, len);
	struct asph_error err = read_bad("fmt.dat", "byte offset 4");
	assert_string_equal(err.field, "header_format");
	len = metropro(buf, 1, 3, 2, phase, 0, 7);
	write_file("res.dat", buf, len);
	read_bad("res.dat", "phase resolution");
	len = metropro(buf, 1, 3, 2, phase, 0, 0);
	write_file("cut.dat", buf, len - 1);
	read_bad("cut.dat", "the phase map takes bytes");
}

/* ---- Zygo .datx ---- */

struct datx_converter {
	const char *category, *unit;
	double p[4];
};

/* A converter attribute as Zygo writes it: a compound of strings and an
 * array of four doubles (variable-length strings, or fixed ones). */
static void converter_attr(hid_t set, const char *name, const struct datx_converter *c, int fixed)
{
	typedef struct { const char *category, *unit; double p[4]; } vconv;
	typedef struct { char category[16], unit[16]; double p[4]; } fconv;
	hsize_t four = 4, one = 1;
	hid_t str = H5Tcopy(H5T_C_S1), arr = H5Tarray_create2(H5T_NATIVE_DOUBLE, 1, &four), type;

	if (fixed) {
		fconv v = { .p = { c->p[0], c->p[1], c->p[2], c->p[3] } };
		snprintf(v.category, sizeof(v.category), "%s", c->category);
		snprintf(v.unit, sizeof(v.unit), "%s", c->unit);
		H5Tset_size(str, 16);
		type = H5Tcreate(H5T_COMPOUND, sizeof(fconv));
		H5Tinsert(type, "Category", offsetof(fconv, category), str);
		H5Tinsert(type, "BaseUnit", offsetof(fconv, unit), str);
		H5Tinsert(type, "Parameters", offsetof(fconv, p), arr);
		hid_t space = H5Screate_simple(1, &one, NULL);
		hid_t a = H5Acreate2(set, name, type, space, H5P_DEFAULT, H5P_DEFAULT);
		assert_true(H5Awrite(a, type, &v) >= 0);
		H5Aclose(a);
		H5Sclose(space);
	} else {
		vconv v = { c->category, c->unit, { c->p[0], c->p[1], c->p[2], c->p[3] } };
		H5Tset_size(str, H5T_VARIABLE);
		type = H5Tcreate(H5T_COMPOUND, sizeof(vconv));
		H5Tinsert(type, "Category", offsetof(vconv, category), str);
		H5Tinsert(type, "BaseUnit", offsetof(vconv, unit), str);
		H5Tinsert(type, "Parameters", offsetof(vconv, p), arr);
		hid_t space = H5Screate_simple(1, &one, NULL);
		hid_t a = H5Acreate2(set, name, type, space, H5P_DEFAULT, H5P_DEFAULT);
		assert_true(H5Awrite(a, type, &v) >= 0);
		H5Aclose(a);
		H5Sclose(space);
	}
	H5Tclose(type);
	H5Tclose(arr);
	H5Tclose(str);
}

static void write_datx(const char *name, const double *z, int w, int h, double no_data,
		       const struct datx_converter *zc, int fixed)
{
	hid_t f = H5Fcreate(path_of(name), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
	assert_true(f >= 0);
	hid_t g1 = H5Gcreate2(f, "/Data", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
	hid_t g2 = H5Gcreate2(f, "/Data/Surface", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
	hsize_t dims[2] = { (hsize_t)h, (hsize_t)w }, one = 1;
	hid_t space = H5Screate_simple(2, dims, NULL);
	hid_t set = H5Dcreate2(g2, "{5D3A8E11-0C2B-4B8F-9E7A-1F2D3C4B5A69}", H5T_IEEE_F64LE, space,
			       H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
	assert_true(H5Dwrite(set, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, z) >= 0);
	hid_t s1 = H5Screate_simple(1, &one, NULL);
	hid_t a = H5Acreate2(set, "No Data", H5T_IEEE_F64LE, s1, H5P_DEFAULT, H5P_DEFAULT);
	H5Awrite(a, H5T_NATIVE_DOUBLE, &no_data);
	H5Aclose(a);
	H5Sclose(s1);
	struct datx_converter lateral = { "LateralCat", "Meters", { 0, 6.5e-6, 0, 0 } };
	converter_attr(set, "X Converter", &lateral, fixed);
	lateral.p[1] = 7.25e-6;
	converter_attr(set, "Y Converter", &lateral, fixed);
	converter_attr(set, "Z Converter", zc, fixed);
	H5Dclose(set);
	H5Sclose(space);
	H5Gclose(g2);
	H5Gclose(g1);
	H5Fclose(f);
}

static void test_datx(void **state)
{
	const double big = 1.7976931348623157e308;
	double z[6] = { 12.5, big, -3.25, 0, 48, NAN };
	struct datx_converter nm = { "HeightCat", "NanoMeters", { 0, 0, 0, 0 } };
	struct datx_converter fringes = { "HeightCat", "Fringes", { 0, 632.8e-9, 0.5, 1.0 } };

	for (int fixed = 0; fixed < 2; fixed++) {
		char name[32];
		snprintf(name, sizeof(name), "nm%d.datx", fixed);
		write_datx(name, z, 3, 2, big, &nm, fixed);
		struct asph_points_read_info info;
		struct asph_points *p = read_ok(name, NULL, &info);
		assert_int_equal(info.format, ASPH_POINTS_DATX);
		assert_int_equal(info.n_invalid, 2);
		assert_int_equal(p->n, 4);
		double dx = 6.5e-6 * 1000, dy = 7.25e-6 * 1000;
		expect_point(p, 0, -dx, 0.5 * dy, 12.5 * 1e-6);
		expect_point(p, 1, dx, 0.5 * dy, -3.25 * 1e-6);
		expect_point(p, 3, 0, -0.5 * dy, 48 * 1e-6);
		asph_points_free(p);
	}
	write_datx("fringes.datx", z, 3, 2, big, &fringes, 0);
	struct asph_points *p = read_ok("fringes.datx", NULL, NULL);
	expect_point(p, 1, 6.5e-6 * 1000, 0.5 * 7.25e-6 * 1000, -3.25 * (632.8e-9 * 0.5 * 1.0 * 1000));
	asph_points_free(p);
	/* a map whose values lie in another file is not followed there */
	hid_t f = H5Fcreate(path_of("external.datx"), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
	hid_t g = H5Gcreate2(f, "/Data", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
	hid_t g2 = H5Gcreate2(f, "/Data/Surface", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
	hsize_t dims[2] = { 2, 3 };
	hid_t space = H5Screate_simple(2, dims, NULL), dcpl = H5Pcreate(H5P_DATASET_CREATE);
	assert_true(H5Pset_external(dcpl, path_of("raw.bin"), 0, 48) >= 0);
	hid_t set = H5Dcreate2(g2, "map", H5T_IEEE_F64LE, space, H5P_DEFAULT, dcpl, H5P_DEFAULT);
	assert_true(set >= 0);
	H5Dclose(set);
	H5Pclose(dcpl);
	H5Sclose(space);
	H5Gclose(g2);
	H5Gclose(g);
	H5Fclose(f);
	read_bad("external.datx", "keeps its values outside the file");

	struct datx_converter volts = { "HeightCat", "Volts", { 0, 0, 0, 0 } };
	write_datx("volts.datx", z, 3, 2, big, &volts, 1);
	struct asph_error err = read_bad("volts.datx", "not a length");
	assert_string_equal(err.field, "Z Converter");

	/* A file on which libhdf5 copies a negative size (H5HG_read, found
	 * by fuzzing): its decoding process ends, the reader names the file
	 * and what happened, and the next file reads. */
	char crash[1024];
	struct asph_points *none = NULL;
	snprintf(crash, sizeof(crash), "%s/../fuzz/corpus/points-datx/%s", getenv("ASPH_TEST_DATA"),
		 "regress-h5hg-read-negative-size.datx");
	asph_error_clear(&err);
	assert_true(asph_points_read_as(crash, NULL, &none, NULL, &err) < 0);
	assert_null(none);
	assert_string_equal(err.source, crash);
	if (!strstr(err.message, "datx: libhdf5 crashed on the file (signal SIG")) {
		print_error("%s\n", err.message);
		fail();
	}
	asph_points_free(read_ok("fringes.datx", NULL, NULL));
}

/* The format names one table defines, and detection of each magic. */
static void test_formats(void **state)
{
	enum asph_points_format f;

	assert_int_equal(asph_points_format_parse("csv", &f), 0);
	assert_int_equal(f, ASPH_POINTS_TEXT);
	assert_int_equal(asph_points_format_parse("dat", &f), 0);
	assert_int_equal(f, ASPH_POINTS_METROPRO);
	assert_int_equal(asph_points_format_parse("zip", &f), -EINVAL);
	char names[128];
	assert_true(asph_points_format_names(names, sizeof(names)) < sizeof(names));
	for (f = ASPH_POINTS_AUTO; f <= ASPH_POINTS_DATX; f++) {
		enum asph_points_format back;
		assert_int_equal(asph_points_format_parse(asph_points_format_name(f), &back), 0);
		assert_int_equal(back, f);
		assert_non_null(strstr(names, asph_points_format_name(f)));
	}
	/* --format forces: a MetroPro file read as text is refused as text */
	struct asph_points_read_options text = { .format = ASPH_POINTS_TEXT };
	struct asph_points *p = NULL;
	struct asph_error err;
	static const char sdf[] = "aBCR-1.0\n";
	assert_true(asph_points_read_memory_as(sdf, strlen(sdf), "x.txt", NULL, &p, NULL, &err) < 0);
	assert_non_null(strstr(err.message, "sdf:"));
	assert_true(asph_points_read_memory_as(sdf, strlen(sdf), "x.txt", &text, &p, NULL, &err) < 0);
	assert_non_null(strstr(err.message, "text:"));
}

/* The units' list names each unit once, every name parses, and a buffer
 * too short is cut, not overrun. */
static void test_unit_names(void **state)
{
	char list[128], cut[8], *save = NULL;
	size_t n = asph_points_unit_names(list, sizeof(list));
	double mm;

	(void)state;
	assert_string_equal(list, "nm, um, mm, cm, m, in");
	assert_int_equal(n, strlen(list));
	for (char *t = strtok_r(list, ", ", &save); t; t = strtok_r(NULL, ", ", &save))
		assert_int_equal(asph_points_unit_parse(t, &mm), 0);
	assert_int_equal(asph_points_unit_names(cut, sizeof(cut)), n);
	assert_string_equal(cut, "nm, um,");
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_text_variants),
		cmocka_unit_test(test_x3p_matrix_float_scaled),
		cmocka_unit_test(test_x3p_matrix_integer_types),
		cmocka_unit_test(test_x3p_inline),
		cmocka_unit_test(test_x3p_errors),
		cmocka_unit_test(test_x3p_own_exports),
		cmocka_unit_test(test_sdf),
		cmocka_unit_test(test_metropro),
		cmocka_unit_test(test_datx),
		cmocka_unit_test(test_formats),
		cmocka_unit_test(test_unit_names),
	};
	return cmocka_run_group_tests(tests, setup, teardown);
}
