/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <sqlite3.h>

#include "jobs-store.h"
#include "store.h"
#include "store-sql.h"
#include "util-mem.h"

/* The states of the queue, of the index jobs_queue_order. */
#define QUEUE_STATES (1u << JOB_QUEUED | 1u << JOB_RUNNING | 1u << JOB_PAUSED)

#define JOB_COLUMNS "id, state, priority, seq, label, instrument, uid, user, spec," \
	" submitted_ns, started_ns, finished_ns, points_done, points_total," \
	" reason, result, scan_path, resume, attempts, part, lot, serial"

/* The job's columns (JOB_COLUMNS) from column o on. */
static int read_job_at(sqlite3_stmt *st, int o, struct job_record *j)
{
	memset(j, 0, sizeof(*j));
	j->id = sqlite3_column_int64(st, o);
	j->state = (enum job_state)sqlite3_column_int(st, o + 1);
	j->priority = sqlite3_column_int64(st, o + 2);
	j->seq = sqlite3_column_int64(st, o + 3);
	j->label = store_column_text(st, o + 4);
	j->instrument = store_column_text(st, o + 5);
	j->uid = sqlite3_column_int64(st, o + 6);
	j->user = store_column_text(st, o + 7);
	j->spec = store_column_text(st, o + 8);
	j->submitted_ns = sqlite3_column_int64(st, o + 9);
	j->started_ns = sqlite3_column_int64(st, o + 10);
	j->finished_ns = sqlite3_column_int64(st, o + 11);
	j->points_done = sqlite3_column_int64(st, o + 12);
	j->points_total = sqlite3_column_int64(st, o + 13);
	j->reason = store_column_text(st, o + 14);
	j->result = store_column_text(st, o + 15);
	j->scan_path = store_column_text(st, o + 16);
	j->resume = sqlite3_column_int(st, o + 17) != 0;
	j->attempts = sqlite3_column_int64(st, o + 18);
	j->part = store_column_text(st, o + 19);
	j->lot = store_column_text(st, o + 20);
	j->serial = store_column_text(st, o + 21);
	if (!j->instrument || !j->spec) {
		job_record_clear(j);
		return -ENOMEM;
	}
	return 0;
}

static int read_job(sqlite3_stmt *st, struct job_record *j)
{
	return read_job_at(st, 0, j);
}

static int add_history(struct store *s, int64_t id, enum job_state state,
		       const char *reason, int64_t actor_uid, const char *actor, int64_t now)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"INSERT INTO history (job, t_ns, state, reason, actor_uid, actor)"
		" VALUES (?,?,?,?,?,?)");

	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, id);
	sqlite3_bind_int64(st, 2, now);
	sqlite3_bind_int(st, 3, state);
	store_bind_text(st, 4, reason);
	sqlite3_bind_int64(st, 5, actor_uid);
	store_bind_text(st, 6, actor);
	return store_step_done(st);
}

