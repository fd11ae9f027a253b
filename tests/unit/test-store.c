/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "rmtree.h"
#include "store.h"

struct fixture {
	char dir[64];
	char path[128];
	struct store *s;
};

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));

	snprintf(f->dir, sizeof(f->dir), "/tmp/test-store-XXXXXX");
	if (!mkdtemp(f->dir))
		return -1;
	snprintf(f->path, sizeof(f->path), "%s/jobs.sqlite", f->dir);
	if (store_open(f->path, &f->s, NULL) < 0)
		return -1;
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;
	store_close(f->s);
	if (rmtree(f->dir) < 0)
		return -1;
	free(f);
	return 0;
}

static int64_t add(struct store *s, const char *instrument, int64_t prio, const char *label)
{
	struct job_record j = {
		.state = JOB_QUEUED, .priority = prio, .label = (char *)label,
		.instrument = (char *)instrument, .uid = 1013, .user = (char *)"anna",
		.spec = (char *)"{\"lens\":{}}", .points_total = 4321,
	};
	assert_int_equal(store_insert(s, &j, 1763700000123456789LL), 0);
	assert_true(j.id > 0);
	return j.id;
}

/* Priority first, then submission order, per instrument. */
static void test_queue_order(void **state)
{
	struct fixture *f = *state;
	int64_t a = add(f->s, "m1", 0, "a"), b = add(f->s, "m1", 3, "b");
	int64_t c = add(f->s, "m2", 9, "c"), d = add(f->s, "m1", 3, "d");
	struct job_record j;

	assert_int_equal(store_next(f->s, "m1", &j), 0);
	assert_int_equal(j.id, b);
	assert_string_equal(j.user, "anna");
	assert_int_equal(j.points_total, 4321);
	assert_int_equal(j.submitted_ns, 1763700000123456789LL);
	job_record_clear(&j);
	assert_int_equal(store_set_state(f->s, b, JOB_RUNNING, NULL, 0, NULL, 5), 0);
	assert_int_equal(store_next(f->s, "m1", &j), 0);
	assert_int_equal(j.id, d);
	job_record_clear(&j);
	assert_int_equal(store_next(f->s, "m2", &j), 0);
	assert_int_equal(j.id, c);
	job_record_clear(&j);
	assert_int_equal(store_next(f->s, "m3", &j), -ENOENT);
	(void)a;
}

static int count_events(const struct store_event *e, void *data)
{
	int *n = data;

	if (*n == 1) {
		assert_int_equal(e->state, JOB_RUNNING);
		assert_int_equal(e->actor_uid, 77);
	}
	if (*n == 2) {
		assert_int_equal(e->state, JOB_INTERRUPTED);
		assert_non_null(e->reason);
	}
	(*n)++;
	return 0;
}

/* Jobs running at a crash come back interrupted and resumable, with the
 * transition in their history; the store survives reopening. */
static void test_recover(void **state)
{
	struct fixture *f = *state;
	int64_t a = add(f->s, "m1", 0, NULL), b = add(f->s, "m1", 0, NULL);
	struct job_record j;
	int64_t counts[JOB_N_STATES];
	int n = 0;

	assert_int_equal(store_get(f->s, a, &j), 0);
	free(j.scan_path);
	j.scan_path = strdup("jobs/1/scan.asphscan");
	assert_int_equal(store_update(f->s, &j), 0);
	job_record_clear(&j);
	assert_int_equal(store_set_state(f->s, a, JOB_RUNNING, NULL, 77, NULL, 6), 0);
	assert_int_equal(store_set_state(f->s, b, JOB_PAUSED, NULL, 77, NULL, 7), 0);
	store_close(f->s);
	assert_int_equal(store_open(f->path, &f->s, NULL), 0);
	assert_int_equal(store_recover(f->s, 8), 2);
	assert_int_equal(store_get(f->s, a, &j), 0);
	assert_int_equal(j.state, JOB_INTERRUPTED);
	assert_true(j.resume);
	job_record_clear(&j);
	assert_int_equal(store_get(f->s, b, &j), 0);
	assert_false(j.resume);  /* nothing recorded: nothing to continue */
	job_record_clear(&j);
	assert_int_equal(store_history(f->s, a, count_events, &n), 0);
	assert_int_equal(n, 3);
	assert_int_equal(store_count(f->s, counts), 0);
	assert_int_equal(counts[JOB_INTERRUPTED], 2);
	assert_int_equal(counts[JOB_QUEUED], 0);
	assert_int_equal(store_get(f->s, 999, &j), -ENOENT);
}

static int collect(const struct job_record *j, void *data)
{
	int64_t *ids = data;

	while (*ids)
		ids++;
	*ids = j->id;
	return 0;
}

