/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdbool.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <sqlite3.h>

#include "log.h"
#include "store.h"
#include "store-schema.h"
#include "store-sql.h"
#include "util-mem.h"
#include "util-time.h"

struct store {
	sqlite3 *db;
	char *reserve;          /* "<store>.reserve", see store_renew_reserve() */
};

/* Room for the job store to record the end of the jobs that a full disk
 * stops: a few transactions of a few pages each. */
#define RESERVE_BYTES (1 << 20)

/*
 * The schema, one version for the file: the store creates every table and
 * upgrades them together, after one backup. Each module's tables are its
 * own (store-schema.h): jobs and history in jobs-schema.c, tokens in
 * tokens-schema.c, locks in locks-schema.c, the outbox in outbox-schema.c;
 * meta, the settings and the version, is the store's.
 */
static const char meta_table[] =
	"CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);";

/* In the order their tables are made: the order of the tables in the
 * stores made so far. */
const struct store_schema *const store_schemas[] = {
	&jobs_schema, &tokens_schema, &locks_schema, &outbox_schema,
};
const size_t store_n_schemas = ARRAY_SIZE(store_schemas);

static int sql_error(struct store *s, struct asph_error *err, const char *what)
{
	return asph_error_set(err, -EIO, "%s: %s", what, sqlite3_errmsg(s->db));
}

/* A full or read-only disk is told apart: the daemon acts on it. */
int store_errno(int rc)
{
	switch (rc & 0xff) {
	case SQLITE_FULL:
		return -ENOSPC;
	case SQLITE_READONLY:
		return -EROFS;
	default:
		return -EIO;
	}
}

int store_exec(struct store *s, const char *sql)
{
	int rc = sqlite3_exec(s->db, sql, NULL, NULL, NULL);

	return rc == SQLITE_OK ? 0 : store_errno(rc);
}

sqlite3_stmt *store_prepare(struct store *s, const char *sql)
{
	sqlite3_stmt *st = NULL;

	if (sqlite3_prepare_v2(s->db, sql, -1, &st, NULL) != SQLITE_OK)
		return NULL;
	return st;
}

int store_step_done(sqlite3_stmt *st)
{
	int rc = sqlite3_step(st);

	return rc == SQLITE_DONE ? 0 : store_errno(rc);
}

/* The one row a query of one record reads: 0, -ENOENT when there is none. */
int store_step_row(sqlite3_stmt *st)
{
	int rc = sqlite3_step(st);

	if (rc == SQLITE_ROW)
		return 0;
	return rc == SQLITE_DONE ? -ENOENT : -EIO;
}

/* The module's step to version, NULL when it has none. */
static const struct store_step *schema_step(const struct store_schema *m, long version)
{
	for (size_t i = 0; i < m->n_steps; i++)
		if (m->steps[i].version == version)
			return &m->steps[i];
	return NULL;
}

/* Every table of every version that the store lacks, version by version,
 * module by module; run on every open. */
static int create_tables(struct store *s)
{
	int r = store_exec(s, meta_table);

	for (long v = 1; r == 0 && v <= STORE_SCHEMA_VERSION; v++)
		for (size_t i = 0; r == 0 && i < store_n_schemas; i++) {
			const struct store_step *step = schema_step(store_schemas[i], v);

			if (step && step->tables)
				r = store_exec(s, step->tables);
		}
	return r;
}

/* The columns of step that the store lacks, added. */
static int add_columns(struct store *s, const struct store_step *step)
{
	for (size_t i = 0; i < step->n_columns; i++) {
		const struct store_column *c = &step->columns[i];
		char sql[160];
		sqlite3_stmt *st;
		bool have;

		snprintf(sql, sizeof(sql), "SELECT 1 FROM pragma_table_info('%s') WHERE name = '%s'",
			 c->table, c->column);
		if (sqlite3_prepare_v2(s->db, sql, -1, &st, NULL) != SQLITE_OK)
			return -EIO;
		have = sqlite3_step(st) == SQLITE_ROW;
		sqlite3_finalize(st);
		snprintf(sql, sizeof(sql), "ALTER TABLE %s ADD COLUMN %s TEXT", c->table, c->column);
		if (!have && store_exec(s, sql) < 0)
			return -EIO;
	}
	return 0;
}