int store_insert(struct store *s, struct job_record *j, int64_t now_ns)
{
	_cleanup_stmt_ sqlite3_stmt *st = NULL;
	int r;

	r = store_begin(s);
	if (r < 0)
		return r;
	st = store_prepare(s, "INSERT INTO jobs (state, priority, seq, label, instrument, uid,"
		     " user, spec, submitted_ns, started_ns, finished_ns, points_done,"
		     " points_total, reason, result, scan_path, resume, attempts, part, lot, serial)"
		     " VALUES (?,?,(SELECT IFNULL(MAX(seq),0)+1 FROM jobs),?,?,?,?,?,?,0,0,0,?,NULL,NULL,?,0,0,"
		     "?,?,?)");
	if (!st) {
		store_rollback(s);
		return -EIO;
	}
	sqlite3_bind_int(st, 1, j->state);
	sqlite3_bind_int64(st, 2, j->priority);
	store_bind_text(st, 3, j->label);
	store_bind_text(st, 4, j->instrument);
	sqlite3_bind_int64(st, 5, j->uid);
	store_bind_text(st, 6, j->user);
	store_bind_text(st, 7, j->spec);
	sqlite3_bind_int64(st, 8, now_ns);
	sqlite3_bind_int64(st, 9, j->points_total);
	store_bind_text(st, 10, j->scan_path);
	store_bind_text(st, 11, j->part);
	store_bind_text(st, 12, j->lot);
	store_bind_text(st, 13, j->serial);
	r = store_step_done(st);
	if (r < 0) {
		store_rollback(s);
		return r;
	}
	j->id = sqlite3_last_insert_rowid(store_db(s));
	j->submitted_ns = now_ns;
	r = add_history(s, j->id, j->state, NULL, j->uid, j->user, now_ns);
	if (r < 0) {
		store_rollback(s);
		return r;
	}
	r = store_commit(s);
	if (r < 0) {
		store_rollback(s);
		return r;
	}
	{
		_cleanup_stmt_ sqlite3_stmt *q = store_prepare(s, "SELECT seq FROM jobs WHERE id = ?");
		if (q) {
			sqlite3_bind_int64(q, 1, j->id);
			if (sqlite3_step(q) == SQLITE_ROW)
				j->seq = sqlite3_column_int64(q, 0);
		}
	}
	return 0;
}

int store_skip_ids(struct store *s, int64_t last)
{
	_cleanup_stmt_ sqlite3_stmt *ins = store_prepare(s,
		"INSERT INTO sqlite_sequence (name, seq) SELECT 'jobs', 0"
		" WHERE NOT EXISTS (SELECT 1 FROM sqlite_sequence WHERE name = 'jobs')");
	_cleanup_stmt_ sqlite3_stmt *up = store_prepare(s,
		"UPDATE sqlite_sequence SET seq = ?1 WHERE name = 'jobs' AND seq < ?1");
	int r;

	if (!ins || !up)
		return -EIO;
	r = store_begin(s);
	if (r == 0)
		r = store_step_done(ins);
	sqlite3_bind_int64(up, 1, last);
	if (r == 0)
		r = store_step_done(up);
	if (r == 0 && (r = store_commit(s)) == 0)
		return sqlite3_changes(store_db(s)) > 0;
	store_rollback(s);
	return r;
}

int store_get(struct store *s, int64_t id, struct job_record *out)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "SELECT " JOB_COLUMNS " FROM jobs WHERE id = ?");
	int r;

	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, id);
	r = store_step_row(st);
	if (r < 0)
		return r;
	return read_job(st, out);
}

/* The state change and its history entry, inside a transaction. */
static int change_state(struct store *s, int64_t id, enum job_state state,
			const char *reason, int64_t actor_uid, const char *actor, int64_t now_ns)
{
	/* A state change without a reason keeps the last one (a pause does
	 * not explain away a fault), except a return to the queue: a re-queued
	 * job starts afresh, so a failure it later recovers from is not shown
	 * as its reason once it completes. The history keeps every reason. */
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, state == JOB_QUEUED
			? "UPDATE jobs SET state = ?, reason = ? WHERE id = ?"
			: "UPDATE jobs SET state = ?, reason = IFNULL(?, reason) WHERE id = ?");
	int r;

	if (!st)
		return -EIO;
	sqlite3_bind_int(st, 1, state);
	store_bind_text(st, 2, reason);
	sqlite3_bind_int64(st, 3, id);
	r = store_step_done(st);
	if (r == 0)
		r = add_history(s, id, state, reason, actor_uid, actor, now_ns);
	return r;
}

int store_set_state(struct store *s, int64_t id, enum job_state state,
		    const char *reason, int64_t actor_uid, const char *actor, int64_t now_ns)
{
	int r = store_begin(s);

	if (r < 0)
		return r;
	r = change_state(s, id, state, reason, actor_uid, actor, now_ns);
	if (r == 0)
		r = store_commit(s);
	if (r < 0)
		store_rollback(s);
	return r;
}

