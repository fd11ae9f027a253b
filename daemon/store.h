/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The job store: SQLite in WAL mode under the state directory. Jobs, their
 * states and every transition survive a restart. Used from the event loop
 * thread only.
 */
#ifndef ASPHD_STORE_H
#define ASPHD_STORE_H

#include <stdbool.h>
#include <stdint.h>

#include "asph/error.h"
#include "job.h"

struct store;

/* Opens or creates path; upgrades an older schema after a backup (below),
 * nothing it does not know (-EPROTO for a newer schema). */
int store_open(const char *path, struct store **out, struct asph_error *err);
void store_close(struct store *s);

/* Inserts j (id and seq are assigned and written back), with a history
 * entry. */
int store_insert(struct store *s, struct job_record *j, int64_t now_ns);
/* Ids up to last are taken (by job folders the store does not know, a
 * store put back from a backup): the next job gets a higher one. 1 when
 * that moved the next id, 0 when it was higher already, or -errno. */
int store_skip_ids(struct store *s, int64_t last);
/* -ENOENT when there is no such job. */
int store_get(struct store *s, int64_t id, struct job_record *out);

/* A state change with its history entry; reason may be NULL; actor names
 * who caused it (a user, a token; NULL: the daemon). */
int store_set_state(struct store *s, int64_t id, enum job_state state,
		    const char *reason, int64_t actor_uid, const char *actor, int64_t now_ns);
/* A state change as store_set_state(), with every mutable column of j
 * written in the same transaction. */
int store_transition(struct store *s, const struct job_record *j, enum job_state state,
		     const char *reason, int64_t actor_uid, const char *actor, int64_t now_ns);
/* Writes every mutable column of j (state history is not touched). */
int store_update(struct store *s, const struct job_record *j);
int store_set_progress(struct store *s, int64_t id, int64_t done,
		       int64_t total);

/* A filter's uid that selects every submitter (-1 is the uid of the jobs
 * submitted over TCP). */
#define STORE_ANY_UID INT64_MIN

struct store_filter {
	unsigned states;        /* bit per enum job_state; 0 = all */
	const char *instrument; /* or NULL */
	int64_t uid;            /* STORE_ANY_UID = any */
	const char *label;      /* exact, or NULL */
	const char *user;       /* the submitter's name, exact, or NULL */
	const char *part, *lot, *serial;        /* exact, or NULL */
	int64_t before_id;      /* only ids below; 0 = no bound */
	int64_t offset, limit;
	bool queue_order;       /* priority, seq, id; else newest first */
	/* queue_order, a listing taken up where it stopped (each a seek of
	 * the queue's index, so that a listing costs its length, not its
	 * square): with after, the jobs of priority after_priority after
	 * (after_seq, after_id); with below, those of a lower priority. */
	bool after, below;
	int64_t after_priority, after_seq, after_id;
};

typedef int (*store_job_fn)(const struct job_record *j, void *data);

/* Calls fn for each matching job; returns the count of jobs that match the
 * filter without offset/limit in *total (may be NULL). */
int store_list(struct store *s, const struct store_filter *f,
	       store_job_fn fn, void *data, int64_t *total);
/* The count of jobs that match the filter without offset/limit. */
int store_total(struct store *s, const struct store_filter *f, int64_t *total);

/* The queued job of an instrument that runs next; -ENOENT when none. */
int store_next(struct store *s, const char *instrument,
	       struct job_record *out);

struct store_event {
	int64_t t_ns;
	enum job_state state;
	const char *reason;
	int64_t actor_uid;
	const char *actor;      /* NULL: the daemon, or a store of schema 1 */
};
typedef int (*store_event_fn)(const struct store_event *e, void *data);
int store_history(struct store *s, int64_t id, store_event_fn fn, void *data);

/* Jobs that were running or paused when the daemon stopped become
 * interrupted; returns how many. */
int store_recover(struct store *s, int64_t now_ns);

/* Number of jobs per state. */
int store_count(struct store *s, int64_t counts[JOB_N_STATES]);

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

/* --- API tokens (tokens.c): name, role, SHA-256 of the secret */

struct store_token {
	const char *name;
	int role;
	const uint8_t *digest;  /* 32 bytes */
	int64_t created_ns, expires_ns, revoked_ns;     /* 0: never, not */
	const char *created_by;
};
typedef int (*store_token_fn)(const struct store_token *t, void *data);
/* -EEXIST when a token of that name exists (revoked or not). */
int store_token_insert(struct store *s, const struct store_token *t);
int store_token_list(struct store *s, store_token_fn fn, void *data);
/* -ENOENT when there is no such token, -EALREADY when it is revoked. */
int store_token_revoke(struct store *s, const char *name, int64_t now_ns);

/* --- the operator locks of instruments (jobs.c) */

struct store_lock {
	const char *instrument;
	const char *holder;     /* a user or token name */
	int64_t holder_uid;
	const char *reason;
	int64_t since_ns;
	bool pause;             /* a running job is paused while it holds */
	int64_t paused_job;     /* the job the lock paused, 0: none */
};
typedef int (*store_lock_fn)(const struct store_lock *l, void *data);
int store_lock_set(struct store *s, const struct store_lock *l);
int store_lock_clear(struct store *s, const char *instrument);
int store_lock_list(struct store *s, store_lock_fn fn, void *data);

/* --- the outbox (outbox.c): what waits for a broker or a database */

struct store_outbox_item {
	int64_t id;             /* assigned by store_outbox_add() */
	const char *sink;       /* "mqtt", "postgres" */
	const char *topic;      /* MQTT; NULL for the database */
	const char *payload;
	int qos;
	bool retain;
	const char *message_id;
	int64_t created_ns;
};
typedef int (*store_outbox_fn)(const struct store_outbox_item *it, void *data);
int store_outbox_add(struct store *s, struct store_outbox_item *it);
/* Items of sink with an id above after, oldest first, at most limit. */
int store_outbox_list(struct store *s, const char *sink, int64_t after, int64_t limit,
		      store_outbox_fn fn, void *data);
/* Acknowledged: gone. 0 also when it was gone before. */
int store_outbox_remove(struct store *s, int64_t id);
/* Items waiting for sink. */
int store_outbox_count(struct store *s, const char *sink, int64_t *n);
/* Moves item id (any sink) to sink to, keeping its id and text: 0, also
 * when it was gone. */
int store_outbox_move(struct store *s, int64_t id, const char *to);
/* Moves every item of sink from to sink to; *n: how many (may be NULL). */
int store_outbox_move_all(struct store *s, const char *from, const char *to, int64_t *n);

/* A state change as history keeps it, with the job's fields the outbox
 * tells: the rowid orders them. */
struct store_change {
	int64_t rowid;
	int64_t t_ns;
	const struct job_record *job;
	enum job_state state;
	int previous;           /* < 0: none (a new job) */
	const char *reason;
	const char *actor;
};
typedef int (*store_change_fn)(const struct store_change *c, void *data);
/* The changes after rowid after, in order, at most limit. */
int store_changes(struct store *s, int64_t after, int64_t limit, store_change_fn fn,
		  void *data);
/* The newest history rowid (0: none). */
int store_last_change(struct store *s, int64_t *rowid);

/* Runs several changes in one transaction. */
int store_begin(struct store *s);
int store_commit(struct store *s);
void store_rollback(struct store *s);

#endif
