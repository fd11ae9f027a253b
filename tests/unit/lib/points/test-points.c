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

#include "asph/points.h"
#include "rmtree.h"

static char dir[] = "/tmp/asph-test-points-XXXXXX";

static int setup(void **state)
{
	return mkdtemp(dir) ? 0 : -1;
}

static int teardown(void **state)
{
	return rmtree(dir);
}

static struct asph_points *sample(size_t n, int with_value, int with_mesh)
{
	struct asph_points *p = asph_points_alloc(n);
	assert_non_null(p);
	for (size_t i = 0; i < n; i++) {
		/* values whose decimal forms need all 17 digits */
		p->xyz[3 * i] = sin(1.37 * (double)i + 0.1) * 19.7;
		p->xyz[3 * i + 1] = cos(2.91 * (double)i) * 7.3e-3;
		p->xyz[3 * i + 2] = exp(-(double)i / 7.0) / 3.0;
	}
	if (with_value) {
		assert_int_equal(asph_points_add_value(p, "residual_nm"), 0);
		for (size_t i = 0; i < n; i++)
			p->value[i] = ((double)i - 3.3) * 1.7;
	}
	if (with_mesh && n >= 3) {
		p->n_triangles = n - 2;
		p->triangles = malloc(3 * p->n_triangles * sizeof(uint32_t));
		for (size_t t = 0; t < p->n_triangles; t++) {
			p->triangles[3 * t] = (uint32_t)t;
			p->triangles[3 * t + 1] = (uint32_t)t + 1;
			p->triangles[3 * t + 2] = (uint32_t)t + 2;
		}
	}
	return p;
}

static void round_trip(const char *ext, int with_value, int with_mesh)
{
	char path[256];
	snprintf(path, sizeof(path), "%s/pts.%s", dir, ext);
	struct asph_points *p = sample(11, with_value, with_mesh), *q = NULL;
	struct asph_error err;
	assert_int_equal(asph_points_write(path, p, NULL, &err), 0);
	assert_int_equal(asph_points_read(path, &q, &err), 0);
	assert_int_equal(q->n, p->n);
	assert_memory_equal(q->xyz, p->xyz, 3 * p->n * sizeof(double));
	if (with_value) {
		assert_non_null(q->value);
		assert_string_equal(q->value_name, "residual_nm");
		assert_memory_equal(q->value, p->value, p->n * sizeof(double));
	}
	if (with_mesh) {
		assert_int_equal(q->n_triangles, p->n_triangles);
		assert_memory_equal(q->triangles, p->triangles, 3 * p->n_triangles * sizeof(uint32_t));
	}
	asph_points_free(p);
	asph_points_free(q);
}

static void test_round_trips(void **state)
{
	round_trip("csv", 0, 0);
	round_trip("csv", 1, 0);
	round_trip("ply", 0, 1);
	round_trip("ply", 1, 1);
	round_trip("json", 1, 1);
	round_trip("json", 0, 0);
}

static void test_ply_binary(void **state)
{
	char path[256];
	snprintf(path, sizeof(path), "%s/bin.ply", dir);
	FILE *f = fopen(path, "wb");
	assert_non_null(f);
	fprintf(f, "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
		   "property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
		   "element face 1\nproperty list uchar uint vertex_indices\nend_header\n");
	const float v[3][3] = { { 1.5f, -2.25f, 0.125f }, { 3, 4, 5 }, { -1, 0.5f, 2 } };
	for (int i = 0; i < 3; i++) {
		fwrite(v[i], sizeof(float), 3, f);
		fputc(200, f);
	}
	unsigned char cnt = 3;
	uint32_t idx[3] = { 2, 0, 1 };
	fwrite(&cnt, 1, 1, f);
	fwrite(idx, 4, 3, f);
	fclose(f);
	struct asph_points *p = NULL;
	struct asph_error err;
	assert_int_equal(asph_points_read(path, &p, &err), 0);
	assert_int_equal(p->n, 3);
	assert_true(p->xyz[0] == 1.5 && p->xyz[1] == -2.25 && p->xyz[8] == 2);
	assert_int_equal(p->n_triangles, 1);
	assert_true(p->triangles[0] == 2 && p->triangles[2] == 1);
	asph_points_free(p);
}

