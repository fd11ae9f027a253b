/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>
#include <jansson.h>

#include "config.h"
#include "asph/points.h"
#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "crc32c.h"

#define RECORD 88
#define BLOCK_OVERHEAD 36

static char tmpdir[64];

/* ------------------------------------------------------------ helpers */

static const char prescription[] =
	"{\"type\":\"even_asphere\",\"R\":20.097,\"k\":-1,"
	"\"A\":{\"4\":-2.0868e-05,\"6\":-3.9031e-09,\"8\":3.4102e-11},"
	"\"aperture_diameter\":40}";
static const char plan[] =
	"{\"method\":\"op\",\"density\":{\"kind\":\"h\",\"value\":0.1},"
	"\"spacing_mm\":0.3333333333333333,\"points\":12345}";
static const char instrument[] =
	"{\"stage\":{\"driver\":\"mock\",\"options\":{\"speed\":12.5}},"
	"\"probe\":{\"driver\":\"mock\",\"version\":\"1.2\",\"tip_radius\":0.0015}}";
static const char metadata[] = "{\"job\":\"j-1742\",\"operator\":\"Ana\"}";

static const struct asph_scanfile_header_info info = {
	prescription, plan, instrument, metadata,
};

struct fake_clock {
	uint64_t t;
};

static uint64_t fake_now(void *data)
{
	return ((struct fake_clock *)data)->t;
}

/* A point whose every field differs from its neighbours', with awkward
 * doubles (negative zero, subnormals, huge) sprinkled in. */
static struct asph_scanfile_point pattern(uint64_t i)
{
	struct asph_scanfile_point p = {
		.plan_index = i * 7 + 3,
		.x = 17.25 * sin(0.37 * (double)i + 0.1),
		.y = -9.5 * cos(0.291 * (double)i + 0.2),
		.z = 0.0123 * (double)i - 3.1,
		.raw = 1e-3 * sqrt((double)i + 0.5),
		.t_ns = 1000003 * i + 17,
		.flags = i % 3 == 1 ? ASPH_SCANFILE_POINT_TIP_COMPENSATED : 0,
		.position_source = (uint32_t)(i % 5),
		.stage = { 1.25 * (double)i, -0.5 * (double)i - 0.125, 3e-7 * (double)i },
	};
	if (i % 97 == 5) {
		p.x = -0.0;
		p.y = DBL_TRUE_MIN * (double)(i + 1);
		p.raw = -DBL_MAX;
	}
	return p;
}

static uint64_t bits(double d)
{
	uint64_t u;
	memcpy(&u, &d, sizeof(u));
	return u;
}

static void assert_point_eq(const struct asph_scanfile_point *a,
			    const struct asph_scanfile_point *b)
{
	assert_int_equal(a->plan_index, b->plan_index);
	assert_int_equal(bits(a->x), bits(b->x));
	assert_int_equal(bits(a->y), bits(b->y));
	assert_int_equal(bits(a->z), bits(b->z));
	assert_int_equal(bits(a->raw), bits(b->raw));
	assert_int_equal(a->t_ns, b->t_ns);
	assert_int_equal(a->flags, b->flags);
	assert_int_equal(a->position_source, b->position_source);
	for (int k = 0; k < 3; k++)
		assert_int_equal(bits(a->stage[k]), bits(b->stage[k]));
}

static void assert_pattern(const struct asph_scanfile *s, size_t n)
{
	assert_int_equal(s->n, n);
	assert_int_equal(s->report.n_points, n);
	for (size_t i = 0; i < n; i++) {
		struct asph_scanfile_point e = pattern(i);
		assert_point_eq(&s->points[i], &e);
	}
}

static char *tmp_path(const char *name)
{
	static char buf[4][sizeof(tmpdir) + 256];
	static int k;
	char *p = buf[k++ % 4];

	snprintf(p, sizeof(buf[0]), "%s/%s", tmpdir, name);
	return p;
}

static uint8_t *slurp(const char *path, size_t *len)
{
	FILE *f = fopen(path, "rb");
	assert_non_null(f);
	fseek(f, 0, SEEK_END);
	long n = ftell(f);
	fseek(f, 0, SEEK_SET);
	uint8_t *b = malloc((size_t)n + 1);
	assert_non_null(b);
	assert_int_equal(fread(b, 1, (size_t)n, f), (size_t)n);
	fclose(f);
	*len = (size_t)n;
	return b;
}

static void spit(const char *path, const uint8_t *b, size_t len)
{
	FILE *f = fopen(path, "wb");
	assert_non_null(f);
	assert_int_equal(fwrite(b, 1, len, f), len);
	fclose(f);
}

static uint32_t le32(const uint8_t *p)
{
	return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 |
	       (uint32_t)p[3] << 24;
}

static uint64_t le64(const uint8_t *p)
{
	return le32(p) | (uint64_t)le32(p + 4) << 32;
}

static void put32(uint8_t *p, uint32_t v)
{
	for (int i = 0; i < 4; i++)
		p[i] = (uint8_t)(v >> (8 * i));
}

static size_t header_end(const uint8_t *file)
{
	return 20 + le32(file + 12);
}

static void append_pattern(struct asph_scanfile_writer *w, uint64_t from, uint64_t n)
{
	struct asph_error err;
	for (uint64_t i = from; i < from + n; i++) {
		struct asph_scanfile_point p = pattern(i);
		assert_int_equal(asph_scanfile_writer_append(w, &p, 1, &err), 0);
	}
}

/* Writes n pattern points in blocks of block_points, then ends the scan
 * with outcome (or leaves it unfinished). */
static void make_scan(const char *path, uint32_t block_points, uint64_t n,
		      enum asph_scanfile_outcome outcome, const char *reason)
{
	struct fake_clock clk = { 5 };
	struct asph_scanfile_writer_options o = {
		.flags = ASPH_SCANFILE_OVERWRITE, .block_points = block_points,
		.clock = fake_now, .clock_data = &clk,
	};
	struct asph_scanfile_writer *w;
	struct asph_error err;

	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);
	append_pattern(w, 0, n);
	if (outcome == ASPH_SCANFILE_UNFINISHED)
		assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	else
		assert_int_equal(asph_scanfile_writer_finish(w, outcome, reason, &err), 0);
}

static void assert_json_same(const char *a, const char *b)
{
	json_t *ja = json_loads(a, 0, NULL), *jb = json_loads(b, 0, NULL);
	assert_non_null(ja);
	assert_non_null(jb);
	assert_true(json_equal(ja, jb));
	json_decref(ja);
	json_decref(jb);
}

static uint64_t count_on_disk(const char *path)
{
	struct asph_scanfile *s;
	struct asph_error err;
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	uint64_t n = s->n;
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_END);
	asph_scanfile_free(s);
	return n;
}

/* -------------------------------------------------------------- tests */

static void test_crc32c(void **state)
{
	static const char check[] = "123456789";
	assert_int_equal(crc32c(0, check, 9), 0xe3069283u);
	/* RFC 3720 B.4: 32 bytes of zeros, of 0xff */
	uint8_t z[32] = { 0 }, f[32];
	memset(f, 0xff, sizeof(f));
	assert_int_equal(crc32c(0, z, 32), 0x8a9136aau);
	assert_int_equal(crc32c(0, f, 32), 0x62a8ab43u);
	assert_int_equal(crc32c(crc32c(0, check, 4), check + 4, 5), 0xe3069283u);
	assert_int_equal(crc32c_portable(0, check, 9), 0xe3069283u);

	/* both paths agree at every length and alignment */
	uint8_t buf[300];
	uint64_t x = 0x853c49e6748fea9bull;
	for (size_t i = 0; i < sizeof(buf); i++) {
		x ^= x << 13, x ^= x >> 7, x ^= x << 17;
		buf[i] = (uint8_t)(x >> 24);
	}
	for (size_t off = 0; off < 9; off++)
		for (size_t len = 0; len + off <= sizeof(buf); len += 1 + len / 8)
			assert_int_equal(crc32c(0x1234567u, buf + off, len),
					 crc32c_portable(0x1234567u, buf + off, len));
}

