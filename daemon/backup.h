/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Copies of the job store for the clients that ask (backup.start,
 * proto/README.md; `asphctl backup FILE`). Each copy is made on a thread
 * of its own by store_backup(): its own connection to the store and one
 * read transaction, so that the copy is of one moment while jobs go on,
 * and neither the event loop nor the store's writers wait for it. It goes
 * into STATE_DIR/backup/copy-TIME-N.sqlite, the client reads it back in
 * pieces (backup.file), and it is removed when that client is done with
 * it: when its session ends, or when it starts another copy. One copy is
 * made at a time, and none when the state directory lacks the room for it
 * besides limits.min_free_disk_mb. Copies left by a daemon that died are
 * removed at the next start.
 *
 * A copy belongs to an owner, an opaque pointer (rpc.c's session).
 * Event loop thread, but for the copying threads inside backup.c.
 */
#ifndef ASPHD_BACKUP_H
#define ASPHD_BACKUP_H

#include <stdint.h>

#include <systemd/sd-event.h>

#include "asph/error.h"
#include "settings.h"

struct backups_setup {
	sd_event *event;                        /* the threads report here */
	const char *store_path;                 /* STATE_DIR/jobs.sqlite */
	const struct settings_limits *limits;   /* read at each use */
};

struct backups;

/* Makes STATE_DIR/backup if missing and removes the copies left there by
 * a daemon that died. 0, or -errno with err. */
int backups_new(const struct backups_setup *setup, struct backups **out,
		struct asph_error *err);
/* Cancels the copies being made (each stops within a step), removes them
 * all and frees. */
void backups_free(struct backups *b);

enum backup_state {
	BACKUP_COPYING,
	BACKUP_DONE,
	BACKUP_FAILED,
};

const char *backup_state_name(enum backup_state s);

/* A copy as backup.get shows it; the strings live as long as the copy. */
struct backup_info {
	const char *name;               /* copy-TIME-N.sqlite */
	enum backup_state state;
	int64_t pages_done, pages_total;        /* of the store's pages */
	int64_t size;                   /* bytes, once done */
	const char *sha256;             /* hex, once done; else NULL */
	const char *error;              /* why it failed; else NULL */
	int64_t started_ns, finished_ns;        /* realtime; 0: not yet */
};

/*
 * Starts a copy for owner (who names it in the log), ending owner's
 * previous one. 0, -EBUSY when a copy is being made (err says for whom),
 * -EDQUOT when the state directory has not the room (err says how much),
 * or -errno with err.
 */
int backups_start(struct backups *b, const void *owner, const char *who,
		  struct asph_error *err);
/* owner's copy: 0, or -ENOENT when it has none. */
int backups_get(struct backups *b, const void *owner, struct backup_info *out);
/* The descriptor (borrowed) of owner's finished copy, to read with
 * pread(): 0, -ENOENT (no copy), -EAGAIN (still copying), -EIO (it failed:
 * backups_get() says why). */
int backups_fd(struct backups *b, const void *owner, int *fd);
/* owner is gone: its copy is removed (a copy being made, once its thread
 * has stopped). */
void backups_release(struct backups *b, const void *owner);

#endif
