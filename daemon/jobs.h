/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The job queue: the one owner and writer of job state. Jobs wait in the
 * store (jobs-store.h) ordered by priority, then submission; each idle
 * instrument takes its first queued job and runs it on its worker
 * (runner.h). Every change of a job's state goes through this module: it
 * records the change, counts it, logs it and builds its event (events.h).
 * It also owns whether the queue runs, and what each instrument is doing.
 *
 * The operations return 0 or a negative errno, with a message in err
 * (may be NULL) for a person:
 *   -ENOENT   no such job
 *   -ENODEV   no such instrument
 *   -EINVAL   the job's state does not allow this
 *   -ENOBUFS  the queue is at its limit (limits.max_queue)
 *   -EDQUOT   the state directory has no room for the job's recording and
 *             limits.min_free_disk_mb
 *   -ENODATA  the job has no result
 *   -EPERM    a file that is not one of the job's result
 *   -EBUSY    the instrument is locked by another (jobs_lock())
 *   -ENOMEM   out of memory
 *   -EIO, -ENOSPC, -EROFS, ...: the store could not be read or written
 *
 * Event loop thread.
 */
#ifndef ASPHD_JOBS_H
#define ASPHD_JOBS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>
#include <systemd/sd-event.h>

#include "asph/error.h"
#include "events.h"
#include "instruments.h"
#include "jobs-store.h"
#include "settings.h"

struct jobs_setup {
	sd_event *event;                        /* the workers report here */
	const char *state_dir;                  /* jobs.sqlite and jobs/ID/ */
	const struct instruments *instruments;  /* one worker each */
	struct events *events;
	const struct settings_limits *limits;   /* read at each use: may change */
};

struct jobs;

/*
 * Opens the state directory (dirs_open_state(): checked from "/", made
 * private) and the job store in it, marks the jobs that were
 * running when the daemon stopped interrupted, and starts a worker per
 * instrument. Starts no job: jobs_schedule() does. The setup's pointers
 * must outlive jobs.
 */
int jobs_new(const struct jobs_setup *setup, struct jobs **out, struct asph_error *err);
/* Stops the workers (a running scan at its next point) and frees. */
void jobs_free(struct jobs *jobs);

/* Who asks for a change: recorded in the job's history, named in the log. */
struct job_actor {
	int64_t uid;
	const char *name;
};

struct job_submission {
	const char *spec;       /* the normalized specification (jobspec.h) */
	int64_t points;         /* its plan's size */
	const char *instrument; /* NULL: the first configured */
	int64_t priority;
	const char *label;      /* may be NULL */
	const char *part, *lot, *serial;        /* what is measured; each may be NULL */
	/* A job of measured data: the file jobs_open_data() gave, written,
	 * linked into the job's folder as data_name before the job can start;
	 * NULL (and data_fd unused) for a plan. */
	const char *data_name;
	int data_fd;
};

/* An unnamed file (O_TMPFILE) in the state directory, for a job's
 * measured data before the job exists; the descriptor or -errno. */
int jobs_open_data(const struct jobs *jobs);

/* Whether instrument (NULL: the first) names one of the daemon's
 * instruments: 0 or -ENODEV. */
int jobs_check_instrument(const struct jobs *jobs, const char *instrument,
			  struct asph_error *err);

/* Whether a job for instrument (NULL: the first) would be taken now: the
 * instrument exists and the queue has room. jobs_submit() checks it
 * again. */
int jobs_check_submit(const struct jobs *jobs, const char *instrument, struct asph_error *err);

/*
 * The changes. Each one that succeeds fills out (may be NULL; the caller
 * clears it with job_record_clear()) with the job as it is afterwards.
 */
int jobs_submit(struct jobs *jobs, const struct job_submission *sub,
		const struct job_actor *who, struct job_record *out, struct asph_error *err);
/* A queued or interrupted job is cancelled at once; a running or paused
 * one is stopped, and becomes cancelled when its worker has stopped: also
 * when the queue was stopped with abort before, or the worker was
 * characterizing the recorded scan or had just finished (but a job that
 * fails meanwhile stays failed). Its recording is kept. */
int jobs_cancel(struct jobs *jobs, int64_t id, const struct job_actor *who,
		struct job_record *out, struct asph_error *err);
int jobs_pause(struct jobs *jobs, int64_t id, const struct job_actor *who,
	       struct job_record *out, struct asph_error *err);
/* A paused job runs again; an interrupted one is queued to continue. */
int jobs_resume(struct jobs *jobs, int64_t id, const struct job_actor *who,
		struct job_record *out, struct asph_error *err);
/* A failed, interrupted or cancelled job is queued again, continuing its
 * recorded scan, or with restart recording a new one (a completed job
 * only with restart). */