static void test_names(void **state)
{
	enum asph_scanfile_outcome o;
	for (int i = ASPH_SCANFILE_UNFINISHED; i <= ASPH_SCANFILE_FAILED; i++) {
		assert_int_equal(asph_scanfile_outcome_from_name(
					 asph_scanfile_outcome_name(i), &o), 0);
		assert_int_equal(o, i);
	}
	assert_int_equal(asph_scanfile_outcome_from_name("done", &o), -EINVAL);
	assert_string_equal(asph_scanfile_stop_name(ASPH_SCANFILE_STOP_CHECKSUM), "checksum");
	assert_string_equal(asph_scanfile_stop_name(ASPH_SCANFILE_STOP_TORN), "torn");

	uint32_t mask = 77;
	struct asph_error err;
	assert_int_equal(asph_scanfile_flags_parse("retried,low-signal", &mask, &err), 0);
	assert_int_equal(mask, ASPH_SCANFILE_POINT_RETRIED | ASPH_SCANFILE_POINT_LOW_SIGNAL);
	assert_int_equal(asph_scanfile_flags_parse("", &mask, &err), 0);
	assert_int_equal(mask, 0);
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_flags_parse("retried,low", &mask, &err), -EINVAL);
	assert_non_null(strstr(err.message, "'low'"));
	assert_int_equal(asph_scanfile_flags_parse("retried,", &mask, &err), 0);
	assert_int_equal(mask, ASPH_SCANFILE_POINT_RETRIED);
	assert_string_equal(asph_scanfile_flag_name(ASPH_SCANFILE_POINT_TIP_COMPENSATED),
			    "tip-compensated");
	assert_string_equal(asph_scanfile_flag_name(ASPH_SCANFILE_POINT_OUT_OF_RANGE),
			    "out-of-range");
	assert_null(asph_scanfile_flag_name(1u << 9));
	assert_null(asph_scanfile_flag_name(3));
}

static void test_round_trip(void **state)
{
	const char *path = tmp_path("round.scan");
	struct fake_clock clk = { 1000 };
	struct asph_scanfile_writer_options o = {
		.block_points = 1000, .clock = fake_now, .clock_data = &clk,
	};
	struct asph_scanfile_writer *w;
	struct asph_scanfile *s;
	struct asph_error err;
	const size_t sizes[] = { 1, 7, 3001, 999, 1000, 2500, 1, 4836 };
	uint64_t n = 0;

	struct asph_scanfile_point *batch = calloc(5000, sizeof(*batch));
	int64_t before = time(NULL) * (int64_t)1000000000;
	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);
	for (size_t k = 0; k < sizeof(sizes) / sizeof(sizes[0]); k++) {
		for (size_t i = 0; i < sizes[k]; i++)
			batch[i] = pattern(n + i);
		assert_int_equal(asph_scanfile_writer_append(w, batch, sizes[k], &err), 0);
		n += sizes[k];
		assert_int_equal(asph_scanfile_writer_n_points(w), n);
		assert_int_equal(asph_scanfile_writer_n_synced(w), n / 1000 * 1000);
	}
	assert_int_equal(n, 12345);
	free(batch);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED,
						     "all 12345 points, \"quoted\"", &err), 0);
	int64_t after = (time(NULL) + 1) * (int64_t)1000000000;

	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, n);
	const struct asph_scanfile_header *h = &s->header;
	assert_int_equal(h->version_major, 1);
	assert_int_equal(h->version_minor, 1);
	assert_json_same(h->prescription, prescription);
	assert_json_same(h->plan, plan);
	assert_json_same(h->instrument, instrument);
	assert_json_same(h->metadata, metadata);
	assert_string_equal(h->software_version, ASPH_VERSION);
	assert_true(h->created_ns >= before && h->created_ns <= after);
	assert_int_equal(strlen(h->created), 30);
	assert_int_equal(h->created[10], 'T');
	/* the exact text of a member survives, bit for bit in its reals */
	assert_non_null(strstr(h->plan, "\"spacing_mm\":0.33333333333333331"));

	const struct asph_scanfile_report *r = &s->report;
	assert_int_equal(r->n_blocks, 13 + 1);
	assert_int_equal(r->stop, ASPH_SCANFILE_STOP_END);
	assert_int_equal(r->discarded_bytes, 0);
	assert_int_equal(r->valid_bytes, r->file_size);
	assert_true(r->ended);
	assert_int_equal(r->outcome, ASPH_SCANFILE_COMPLETED);
	assert_string_equal(r->reason, "all 12345 points, \"quoted\"");
	/* when it ended: after it began, on the wall clock */
	assert_true(r->ended_ns >= h->created_ns && r->ended_ns <= after);
	assert_int_equal(r->n_resumes, 0);
	assert_string_equal(r->stop_detail, "");
	struct stat st;
	assert_int_equal(stat(path, &st), 0);
	assert_int_equal((uint64_t)st.st_size, r->file_size);
	asph_scanfile_free(s);
	unlink(path);
}

/* The byte layout of docs/scan-format.md, checked byte by byte. */
static void test_layout(void **state)
{
	const char *path = tmp_path("layout.scan");
	struct asph_scanfile_writer *w;
	struct asph_error err;
	struct asph_scanfile_point p = {
		.plan_index = 0x0102030405060708ull, .x = 1.5, .y = -2.25, .z = 0.1,
		.raw = 3e-3, .t_ns = 123456789012ull,
		.flags = ASPH_SCANFILE_POINT_LOW_SIGNAL | ASPH_SCANFILE_POINT_RETRIED,
		.position_source = ASPH_SCANFILE_POSITION_INTERPOLATED,
		.stage = { -7.5, 0.375, 2.0625 },
	};
	size_t len;

	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, &err), 0);
	assert_int_equal(asph_scanfile_writer_append(w, &p, 1, &err), 0);
	assert_int_equal(asph_scanfile_writer_flush(w, &err), 0);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_ABORTED, NULL, &err), 0);
	uint8_t *b = slurp(path, &len);

	assert_memory_equal(b, "ASPHSCAN", 8);
	assert_int_equal(b[8] | b[9] << 8, 1);
	assert_int_equal(b[10] | b[11] << 8, 1);
	uint32_t hl = le32(b + 12);
	assert_int_equal(le32(b + 16), crc32c(crc32c(0, b, 16), b + 20, hl));
	assert_int_equal(b[20], '{');

	const uint8_t *k = b + 20 + hl;
	assert_memory_equal(k, "ASPB", 4);
	assert_int_equal(k[4] | k[5] << 8, 1);         /* points */
	assert_int_equal(k[6] | k[7] << 8, RECORD);
	assert_int_equal(le64(k + 8), 0);               /* sequence */
	assert_int_equal(le64(k + 16), 0);              /* first point */
	assert_int_equal(le32(k + 24), 1);              /* count */
	assert_int_equal(le32(k + 28), RECORD);         /* payload */
	const uint8_t *rec = k + 32;
	assert_int_equal(le64(rec), 0x0102030405060708ull);
	assert_int_equal(le64(rec + 8), bits(1.5));
	assert_int_equal(le64(rec + 16), bits(-2.25));
	assert_int_equal(le64(rec + 24), bits(0.1));
	assert_int_equal(le64(rec + 32), bits(3e-3));
	assert_int_equal(le64(rec + 40), 123456789012ull);
	assert_int_equal(le32(rec + 48), 0xc);
	assert_int_equal(le32(rec + 52), 3);            /* interpolated */
	assert_int_equal(le64(rec + 56), bits(-7.5));
	assert_int_equal(le64(rec + 64), bits(0.375));
	assert_int_equal(le64(rec + 72), bits(2.0625));
	assert_int_equal(le64(rec + 80), 0);            /* reserved */
	assert_int_equal(le32(k + 32 + RECORD), crc32c(0, k, 32 + RECORD));

	const uint8_t *e = k + BLOCK_OVERHEAD + RECORD;
	assert_memory_equal(e, "ASPB", 4);
	assert_int_equal(e[4] | e[5] << 8, 2);          /* end */
	assert_int_equal(le64(e + 8), 1);
	assert_int_equal(le64(e + 16), 1);
	assert_int_equal(le32(e + 24), 0);
	uint32_t pl = le32(e + 28);
	assert_int_equal((size_t)(e - b) + BLOCK_OVERHEAD + pl, len);
	json_t *end = json_loadb((const char *)e + 32, pl, 0, NULL);
	assert_non_null(end);
	assert_string_equal(json_string_value(json_object_get(end, "outcome")), "aborted");
	assert_true(json_is_null(json_object_get(end, "reason")));
	assert_int_equal(json_integer_value(json_object_get(end, "points")), 1);
	json_decref(end);
	assert_int_equal(le32(e + 32 + pl), crc32c(0, e, 32 + pl));
	free(b);
	unlink(path);
}