int store_transition(struct store *s, const struct job_record *j, enum job_state state,
		     const char *reason, int64_t actor_uid, const char *actor, int64_t now_ns)
{
	int r = store_begin(s);

	if (r < 0)
		return r;
	r = store_update(s, j);
	if (r == 0)
		r = change_state(s, j->id, state, reason, actor_uid, actor, now_ns);
	if (r == 0)
		r = store_commit(s);
	if (r < 0)
		store_rollback(s);
	return r;
}

int store_update(struct store *s, const struct job_record *j)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"UPDATE jobs SET state=?, priority=?, seq=?, started_ns=?, finished_ns=?,"
		" points_done=?, points_total=?, reason=?, result=?, scan_path=?, resume=?,"
		" attempts=? WHERE id=?");

	if (!st)
		return -EIO;
	sqlite3_bind_int(st, 1, j->state);
	sqlite3_bind_int64(st, 2, j->priority);
	sqlite3_bind_int64(st, 3, j->seq);
	sqlite3_bind_int64(st, 4, j->started_ns);
	sqlite3_bind_int64(st, 5, j->finished_ns);
	sqlite3_bind_int64(st, 6, j->points_done);
	sqlite3_bind_int64(st, 7, j->points_total);
	store_bind_text(st, 8, j->reason);
	store_bind_text(st, 9, j->result);
	store_bind_text(st, 10, j->scan_path);
	sqlite3_bind_int(st, 11, j->resume);
	sqlite3_bind_int64(st, 12, j->attempts);
	sqlite3_bind_int64(st, 13, j->id);
	return store_step_done(st);
}

int store_set_progress(struct store *s, int64_t id, int64_t done, int64_t total)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"UPDATE jobs SET points_done = ?, points_total = ? WHERE id = ?");
	int r;

	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, done);
	sqlite3_bind_int64(st, 2, total);
	sqlite3_bind_int64(st, 3, id);
	/* Progress is a hint (a resumed scan starts from its file), so its
	 * commit skips the fsync that would stall the event loop; the next
	 * state change's commit makes it durable with everything else. */
	store_exec(s, "PRAGMA synchronous=NORMAL");
	r = store_step_done(st);
	store_exec(s, "PRAGMA synchronous=FULL");
	return r;
}

/* Builds the WHERE clause; binds follow the same order. */
static void filter_sql(const struct store_filter *f, char *sql, size_t size)
{
	size_t n = strlen(sql);

	n += (size_t)snprintf(sql + n, size - n, " WHERE 1");
	/* "state IN (...)" as the queue's index says it, so that a listing of
	 * the queue may use it */
	if (f->states) {
		n += (size_t)snprintf(sql + n, size - n, " AND state IN (");
		for (int k = 0, first = 1; k < JOB_N_STATES; k++)
			if (f->states & (1u << k)) {
				n += (size_t)snprintf(sql + n, size - n, "%s%d", first ? "" : ",", k);
				first = 0;
			}
		n += (size_t)snprintf(sql + n, size - n, ")");
	}
	if (f->instrument)
		n += (size_t)snprintf(sql + n, size - n, " AND instrument = ?");
	if (f->uid != STORE_ANY_UID)
		n += (size_t)snprintf(sql + n, size - n, " AND uid = ?");
	if (f->label)
		n += (size_t)snprintf(sql + n, size - n, " AND label = ?");
	if (f->user)
		n += (size_t)snprintf(sql + n, size - n, " AND user = ?");
	if (f->part)
		n += (size_t)snprintf(sql + n, size - n, " AND part = ?");
	if (f->lot)
		n += (size_t)snprintf(sql + n, size - n, " AND lot = ?");
	if (f->serial)
		n += (size_t)snprintf(sql + n, size - n, " AND serial = ?");
	if (f->before_id > 0)
		n += (size_t)snprintf(sql + n, size - n, " AND id < ?");
	if (f->after)
		snprintf(sql + n, size - n, " AND priority = ? AND (seq, id) > (?, ?)");
	else if (f->below)
		snprintf(sql + n, size - n, " AND priority < ?");
}

