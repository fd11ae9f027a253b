/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the files of the job queue share. Calls go one way:
 *
 *   jobs.c (set up and end; the changes: submit, cancel, pause, resume,
 *           requeue, move, the queue started and stopped)
 *     → jobs-locks.c (the operator locks: taken, given back, restored at
 *                     the start, and what they refuse)
 *       → jobs-run.c (the workers: a job started on its instrument, the
 *                     queue scheduled, the workers' reports, pause and
 *                     resume of a running job, the shutdown)
 *         → jobs-state.c (the one place a job changes state, a job read
 *                         for a change, the instruments' slots)
 *   jobs-read.c (what is read: a job, listings and cursors, results, the
 *                counts and the activity) → jobs-state.c
 *
 * Event loop thread.
 */
#ifndef ASPHD_JOBS_INTERNAL_H
#define ASPHD_JOBS_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <systemd/sd-event.h>

#include "jobs.h"
#include "runner.h"
#include "store.h"

/* An instrument as the queue sees it: its worker and what it does. */
struct slot {
	struct jobs *jobs;
	const struct instrument *in;
	struct runner *runner;
	struct instrument_activity act;
	char *fault;                    /* act.fault */
	uint64_t last_progress_store_ns;
	bool cancel;                    /* its job's cancel was accepted */
	int64_t cancel_uid;             /* by whom: the history's actor */
	char *cancel_by;
	struct instrument_lock lock;    /* act.lock points here when locked */
	int64_t counted;                /* plan points of its job in act.points_measured */
};

struct jobs {
	sd_event *event;
	struct store *store;
	struct events *events;
	const struct settings_limits *limits;
	char *state_dir;
	int state_fd;                   /* dirs.h: every file goes through it */
	sd_event_source *retry;         /* jobs_schedule() again, after a store error */
	struct slot *slots;
	size_t n_slots;
	int64_t counts[JOB_N_STATES];   /* jobs per state */
	bool queue_running;
	bool stopping;
	void (*stopped)(void *data);
	void *stopped_data;
};

/* ---------------------------------------------------------- jobs-locks.c */

/* The locks outlive a restart. */
int jobs_load_locks(struct jobs *jobs, struct asph_error *err);
void jobs_lock_release(struct slot *sl);
/* -EBUSY when sl is locked by someone other than who: err says by whom and
 * why, its field names the instrument. */
int jobs_check_lock(const struct slot *sl, const struct job_actor *who,
		    struct asph_error *err);

/* ------------------------------------------------------------ jobs-run.c */

/* A worker for each instrument. */
int jobs_start_workers(struct jobs *jobs, const struct instruments *ins,
		       struct asph_error *err);
/* jobs->retry's callback: jobs_schedule() again. */
int jobs_retry_schedule(sd_event_source *s, uint64_t usec, void *data);
/* Whether the state directory has room for points more, and what it keeps
 * free (limits.min_free_disk_mb, 0: no check): 0, or -EDQUOT with why. */
int jobs_check_room(const struct jobs *jobs, int64_t points, char *why, size_t size);
/* running <-> paused: recorded first, then the worker is told, so that a
 * change the store cannot keep does not happen. */
int jobs_set_paused(struct jobs *jobs, struct job_record *j, struct slot *sl, bool pause,
		    const char *reason, const struct job_actor *who, struct asph_error *err);

/* ---------------------------------------------------------- jobs-state.c */

struct slot *jobs_slot_of_instrument(struct jobs *jobs, const char *name);
const struct slot *jobs_slot_of_instrument_name(const struct jobs *jobs, const char *name);
struct slot *jobs_slot_of_job(struct jobs *jobs, int64_t id);
/* The one place a job changes state: j (with its other columns as they are
 * in j) is recorded in the new state, counted, logged and told to the
 * watchers. reason may be NULL. */
int jobs_transition(struct jobs *jobs, struct job_record *j, enum job_state s,
		    const char *reason, const struct job_actor *who, struct asph_error *err);
/* Reads job id for a change. */
int jobs_load(struct jobs *jobs, int64_t id, struct job_record *j, struct asph_error *err);
/* Back to the queue; with restart a new recording. */
int jobs_back_to_queue(struct jobs *jobs, struct job_record *j, bool restart,
		       const struct job_actor *who, struct asph_error *err);
/* The overall verdict of a completed job's result ("pass", "fail",
 * "undecided") in buf, or NULL when it had no tolerance. */
const char *jobs_verdict(const struct job_record *j, char buf[16]);

#endif