/* A block reaches the file after 10,000 appends; a second reader sees it
 * while the writer is still open. */
static void test_flush_by_count(void **state)
{
	const char *path = tmp_path("count.scan");
	struct fake_clock clk = { 777 };
	struct asph_scanfile_writer_options o = { .clock = fake_now, .clock_data = &clk };
	struct asph_scanfile_writer *w;
	struct asph_error err;

	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);
	append_pattern(w, 0, 9999);
	assert_int_equal(asph_scanfile_writer_n_synced(w), 0);
	assert_int_equal(count_on_disk(path), 0);
	append_pattern(w, 9999, 1);
	assert_int_equal(asph_scanfile_writer_n_synced(w), 10000);
	assert_int_equal(count_on_disk(path), 10000);
	append_pattern(w, 10000, 123);
	assert_int_equal(count_on_disk(path), 10000);
	assert_int_equal(asph_scanfile_writer_flush(w, &err), 0);
	assert_int_equal(count_on_disk(path), 10123);
	/* nothing pending: flush writes no empty block */
	assert_int_equal(asph_scanfile_writer_flush(w, &err), 0);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);

	struct asph_scanfile *s;
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 10123);
	assert_int_equal(s->report.n_blocks, 2);
	assert_false(s->report.ended);
	assert_int_equal(s->report.outcome, ASPH_SCANFILE_UNFINISHED);
	assert_int_equal(s->report.ended_ns, 0);
	asph_scanfile_free(s);
	unlink(path);
}

/* A block reaches the file once 1 s has passed since the last sync. */
static void test_flush_by_time(void **state)
{
	const char *path = tmp_path("time.scan");
	const uint64_t s1 = 1000000000;
	struct fake_clock clk = { 5 * s1 + 271 };
	struct asph_scanfile_writer_options o = { .clock = fake_now, .clock_data = &clk };
	struct asph_scanfile_writer *w;
	struct asph_error err;

	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);
	assert_int_equal(asph_scanfile_writer_elapsed_ns(w), 0);
	append_pattern(w, 0, 5);
	clk.t += s1 - 1;
	append_pattern(w, 5, 1);
	assert_int_equal(count_on_disk(path), 0);
	assert_int_equal(asph_scanfile_writer_elapsed_ns(w), s1 - 1);
	clk.t += 1;
	append_pattern(w, 6, 1);
	assert_int_equal(count_on_disk(path), 7);

	/* tick: the time policy without a new point */
	assert_int_equal(asph_scanfile_writer_tick(w, &err), 0);
	clk.t += s1 / 2;
	append_pattern(w, 7, 2);
	assert_int_equal(asph_scanfile_writer_tick(w, &err), 0);
	assert_int_equal(count_on_disk(path), 7);
	clk.t += s1 / 2;
	assert_int_equal(asph_scanfile_writer_tick(w, &err), 0);
	assert_int_equal(count_on_disk(path), 9);
	assert_int_equal(asph_scanfile_writer_n_synced(w), 9);

	/* a custom interval */
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	o.sync_interval_ns = 250000;
	o.flags = ASPH_SCANFILE_OVERWRITE;
	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);
	append_pattern(w, 0, 3);
	clk.t += 249999;
	append_pattern(w, 3, 1);
	assert_int_equal(count_on_disk(path), 0);
	clk.t += 1;
	append_pattern(w, 4, 1);
	assert_int_equal(count_on_disk(path), 5);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	unlink(path);
}

static void check_truncated(const uint8_t *file, size_t len, uint64_t expect_points,
			    size_t valid_end, bool ended)
{
	struct asph_scanfile *s;
	struct asph_error err;

	assert_int_equal(asph_scanfile_read_memory(file, len, "mem", &s, &err), 0);
	assert_pattern(s, expect_points);
	assert_int_equal(s->report.valid_bytes, valid_end);
	assert_int_equal(s->report.discarded_bytes, len - valid_end);
	assert_int_equal(s->report.file_size, len);
	assert_int_equal(s->report.ended, ended);
	assert_int_equal(s->report.stop,
			 len == valid_end ? ASPH_SCANFILE_STOP_END : ASPH_SCANFILE_STOP_TORN);
	assert_int_equal(s->report.stop_offset, valid_end);
	asph_scanfile_free(s);
}

/* Cut the file at every byte of its blocks: each cut keeps the blocks
 * before it and reports what it dropped. */
static void test_torn_tail(void **state)
{
	const char *path = tmp_path("torn.scan");
	size_t len;

	make_scan(path, 7, 21, ASPH_SCANFILE_FAILED, "probe gone");
	uint8_t *b = slurp(path, &len);
	size_t h = header_end(b), blk = BLOCK_OVERHEAD + 7 * RECORD;
	size_t ends[3] = { h + blk, h + 2 * blk, h + 3 * blk };

	for (size_t cut = h; cut < len; cut++) {
		size_t kept = 0;
		while (kept < 3 && ends[kept] <= cut)
			kept++;
		check_truncated(b, cut, 7 * kept, kept ? ends[kept - 1] : h, false);
	}
	check_truncated(b, len, 21, len, true);

	/* the same through a file */
	assert_int_equal(truncate(path, (off_t)(ends[1] + 100)), 0);
	struct asph_scanfile *s;
	struct asph_error err;
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 14);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_TORN);
	assert_int_equal(s->report.discarded_bytes, 100);
	char want[64];
	snprintf(want, sizeof(want), "at offset %zu", ends[1]);
	assert_non_null(strstr(s->report.stop_detail, want));
	asph_scanfile_free(s);

	/* a tail of zeros, as some file systems leave after a power cut */
	uint8_t *z = calloc(1, ends[1] + 4096);
	memcpy(z, b, ends[1]);
	check_truncated(z, ends[1] + 4096, 14, ends[1], false);
	free(z);
	free(b);
	unlink(path);
}