int jobs_requeue(struct jobs *jobs, int64_t id, bool restart, const struct job_actor *who,
		 struct job_record *out, struct asph_error *err);
/* Moves a queued job to position among the queued jobs (0: next; past
 * the end: last); it takes the priority of the job it lands next to. */
int jobs_move(struct jobs *jobs, int64_t id, int64_t position, const struct job_actor *who,
	      struct asph_error *err);
int jobs_queue_start(struct jobs *jobs, const struct job_actor *who, struct asph_error *err);
/* No job starts any more; with abort the running scans stop at their next
 * point and their jobs become interrupted. */
int jobs_queue_stop(struct jobs *jobs, bool abort, const struct job_actor *who,
		    struct asph_error *err);

/*
 * The operator lock of an instrument: no job starts on it, and the
 * mutating calls of anyone but its holder (the same name and uid) on it or
 * its jobs fail with -EBUSY (err names the holder, the reason and since
 * when; err->field the instrument). With pause, its running job pauses at
 * the next point. The holder may lock again to change the reason or the
 * pause. The lock is kept in the store and outlives a restart.
 *   -ENODEV  no such instrument
 *   -EBUSY   locked by another
 */
int jobs_lock(struct jobs *jobs, const char *instrument, const char *reason, bool pause,
	      const struct job_actor *who, struct asph_error *err);
/* Ends the lock (force: whoever holds it); the job it paused runs again.
 * -EINVAL when it is not locked, -EBUSY when another holds it. */
int jobs_unlock(struct jobs *jobs, const char *instrument, bool force,
		const struct job_actor *who, struct asph_error *err);
/* The lock of instrument, or NULL. */
const struct instrument_lock *jobs_lock_of(const struct jobs *jobs, const char *instrument);

/* Starts the first queued job of every idle instrument. */
void jobs_schedule(struct jobs *jobs);
/*
 * Shutdown: starts no job any more and stops every running scan at its
 * next point (the job becomes interrupted and resumable). stopped(data)
 * is called once no worker runs a job, at once when none does.
 */
void jobs_shutdown(struct jobs *jobs, void (*stopped)(void *data), void *data);

/* --- reading */

int jobs_get(struct jobs *jobs, int64_t id, struct job_record *out, struct asph_error *err);
/* As store_list(). */
int jobs_list(struct jobs *jobs, const struct store_filter *f, store_job_fn fn, void *data,
	      int64_t *total, struct asph_error *err);
/* The number of jobs f selects (without its offset and limit). */
int jobs_count(struct jobs *jobs, const struct store_filter *f, int64_t *out,
	       struct asph_error *err);
/* The queue: running, paused and queued jobs, in the order they run. */
int jobs_list_queue(struct jobs *jobs, store_job_fn fn, void *data, struct asph_error *err);

/*
 * A listing taken a few jobs at a time (a long answer is made in slices,
 * turns.h): the jobs f selects (NULL: the queue, in the order it runs),
 * from f's offset and at most f's limit of them (0: all). It takes up
 * after the last job it gave: a job that moves in the meantime may be
 * left out or come twice, as in any listing made while the queue changes.
 */
struct jobs_cursor;
int jobs_cursor_new(struct jobs *jobs, const struct store_filter *f, struct jobs_cursor **out);
/* Up to max jobs through fn: 1 when more may follow, 0 at the end, or
 * -errno (err says what). */
int jobs_cursor_next(struct jobs_cursor *c, size_t max, store_job_fn fn, void *data,
		     struct asph_error *err);
void jobs_cursor_free(struct jobs_cursor *c);
int jobs_history(struct jobs *jobs, int64_t id, store_event_fn fn, void *data,
		 struct asph_error *err);
/* The job object of proto/README.md, with the live progress of a running
 * job. */
json_t *jobs_job_to_json(const struct jobs *jobs, const struct job_record *j);
/* The result of a completed job, with "dir", its folder. */
int jobs_result(struct jobs *jobs, int64_t id, json_t **out, struct asph_error *err);
/* One of the files of a completed job's result (a name its "files" lists),
 * opened for reading beneath the state directory without following a
 * symlink: *out is the descriptor. -ENODATA when the job has no result,
 * -EPERM for a name the result does not list. */
int jobs_result_file(struct jobs *jobs, int64_t id, const char *name, int *out,
		     struct asph_error *err);

bool jobs_queue_running(const struct jobs *jobs);
/* Jobs in each state. */
const int64_t *jobs_counts(const struct jobs *jobs);
/* What instrument i (as in instruments.h) is doing. */
const struct instrument_activity *jobs_activity(const struct jobs *jobs, size_t i);
/* One line for people: "idle", "measuring job 12: 45 %", "idle, queue
 * stopped", "stopping" (systemd's STATUS=, daemon.status). */
void jobs_status_text(const struct jobs *jobs, char *buf, size_t size);

#endif
