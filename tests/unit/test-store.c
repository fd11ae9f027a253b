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

#include <dirent.h>
#include <sys/stat.h>

#include <cmocka.h>
#include <sqlite3.h>

#include "jobs-store.h"
#include "rmtree.h"
#include "store.h"
#include "store-schema.h"
#include "util-mem.h"

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

/* The number of rows query returns in db, its ?1 and ?2 bound to a and b. */
static int rows_of(sqlite3 *db, const char *query, const char *a, const char *b)
{
	sqlite3_stmt *st = NULL;
	int n = 0;

	assert_int_equal(sqlite3_prepare_v2(db, query, -1, &st, NULL), SQLITE_OK);
	sqlite3_bind_text(st, 1, a, -1, SQLITE_STATIC);
	sqlite3_bind_text(st, 2, b, -1, SQLITE_STATIC);
	while (sqlite3_step(st) == SQLITE_ROW)
		n++;
	sqlite3_finalize(st);
	return n;
}

/* What the statements sql create as "CREATE KIND IF NOT EXISTS NAME" is in
 * the store as an object of that type; their number. */
static int assert_created(sqlite3 *db, const char *module, const char *sql, const char *kind,
			  const char *type)
{
	char prefix[64], name[64];
	int n = 0;

	snprintf(prefix, sizeof(prefix), "CREATE %s IF NOT EXISTS ", kind);
	for (const char *p = sql ? strstr(sql, prefix) : NULL; p; p = strstr(p, prefix), n++) {
		p += strlen(prefix);
		snprintf(name, sizeof(name), "%.*s", (int)strcspn(p, " ("), p);
		if (rows_of(db, "SELECT 1 FROM sqlite_master WHERE type = ?1 AND name = ?2",
			    type, name) != 1)
			fail_msg("%s's %s %s is missing", module, type, name);
	}
	return n;
}

/* The modules with tables in the store, listed here again so that one
 * left out of store.c's list is noticed. */
static const struct store_schema *const modules[] = {
	&jobs_schema, &locks_schema, &tokens_schema, &outbox_schema,
};

/* The store at path holds the tables, indexes and columns of every
 * module's schema (store-schema.h) and meta, and nothing besides. */
static void assert_schema_is_modules(const char *path)
{
	sqlite3 *db = NULL;
	int named = 1;          /* meta, the store's own */

	assert_int_equal(sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL), SQLITE_OK);
	assert_int_equal(rows_of(db, "SELECT 1 FROM sqlite_master WHERE type = ?1 AND name = ?2",
				 "table", "meta"), 1);
	assert_int_equal(store_n_schemas, ARRAY_SIZE(modules));
	for (size_t i = 0; i < ARRAY_SIZE(modules); i++)
		for (size_t k = 0; k < modules[i]->n_steps; k++) {
			const struct store_step *step = &modules[i]->steps[k];

			/* a step of a later version would never run */
			assert_in_range(step->version, 1, STORE_SCHEMA_VERSION);
			named += assert_created(db, modules[i]->module, step->tables, "TABLE", "table");
			named += assert_created(db, modules[i]->module, step->tables, "INDEX", "index");
			named += assert_created(db, modules[i]->module, step->indexes, "INDEX", "index");
			for (size_t c = 0; c < step->n_columns; c++)
				if (rows_of(db, "SELECT 1 FROM pragma_table_info(?1) WHERE name = ?2",
					    step->columns[c].table, step->columns[c].column) != 1)
					fail_msg("%s's column %s.%s is missing", modules[i]->module,
						 step->columns[c].table, step->columns[c].column);
		}
	/* (sqlite_sequence and the automatic indexes are SQLite's) */
	assert_int_equal(rows_of(db, "SELECT 1 FROM sqlite_master WHERE substr(name, 1, 7) <> ?1",
				 "sqlite_", NULL), named);
	sqlite3_close(db);
}

