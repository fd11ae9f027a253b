/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdbool.h>

#include <sqlite3.h>

#include "locks-store.h"
#include "store.h"
#include "store-sql.h"

int store_lock_set(struct store *s, const struct store_lock *l)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"INSERT INTO locks (instrument, holder, holder_uid, reason, since_ns, pause,"
		" paused_job) VALUES (?,?,?,?,?,?,?) ON CONFLICT(instrument) DO UPDATE SET"
		" holder = excluded.holder, holder_uid = excluded.holder_uid,"
		" reason = excluded.reason, since_ns = excluded.since_ns,"
		" pause = excluded.pause, paused_job = excluded.paused_job");

	if (!st)
		return -EIO;
	store_bind_text(st, 1, l->instrument);
	store_bind_text(st, 2, l->holder);
	sqlite3_bind_int64(st, 3, l->holder_uid);
	store_bind_text(st, 4, l->reason);
	sqlite3_bind_int64(st, 5, l->since_ns);
	sqlite3_bind_int(st, 6, l->pause);
	sqlite3_bind_int64(st, 7, l->paused_job);
	return store_step_done(st);
}

int store_lock_clear(struct store *s, const char *instrument)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s, "DELETE FROM locks WHERE instrument = ?");

	if (!st)
		return -EIO;
	store_bind_text(st, 1, instrument);
	return store_step_done(st);
}

int store_lock_list(struct store *s, store_lock_fn fn, void *data)
{
	_cleanup_stmt_ sqlite3_stmt *st = store_prepare(s,
		"SELECT instrument, holder, holder_uid, reason, since_ns, pause, paused_job"
		" FROM locks ORDER BY instrument");
	int r;

	if (!st)
		return -EIO;
	while ((r = sqlite3_step(st)) == SQLITE_ROW) {
		struct store_lock l = {
			.instrument = (const char *)sqlite3_column_text(st, 0),
			.holder = (const char *)sqlite3_column_text(st, 1),
			.holder_uid = sqlite3_column_int64(st, 2),
			.reason = (const char *)sqlite3_column_text(st, 3),
			.since_ns = sqlite3_column_int64(st, 4),
			.pause = sqlite3_column_int(st, 5) != 0,
			.paused_job = sqlite3_column_int64(st, 6),
		};
		int k;
		if (!l.instrument || !l.holder || !l.reason)
			return -ENOMEM;
		k = fn(&l, data);
		if (k < 0)
			return k;
	}
	return r == SQLITE_DONE ? 0 : -EIO;
}
