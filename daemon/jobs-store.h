/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The jobs' tables in the store (store.h): the jobs, in the queue's order,
 * and the history of every state change. Written by the queue (jobs*.c)
 * only; the outbox reads the history (store_changes()). Event loop thread.
 */
#ifndef ASPHD_JOBS_STORE_H
#define ASPHD_JOBS_STORE_H

#include <stdbool.h>
#include <stdint.h>

#include "job.h"

struct store;

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

#endif