struct bad_csv {
	const char *text;
	int line, column;
	const char *field;
	const char *needle;
};

static const struct bad_csv bad[] = {
	{ "", 0, 0, "", "empty file" },
	{ "# only a comment\n\n", 0, 0, "", "empty file" },
	{ "x,y\n1,2\n", 1, 1, "", "does not name the columns x, y, z" },
	{ "1,2\n3,4\n", 1, 1, "", "three columns" },
	{ "x,y,z\n1,2,3\n4,nan,6\n", 3, 3, "y", "not a finite number" },
	{ "x,y,z\n1,2,3\n4,5\n", 3, 0, "", "expected 3 columns" },
	{ "x,y,z\n1,2,3,4\n", 2, 0, "", "found more" },
	{ "x,y,z\n1,2,abc\n", 2, 5, "z", "not a number: 'abc'" },
	{ "x,y,z\n1,,3\n", 2, 3, "y", "empty value" },
	{ "x,y,z\n1,2,inf\n", 2, 5, "z", "not a finite number" },
	{ "x,y,z\n1,2,1e999\n", 2, 5, "z", "not a finite number" },
	{ "\"x\",\"y\",\"z\n1,2,3\n", 1, 9, "", "does not close" },
	{ "x,y,z\n\"1\"2,2,3\n", 2, 4, "", "after the closing quote" },
	{ "x,y,z\n1,\"2 mm\",3\n", 2, 4, "y", "not a number: '2 mm'" },
	{ "X,Y,Q\n1,2,3\n", 1, 1, "", "does not name the columns x, y, z" },
	{ "x [furlong],y,z\n1,2,3\n", 1, 1, "x [furlong]", "unknown unit" },
	{ "x,y,z,x\n1,2,3,4\n", 1, 7, "x", "two columns name x" },
	{ "Operator: A\n1;2;3\n4;5,5\n", 3, 1, "", "three columns" },
	{ "1;2;3\n4;5,5.5;6\n", 2, 3, "", "not a number: '5,5.5'" },
	{ "1 2 3\n4 5 6 end\n", 2, 7, "", "not a number: 'end'" },
};

static void test_csv_errors(void **state)
{
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
		struct asph_points *p = NULL;
		struct asph_error err;
		asph_error_clear(&err);
		int r = asph_points_read_csv_text(bad[i].text, strlen(bad[i].text), "pts.csv", &p, &err);
		if (r != -EINVAL || p || err.line != bad[i].line ||
		    (bad[i].column && err.column != bad[i].column) ||
		    strcmp(err.field, bad[i].field) || !strstr(err.message, bad[i].needle) ||
		    strcmp(err.source, "pts.csv")) {
			char buf[512];
			print_error("case %zu: r=%d '%s'\n", i, r, asph_error_format(&err, buf, sizeof(buf)));
			fail();
		}
	}
}

static void test_csv_tolerant(void **state)
{
	const char text[] = "# plan\r\n x , y , z ,residual_nm\r\n1, 2 ,3,4\r\n\r\n# gap\n5,6,7,8";
	struct asph_points *p = NULL;
	assert_int_equal(asph_points_read_csv_text(text, strlen(text), "t", &p, NULL), 0);
	assert_int_equal(p->n, 2);
	assert_true(p->xyz[3] == 5 && p->xyz[5] == 7);
	assert_string_equal(p->value_name, "residual_nm");
	assert_true(p->value[1] == 8);
	asph_points_free(p);
}

/* A line profile as a tactile profilometer exports it: x and z named,
 * no y; read as the profile along x (y = 0), units from the header. */
