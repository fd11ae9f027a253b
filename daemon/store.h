/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The job store: SQLite in WAL mode under the state directory. Jobs, their
 * states and every transition survive a restart. This is the connection:
 * opening, the migration runner (one schema version and one backup for
 * every table), transactions, settings, the disk's reserve and backups.
 * The tables are their modules' own: their schemas in jobs-schema.c,
 * locks-schema.c, tokens-schema.c and outbox-schema.c (store-schema.h),
 * their queries in jobs-store.h, locks-store.h, tokens.c and outbox.c,
 * through store-sql.h. Used from the event loop thread only (backups: any).
 */
#ifndef ASPHD_STORE_H
#define ASPHD_STORE_H

#include <stdbool.h>
#include <stdint.h>

#include "asph/error.h"

struct store;

/* Opens or creates path; upgrades an older schema after a backup (below),
 * nothing it does not know (-EPROTO for a newer schema). */
int store_open(const char *path, struct store **out, struct asph_error *err);
void store_close(struct store *s);

/* Key-value settings that outlive a restart (e.g. "queue.running"). */
int store_meta_get(struct store *s, const char *key, char **value);
int store_meta_set(struct store *s, const char *key, const char *value);

/*
 * A file of 1 MiB next to the store, kept so that the end of a job stopped
 * by a full disk can still be recorded: store_release_reserve() deletes it
 * (0, or -errno), store_renew_reserve() creates it again when there is
 * room (0, or -errno). Store writes on a full disk fail with -ENOSPC, on a
 * read-only one with -EROFS.
 */
int store_renew_reserve(struct store *s);
int store_release_reserve(struct store *s);
/* Whether the reserve of the store at path is there, whole (any thread). */
bool store_reserve_ready(const char *path);

/*
 * Backups: a consistent copy of the store made while it is in use. The
 * copy is read in one read transaction (WAL: the store's writers go on
 * meanwhile), a few hundred pages a step; progress (may be NULL) is told
 * after each step with the pages copied and in all, and a nonzero return
 * stops the copy (-ECANCELED). dst must not exist: it is created (0640), a
 * complete SQLite file of its own (no write-ahead log), synced with its
 * directory entry, and removed again on failure. store_open() makes one
 * into DIR/backup/jobs-schemaN-YYYYmmddTHHMMSSZ.sqlite before it upgrades
 * a store of schema N, and logs it; no upgrade goes without it.
 */
typedef int (*store_backup_fn)(int64_t pages_done, int64_t pages_total, void *data);
/* The store at path into dst, through a connection of its own (any thread). */
int store_backup(const char *path, const char *dst, store_backup_fn progress, void *data,
		 struct asph_error *err);
/* The backups' directory beside the store at path, "DIR/backup", with make
 * made (0750) when missing (else -ENOENT); a symlink or a file there is
 * refused (-ENOTDIR). */
int store_backup_dir(const char *path, bool make, char **dir, struct asph_error *err);

/* Runs several changes in one transaction. */
int store_begin(struct store *s);
int store_commit(struct store *s);
void store_rollback(struct store *s);

#endif