/* Every module's steps after version up to STORE_SCHEMA_VERSION: the
 * columns they add, then their indexes. */
static int upgrade_tables(struct store *s, long version)
{
	for (long v = version + 1; v <= STORE_SCHEMA_VERSION; v++)
		for (size_t i = 0; i < store_n_schemas; i++) {
			const struct store_step *step = schema_step(store_schemas[i], v);

			if (!step)
				continue;
			if (add_columns(s, step) < 0 ||
			    (step->indexes && store_exec(s, step->indexes) < 0))
				return -EIO;
		}
	return 0;
}

/* The schema version of the store: 0 for a new one (no meta table, or no
 * version in it); -EPROTO for a store that is damaged, not asphd's, or
 * newer than this daemon. */
static int read_version(struct store *s, long *version, struct asph_error *err)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'meta'");
	_cleanup_free_ char *v = NULL;
	char *end;
	int r;

	*version = 0;
	if (!st)
		return sql_error(s, err, "reading the schema version");
	r = store_step_row(st);
	if (r == -ENOENT)
		return 0;
	r = r < 0 ? r : store_meta_get(s, "schema", &v);
	if (r == -ENOENT)
		return 0;
	if (r < 0)
		return sql_error(s, err, "reading the schema version");
	/* only digits: strtol alone would take " 1", "+1" or "1x" */
	errno = 0;
	*version = strtol(v, &end, 10);
	if (v[0] < '0' || v[0] > '9' || *end || errno || *version < 1)
		return asph_error_set(err, -EPROTO,
				      "the job store's schema version \"%.32s\" is not a number "
				      "from 1 on: the store is damaged or not asphd's", v);
	if (*version > STORE_SCHEMA_VERSION)
		return asph_error_set(err, -EPROTO,
				      "the job store has schema %ld, newer than %d",
				      *version, STORE_SCHEMA_VERSION);
	return 0;
}

/* A new store gets the version; an older one is upgraded in place (its
 * backup is made before, in store_open()). */
static int set_version(struct store *s, long version, struct asph_error *err)
{
	char buf[16], what[64];
	int r;

	snprintf(buf, sizeof(buf), "%d", STORE_SCHEMA_VERSION);
	if (version == 0)
		return upgrade_tables(s, 0) < 0 ? sql_error(s, err, "creating the store")
						: store_meta_set(s, "schema", buf);
	if (version == STORE_SCHEMA_VERSION)
		return 0;
	if (store_begin(s) < 0 || upgrade_tables(s, version) < 0 ||
	    store_meta_set(s, "schema", buf) < 0 || store_commit(s) < 0) {
		snprintf(what, sizeof(what), "upgrading the job store to schema %d",
			 STORE_SCHEMA_VERSION);
		r = sql_error(s, err, what);
		store_rollback(s);
		return r;
	}
	return 0;
}

/* ------------------------------------------------------------ backups */

/* Pages copied per step (a MiB of 4 KiB pages): progress moves and a
 * cancel is heard soon. */
#define BACKUP_STEP_PAGES 256