static void test_text_profile(void **state)
{
	const char text[] = "X [mm]\tZ [um]\r\n-2,5\t1,25\r\n0\t0\r\n2,5\t-0,5\r\n";
	const char named[] = "z,x,residual_nm\n0.004,1,7\n";
	struct asph_points *p = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_points_read_csv_text(text, strlen(text), "p.txt", &p, &err), 0);
	assert_int_equal(p->n, 3);
	assert_true(p->xyz[0] == -2.5 && p->xyz[1] == 0 && p->xyz[2] == 1.25e-3);
	assert_true(p->xyz[3] == 0 && p->xyz[4] == 0 && p->xyz[5] == 0);
	assert_true(p->xyz[6] == 2.5 && p->xyz[7] == 0 && p->xyz[8] == -0.5e-3);
	asph_points_free(p);
	assert_int_equal(asph_points_read_csv_text(named, strlen(named), "p.csv", &p, &err), 0);
	assert_true(p->n == 1 && p->xyz[0] == 1 && p->xyz[1] == 0 && p->xyz[2] == 0.004);
	assert_true(p->value[0] == 7);
	asph_points_free(p);
}

/* Headers as R's write.csv() and spreadsheets write them. */
static void test_csv_quoted_header(void **state)
{
	static const char *const texts[] = {
		"\"x\",\"y\",\"z\"\n1.5,-2.25,0.125\n3,4,5\n",
		"X,Y,Z\n1.5,-2.25,0.125\n3,4,5\n",
		/* R's row names: an unnamed first column of quoted numbers */
		"\"\",\"X\",\"Y\",\"Z\"\n\"1\",1.5,-2.25,0.125\n\"2\",3,4,5\n",
		/* a byte-order mark, CR LF, blanks around the quotes, quoted values */
		"\xef\xbb\xbf \"Z\" , \"y\",\"x\"\r\n\"0.125\",-2.25,1.5\r\n5,\"4\",3\r\n",
	};
	for (size_t i = 0; i < sizeof(texts) / sizeof(texts[0]); i++) {
		struct asph_points *p = NULL;
		struct asph_error err;
		asph_error_clear(&err);
		if (asph_points_read_csv_text(texts[i], strlen(texts[i]), "r.csv", &p, &err) < 0) {
			char buf[512];
			print_error("case %zu: %s\n", i, asph_error_format(&err, buf, sizeof(buf)));
			fail();
		}
		assert_int_equal(p->n, 2);
		assert_true(p->xyz[0] == 1.5 && p->xyz[1] == -2.25 && p->xyz[2] == 0.125);
		assert_true(p->xyz[3] == 3 && p->xyz[4] == 4 && p->xyz[5] == 5);
		assert_null(p->value);
		asph_points_free(p);
	}
	/* a quoted value column keeps its name */
	const char *named = "\"x\",\"y\",\"z\",\"residual_nm\"\n1,2,3,4.5\n";
	struct asph_points *p = NULL;
	assert_int_equal(asph_points_read_csv_text(named, strlen(named), "r.csv", &p, NULL), 0);
	assert_string_equal(p->value_name, "residual_nm");
	assert_true(p->value[0] == 4.5);
	asph_points_free(p);
}

static void test_ply_errors(void **state)
{
	const char *cases[][2] = {
		{ "plx\n", "no header naming" },
		{ "ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\n"
		  "property double z\nend_header\n1 2 3\n", "ends at vertex 1" },
		{ "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
		  "property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
		  "1 2 3\n3 0 0 7\n", "out of range" },
		{ "ply\nformat binary_big_endian 1.0\nend_header\n", "not supported" },
		{ "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\n", "without end_header" },
		{ "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
		  "property double z\nend_header\n1 nan 3\n", "not a finite" },
	};
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		char path[256];
		snprintf(path, sizeof(path), "%s/bad%zu.ply", dir, i);
		FILE *f = fopen(path, "w");
		fputs(cases[i][0], f);
		fclose(f);
		struct asph_points *p = NULL;
		struct asph_error err;
		asph_error_clear(&err);
		assert_true(asph_points_read(path, &p, &err) < 0);
		assert_null(p);
		if (!strstr(err.message, cases[i][1])) {
			print_error("case %zu: '%s'\n", i, err.message);
			fail();
		}
	}
}