static int filter_bind(sqlite3_stmt *st, const struct store_filter *f)
{
	int i = 1;

	if (f->instrument)
		store_bind_text(st, i++, f->instrument);
	if (f->uid != STORE_ANY_UID)
		sqlite3_bind_int64(st, i++, f->uid);
	if (f->label)
		store_bind_text(st, i++, f->label);
	if (f->user)
		store_bind_text(st, i++, f->user);
	if (f->part)
		store_bind_text(st, i++, f->part);
	if (f->lot)
		store_bind_text(st, i++, f->lot);
	if (f->serial)
		store_bind_text(st, i++, f->serial);
	if (f->before_id > 0)
		sqlite3_bind_int64(st, i++, f->before_id);
	if (f->after) {
		sqlite3_bind_int64(st, i++, f->after_priority);
		sqlite3_bind_int64(st, i++, f->after_seq);
		sqlite3_bind_int64(st, i++, f->after_id);
	} else if (f->below) {
		sqlite3_bind_int64(st, i++, f->after_priority);
	}
	return i;
}

int store_total(struct store *s, const struct store_filter *f, int64_t *total)
{
	char sql[768] = "SELECT COUNT(*) FROM jobs";
	_cleanup_stmt_ sqlite3_stmt *c = NULL;

	filter_sql(f, sql, sizeof(sql));
	c = store_prepare(s, sql);
	if (!c)
		return -EIO;
	filter_bind(c, f);
	if (sqlite3_step(c) != SQLITE_ROW)
		return -EIO;
	*total = sqlite3_column_int64(c, 0);
	return 0;
}

int store_list(struct store *s, const struct store_filter *f,
	       store_job_fn fn, void *data, int64_t *total)
{
	char sql[1024] = "SELECT " JOB_COLUMNS " FROM jobs";
	_cleanup_stmt_ sqlite3_stmt *st = NULL;
	int i, r;

	if (total && (r = store_total(s, f, total)) < 0)
		return r;
	/* A slice of the queue: its index in its order, a seek and a few
	 * steps, not a sort of the whole queue. */
	if (f->queue_order && f->states == QUEUE_STATES && (f->after || f->below || f->limit > 0))
		strncat(sql, " INDEXED BY jobs_queue_order", sizeof(sql) - strlen(sql) - 1);
	filter_sql(f, sql, sizeof(sql));
	strncat(sql, f->queue_order ? " ORDER BY priority DESC, seq, id" : " ORDER BY id DESC",
		sizeof(sql) - strlen(sql) - 1);
	strncat(sql, " LIMIT ? OFFSET ?", sizeof(sql) - strlen(sql) - 1);
	st = store_prepare(s, sql);
	if (!st)
		return -EIO;
	i = filter_bind(st, f);
	sqlite3_bind_int64(st, i, f->limit > 0 ? f->limit : -1);
	sqlite3_bind_int64(st, i + 1, f->offset);
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		struct job_record j;
		int k = read_job(st, &j);
		if (k < 0)
			return k;
		k = fn(&j, data);
		job_record_clear(&j);
		if (k < 0)
			return k;
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}

int store_next(struct store *s, const char *instrument, struct job_record *out)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "SELECT " JOB_COLUMNS
		" FROM jobs WHERE state = ? AND instrument = ? ORDER BY priority DESC, seq LIMIT 1");
	int r;

	if (!st)
		return -EIO;
	sqlite3_bind_int(st, 1, JOB_QUEUED);
	store_bind_text(st, 2, instrument);
	r = store_step_row(st);
	if (r < 0)
		return r;
	return read_job(st, out);
}

int store_history(struct store *s, int64_t id, store_event_fn fn, void *data)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT t_ns, state, reason, actor_uid, actor FROM history WHERE job = ?"
		" ORDER BY rowid");
	int r;

	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, id);
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		struct store_event e = {
			.t_ns = sqlite3_column_int64(st, 0),
			.state = (enum job_state)sqlite3_column_int(st, 1),
			.reason = (const char *)sqlite3_column_text(st, 2),
			.actor_uid = sqlite3_column_int64(st, 3),
			.actor = (const char *)sqlite3_column_text(st, 4),
		};
		int k = fn(&e, data);
		if (k < 0)
			return k;
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}

