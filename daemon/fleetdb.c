/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The schema and its migrations; the writer thread (writer_thread()) and
 * the loop's side. */
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <libpq-fe.h>

#include "fleetdb.h"
#include "log.h"
#include "mailbox.h"
#include "util-mem.h"
#include "util-time.h"

#define RECONNECT_MAX_S 30
#define JOIN_WAIT_S 5
/* Any 64-bit number the migrations of every asphd agree on. */
#define MIGRATION_LOCK "7305968611452715313"

/* Migration N brings the schema from N - 1 to N (index N - 1). Never
 * change one that was released: add the next. */
static const char *const migrations[FLEETDB_SCHEMA_VERSION] = {
	/* 1: the results, their indexes and the view of the newest. */
	"CREATE TABLE asphd.results ("
	" daemon_id uuid NOT NULL,"
	" job_id bigint NOT NULL,"
	" host text NOT NULL,"
	" instrument text NOT NULL,"
	" state text NOT NULL CHECK (state IN ('completed', 'failed', 'cancelled')),"
	" label text, part text, lot text, serial text,"
	" submitted_by text,"
	" submitted_at timestamptz, started_at timestamptz, finished_at timestamptz NOT NULL,"
	" reason text,"
	" points bigint, attempts integer,"
	" verdict text CHECK (verdict IN ('pass', 'fail', 'undecided')),"
	" rms_nm double precision, pv_nm double precision,"
	" summary jsonb, uncertainty jsonb, provenance jsonb, files jsonb NOT NULL,"
	" scan_sha256 text, result_sha256 text,"
	" message_id text NOT NULL,"
	" stored_at timestamptz NOT NULL DEFAULT now(),"
	" updated_at timestamptz NOT NULL DEFAULT now(),"
	" PRIMARY KEY (daemon_id, job_id));"
	"CREATE INDEX results_finished ON asphd.results (finished_at DESC);"
	"CREATE INDEX results_part ON asphd.results (part, lot, serial);"
	"CREATE INDEX results_host ON asphd.results (host, finished_at DESC);"
	"CREATE VIEW asphd.fleet_results AS"
	" SELECT finished_at, host, instrument, job_id, state, verdict, part, lot, serial,"
	" label, rms_nm, pv_nm, submitted_by, daemon_id"
	" FROM asphd.results ORDER BY finished_at DESC;"
	"COMMENT ON VIEW asphd.fleet_results IS"
	" 'the newest results across daemons first (docs/fleet.md)';",
};

/*
 * The upsert of one row, from the outbox's JSON ($1). A message delivered
 * again (the same message id) changes nothing; a job that ended again
 * (re-queued) replaces its row.
 */
static const char upsert[] =
	"INSERT INTO asphd.results (daemon_id, job_id, host, instrument, state, label, part, lot,"
	" serial, submitted_by, submitted_at, started_at, finished_at, reason, points, attempts,"
	" verdict, rms_nm, pv_nm, summary, uncertainty, provenance, files, scan_sha256,"
	" result_sha256, message_id)"
	" SELECT (p->>'daemon')::uuid, (p->>'job')::bigint, p->>'host', p->>'instrument',"
	" p->>'state', p->>'label', p->>'part', p->>'lot', p->>'serial',"
	" p->'submitted_by'->>'name', (p->>'submitted')::timestamptz,"
	" (p->>'started')::timestamptz, (p->>'finished')::timestamptz, p->>'reason',"
	" (p->>'points')::bigint, (p->>'attempts')::integer, p->>'verdict',"
	" (p->'summary'->>'rms_nm')::double precision, (p->'summary'->>'pv_nm')::double precision,"
	" NULLIF(p->'summary', 'null'::jsonb), NULLIF(p->'uncertainty', 'null'::jsonb),"
	" NULLIF(p->'provenance', 'null'::jsonb), p->'files',"
	" coalesce(p->'provenance'->'scan'->>'sha256', p->'provenance'->'measured'->>'sha256'),"
	" p->'files'->>'result.json', p->>'message_id'"
	" FROM (SELECT $1::jsonb AS p) AS m"
	" ON CONFLICT (daemon_id, job_id) DO UPDATE SET host = EXCLUDED.host,"
	" instrument = EXCLUDED.instrument, state = EXCLUDED.state, label = EXCLUDED.label,"
	" part = EXCLUDED.part, lot = EXCLUDED.lot, serial = EXCLUDED.serial,"
	" submitted_by = EXCLUDED.submitted_by, submitted_at = EXCLUDED.submitted_at,"
	" started_at = EXCLUDED.started_at, finished_at = EXCLUDED.finished_at,"
	" reason = EXCLUDED.reason, points = EXCLUDED.points, attempts = EXCLUDED.attempts,"
	" verdict = EXCLUDED.verdict, rms_nm = EXCLUDED.rms_nm, pv_nm = EXCLUDED.pv_nm,"
	" summary = EXCLUDED.summary, uncertainty = EXCLUDED.uncertainty,"
	" provenance = EXCLUDED.provenance, files = EXCLUDED.files,"
	" scan_sha256 = EXCLUDED.scan_sha256, result_sha256 = EXCLUDED.result_sha256,"
	" message_id = EXCLUDED.message_id, updated_at = now()"
	" WHERE asphd.results.message_id <> EXCLUDED.message_id";