static void test_missing_file(void **state)
{
	struct asph_points *p = NULL;
	struct asph_error err;
	assert_int_equal(asph_points_read("/nonexistent/dir/p.csv", &p, &err), -ENOENT);
	assert_string_equal(err.source, "/nonexistent/dir/p.csv");
	struct asph_points *q = sample(3, 0, 0);
	assert_int_equal(asph_points_write("/nonexistent/dir/p.csv", q, NULL, &err), -ENOENT);
	asph_points_free(q);
}

/* The same bytes read from memory and from a file give the same points;
 * the format follows the source's extension. */
static void test_read_memory(void **state)
{
	static const char ply[] =
		"ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
		"property double z\nproperty double residual_nm\nelement face 1\n"
		"property list uchar int vertex_indices\nend_header\n"
		"0.731 -1.29 0.0417 3.5\n2.6 0.37 -0.112 -1.25\n-1.9 2.03 0.2283 0.75\n3 2 0 1\n";
	static const char json[] = "{\"points\": [[0.731, -1.29, 0.0417], [2.6, 0.37, -0.112]],"
				   " \"triangles\": []}";
	static const char csv[] = "x,y,z\n0.731,-1.29,0.0417\n";
	char path[256];
	struct asph_points *m = NULL, *f = NULL;
	struct asph_error err;

	snprintf(path, sizeof(path), "%s/mem.ply", dir);
	FILE *fp = fopen(path, "w");
	assert_non_null(fp);
	fputs(ply, fp);
	fclose(fp);
	assert_int_equal(asph_points_read(path, &f, &err), 0);
	assert_int_equal(asph_points_read_memory(ply, strlen(ply), "scan.PLY", &m, &err), 0);
	assert_int_equal(m->n, 3);
	assert_memory_equal(m->xyz, f->xyz, 9 * sizeof(double));
	assert_memory_equal(m->value, f->value, 3 * sizeof(double));
	assert_string_equal(m->value_name, "residual_nm");
	assert_int_equal(m->n_triangles, 1);
	assert_true(m->triangles[0] == 2 && m->triangles[1] == 0 && m->triangles[2] == 1);
	asph_points_free(m);
	asph_points_free(f);

	assert_int_equal(asph_points_read_memory(json, strlen(json), "p.json", &m, &err), 0);
	assert_int_equal(m->n, 2);
	assert_true(m->xyz[3] == 2.6 && m->xyz[5] == -0.112 && !m->triangles);
	asph_points_free(m);
	/* No extension: CSV; the bytes need no terminating NUL (the last two
	 * are left out). */
	assert_int_equal(asph_points_read_memory(csv, sizeof(csv) - 3, "<memory>", &m, &err), 0);
	assert_int_equal(m->n, 1);
	assert_true(m->xyz[0] == 0.731 && m->xyz[2] == 0.041);
	asph_points_free(m);
	/* The content decides, not the name: a PLY called .csv is a PLY. */
	assert_int_equal(asph_points_read_memory(ply, strlen(ply), "p.csv", &m, &err), 0);
	assert_int_equal(m->n_triangles, 1);
	asph_points_free(m);
	/* and a forced format reads it as that, refused as such */
	struct asph_points_read_options text = { .format = ASPH_POINTS_TEXT };
	assert_int_equal(asph_points_read_memory_as(ply, strlen(ply), "p.ply", &text, &m, NULL, &err),
			 -EINVAL);
	assert_null(m);
	assert_string_equal(err.source, "p.ply");
}

/* Headers whose counts the data cannot hold are refused before anything of
 * that size is allocated (a 120-byte file once asked for 6 GiB), and a
 * binary header ending without a newline reads no byte past the end. */