int store_recover(struct store *s, int64_t now_ns)
{
	_cleanup_stmt_ sqlite3_stmt *sel = store_prepare(s,
		"SELECT id FROM jobs WHERE state IN (?, ?)");
	int64_t ids[64];
	int n = 0, total = 0, r;

	if (!sel)
		return -EIO;
	do {
		n = 0;
		sqlite3_reset(sel);
		sqlite3_bind_int(sel, 1, JOB_RUNNING);
		sqlite3_bind_int(sel, 2, JOB_PAUSED);
		while (n < (int)ARRAY_SIZE(ids) && sqlite3_step(sel) == SQLITE_ROW)
			ids[n++] = sqlite3_column_int64(sel, 0);
		sqlite3_reset(sel);
		for (int i = 0; i < n; i++) {
			r = store_set_state(s, ids[i], JOB_INTERRUPTED,
					    "the daemon stopped during the scan", 0, NULL, now_ns);
			if (r < 0)
				return r;
			_cleanup_stmt_ sqlite3_stmt *u = store_prepare(s,
				"UPDATE jobs SET resume = 1 WHERE id = ? AND scan_path IS NOT NULL");
			if (!u)
				return -EIO;
			sqlite3_bind_int64(u, 1, ids[i]);
			if (store_step_done(u) < 0)
				return -EIO;
		}
		total += n;
	} while (n == (int)ARRAY_SIZE(ids));
	return total;
}

int store_count(struct store *s, int64_t counts[JOB_N_STATES])
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT state, COUNT(*) FROM jobs GROUP BY state");
	int r;

	if (!st)
		return -EIO;
	memset(counts, 0, sizeof(int64_t) * JOB_N_STATES);
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		int k = sqlite3_column_int(st, 0);
		if (k >= 0 && k < JOB_N_STATES)
			counts[k] = sqlite3_column_int64(st, 1);
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}

int store_changes(struct store *s, int64_t after, int64_t limit, store_change_fn fn,
		  void *data)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT h.rowid, h.t_ns, h.state, h.reason, h.actor,"
		" (SELECT p.state FROM history p WHERE p.job = h.job AND p.rowid < h.rowid"
		"  ORDER BY p.rowid DESC LIMIT 1), jobs.id, jobs.state, priority, seq, label,"
		" instrument, uid, user, spec, submitted_ns, started_ns, finished_ns, points_done,"
		" points_total, jobs.reason, result, scan_path, resume, attempts, part, lot, serial"
		" FROM history h JOIN jobs ON jobs.id = h.job WHERE h.rowid > ?"
		" ORDER BY h.rowid LIMIT ?");
	int r;

	if (!st)
		return -EIO;
	sqlite3_bind_int64(st, 1, after);
	sqlite3_bind_int64(st, 2, limit);
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		struct job_record j;
		struct store_change c = {
			.rowid = sqlite3_column_int64(st, 0),
			.t_ns = sqlite3_column_int64(st, 1),
			.state = (enum job_state)sqlite3_column_int(st, 2),
			.reason = (const char *)sqlite3_column_text(st, 3),
			.actor = (const char *)sqlite3_column_text(st, 4),
			.previous = sqlite3_column_type(st, 5) == SQLITE_NULL
				    ? -1 : sqlite3_column_int(st, 5),
			.job = &j,
		};
		int k = read_job_at(st, 6, &j);
		if (k < 0)
			return k;
		k = fn(&c, data);
		job_record_clear(&j);
		if (k < 0)
			return k;
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}

int store_last_change(struct store *s, int64_t *rowid)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "SELECT IFNULL(MAX(rowid), 0) FROM history");

	if (!st)
		return -EIO;
	if (sqlite3_step(st) != SQLITE_ROW)
		return -EIO;
	*rowid = sqlite3_column_int64(st, 0);
	return 0;
}