/* Any changed byte of a block is caught; the blocks before it are kept. */
static void test_corrupt_byte(void **state)
{
	const char *path = tmp_path("corrupt.scan");
	struct asph_error err;
	size_t len;

	make_scan(path, 7, 21, ASPH_SCANFILE_COMPLETED, NULL);
	uint8_t *b = slurp(path, &len);
	size_t h = header_end(b), blk = BLOCK_OVERHEAD + 7 * RECORD;
	size_t start = h + blk;

	for (size_t i = start; i < start + blk; i++) {
		struct asph_scanfile *s;
		b[i] ^= 0x5a;
		assert_int_equal(asph_scanfile_read_memory(b, len, "mem", &s, &err), 0);
		b[i] ^= 0x5a;
		assert_pattern(s, 7);
		assert_true(s->report.stop == ASPH_SCANFILE_STOP_CHECKSUM ||
			    s->report.stop == ASPH_SCANFILE_STOP_CORRUPT);
		assert_int_equal(s->report.stop_offset, start);
		assert_int_equal(s->report.discarded_bytes, len - start);
		assert_false(s->report.ended);
		if (i >= start + 32) {   /* payload and CRC */
			char want[80];
			snprintf(want, sizeof(want), "checksum mismatch in block at offset %zu", start);
			assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_CHECKSUM);
			assert_string_equal(s->report.stop_detail, want);
		}
		asph_scanfile_free(s);
	}

	/* a block repeated: out of sequence */
	uint8_t *d = malloc(len + blk);
	memcpy(d, b, start + blk);
	memcpy(d + start + blk, b + start, len - start);
	struct asph_scanfile *s;
	assert_int_equal(asph_scanfile_read_memory(d, len + blk, "mem", &s, &err), 0);
	assert_pattern(s, 14);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_CORRUPT);
	assert_non_null(strstr(s->report.stop_detail, "out of sequence"));
	asph_scanfile_free(s);

	/* data after the end block */
	memcpy(d, b, len);
	memcpy(d + len, "trailing", 8);
	assert_int_equal(asph_scanfile_read_memory(d, len + 8, "mem", &s, &err), 0);
	assert_pattern(s, 21);
	assert_true(s->report.ended);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_CORRUPT);
	assert_int_equal(s->report.discarded_bytes, 8);
	asph_scanfile_free(s);
	free(d);
	free(b);
	unlink(path);
}

static void expect_open_error(const uint8_t *b, size_t len, int code, const char *text)
{
	struct asph_scanfile *s = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_read_memory(b, len, "bad.scan", &s, &err), code);
	assert_null(s);
	assert_int_equal(err.code, code);
	assert_string_equal(err.source, "bad.scan");
	if (!strstr(err.message, text))
		fail_msg("\"%s\" does not say \"%s\"", err.message, text);
}

static void reseal_header(uint8_t *b)
{
	put32(b + 16, crc32c(crc32c(0, b, 16), b + 20, le32(b + 12)));
}

static void test_bad_files(void **state)
{
	const char *path = tmp_path("bad.scan");
	struct asph_scanfile *s = NULL;
	struct asph_error err;
	size_t len;

	make_scan(path, 7, 3, ASPH_SCANFILE_COMPLETED, NULL);
	uint8_t *b = slurp(path, &len);
	uint8_t *c = malloc(len);
	size_t h = header_end(b);

	expect_open_error(b, 0, -EBADMSG, "empty file");
	expect_open_error((const uint8_t *)"PK\3\4 a zip file, say", 20, -EBADMSG, "bad magic");
	expect_open_error(b, 5, -EBADMSG, "truncated header");
	expect_open_error(b, 19, -EBADMSG, "truncated header");
	expect_open_error(b, h - 1, -EBADMSG, "truncated header");

	uint64_t x = 0x9e3779b97f4a7c15ull;
	for (size_t i = 0; i < len; i++) {
		x ^= x << 13, x ^= x >> 7, x ^= x << 17;
		c[i] = (uint8_t)x;
	}
	expect_open_error(c, len, -EBADMSG, "bad magic");

	memcpy(c, b, len);
	c[7] = 'M';
	expect_open_error(c, len, -EBADMSG, "bad magic");

	memcpy(c, b, len);
	c[8] = 2;
	reseal_header(c);
	expect_open_error(c, len, -ENOTSUP, "format version 2.1 is newer");

	memcpy(c, b, len);
	c[8] = 0;
	expect_open_error(c, len, -EBADMSG, "invalid format version");

	memcpy(c, b, len);
	c[40] ^= 1;
	expect_open_error(c, len, -EBADMSG, "header checksum mismatch");

	memcpy(c, b, len);
	put32(c + 12, ASPH_SCANFILE_MAX_HEADER + 1);
	expect_open_error(c, len, -EBADMSG, "header length");

	/* a valid checksum over malformed JSON: line and column */
	memcpy(c, b, len);
	assert_memory_equal(c + 20, "{\n  \"format\"", 12);
	c[23] = '!';
	reseal_header(c);
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_read_memory(c, len, "bad.scan", &s, &err), -EBADMSG);
	assert_int_equal(err.line, 2);
	assert_true(err.column > 0);

	/* a header without a plan */
	memcpy(c, b, len);
	char *plan_key = memmem(c + 20, h - 20, "\"plan\"", 6);
	assert_non_null(plan_key);
	memcpy(plan_key, "\"plam\"", 6);
	reseal_header(c);
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_read_memory(c, len, "bad.scan", &s, &err), -EBADMSG);
	assert_string_equal(err.field, "plan");

	/* a newer minor version reads */
	memcpy(c, b, len);
	c[10] = 7;
	reseal_header(c);
	assert_int_equal(asph_scanfile_read_memory(c, len, "bad.scan", &s, &err), 0);
	assert_int_equal(s->header.version_minor, 7);
	assert_pattern(s, 3);
	asph_scanfile_free(s);

	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_read(tmp_path("absent.scan"), &s, &err), -ENOENT);
	assert_non_null(strstr(err.source, "absent.scan"));
	assert_true(asph_scanfile_read(tmpdir, &s, &err) < 0);
	free(c);
	free(b);
	unlink(path);
}

/* Arbitrary damage never crashes or hangs the reader and never invents
 * points. */
static void test_mutations(void **state)
{
	const char *path = tmp_path("mut.scan");
	size_t len;

	make_scan(path, 5, 17, ASPH_SCANFILE_COMPLETED, "ok");
	uint8_t *b = slurp(path, &len);
	uint8_t *c = malloc(len + 64);
	uint64_t x = 0x2545f4914f6cdd1dull;
	int n_iter = getenv("ASPH_UNDER_VALGRIND") ? 300 : 3000;

	for (int it = 0; it < n_iter; it++) {
		size_t n = len;
		memcpy(c, b, len);
		for (int k = 0; k < 1 + it % 4; k++) {
			x ^= x << 13, x ^= x >> 7, x ^= x << 17;
			size_t at = (size_t)(x >> 16) % n;
			switch (x % 4) {
			case 0: c[at] ^= (uint8_t)(x >> 8) | 1; break;
			case 1: n = at; break;
			case 2: c[at] = 0xff; break;
			default: put32(c + (at & ~(size_t)3) - ((at & ~(size_t)3) + 4 > n ? 4 : 0),
					(uint32_t)(x >> 32)); break;
			}
			if (n < 8)
				break;
		}
		struct asph_scanfile *s = NULL;
		struct asph_error err;
		int r = asph_scanfile_read_memory(c, n, "mut", &s, &err);
		if (r < 0) {
			assert_true(r == -EBADMSG || r == -ENOTSUP);
			continue;
		}
		assert_true(s->n <= 17);
		assert_true(s->report.valid_bytes + s->report.discarded_bytes == n);
		for (size_t i = 0; i < s->n; i++) {
			struct asph_scanfile_point e = pattern(i);
			/* damage that keeps the checksum is not expected from
			 * one random byte, so every kept point is intact */
			assert_int_equal(s->points[i].t_ns, e.t_ns);
		}
		asph_scanfile_free(s);
	}
	free(c);
	free(b);
	unlink(path);
}

