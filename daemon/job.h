/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job as the daemon knows it: its states and its record, which the queue
 * (jobs.h) changes, the job store (jobs-store.h) keeps, and the methods and
 * events tell. Pure: no state of its own, any thread.
 */
#ifndef ASPHD_JOB_H
#define ASPHD_JOB_H

#include <stdbool.h>
#include <stdint.h>

enum job_state {
	JOB_QUEUED = 0,
	JOB_RUNNING,
	JOB_PAUSED,
	JOB_COMPLETED,
	JOB_FAILED,
	JOB_CANCELLED,
	JOB_INTERRUPTED,
	JOB_N_STATES
};

const char *job_state_name(enum job_state s);
int job_state_from_name(const char *name, enum job_state *out);
/* Completed, failed, cancelled: nothing more happens unless re-queued. */
bool job_state_final(enum job_state s);

struct job_record {
	int64_t id;
	enum job_state state;
	int64_t priority;       /* higher runs first */
	int64_t seq;            /* then lower first */
	char *label;
	char *instrument;
	int64_t uid;
	char *user;
	char *spec;             /* the normalized submission, JSON */
	int64_t submitted_ns, started_ns, finished_ns;   /* 0 = not yet */
	int64_t points_done, points_total;
	char *reason;           /* of the last failure or interruption */
	char *result;           /* JSON, once completed */
	char *scan_path;        /* relative to the state directory */
	bool resume;            /* the next run continues scan_path */
	int64_t attempts;
	char *part, *lot, *serial;      /* what was measured; NULL: not given */
};

void job_record_clear(struct job_record *j);

#endif