static void test_list(void **state)
{
	struct fixture *f = *state;
	int64_t id[6], got[8] = { 0 }, total = 0;
	struct store_filter flt = { .uid = STORE_ANY_UID, .limit = 2, .offset = 1 };

	for (int i = 0; i < 6; i++)
		id[i] = add(f->s, i % 2 ? "m1" : "m2", 0, i < 3 ? "x" : "y");
	assert_int_equal(store_set_state(f->s, id[4], JOB_FAILED, "stage fault", 0, NULL, 9), 0);
	/* newest first, paged */
	assert_int_equal(store_list(f->s, &flt, collect, got, &total), 0);
	assert_int_equal(total, 6);
	assert_int_equal(got[0], id[4]);
	assert_int_equal(got[1], id[3]);
	assert_int_equal(got[2], 0);
	/* by state, instrument, label */
	memset(got, 0, sizeof(got));
	flt = (struct store_filter){ .uid = STORE_ANY_UID, .states = 1u << JOB_QUEUED, .instrument = "m2",
				     .label = "x" };
	assert_int_equal(store_list(f->s, &flt, collect, got, &total), 0);
	assert_int_equal(total, 2);
	assert_int_equal(got[0], id[2]);
	assert_int_equal(got[1], id[0]);
	flt = (struct store_filter){ .uid = 4242 };
	assert_int_equal(store_list(f->s, &flt, collect, got, &total), 0);
	assert_int_equal(total, 0);

	/* a pause keeps the reason of a fault; a re-queue starts afresh */
	struct job_record j;
	assert_int_equal(store_set_state(f->s, id[4], JOB_PAUSED, NULL, 0, NULL, 10), 0);
	assert_int_equal(store_get(f->s, id[4], &j), 0);
	assert_string_equal(j.reason, "stage fault");
	job_record_clear(&j);
	assert_int_equal(store_set_state(f->s, id[4], JOB_QUEUED, NULL, 0, NULL, 11), 0);
	assert_int_equal(store_set_state(f->s, id[4], JOB_COMPLETED, NULL, 0, NULL, 12), 0);
	assert_int_equal(store_get(f->s, id[4], &j), 0);
	assert_null(j.reason);
	job_record_clear(&j);
}

static void test_meta_and_schema(void **state)
{
	struct fixture *f = *state;
	char *v = NULL;
	struct store *s2 = NULL;
	struct asph_error err;

	assert_int_equal(store_meta_get(f->s, "queue.running", &v), -ENOENT);
	assert_int_equal(store_meta_set(f->s, "queue.running", "0"), 0);
	assert_int_equal(store_meta_set(f->s, "queue.running", "1"), 0);
	assert_int_equal(store_meta_get(f->s, "queue.running", &v), 0);
	assert_string_equal(v, "1");
	free(v);
	/* a store written by a newer daemon is not touched */
	assert_int_equal(store_meta_set(f->s, "schema", "99"), 0);
	assert_int_equal(store_open(f->path, &s2, &err), -EPROTO);
	assert_non_null(strstr(err.message, "99"));
	assert_int_equal(job_state_from_name("interrupted", &(enum job_state){ 0 }), 0);
	assert_int_equal(job_state_from_name("gone", &(enum job_state){ 0 }), -EINVAL);
	assert_true(job_state_final(JOB_CANCELLED));
	assert_false(job_state_final(JOB_INTERRUPTED));
}

/* A schema version that is not a plain decimal number from 1 on is a
 * damaged store: refused, never read as 0 (atoi) or clipped. */
static void test_schema_corrupt(void **state)
{
	static const char *const bad[] = {
		"", "x", "1x", " 1", "+1", "-3", "0", "0x1", "1.0",
		"99999999999999999999999",
	};
	struct fixture *f = *state;
	struct store *s2 = NULL;
	struct asph_error err;

	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
		assert_int_equal(store_meta_set(f->s, "schema", bad[i]), 0);
		asph_error_clear(&err);
		assert_int_equal(store_open(f->path, &s2, &err), -EPROTO);
		assert_null(s2);
		assert_non_null(strstr(err.message, "is not a number from 1 on"));
	}
	/* a version with leading zeros is still that version: 1 is upgraded */
	assert_int_equal(store_meta_set(f->s, "schema", "001"), 0);
	assert_int_equal(store_open(f->path, &s2, &err), 0);
	store_close(s2);
	s2 = NULL;
	{
		char *v = NULL;
		assert_int_equal(store_meta_get(f->s, "schema", &v), 0);
		assert_string_equal(v, "2");
		free(v);
	}
	assert_int_equal(store_meta_set(f->s, "schema", "3"), 0);
	assert_int_equal(store_open(f->path, &s2, &err), -EPROTO);
	assert_non_null(strstr(err.message, "schema 3, newer than 2"));
}

/* A symlink in place of the store or of its write-ahead log: refused, and
 * the file it points at is left as it was. */
static void test_no_symlinks(void **state)
{
	struct fixture *f = *state;
	struct asph_error err;
	struct store *s2 = NULL;
	char other[128], link[160], victim[128];
	FILE *v;

	snprintf(victim, sizeof(victim), "%s/victim", f->dir);
	v = fopen(victim, "w");
	assert_non_null(v);
	fputs("precious", v);
	fclose(v);
	snprintf(other, sizeof(other), "%s/other.sqlite", f->dir);
	assert_int_equal(symlink(victim, other), 0);
	asph_error_clear(&err);
	assert_int_equal(store_open(other, &s2, &err), -ELOOP);
	assert_non_null(strstr(err.message, "not a regular file"));
	unlink(other);
	snprintf(link, sizeof(link), "%s-wal", other);
	assert_int_equal(symlink(victim, link), 0);
	assert_int_equal(store_open(other, &s2, &err), -ELOOP);
	v = fopen(victim, "r");
	char buf[16] = "";
	assert_non_null(fgets(buf, sizeof(buf), v));
	fclose(v);
	assert_string_equal(buf, "precious");
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_queue_order, setup, teardown),
		cmocka_unit_test_setup_teardown(test_recover, setup, teardown),
		cmocka_unit_test_setup_teardown(test_list, setup, teardown),
		cmocka_unit_test_setup_teardown(test_meta_and_schema, setup, teardown),
		cmocka_unit_test_setup_teardown(test_schema_corrupt, setup, teardown),
		cmocka_unit_test_setup_teardown(test_no_symlinks, setup, teardown),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