static void test_create_errors(void **state)
{
	const char *path = tmp_path("create.scan");
	struct asph_scanfile_writer *w = NULL;
	struct asph_error err;
	struct asph_scanfile_header_info bad = info;

	bad.plan = NULL;
	assert_int_equal(asph_scanfile_writer_create(path, &bad, NULL, &w, &err), -EINVAL);
	assert_string_equal(err.field, "plan");
	bad = info;
	bad.instrument = "{\"stage\": [1, 2,, 3]}";
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_create(path, &bad, NULL, &w, &err), -EINVAL);
	assert_string_equal(err.field, "instrument");
	assert_int_equal(err.line, 1);
	assert_true(err.column >= 16 && err.column <= 18);
	bad = info;
	bad.prescription = "[1]";
	assert_int_equal(asph_scanfile_writer_create(path, &bad, NULL, &w, &err), -EINVAL);
	assert_string_equal(err.field, "prescription");
	assert_int_equal(access(path, F_OK), -1);

	struct asph_scanfile_writer_options o = { .block_points = ASPH_SCANFILE_MAX_BLOCK_POINTS + 1 };
	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), -EINVAL);

	/* metadata is optional */
	bad = info;
	bad.metadata = NULL;
	assert_int_equal(asph_scanfile_writer_create(path, &bad, NULL, &w, &err), 0);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	struct asph_scanfile *s;
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_string_equal(s->header.metadata, "{}");
	assert_int_equal(s->n, 0);
	assert_int_equal(s->report.n_blocks, 0);
	asph_scanfile_free(s);

	/* no overwrite unless asked */
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, &err), -EEXIST);
	assert_string_equal(err.source, path);
	o.block_points = 0;
	o.flags = ASPH_SCANFILE_OVERWRITE;
	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);

	/* one writer at a time */
	struct asph_scanfile_writer *w2 = NULL;
	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w2, &err), -EBUSY);
	assert_int_equal(asph_scanfile_writer_resume(path, NULL, NULL, &w2, &err), -EBUSY);
	assert_null(w2);

	/* non-finite coordinates need the out-of-range flag */
	struct asph_scanfile_point p[2] = { pattern(0), pattern(1) };
	p[1].z = NAN;
	assert_int_equal(asph_scanfile_writer_append(w, p, 2, &err), -EINVAL);
	assert_int_equal(asph_scanfile_writer_n_points(w), 0);
	p[1].flags |= ASPH_SCANFILE_POINT_OUT_OF_RANGE;
	assert_int_equal(asph_scanfile_writer_append(w, p, 2, &err), 0);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_UNFINISHED, NULL, &err),
			 -EINVAL);
	assert_int_equal(asph_scanfile_writer_close(NULL, &err), 0);
	unlink(path);
}

static void test_dev_full(void **state)
{
	struct asph_scanfile_writer_options o = { .flags = ASPH_SCANFILE_OVERWRITE };
	struct asph_scanfile_writer *w = NULL;
	struct asph_error err;

	if (access("/dev/full", W_OK) < 0)
		skip();
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_create("/dev/full", &info, &o, &w, &err), -ENOSPC);
	assert_null(w);
	assert_non_null(strstr(err.message, "writing the header"));
	assert_int_equal(access("/dev/full", W_OK), 0);
}

/* A write that fails half-way (file size limit) is cut off again; the
 * writer keeps returning the first error; the file reads clean. */
static void test_write_error(void **state)
{
	const char *path = tmp_path("efbig.scan");
	struct asph_scanfile_writer_options o = { .block_points = 7 };
	struct asph_scanfile_writer *w;
	struct asph_error err;
	struct rlimit old, lim;
	size_t blk = BLOCK_OVERHEAD + 7 * RECORD;

	assert_int_equal(asph_scanfile_writer_create(path, &info, &o, &w, &err), 0);
	struct stat st;
	assert_int_equal(stat(path, &st), 0);
	size_t h = (size_t)st.st_size;

	assert_int_equal(getrlimit(RLIMIT_FSIZE, &old), 0);
	lim = old;
	lim.rlim_cur = h + 2 * blk + blk / 2;
	if (old.rlim_max != RLIM_INFINITY && old.rlim_max < lim.rlim_cur)
		skip();
	void (*prev)(int) = signal(SIGXFSZ, SIG_IGN);
	assert_int_equal(setrlimit(RLIMIT_FSIZE, &lim), 0);

	struct asph_scanfile_point p[21];
	for (int i = 0; i < 21; i++)
		p[i] = pattern((uint64_t)i);
	int r = asph_scanfile_writer_append(w, p, 21, &err);
	assert_int_equal(setrlimit(RLIMIT_FSIZE, &old), 0);
	signal(SIGXFSZ, prev);

	assert_int_equal(r, -EFBIG);
	assert_int_equal(err.code, -EFBIG);
	assert_int_equal(asph_scanfile_writer_n_synced(w), 14);
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_append(w, p, 1, &err), -EFBIG);
	assert_non_null(strstr(err.message, "writing a block"));
	assert_int_equal(asph_scanfile_writer_flush(w, &err), -EFBIG);
	assert_int_equal(asph_scanfile_writer_tick(w, &err), -EFBIG);

	/* readable up to the last good block while still open */
	struct asph_scanfile *s;
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 14);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_END);
	assert_int_equal(s->report.file_size, h + 2 * blk);
	asph_scanfile_free(s);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_FAILED, "disk", &err), -EFBIG);
	assert_int_equal(count_on_disk(path), 14);
	unlink(path);
}

static json_t *event(const struct asph_scanfile *s, size_t i)
{
	assert_true(i < s->n_events);
	json_t *e = json_loads(s->events[i], 0, NULL);
	assert_non_null(e);
	return e;
}