static void test_ply_counts_beyond_data(void **state)
{
	static const char *const cases[][2] = {
		{ "ply\nformat ascii 1.0\nelement vertex 268435456\nproperty double x\n"
		  "property double y\nproperty double z\nend_header\n1 2 3\n", "announces" },
		{ "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
		  "property double y\nproperty double z\nelement face 200000000\n"
		  "property list uchar int vertex_indices\nend_header\n0123456789abcdefghijklmn", "announces" },
		{ "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty uchar x\n"
		  "property uchar y\nproperty uchar z\nend_header", "announces" },
	};
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_points *p = NULL;
		struct asph_error err;
		asph_error_clear(&err);
		/* Exactly len bytes on the heap, so a read past them is seen by
		 * ASan and valgrind. */
		size_t len = strlen(cases[i][0]);
		char *copy = malloc(len);
		assert_non_null(copy);
		memcpy(copy, cases[i][0], len);
		assert_int_equal(asph_points_read_memory(copy, len, "c.ply", &p, &err), -EINVAL);
		free(copy);
		assert_null(p);
		assert_string_equal(err.field, "element");
		if (!strstr(err.message, cases[i][1])) {
			print_error("case %zu: '%s'\n", i, err.message);
			fail();
		}
	}
}

/* Vertices or faces beyond the header's counts are refused, not dropped,
 * and a NUL byte in an ASCII body is not read as a zero. */
static void test_ply_data_beyond_counts(void **state)
{
	static const char head[] =
		"ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\nproperty double y\n"
		"property double z\nend_header\n";
	static const char body[] = "0.731 -1.29 0.0417\n2.6 0.37 -0.112\n";
	char text[512];
	struct asph_points *p = NULL;
	struct asph_error err;

	snprintf(text, sizeof(text), "%s%s-1.9 2.03 0.2283\n", head, body);
	assert_int_equal(asph_points_read_memory(text, strlen(text), "a.ply", &p, &err), -EINVAL);
	assert_null(p);
	assert_int_equal(err.line, 10);
	assert_int_equal(err.column, 1);
	assert_non_null(strstr(err.message, "data after the 2 vertices"));

	/* Trailing blank lines are fine. */
	snprintf(text, sizeof(text), "%s%s\n \r\n", head, body);
	assert_int_equal(asph_points_read_memory(text, strlen(text), "a.ply", &p, &err), 0);
	assert_int_equal(p->n, 2);
	asph_points_free(p);

	/* "0.37" with its 7 replaced by a NUL byte: y reads 0.3, and z meets
	 * the NUL. */
	size_t n = (size_t)snprintf(text, sizeof(text), "%s%s", head, body);
	char *nul = strstr(text, "0.37");
	nul[3] = '\0';
	assert_int_equal(asph_points_read_memory(text, n, "a.ply", &p, &err), -EINVAL);
	assert_string_equal(err.field, "z");

	static const char bin_head[] =
		"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
		"property double y\nproperty double z\nend_header\n";
	const double xyz[4] = { 0.731, -1.29, 0.0417, 2.6 };
	n = strlen(bin_head);
	memcpy(text, bin_head, n);
	memcpy(text + n, xyz, sizeof(xyz));
	assert_int_equal(asph_points_read_memory(text, n + 3 * sizeof(double), "b.ply", &p, &err), 0);
	assert_true(p->n == 1 && p->xyz[2] == 0.0417);
	asph_points_free(p);
	assert_int_equal(asph_points_read_memory(text, n + sizeof(xyz), "b.ply", &p, &err), -EINVAL);
	assert_non_null(strstr(err.message, "8 bytes after the 1 vertices"));
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_round_trips),
		cmocka_unit_test(test_ply_binary),
		cmocka_unit_test(test_csv_errors),
		cmocka_unit_test(test_csv_tolerant),
		cmocka_unit_test(test_csv_quoted_header),
		cmocka_unit_test(test_text_profile),
		cmocka_unit_test(test_ply_errors),
		cmocka_unit_test(test_missing_file),
		cmocka_unit_test(test_read_memory),
		cmocka_unit_test(test_ply_counts_beyond_data),
		cmocka_unit_test(test_ply_data_beyond_counts),
	};
	return cmocka_run_group_tests(tests, setup, teardown);
}