int store_backup_dir(const char *path, bool make, char **out, struct asph_error *err)
{
	const char *slash = strrchr(path, '/');
	_cleanup_free_ char *dir = NULL;
	struct stat st;

	if (asprintf(&dir, "%.*s/backup", slash ? (int)(slash - path) : 1, slash ? path : ".") < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (make && mkdir(dir, 0750) < 0 && errno != EEXIST)
		return asph_error_set(err, -errno, "cannot make %s: %s", dir, strerror(errno));
	if (lstat(dir, &st) < 0)
		return asph_error_set(err, -errno, "%s: %s", dir, strerror(errno));
	if (!S_ISDIR(st.st_mode))
		return asph_error_set(err, -ENOTDIR, "%s is not a directory: refusing to keep "
				      "the job store's backups there", dir);
	*out = steal_ptr(dir);
	return 0;
}

/* fsync() of a file or a directory. */
static int sync_path(const char *path, int flags)
{
	int fd = open(path, flags | O_CLOEXEC | O_NOFOLLOW), r = 0;

	if (fd < 0)
		return -errno;
	if (fsync(fd) < 0)
		r = -errno;
	close(fd);
	return r;
}

/* The file dst and its directory's entry of it, on disk. */
static int sync_new_file(const char *dst)
{
	_cleanup_free_ char *dir = strdup(dst);
	char *slash = dir ? strrchr(dir, '/') : NULL;
	int r = sync_path(dst, O_RDONLY);

	if (r < 0 || !slash)
		return r;
	*slash = '\0';
	return sync_path(slash == dir ? "/" : dir, O_RDONLY | O_DIRECTORY);
}

/* The copy of src into the new file dst, step by step, in one read
 * transaction of src: a snapshot of one moment, which the store's writers
 * do not wait for (WAL). The copy is written without a journal (it is
 * removed unless complete) and synced once at the end. */
static int copy_db(sqlite3 *src, sqlite3 *out, const char *dst, store_backup_fn progress,
		   void *data, struct asph_error *err)
{
	sqlite3_backup *b;
	bool cancelled = false;
	int rc;

	if (sqlite3_exec(out, "PRAGMA journal_mode=OFF; PRAGMA synchronous=OFF", NULL, NULL,
			 NULL) != SQLITE_OK)
		return asph_error_set(err, -EIO, "%s: %s", dst, sqlite3_errmsg(out));
	if (sqlite3_exec(src, "BEGIN; SELECT COUNT(*) FROM sqlite_master", NULL, NULL,
			 NULL) != SQLITE_OK)
		return asph_error_set(err, -EIO, "reading the job store: %s", sqlite3_errmsg(src));
	b = sqlite3_backup_init(out, "main", src, "main");
	if (!b)
		return asph_error_set(err, -EIO, "%s: %s", dst, sqlite3_errmsg(out));
	do {
		rc = sqlite3_backup_step(b, BACKUP_STEP_PAGES);
		if ((rc == SQLITE_OK || rc == SQLITE_DONE) && progress &&
		    progress(sqlite3_backup_pagecount(b) - sqlite3_backup_remaining(b),
			     sqlite3_backup_pagecount(b), data))
			cancelled = rc == SQLITE_OK;
	} while (rc == SQLITE_OK && !cancelled);
	sqlite3_backup_finish(b);
	if (cancelled)
		return asph_error_set(err, -ECANCELED, "the backup was cancelled");
	if (rc != SQLITE_DONE)
		return asph_error_set(err, store_errno(rc), "copying the job store into %s: %s", dst,
				      sqlite3_errstr(rc));
	/* a file of its own, without a write-ahead log beside it */
	if (sqlite3_exec(out, "PRAGMA journal_mode=DELETE", NULL, NULL, NULL) != SQLITE_OK)
		return asph_error_set(err, -EIO, "%s: %s", dst, sqlite3_errmsg(out));
	return 0;
}

static int backup_db(sqlite3 *src, const char *dst, store_backup_fn progress, void *data,
		     struct asph_error *err)
{
	sqlite3 *out = NULL;
	int fd, r;

	fd = open(dst, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0640);
	if (fd < 0)
		return asph_error_set(err, -errno, "%s: %s", dst, strerror(errno));
	close(fd);
	if (sqlite3_open_v2(dst, &out, SQLITE_OPEN_READWRITE | SQLITE_OPEN_NOMUTEX |
			    SQLITE_OPEN_NOFOLLOW, NULL) != SQLITE_OK)
		r = asph_error_set(err, -EIO, "%s: %s", dst,
				   out ? sqlite3_errmsg(out) : "out of memory");
	else
		r = copy_db(src, out, dst, progress, data, err);
	if (!sqlite3_get_autocommit(src))
		sqlite3_exec(src, "ROLLBACK", NULL, NULL, NULL);    /* (the read transaction) */
	if (sqlite3_close(out) != SQLITE_OK && r == 0)
		r = asph_error_set(err, -EIO, "%s: cannot close it", dst);
	if (r == 0 && (r = sync_new_file(dst)) < 0)
		asph_error_set(err, r, "%s: %s", dst, strerror(-r));
	if (r < 0)
		unlink(dst);
	return r;
}

int store_backup(const char *path, const char *dst, store_backup_fn progress, void *data,
		 struct asph_error *err)
{
	sqlite3 *src = NULL;
	int r;

	if (sqlite3_open_v2(path, &src, SQLITE_OPEN_READWRITE | SQLITE_OPEN_NOMUTEX |
			    SQLITE_OPEN_NOFOLLOW, NULL) != SQLITE_OK) {
		r = asph_error_set(err, -EIO, "cannot open the job store %s: %s", path,
				   src ? sqlite3_errmsg(src) : "out of memory");
		sqlite3_close(src);
		return r;
	}
	sqlite3_busy_timeout(src, 5000);
	r = backup_db(src, dst, progress, data, err);
	sqlite3_close(src);
	return r;
}

/* The store as it is, into DIR/backup/jobs-schemaN-TIME.sqlite, before
 * its upgrade from schema N: no upgrade without it. */
static int backup_before_upgrade(struct store *s, const char *path, long version,
				 struct asph_error *err)
{
	_cleanup_free_ char *dir = NULL, *dst = NULL;
	char stamp[ISO8601_SIZE];
	struct asph_error why;
	int r;

	asph_error_clear(&why);
	r = store_backup_dir(path, true, &dir, &why);
	iso8601_basic_utc(now_realtime_ns(), stamp, sizeof(stamp));
	if (r == 0 && asprintf(&dst, "%s/jobs-schema%ld-%s.sqlite", dir, version, stamp) < 0) {
		dst = NULL;
		r = asph_error_set(&why, -ENOMEM, "out of memory");
	}
	if (r == 0)
		r = backup_db(s->db, dst, NULL, NULL, &why);
	if (r < 0)
		return asph_error_set(err, r, "the job store %s has schema %ld; it is upgraded to "
				      "schema %d only after a backup, which failed: %s", path,
				      version, STORE_SCHEMA_VERSION, why.message);
	log_notice("the job store %s has schema %ld: backed up to %s before its upgrade to "
		   "schema %d", path, version, dst, STORE_SCHEMA_VERSION);
	return 0;
}

/* The store and its journals are regular files where they are: never
 * opened through a symlink (SQLite's NOFOLLOW covers the store itself). */
static int check_files(const char *path, struct asph_error *err)
{
	static const char *const suffixes[] = { "", "-wal", "-shm", "-journal", ".reserve" };
	char name[4096];
	struct stat st;

	for (size_t i = 0; i < ARRAY_SIZE(suffixes); i++) {
		snprintf(name, sizeof(name), "%s%s", path, suffixes[i]);
		if (lstat(name, &st) == 0 && !S_ISREG(st.st_mode))
			return asph_error_set(err, -ELOOP, "%s is not a regular file: refusing "
					      "to use it for the job store", name);
	}
	return 0;
}

int store_open(const char *path, struct store **out, struct asph_error *err)
{
	struct store *s;
	long version;
	int r = check_files(path, err);

	if (r < 0)
		return r;
	s = calloc(1, sizeof(*s));
	if (!s)
		return -ENOMEM;
	if (sqlite3_open_v2(path, &s->db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE |
			    SQLITE_OPEN_NOMUTEX | SQLITE_OPEN_NOFOLLOW, NULL) != SQLITE_OK) {
		r = asph_error_set(err, -EIO, "cannot open the job store %s: %s", path,
				   s->db ? sqlite3_errmsg(s->db) : "out of memory");
		store_close(s);
		return r;
	}
	sqlite3_busy_timeout(s->db, 5000);
	/* WAL with synchronous=FULL: a committed state change survives power
	 * loss, and readers never block the writer. */
	if (store_exec(s, "PRAGMA journal_mode=WAL;") < 0 ||
	    store_exec(s, "PRAGMA synchronous=FULL;") < 0 ||
	    store_exec(s, "PRAGMA foreign_keys=ON;") < 0) {
		r = sql_error(s, err, path);
		store_close(s);
		return r;
	}
	/* An older store is copied as it is before anything of it changes. */
	r = read_version(s, &version, err);
	if (r == 0 && version > 0 && version < STORE_SCHEMA_VERSION)
		r = backup_before_upgrade(s, path, version, err);
	if (r == 0 && create_tables(s) < 0)
		r = sql_error(s, err, path);
	if (r == 0)
		r = set_version(s, version, err);
	if (r < 0) {
		store_close(s);
		return r;
	}
	if (asprintf(&s->reserve, "%s.reserve", path) < 0) {
		s->reserve = NULL;
		store_close(s);
		return -ENOMEM;
	}
	store_renew_reserve(s);
	*out = s;
	return 0;
}

void store_close(struct store *s)
{
	if (!s)
		return;
	sqlite3_close(s->db);
	free(s->reserve);
	free(s);
}

int store_renew_reserve(struct store *s)
{
	struct stat st;
	int fd, r;

	if (!s->reserve)
		return -ENOMEM;
	if (lstat(s->reserve, &st) == 0 && S_ISREG(st.st_mode) && st.st_size >= RESERVE_BYTES)
		return 0;
	fd = open(s->reserve, O_WRONLY | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0600);
	if (fd < 0)
		return -errno;
	r = -posix_fallocate(fd, 0, RESERVE_BYTES);
	close(fd);
	if (r < 0)
		unlink(s->reserve);
	return r;
}

bool store_reserve_ready(const char *path)
{
	char name[4096];
	struct stat st;

	snprintf(name, sizeof(name), "%s.reserve", path);
	return lstat(name, &st) == 0 && S_ISREG(st.st_mode) && st.st_size >= RESERVE_BYTES;
}

int store_release_reserve(struct store *s)
{
	if (!s->reserve)
		return -ENOENT;
	return unlink(s->reserve) < 0 ? -errno : 0;
}

void store_bind_text(sqlite3_stmt *st, int i, const char *v)
{
	if (v)
		sqlite3_bind_text(st, i, v, -1, SQLITE_TRANSIENT);
	else
		sqlite3_bind_null(st, i);
}

char *store_column_text(sqlite3_stmt *st, int i)
{
	const unsigned char *t = sqlite3_column_text(st, i);

	return t ? strdup((const char *)t) : NULL;
}

sqlite3 *store_db(struct store *s)
{
	return s->db;
}

int store_meta_get(struct store *s, const char *key, char **value)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "SELECT value FROM meta WHERE key = ?");
	int r;

	if (!st)
		return -EIO;
	store_bind_text(st, 1, key);
	r = store_step_row(st);
	if (r < 0)
		return r;
	*value = store_column_text(st, 0);
	return *value ? 0 : -ENOMEM;
}

int store_meta_set(struct store *s, const char *key, const char *value)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"INSERT INTO meta (key, value) VALUES (?, ?)"
		" ON CONFLICT(key) DO UPDATE SET value = excluded.value");

	if (!st)
		return -EIO;
	store_bind_text(st, 1, key);
	store_bind_text(st, 2, value);
	return store_step_done(st);
}

int store_begin(struct store *s)
{
	return store_exec(s, "BEGIN IMMEDIATE");
}

int store_commit(struct store *s)
{
	return store_exec(s, "COMMIT");
}

void store_rollback(struct store *s)
{
	store_exec(s, "ROLLBACK");
}