static void test_resume(void **state)
{
	const char *path = tmp_path("resume.scan");
	struct fake_clock clk = { 31337 };
	struct asph_scanfile_writer_options o = {
		.block_points = 7, .clock = fake_now, .clock_data = &clk,
	};
	struct asph_scanfile_writer *w;
	struct asph_scanfile *rec = NULL, *s;
	struct asph_error err;
	size_t blk = BLOCK_OVERHEAD + 7 * RECORD;

	make_scan(path, 7, 19, ASPH_SCANFILE_UNFINISHED, NULL);
	struct stat st;
	assert_int_equal(stat(path, &st), 0);
	/* tear the last block (5 points) */
	assert_int_equal(truncate(path, st.st_size - 50), 0);
	size_t tail = (size_t)st.st_size - 50 - (size_t)(st.st_size - 5 * RECORD - BLOCK_OVERHEAD);

	assert_int_equal(asph_scanfile_writer_resume(path, &o, &rec, &w, &err), 0);
	assert_pattern(rec, 14);
	assert_int_equal(rec->report.stop, ASPH_SCANFILE_STOP_TORN);
	assert_int_equal(rec->report.discarded_bytes, tail);
	assert_int_equal(asph_scanfile_writer_n_points(w), 14);
	assert_int_equal(asph_scanfile_writer_n_synced(w), 14);
	assert_true(asph_scanfile_writer_elapsed_ns(w) >= rec->points[13].t_ns);
	asph_scanfile_free(rec);

	append_pattern(w, 14, 10);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED, NULL, &err), 0);
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 24);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_END);
	assert_true(s->report.ended);
	assert_int_equal(s->report.n_resumes, 1);
	/* blocks: 2 + resume + 2 + end */
	assert_int_equal(s->report.n_blocks, 6);
	json_t *e = event(s, 0);
	assert_string_equal(json_string_value(json_object_get(e, "event")), "resume");
	assert_string_equal(json_string_value(json_object_get(e, "stop")), "torn");
	assert_int_equal(json_integer_value(json_object_get(e, "discarded_bytes")), tail);
	assert_int_equal(json_integer_value(json_object_get(e, "points")), 14);
	assert_null(json_object_get(e, "previous_outcome"));
	json_decref(e);
	asph_scanfile_free(s);

	/* a completed scan never resumes */
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_resume(path, &o, NULL, &w, &err), -EALREADY);
	assert_non_null(strstr(err.message, "completed"));
	o.flags = ASPH_SCANFILE_REOPEN_ENDED;
	assert_int_equal(asph_scanfile_writer_resume(path, &o, NULL, &w, &err), -EALREADY);

	/* a failed one does when asked; its end block goes into the record */
	make_scan(path, 7, 9, ASPH_SCANFILE_FAILED, "stage limit hit");
	o.flags = 0;
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_resume(path, &o, NULL, &w, &err), -EALREADY);
	assert_non_null(strstr(err.message, "failed: stage limit hit"));
	o.flags = ASPH_SCANFILE_REOPEN_ENDED;
	assert_int_equal(asph_scanfile_writer_resume(path, &o, NULL, &w, &err), 0);
	append_pattern(w, 9, 3);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 12);
	assert_false(s->report.ended);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_END);
	e = event(s, 0);
	assert_string_equal(json_string_value(json_object_get(e, "previous_outcome")), "failed");
	assert_string_equal(json_string_value(json_object_get(e, "previous_reason")),
			    "stage limit hit");
	assert_string_equal(json_string_value(json_object_get(e, "stop")), "end");
	json_decref(e);
	asph_scanfile_free(s);

	/* resuming twice, with nothing to cut */
	assert_int_equal(asph_scanfile_writer_resume(path, &o, NULL, &w, &err), 0);
	append_pattern(w, 12, 2);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 14);
	assert_int_equal(s->report.n_resumes, 2);
	e = event(s, 1);
	assert_int_equal(json_integer_value(json_object_get(e, "discarded_bytes")), 0);
	json_decref(e);
	asph_scanfile_free(s);

	/* damage with valid blocks after it: nothing is cut */
	make_scan(path, 7, 21, ASPH_SCANFILE_UNFINISHED, NULL);
	size_t len;
	uint8_t *b = slurp(path, &len);
	size_t mid = header_end(b) + blk + 100;
	b[mid] ^= 0x10;
	spit(path, b, len);
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_resume(path, &o, NULL, &w, &err), -EBADMSG);
	assert_non_null(strstr(err.message, "valid block follows"));
	assert_int_equal(stat(path, &st), 0);
	assert_int_equal((size_t)st.st_size, len);
	/* damage in the last block: cut */
	b[mid] ^= 0x10;
	b[len - 3] ^= 0x10;
	spit(path, b, len);
	assert_int_equal(asph_scanfile_writer_resume(path, &o, &rec, &w, &err), 0);
	assert_int_equal(rec->report.stop, ASPH_SCANFILE_STOP_CHECKSUM);
	assert_pattern(rec, 14);
	asph_scanfile_free(rec);
	append_pattern(w, 14, 7);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	assert_int_equal(count_on_disk(path), 21);
	free(b);
	unlink(path);
}

static void test_export(void **state)
{
	const char *path = tmp_path("export.scan");
	const char *csv = tmp_path("export.csv");
	const char *ply = tmp_path("export.ply");
	struct asph_scanfile_writer *w;
	struct asph_scanfile *s;
	struct asph_points *pts;
	struct asph_error err;
	struct asph_scanfile_point p[40];

	for (int i = 0; i < 40; i++) {
		p[i] = pattern((uint64_t)i);
		p[i].y = 0.5 + 0.25 * i;   /* a normal number instead of a subnormal */
		if (i % 9 == 4) {
			p[i].flags |= ASPH_SCANFILE_POINT_OUT_OF_RANGE;
			p[i].z = NAN;
		}
		if (i % 11 == 2)
			p[i].flags |= ASPH_SCANFILE_POINT_LOW_SIGNAL;
	}
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, &err), 0);
	assert_int_equal(asph_scanfile_writer_append(w, p, 40, &err), 0);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED, NULL, &err), 0);
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);

	for (int pass = 0; pass < 2; pass++) {
		uint32_t excl = pass ? ASPH_SCANFILE_POINT_LOW_SIGNAL : 0;
		assert_int_equal(asph_scanfile_to_points(s, excl, &pts, &err), 0);
		size_t k = 0;
		for (int i = 0; i < 40; i++) {
			if (p[i].flags & (ASPH_SCANFILE_POINT_OUT_OF_RANGE | excl))
				continue;
			assert_true(k < pts->n);
			assert_int_equal(bits(pts->xyz[3 * k]), bits(p[i].x));
			assert_int_equal(bits(pts->xyz[3 * k + 1]), bits(p[i].y));
			assert_int_equal(bits(pts->xyz[3 * k + 2]), bits(p[i].z));
			k++;
		}
		assert_int_equal(k, pts->n);
		assert_int_equal(k, pass ? 40 - 4 - 3 : 40 - 4);   /* 4, 13, 22, 31; 2, 24, 35 */
		asph_points_free(pts);
	}

	struct asph_scanfile_report rep;
	const char *outs[] = { csv, ply };
	for (int f = 0; f < 2; f++) {
		struct asph_points *direct;
		assert_int_equal(asph_scanfile_export(path, outs[f], 0, &rep, &err), 0);
		assert_true(rep.ended);
		assert_null(rep.reason);
		assert_int_equal(asph_points_read(outs[f], &pts, &err), 0);
		assert_int_equal(asph_scanfile_to_points(s, 0, &direct, &err), 0);
		assert_int_equal(pts->n, direct->n);
		for (size_t i = 0; i < 3 * pts->n; i++)
			assert_int_equal(bits(pts->xyz[i]), bits(direct->xyz[i]));
		asph_points_free(direct);
		asph_points_free(pts);
		unlink(outs[f]);
	}

	/* a kept point must be finite */
	s->points[3].x = INFINITY;
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_to_points(s, 0, &pts, &err), -EBADMSG);
	assert_non_null(strstr(err.message, "point 3"));
	asph_scanfile_free(s);
	unlink(path);
}