static void test_meta_and_schema(void **state)
{
	struct fixture *f = *state;
	char *v = NULL;
	struct store *s2 = NULL;
	struct asph_error err;

	assert_schema_is_modules(f->path);
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

/* The number of rows of a table in the SQLite file path, read with
 * SQLite itself (not through store.c); -1 when there is no such table. */
static int64_t rows_in(const char *path, const char *table)
{
	sqlite3 *db = NULL;
	sqlite3_stmt *st = NULL;
	char sql[128];
	int64_t n = -1;

	snprintf(sql, sizeof(sql), "SELECT COUNT(*) FROM %s", table);
	assert_int_equal(sqlite3_open_v2(path, &db, SQLITE_OPEN_READONLY, NULL), SQLITE_OK);
	if (sqlite3_prepare_v2(db, sql, -1, &st, NULL) == SQLITE_OK &&
	    sqlite3_step(st) == SQLITE_ROW)
		n = sqlite3_column_int64(st, 0);
	sqlite3_finalize(st);
	sqlite3_close(db);
	return n;
}

struct steps {
	int calls;
	int64_t last_done, total;
	int stop_after;         /* 0: never */
};

static int count_steps(int64_t done, int64_t total, void *data)
{
	struct steps *s = data;

	assert_true(done >= s->last_done);
	assert_true(done <= total);
	s->last_done = done;
	s->total = total;
	return ++s->calls == s->stop_after;
}

/* A copy of the store in use: every job in it, a file of its own (no
 * write-ahead log: the header's format bytes say "rollback journal"),
 * never written over an existing file, removed when cancelled. */
static void test_backup(void **state)
{
	struct fixture *f = *state;
	struct steps steps = { 0 };
	struct asph_error err;
	char copy[160], big[4096];
	unsigned char header[100];
	FILE *c;

	/* enough pages for several steps of 256 */
	memset(big, 'x', sizeof(big) - 1);
	big[sizeof(big) - 1] = '\0';
	for (int i = 0; i < 600; i++)
		add(f->s, "m1", i % 7, big);
	snprintf(copy, sizeof(copy), "%s/copy.sqlite", f->dir);
	asph_error_clear(&err);
	assert_int_equal(store_backup(f->path, copy, count_steps, &steps, &err), 0);
	assert_true(steps.calls >= 3);
	assert_int_equal(steps.last_done, steps.total);
	assert_int_equal(rows_in(copy, "jobs"), 600);
	assert_int_equal(rows_in(copy, "history"), 600);
	c = fopen(copy, "rb");
	assert_non_null(c);
	assert_int_equal(fread(header, 1, sizeof(header), c), sizeof(header));
	fclose(c);
	assert_memory_equal(header, "SQLite format 3", 16);
	assert_int_equal(header[18], 1);
	assert_int_equal(header[19], 1);
	/* an existing file is not written over */
	assert_int_equal(store_backup(f->path, copy, NULL, NULL, &err), -EEXIST);
	assert_int_equal(rows_in(copy, "jobs"), 600);
	/* cancelled at the second step: nothing is left */
	unlink(copy);
	steps = (struct steps){ .stop_after = 2 };
	assert_int_equal(store_backup(f->path, copy, count_steps, &steps, &err), -ECANCELED);
	assert_int_equal(access(copy, F_OK), -1);
}

/* Ids taken by folders the store does not know are skipped, never reused;
 * a lower bound changes nothing. */
static void test_skip_ids(void **state)
{
	struct fixture *f = *state;

	assert_int_equal(store_skip_ids(f->s, 4), 1);   /* a store without jobs yet */
	assert_int_equal(add(f->s, "m1", 0, "a"), 5);
	assert_int_equal(store_skip_ids(f->s, 10), 1);
	assert_int_equal(add(f->s, "m1", 0, "b"), 11);
	assert_int_equal(store_skip_ids(f->s, 7), 0);
	assert_int_equal(store_skip_ids(f->s, 11), 0);
	assert_int_equal(add(f->s, "m1", 0, "c"), 12);
}

/* The tables of schema 1, as its daemon made them. */
static const char schema_1[] =
	"CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);"
	"CREATE TABLE jobs (id INTEGER PRIMARY KEY AUTOINCREMENT,"
	" state INTEGER NOT NULL, priority INTEGER NOT NULL, seq INTEGER NOT NULL,"
	" label TEXT, instrument TEXT NOT NULL, uid INTEGER NOT NULL, user TEXT,"
	" spec TEXT NOT NULL, submitted_ns INTEGER NOT NULL, started_ns INTEGER NOT NULL,"
	" finished_ns INTEGER NOT NULL, points_done INTEGER NOT NULL,"
	" points_total INTEGER NOT NULL, reason TEXT, result TEXT, scan_path TEXT,"
	" resume INTEGER NOT NULL, attempts INTEGER NOT NULL);"
	"CREATE TABLE history (job INTEGER NOT NULL REFERENCES jobs(id), t_ns INTEGER NOT NULL,"
	" state INTEGER NOT NULL, reason TEXT, actor_uid INTEGER NOT NULL);"
	"INSERT INTO meta VALUES ('schema', '1');"
	"INSERT INTO jobs VALUES (1, 3, 0, 1, 'old', 'm1', 1013, 'anna', '{}', 5, 6, 7, 10, 10,"
	" NULL, NULL, NULL, 0, 1);"
	"INSERT INTO history VALUES (1, 5, 0, NULL, 1013);";

/* A store of schema 1 is copied as it was into backup/ before its
 * upgrade, under the name the upgrade's documentation gives. */
static void test_backup_before_upgrade(void **state)
{
	struct fixture *f = *state;
	char dir[96], path[128], backups[128], copy[400] = "";
	struct store *s = NULL;
	struct job_record j;
	struct dirent *e;
	sqlite3 *db = NULL;
	DIR *d;
	int n = 0;

	snprintf(dir, sizeof(dir), "%s/old", f->dir);
	assert_int_equal(mkdir(dir, 0750), 0);
	snprintf(path, sizeof(path), "%s/jobs.sqlite", dir);
	assert_int_equal(sqlite3_open(path, &db), SQLITE_OK);
	assert_int_equal(sqlite3_exec(db, schema_1, NULL, NULL, NULL), SQLITE_OK);
	sqlite3_close(db);
	assert_int_equal(store_open(path, &s, NULL), 0);
	assert_int_equal(store_get(s, 1, &j), 0);
	assert_string_equal(j.label, "old");
	assert_null(j.part);
	job_record_clear(&j);
	store_close(s);
	snprintf(backups, sizeof(backups), "%s/backup", dir);
	d = opendir(backups);
	assert_non_null(d);
	while ((e = readdir(d)))
		if (e->d_name[0] != '.') {
			n++;
			snprintf(copy, sizeof(copy), "%s/%s", backups, e->d_name);
			/* jobs-schema1-YYYYmmddTHHMMSSZ.sqlite */
			assert_int_equal(strlen(e->d_name), strlen("jobs-schema1-20250101T000000Z.sqlite"));
			assert_memory_equal(e->d_name, "jobs-schema1-", 13);
			assert_int_equal(e->d_name[21], 'T');
			assert_string_equal(e->d_name + 28, "Z.sqlite");
		}
	closedir(d);
	assert_int_equal(n, 1);
	assert_schema_is_modules(path);
	/* the copy is schema 1's store: no tables of schema 2 */
	assert_int_equal(rows_in(copy, "jobs"), 1);
	assert_int_equal(rows_in(copy, "tokens"), -1);
	/* the second start finds schema 2: nothing more is copied */
	assert_int_equal(store_open(path, &s, NULL), 0);
	store_close(s);
	n = 0;
	d = opendir(backups);
	while ((e = readdir(d)))
		n += e->d_name[0] != '.';
	closedir(d);
	assert_int_equal(n, 1);
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
		cmocka_unit_test_setup_teardown(test_backup, setup, teardown),
		cmocka_unit_test_setup_teardown(test_skip_ids, setup, teardown),
		cmocka_unit_test_setup_teardown(test_backup_before_upgrade, setup, teardown),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
