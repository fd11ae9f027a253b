/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The store's connection as the modules whose tables it holds query it
 * (jobs-store.c, locks-store.c, tokens.c, outbox.c): each of them owns its
 * statements, these are what they share. Event loop thread.
 */
#ifndef ASPHD_STORE_SQL_H
#define ASPHD_STORE_SQL_H

#include <sqlite3.h>

#include "store.h"
#include "util-mem.h"

/* The connection, for sqlite3_last_insert_rowid() and sqlite3_changes(). */
sqlite3 *store_db(struct store *s);

/* A statement of sql, NULL when it cannot be prepared. */
sqlite3_stmt *store_prepare(struct store *s, const char *sql);
/* Statements without rows: 0, or -errno (store_errno()). */
int store_exec(struct store *s, const char *sql);

/* SQLite's result code rc as -errno: a full disk (-ENOSPC) and a read-only
 * one (-EROFS) are told apart, for the daemon acts on them; else -EIO. */
int store_errno(int rc);
/* A statement that returns no row run: 0, or -errno (store_errno()). */
int store_step_done(sqlite3_stmt *st);
/* The one row a query of one record reads: 0, -ENOENT when there is none. */
int store_step_row(sqlite3_stmt *st);

/* v bound at i, NULL as SQL NULL. */
void store_bind_text(sqlite3_stmt *st, int i, const char *v);
/* Column i, copied (NULL for NULL, or out of memory). */
char *store_column_text(sqlite3_stmt *st, int i);

DEFINE_TRIVIAL_CLEANUP_FUNC(sqlite3_stmt *, sqlite3_finalize)
#define _cleanup_stmt_ _cleanup_(sqlite3_finalizep)

#endif