/* Kill a writer with SIGKILL: every point it had flushed is in the file. */
static void test_sigkill(void **state)
{
	const char *path = tmp_path("killed.scan");
	int fds[2];
	const uint64_t per_flush = 1000;
	uint64_t reported = 0, v;

	assert_int_equal(pipe(fds), 0);
	pid_t pid = fork();
	assert_true(pid >= 0);
	if (pid == 0) {
		struct asph_scanfile_writer_options o = { .block_points = 4000 };
		struct asph_scanfile_writer *w;
		struct asph_scanfile_point p[100];
		close(fds[0]);
		/* never outlive a parent whose assertion failed */
		prctl(PR_SET_PDEATHSIG, SIGKILL);
		if (asph_scanfile_writer_create(path, &info, &o, &w, NULL) < 0)
			_exit(1);
		for (uint64_t i = 0; i < 5000000; i += 100) {
			for (uint64_t k = 0; k < 100; k++)
				p[k] = pattern(i + k);
			if (asph_scanfile_writer_append(w, p, 100, NULL) < 0)
				_exit(2);
			if ((i + 100) % per_flush == 0) {
				if (asph_scanfile_writer_flush(w, NULL) < 0)
					_exit(3);
				v = i + 100;
				if (write(fds[1], &v, sizeof(v)) != sizeof(v))
					_exit(4);
			}
		}
		_exit(5);
	}
	close(fds[1]);
	while (reported < 20 * per_flush) {
		assert_int_equal(read(fds[0], &v, sizeof(v)), sizeof(v));
		reported = v;
	}
	assert_int_equal(kill(pid, SIGKILL), 0);
	int status;
	assert_int_equal(waitpid(pid, &status, 0), pid);
	assert_true(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
	while (read(fds[0], &v, sizeof(v)) == sizeof(v))
		reported = v;
	close(fds[0]);

	struct asph_scanfile *s;
	struct asph_error err;
	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_true(s->n >= reported);
	assert_pattern(s, s->n);
	assert_false(s->report.ended);
	assert_true(s->report.stop == ASPH_SCANFILE_STOP_END ||
		    s->report.stop == ASPH_SCANFILE_STOP_TORN);
	asph_scanfile_free(s);
	unlink(path);
}

static void test_unknown_block_skipped(void **state)
{
	const char *path = tmp_path("unknown.scan");
	size_t len;

	make_scan(path, 7, 10, ASPH_SCANFILE_UNFINISHED, NULL);
	uint8_t *b = slurp(path, &len);
	uint8_t *c = malloc(len + 36 + 5);
	memcpy(c, b, len);
	uint8_t *k = c + len;
	memcpy(k, "ASPB", 4);
	k[4] = 0x42, k[5] = 0;               /* a type from a newer minor version */
	k[6] = k[7] = 0;
	memset(k + 8, 0, 24);
	k[8] = 2;                            /* sequence */
	k[16] = 10;                          /* first point */
	put32(k + 28, 5);
	memcpy(k + 32, "hello", 5);
	put32(k + 37, crc32c(0, k, 37));
	struct asph_scanfile *s;
	struct asph_error err;
	assert_int_equal(asph_scanfile_read_memory(c, len + 41, "mem", &s, &err), 0);
	assert_pattern(s, 10);
	assert_int_equal(s->report.n_blocks, 3);
	assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_END);
	assert_int_equal(s->report.valid_bytes, len + 41);
	asph_scanfile_free(s);
	free(c);
	free(b);
	unlink(path);
}

/* The reader interface, block by block. */
static void test_reader_blocks(void **state)
{
	const char *path = tmp_path("iter.scan");
	struct asph_scanfile_reader *r;
	const struct asph_scanfile_point *p;
	struct asph_error err;
	size_t n, total = 0, blocks = 0;

	make_scan(path, 6, 20, ASPH_SCANFILE_ABORTED, "operator");
	assert_int_equal(asph_scanfile_reader_open(path, &r, &err), 0);
	assert_json_same(asph_scanfile_reader_header(r)->instrument, instrument);
	int ret;
	while ((ret = asph_scanfile_reader_next(r, &p, &n, &err)) == 1) {
		assert_int_equal(n, blocks < 3 ? 6 : 2);
		for (size_t i = 0; i < n; i++) {
			struct asph_scanfile_point e = pattern(total + i);
			assert_point_eq(&p[i], &e);
		}
		total += n;
		blocks++;
	}
	assert_int_equal(ret, 0);
	assert_int_equal(asph_scanfile_reader_next(r, &p, &n, &err), 0);
	assert_int_equal(total, 20);
	const struct asph_scanfile_report *rep = asph_scanfile_reader_report(r);
	assert_int_equal(rep->outcome, ASPH_SCANFILE_ABORTED);
	assert_string_equal(rep->reason, "operator");
	assert_int_equal(rep->n_points, 20);
	asph_scanfile_reader_free(r);
	unlink(path);
}

/* A prescription goes through the header and parses back to the same
 * bits, which replay needs to reproduce a fit exactly. */
static void test_prescription_through_header(void **state)
{
	const char *path = tmp_path("lens.scan");
	struct asph_prescription p, q;
	struct asph_scanfile_header_info hi = info;
	struct asph_scanfile_writer_options o = { .flags = ASPH_SCANFILE_OVERWRITE };
	struct asph_error err;

	assert_int_equal(asph_prescription_preset("turning-point", &p), 0);
	p.R = 94.6 + 1.0 / 3.0;
	p.A[4] = -6.86465e-6 * M_PI;
	p.A[8] = nextafter(2.22491e-11, 1.0);
	for (int pass = 0; pass < 2; pass++) {
		char *text = NULL;
		struct asph_scanfile_writer *w;
		struct asph_scanfile *s;
		if (pass)
			assert_int_equal(asph_prescription_preset("weak", &p), 0);
		assert_int_equal(asph_prescription_to_json(&p, &text), 0);
		hi.prescription = text;
		assert_int_equal(asph_scanfile_writer_create(path, &hi, &o, &w, &err), 0);
		assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
		free(text);
		assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
		assert_int_equal(asph_prescription_parse(s->header.prescription,
							 strlen(s->header.prescription),
							 path, &q, &err), 0);
		asph_scanfile_free(s);
		assert_int_equal(q.type, p.type);
		assert_string_equal(q.name, p.name);
		assert_int_equal(bits(q.R), bits(p.R));
		assert_int_equal(bits(q.k), bits(p.k));
		assert_int_equal(bits(q.aperture_diameter), bits(p.aperture_diameter));
		for (int i = 0; i <= ASPH_SURFACE_MAX_POWER; i++)
			assert_int_equal(bits(q.A[i]), bits(p.A[i]));
	}
	unlink(path);
}

static int setup(void **state)
{
	snprintf(tmpdir, sizeof(tmpdir), "/tmp/test-scanfile-XXXXXX");
	return mkdtemp(tmpdir) ? 0 : -1;
}

static int teardown(void **state)
{
	DIR *d = opendir(tmpdir);
	struct dirent *e;

	while (d && (e = readdir(d))) {
		if (e->d_name[0] != '.')
			unlink(tmp_path(e->d_name));
	}
	if (d)
		closedir(d);
	return rmdir(tmpdir);
}

/* Reference measurements (1.1): blocks of their own, in measurement order
 * between the points, not counted as points; a resumed scan keeps them. */