/* ------------------------------------------------------------ password */

int fleetdb_password_load(const struct settings *s, char **password, settings_error_fn report,
			  void *data)
{
	const char *path = s->postgres ? s->postgres->password_file : NULL;
	_cleanup_close_ int fd = -1;
	struct asph_error e;
	struct stat st;
	char buf[1024];
	ssize_t n = 0;

	*password = NULL;
	if (!path)
		return 0;
	asph_error_clear(&e);
	fd = open(path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
	if (fd < 0)
		asph_error_set(&e, -errno, "cannot read the password file %s: %s", path,
			       strerror(errno));
	else if (fstat(fd, &st) < 0 || (st.st_mode & 0077) || st.st_uid != geteuid())
		asph_error_set(&e, -EPERM, "the password file %s must belong to the daemon's user "
			       "(uid %u) and be readable by its owner only", path, (unsigned)geteuid());
	else if ((n = read(fd, buf, sizeof(buf) - 1)) <= 0)
		asph_error_set(&e, -EINVAL, "the password file %s is empty: the password goes on "
			       "its first line", path);
	if (!e.message[0]) {
		buf[n] = '\0';
		buf[strcspn(buf, "\r\n")] = '\0';
		*password = strdup(buf);
		explicit_bzero(buf, sizeof(buf));
		if (*password)
			return 0;
		asph_error_set(&e, -ENOMEM, "out of memory");
	}
	settings_locate(s, "postgres.password_file", &e);
	if (report)
		report(&e, data);
	return -EINVAL;
}

/* ------------------------------------------------------------ connecting */

/* The connection string, with the password and the keepalives that find
 * a server gone in about 25 s. Blocking: the writer thread's, and
 * --db-migrate's. */
static PGconn *connect_db(const struct settings_postgres *cfg, const char *password)
{
	const char *keys[] = { "dbname", "password", "application_name", "connect_timeout",
			       "keepalives", "keepalives_idle", "keepalives_interval",
			       "keepalives_count", NULL };
	const char *values[] = { cfg->conninfo, password, "asphd", "10", "1", "10", "5", "3",
				 NULL };

	if (!password) {
		/* The password's place is the end of the lists. */
		keys[1] = "application_name";
		values[1] = "asphd";
	}
	return PQconnectdbParams(keys, values, 1);
}

/* One line of libpq's message. */
static const char *pq_message(const PGconn *c)
{
	static __thread char buf[256];
	const char *m = c ? PQerrorMessage(c) : "out of memory";

	snprintf(buf, sizeof(buf), "%s", m && *m ? m : "unknown error");
	buf[strcspn(buf, "\n")] = '\0';
	return buf;
}

static int exec_ok(PGconn *c, const char *sql, struct asph_error *err, const char *what)
{
	PGresult *res = PQexec(c, sql);
	ExecStatusType st = PQresultStatus(res);
	int r = st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK ? 0
		: asph_error_set(err, -EIO, "%s: %s", what, pq_message(c));

	PQclear(res);
	return r;
}

/* The schema's version, 0 when there is none. */
static int read_version(PGconn *c, int *version, struct asph_error *err)
{
	PGresult *res = PQexec(c, "SELECT COALESCE(max(version), 0) FROM asphd.schema_version");
	int r = 0;

	if (PQresultStatus(res) == PGRES_TUPLES_OK && PQntuples(res) == 1) {
		*version = atoi(PQgetvalue(res, 0, 0));
	} else {
		const char *state = PQresultErrorField(res, PG_DIAG_SQLSTATE);
		/* 42P01: undefined table; 3F000: undefined schema */
		if (state && (!strcmp(state, "42P01") || !strcmp(state, "3F000")))
			*version = 0;
		else
			r = asph_error_set(err, -EIO, "reading the schema's version: %s",
					   pq_message(c));
	}
	PQclear(res);
	return r;
}

static int apply(PGconn *c, int version, struct asph_error *err)
{
	char sql[160];
	int r = exec_ok(c, migrations[version - 1], err, "migration");

	snprintf(sql, sizeof(sql), "INSERT INTO asphd.schema_version (version) VALUES (%d)",
		 version);
	return r < 0 ? r : exec_ok(c, sql, err, "recording the version");
}

void fleetdb_conninfo_shown(const char *conninfo, char *buf, size_t size)
{
	PQconninfoOption *opts = PQconninfoParse(conninfo, NULL);
	size_t n = 0;

	buf[0] = '\0';
	for (PQconninfoOption *o = opts; o && o->keyword; o++) {
		if (!o->val || !o->val[0] || strstr(o->keyword, "password"))
			continue;
		n += (size_t)snprintf(buf + n, n < size ? size - n : 0, "%s%s=%s", n ? " " : "",
				      o->keyword, o->val);
	}
	if (n >= size && size > 4)
		memcpy(buf + size - 4, "...", 4);
	if (!opts)
		snprintf(buf, size, "postgres.conninfo");
	PQconninfoFree(opts);
}

int fleetdb_migrate(const struct settings_postgres *cfg, const char *password, FILE *out,
		    struct asph_error *err)
{
	PGconn *c = connect_db(cfg, password);
	char shown[256];
	int from = 0, r;

	if (!c || PQstatus(c) != CONNECTION_OK) {
		fleetdb_conninfo_shown(cfg->conninfo, shown, sizeof(shown));
		r = asph_error_set(err, -ECONNREFUSED, "cannot connect to the database (%s): %s",
				   shown, pq_message(c));
		PQfinish(c);
		return r;
	}
	r = exec_ok(c, "SET client_min_messages = warning", err, "setting up");
	if (r == 0)
		r = exec_ok(c, "BEGIN", err, "BEGIN");
	if (r == 0)
		r = exec_ok(c, "SELECT pg_advisory_xact_lock(" MIGRATION_LOCK ")", err,
			    "waiting for other migrations");
	if (r == 0)
		r = exec_ok(c, "CREATE SCHEMA IF NOT EXISTS asphd;"
			    "CREATE TABLE IF NOT EXISTS asphd.schema_version ("
			    " version integer PRIMARY KEY,"
			    " applied_at timestamptz NOT NULL DEFAULT now(),"
			    " applied_by text NOT NULL DEFAULT current_user)", err, "the version table");
	if (r == 0)
		r = read_version(c, &from, err);
	if (r == 0 && from > FLEETDB_SCHEMA_VERSION)
		r = asph_error_set(err, -EPROTO, "the database's schema is at version %d, newer "
				   "than this asphd's %d: upgrade asphd", from, FLEETDB_SCHEMA_VERSION);
	for (int v = from + 1; r == 0 && v <= FLEETDB_SCHEMA_VERSION; v++)
		r = apply(c, v, err);
	if (r == 0)
		r = exec_ok(c, "COMMIT", err, "COMMIT");
	if (r == 0 && out)
		fprintf(out, from == FLEETDB_SCHEMA_VERSION
			? "the database's schema is at version %d already\n"
			: "the database's schema went from version %d to %d\n",
			from, FLEETDB_SCHEMA_VERSION);
	PQfinish(c);
	return r;
}

/* ------------------------------------------------------------ the writer */

struct row {
	int64_t id;
	char *payload;
};

enum note_kind { NOTE_ACK, NOTE_UP, NOTE_DOWN, NOTE_REFUSED };

struct note {
	enum note_kind kind;
	int64_t id;
	char why[256];
};

struct fleetdb {
	struct settings_postgres cfg;
	char *password;
	struct mailbox *mailbox;        /* notes for the loop */
	void (*acked)(void *data, int64_t id);
	void (*link)(void *data, bool up, const char *why);
	void (*refused)(void *data, int64_t id, const char *why);
	void *data;
	pthread_t thread;
	bool thread_started;

	pthread_mutex_t lock;           /* what follows */
	pthread_cond_t cond;
	bool stopping;
	struct row *rows;               /* to write, oldest first */
	size_t n_rows, cap_rows;
};

static void post(struct fleetdb *f, enum note_kind kind, int64_t id, const char *why)
{
	struct note n = { .kind = kind, .id = id };

	/* cut to a line of the log */
	snprintf(n.why, sizeof(n.why), "%.*s", (int)sizeof(n.why) - 1, why ? why : "");
	/* Lost when memory is out: the row is written again after a restart. */
	mailbox_post(f->mailbox, &n);
}

/* Waits for a row or the end: the oldest row (copied), or false. */
static bool next_row(struct fleetdb *f, struct row *out)
{
	bool have;

	pthread_mutex_lock(&f->lock);
	while (!f->stopping && !f->n_rows)
		pthread_cond_wait(&f->cond, &f->lock);
	have = !f->stopping;
	if (have) {
		out->id = f->rows[0].id;
		out->payload = strdup(f->rows[0].payload);
		have = out->payload != NULL;
	}
	pthread_mutex_unlock(&f->lock);
	return have;
}

static void drop_first(struct fleetdb *f, int64_t id)
{
	pthread_mutex_lock(&f->lock);
	if (f->n_rows && f->rows[0].id == id) {
		free(f->rows[0].payload);
		memmove(f->rows, f->rows + 1, (f->n_rows - 1) * sizeof(*f->rows));
		f->n_rows--;
	}
	pthread_mutex_unlock(&f->lock);
}

/* Sleeps s seconds unless fleetdb_free() wakes it: true when stopping. */
static bool wait_or_stop(struct fleetdb *f, int s)
{
	struct timespec until;
	bool stop;

	clock_gettime(CLOCK_REALTIME, &until);
	until.tv_sec += s;
	pthread_mutex_lock(&f->lock);
	while (!f->stopping && pthread_cond_timedwait(&f->cond, &f->lock, &until) == 0)
		;
	stop = f->stopping;
	pthread_mutex_unlock(&f->lock);
	return stop;
}

/* A connection with the schema this asphd writes, or NULL (said why). */
static PGconn *open_writer(struct fleetdb *f)
{
	struct asph_error err;
	PGconn *c = connect_db(&f->cfg, f->password);
	char why[600];
	int version = 0;

	asph_error_clear(&err);
	if (!c || PQstatus(c) != CONNECTION_OK) {
		post(f, NOTE_DOWN, 0, pq_message(c));
		PQfinish(c);
		return NULL;
	}
	if (read_version(c, &version, &err) < 0 || version < FLEETDB_SCHEMA_VERSION) {
		if (err.message[0])
			snprintf(why, sizeof(why), "%s", err.message);
		else
			snprintf(why, sizeof(why), "the database's schema is at version %d, this "
				 "asphd writes %d: run asphd --db-migrate", version,
				 FLEETDB_SCHEMA_VERSION);
		post(f, NOTE_DOWN, 0, why);
		PQfinish(c);
		return NULL;
	}
	post(f, NOTE_UP, 0, NULL);
	return c;
}

/*
 * Whether the server refused the row for what it holds, so that sending it
 * again cannot help: a data exception (SQLSTATE class 22, e.g. a value out
 * of a column's range) or an integrity constraint (class 23, e.g. a CHECK
 * an administrator added). Anything else (privileges, a schema not
 * migrated, a server shutting down, a serialization failure) concerns
 * every row and is waited out.
 */
static bool refused_for_good(const PGresult *res)
{
	const char *state = PQresultErrorField(res, PG_DIAG_SQLSTATE);

	return state && (!strncmp(state, "22", 2) || !strncmp(state, "23", 2));
}

/* Writes one row: 0, -EAGAIN (the connection is gone), -EIO (the server
 * refused it: said why), -EBADMSG (refused for good: said why). */
static int write_row(struct fleetdb *f, PGconn *c, const struct row *row)
{
	const char *params[] = { row->payload };
	PGresult *res = PQexecParams(c, upsert, 1, NULL, params, NULL, NULL, 0);
	int r = PQresultStatus(res) == PGRES_COMMAND_OK ? 0
		: PQstatus(c) != CONNECTION_OK ? -EAGAIN
		: refused_for_good(res) ? -EBADMSG : -EIO;

	if (r == -EIO || r == -EBADMSG) {
		char why[256];
		snprintf(why, sizeof(why), "row %" PRId64 " refused: %s", row->id, pq_message(c));
		post(f, r == -EIO ? NOTE_DOWN : NOTE_REFUSED, row->id, why);
	}
	PQclear(res);
	return r;
}

static void *writer_thread(void *data)
{
	struct fleetdb *f = data;
	PGconn *c = NULL;
	int delay = 1;
	struct row row;

	while (next_row(f, &row)) {
		int r = -EAGAIN;

		if (!c)
			c = open_writer(f);
		if (c)
			r = write_row(f, c, &row);
		if (r == 0 || r == -EBADMSG) {
			drop_first(f, row.id);
			if (r == 0)
				post(f, NOTE_ACK, row.id, NULL);
			delay = 1;
		} else {
			if (r == -EAGAIN && c) {
				post(f, NOTE_DOWN, 0, pq_message(c));
				PQfinish(c);
				c = NULL;
			}
			if (wait_or_stop(f, delay)) {
				free(row.payload);
				break;
			}
			delay = delay * 2 > RECONNECT_MAX_S ? RECONNECT_MAX_S : delay * 2;
		}
		free(row.payload);
	}
	PQfinish(c);
	return NULL;
}

/* ------------------------------------------------------------ the loop's side */

static void on_note(void *msg, void *data)
{
	struct fleetdb *f = data;
	const struct note *n = msg;

	switch (n->kind) {
	case NOTE_ACK:
		if (f->acked)
			f->acked(f->data, n->id);
		break;
	case NOTE_REFUSED:
		if (f->refused)
			f->refused(f->data, n->id, n->why);
		break;
	case NOTE_UP:
	case NOTE_DOWN:
		if (f->link)
			f->link(f->data, n->kind == NOTE_UP, n->why);
		break;
	}
}

int fleetdb_new(const struct fleetdb_setup *setup, struct fleetdb **out, struct asph_error *err)
{
	struct fleetdb *f = calloc(1, sizeof(*f));
	int r = 0;

	if (!f)
		return asph_error_set(err, -ENOMEM, "out of memory");
	pthread_mutex_init(&f->lock, NULL);
	pthread_cond_init(&f->cond, NULL);
	f->acked = setup->acked;
	f->link = setup->link;
	f->refused = setup->refused;
	f->data = setup->data;
	f->cfg.conninfo = strdup(setup->cfg->conninfo);
	f->password = setup->password ? strdup(setup->password) : NULL;
	if (!f->cfg.conninfo || (setup->password && !f->password))
		r = asph_error_set(err, -ENOMEM, "out of memory");
	if (r == 0) {
		r = mailbox_new(&(struct mailbox_setup){
				.event = setup->event, .size = sizeof(struct note),
				.deliver = on_note, .data = f }, &f->mailbox);
		if (r < 0)
			asph_error_set(err, r, "postgres: %s", strerror(-r));
	}
	if (r == 0) {
		r = -pthread_create(&f->thread, NULL, writer_thread, f);
		if (r < 0)
			asph_error_set(err, r, "postgres: cannot start its thread: %s", strerror(-r));
		f->thread_started = r == 0;
	}
	if (r < 0) {
		fleetdb_free(f);
		return r;
	}
	*out = f;
	return 0;
}

void fleetdb_free(struct fleetdb *f)
{
	struct timespec until;
	bool joined = true;

	if (!f)
		return;
	if (f->thread_started) {
		pthread_mutex_lock(&f->lock);
		f->stopping = true;
		pthread_cond_broadcast(&f->cond);
		pthread_mutex_unlock(&f->lock);
		clock_gettime(CLOCK_REALTIME, &until);
		until.tv_sec += JOIN_WAIT_S;
		/* A write to a server that stopped answering ends with the
		 * keepalives; the process is ending, and the thread is left to it. */
		if (pthread_timedjoin_np(f->thread, NULL, &until) != 0) {
			log_warning("postgres: the writer did not stop in %d s; leaving it",
				    JOIN_WAIT_S);
			pthread_detach(f->thread);
			joined = false;
		}
	}
	mailbox_close(f->mailbox);
	if (!joined)
		return;
	mailbox_free(f->mailbox);
	for (size_t i = 0; i < f->n_rows; i++)
		free(f->rows[i].payload);
	free(f->rows);
	if (f->password) {
		explicit_bzero(f->password, strlen(f->password));
		free(f->password);
	}
	free(f->cfg.conninfo);
	pthread_mutex_destroy(&f->lock);
	pthread_cond_destroy(&f->cond);
	free(f);
}

int fleetdb_send(struct fleetdb *f, int64_t id, const char *payload)
{
	char *copy = strdup(payload);

	if (!copy)
		return -ENOMEM;
	pthread_mutex_lock(&f->lock);
	if (f->n_rows == f->cap_rows) {
		size_t cap = f->cap_rows ? 2 * f->cap_rows : 16;
		struct row *rows = realloc(f->rows, cap * sizeof(*rows));
		if (!rows) {
			pthread_mutex_unlock(&f->lock);
			free(copy);
			return -ENOMEM;
		}
		f->rows = rows;
		f->cap_rows = cap;
	}
	f->rows[f->n_rows++] = (struct row){ .id = id, .payload = copy };
	pthread_cond_broadcast(&f->cond);
	pthread_mutex_unlock(&f->lock);
	return 0;
}