static void test_references(void **state)
{
	const char *path = tmp_path("refs.scan");
	struct asph_scanfile_writer *w;
	struct asph_scanfile *s;
	struct asph_error err;
	struct asph_scanfile_point ref[3];

	for (int i = 0; i < 3; i++)
		ref[i] = pattern(900 + (uint64_t)i);
	ref[1].flags = ASPH_SCANFILE_POINT_INVALID;
	ref[1].z = NAN;
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, &err), 0);
	assert_int_equal(asph_scanfile_writer_append_references(w, ref, 1, &err), 0);
	append_pattern(w, 0, 17);
	assert_int_equal(asph_scanfile_writer_append_references(w, ref + 1, 2, &err), 0);
	append_pattern(w, 17, 5);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	/* resumed: the references stay, and more come */
	assert_int_equal(asph_scanfile_writer_resume(path, NULL, &s, &w, &err), 0);
	assert_int_equal(s->n_references, 3);
	asph_scanfile_free(s);
	assert_int_equal(asph_scanfile_writer_append_references(w, ref, 1, &err), 0);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED, NULL, &err), 0);

	assert_int_equal(asph_scanfile_read(path, &s, &err), 0);
	assert_pattern(s, 22);
	assert_int_equal(s->report.n_points, 22);
	assert_int_equal(s->report.n_references, 4);
	assert_int_equal(s->n_references, 4);
	assert_point_eq(&s->references[0], &ref[0]);
	assert_point_eq(&s->references[2], &ref[2]);
	assert_point_eq(&s->references[3], &ref[0]);
	assert_true(isnan(s->references[1].z));
	assert_true(s->report.ended);
	asph_scanfile_free(s);

	/* a measured reference without coordinates is refused */
	ref[0].x = NAN;
	assert_int_equal(asph_scanfile_writer_create(path, &info,
		&(struct asph_scanfile_writer_options){ .flags = ASPH_SCANFILE_OVERWRITE }, &w, &err), 0);
	assert_int_equal(asph_scanfile_writer_append_references(w, ref, 1, &err), -EINVAL);
	asph_scanfile_writer_close(w, NULL);
	unlink(path);
}

/* Scans the 1.0 writer wrote (tests/data/scan-1.0) read: 56-byte records,
 * no position source, no stage position. */
static void test_version_1_0_files(void **state)
{
	static const struct {
		const char *name;
		size_t n;
		unsigned resumes;
		uint32_t flags_of_11;   /* the tactile one: reading 12 out of range */
	} files[] = {
		{ "v10-completed.asphscan", 60, 0, 0 },
		{ "v10-tactile.asphscan", 40, 0, ASPH_SCANFILE_POINT_OUT_OF_RANGE },
		{ "v10-resumed.asphscan", 50, 1, 0 },
	};
	const char *data = getenv("ASPH_TEST_DATA");
	char path[512];

	if (!data)
		skip();
	for (size_t i = 0; i < sizeof(files) / sizeof(files[0]); i++) {
		struct asph_scanfile *s;
		struct asph_error err;
		snprintf(path, sizeof(path), "%s/scan-1.0/%s", data, files[i].name);
		if (asph_scanfile_read(path, &s, &err) < 0)
			fail_msg("%s: %s", path, err.message);
		assert_int_equal(s->header.version_major, 1);
		assert_int_equal(s->header.version_minor, 0);
		assert_int_equal(s->n, files[i].n);
		assert_int_equal(s->report.n_resumes, files[i].resumes);
		assert_int_equal(s->report.stop, ASPH_SCANFILE_STOP_END);
		assert_int_equal(s->report.outcome, ASPH_SCANFILE_COMPLETED);
		assert_int_equal(s->n_references, 0);
		assert_int_equal(s->points[11].flags, files[i].flags_of_11);
		for (size_t k = 0; k < s->n; k++) {
			assert_int_equal(s->points[k].position_source, ASPH_SCANFILE_POSITION_UNKNOWN);
			assert_true(isnan(s->points[k].stage[0]) && isnan(s->points[k].stage[2]));
		}
		asph_scanfile_free(s);
	}
}

/* A resumed scan's times go on from the scan's start, not from 1970. */
static void test_resumed_times(void **state)
{
	const char *path = tmp_path("times.scan");
	struct asph_scanfile_writer *w;
	struct asph_scanfile *s;
	struct asph_error err;

	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, &err), 0);
	append_pattern(w, 0, 3);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	assert_int_equal(asph_scanfile_writer_resume(path, NULL, &s, &w, &err), 0);
	/* the pattern's last point is at 2.000006 ms; the file is younger
	 * than a minute */
	uint64_t t = asph_scanfile_writer_elapsed_ns(w);
	assert_true(t >= s->points[2].t_ns && t < 60 * (uint64_t)1000000000);
	asph_scanfile_free(s);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	unlink(path);
}

/* Relative to a directory descriptor: the same file, and never through a
 * symlink planted at the name (to a file the test cares about). */
static void test_at_no_symlinks(void **state)
{
	static const uint8_t precious[] = "not a scan, must stay";
	int dirfd = open(tmpdir, O_RDONLY | O_DIRECTORY);
	struct asph_scanfile_writer *w = NULL;
	struct asph_scanfile_reader *r = NULL;
	struct asph_scanfile *s;
	struct asph_error err;
	uint8_t *back;
	size_t len;

	assert_true(dirfd >= 0);
	assert_int_equal(asph_scanfile_writer_create_at(dirfd, "at.scan", &info, NULL, &w, &err), 0);
	append_pattern(w, 0, 12);
	assert_int_equal(asph_scanfile_writer_close(w, &err), 0);
	assert_int_equal(asph_scanfile_read(tmp_path("at.scan"), &s, &err), 0);
	assert_pattern(s, 12);
	asph_scanfile_free(s);
	assert_int_equal(asph_scanfile_writer_resume_at(dirfd, "at.scan", NULL, NULL, &w, &err), 0);
	append_pattern(w, 12, 3);
	assert_int_equal(asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED, NULL, &err), 0);
	assert_int_equal(asph_scanfile_reader_open_at(dirfd, "at.scan", &r, &err), 0);
	asph_scanfile_reader_free(r);

	spit(tmp_path("victim"), precious, sizeof(precious));
	assert_int_equal(symlink(tmp_path("victim"), tmp_path("link.scan")), 0);
	asph_error_clear(&err);
	assert_int_equal(asph_scanfile_writer_create_at(dirfd, "link.scan", &info,
			 &(struct asph_scanfile_writer_options){ .flags = ASPH_SCANFILE_OVERWRITE },
			 &w, &err), -ELOOP);
	assert_int_equal(asph_scanfile_writer_resume_at(dirfd, "link.scan", NULL, NULL, &w, &err),
			 -ELOOP);
	assert_int_equal(asph_scanfile_reader_open_at(dirfd, "link.scan", &r, &err), -ELOOP);
	back = slurp(tmp_path("victim"), &len);
	assert_int_equal(len, sizeof(precious));
	assert_memory_equal(back, precious, len);
	free(back);
	close(dirfd);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_crc32c),
		cmocka_unit_test(test_at_no_symlinks),
		cmocka_unit_test(test_names),
		cmocka_unit_test(test_round_trip),
		cmocka_unit_test(test_layout),
		cmocka_unit_test(test_flush_by_count),
		cmocka_unit_test(test_flush_by_time),
		cmocka_unit_test(test_torn_tail),
		cmocka_unit_test(test_corrupt_byte),
		cmocka_unit_test(test_bad_files),
		cmocka_unit_test(test_mutations),
		cmocka_unit_test(test_create_errors),
		cmocka_unit_test(test_dev_full),
		cmocka_unit_test(test_write_error),
		cmocka_unit_test(test_resume),
		cmocka_unit_test(test_export),
		cmocka_unit_test(test_sigkill),
		cmocka_unit_test(test_unknown_block_skipped),
		cmocka_unit_test(test_reader_blocks),
		cmocka_unit_test(test_prescription_through_header),
		cmocka_unit_test(test_references),
		cmocka_unit_test(test_version_1_0_files),
		cmocka_unit_test(test_resumed_times),
	};
	return cmocka_run_group_tests(tests, setup, teardown);
}
