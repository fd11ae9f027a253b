/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * One worker thread per instrument runs one job at a time: it computes the
 * sampling plan, runs the scan through the executor into the job's scan
 * file, characterizes the recorded points and writes the result. Reports
 * come back to the event loop thread through an eventfd; progress (of the
 * scan and of the Monte Carlo uncertainty) is coalesced (only the newest
 * is kept) and rate-limited by the worker.
 */
#ifndef ASPHD_RUNNER_H
#define ASPHD_RUNNER_H

#include <stdbool.h>
#include <stdint.h>

#include <systemd/sd-event.h>

struct asph_instrument_config;

/* The recorded scan's name in its job's folder. */
#define RUNNER_SCAN_FILE "scan.asphscan"

/* What a worker needs for one job; every string and dir_fd are owned by
 * the job. */
struct runner_job {
	int64_t id;
	char *spec;             /* the normalized submission (JSON) */
	int dir_fd;             /* the job's folder: its files go through it */
	char *scan_path;        /* absolute, for messages and the scan's library */
	char *result_dir;       /* absolute; exists */
	char *metadata;         /* JSON for the scan header: job, submitter */
	bool resume;            /* continue scan_path */
	uint64_t max_points;
	uint32_t progress_interval_ms;
};

void runner_job_free(struct runner_job *j);

enum runner_report_kind {
	RUNNER_PLANNING,        /* the plan for the tolerance is searched:
				   done of total characterizations */
	RUNNER_STARTED,         /* the plan is computed; total is known */
	RUNNER_PROGRESS,
	RUNNER_CHARACTERIZING,  /* the scan is recorded; the result is being made */
	RUNNER_UNCERTAINTY,     /* its Monte Carlo: done of total (planned) trials */
	RUNNER_PAUSED,          /* the scan stopped at a point and waits */
	RUNNER_RESUMED,
	RUNNER_DONE,
};

enum runner_outcome {
	RUNNER_COMPLETED,       /* result written */
	RUNNER_FAILED,          /* reason says why; points kept */
	RUNNER_ABORTED,         /* cancelled (while measuring or characterizing) */
	RUNNER_STOPPED,         /* daemon shutdown: the scan is resumable */
};

struct runner_report {
	enum runner_report_kind kind;
	int64_t job;
	uint64_t done, total;   /* plan points (RUNNER_UNCERTAINTY: trials) */
	double rate;            /* points (trials) per second */
	double eta_s;           /* < 0 when not known */
	enum runner_outcome outcome;      /* RUNNER_DONE */
	char reason[512];                 /* RUNNER_DONE: failure reason */
	char *result;           /* RUNNER_DONE, completed: the result JSON,
				   owned by the receiver */
};

typedef void (*runner_report_fn)(const struct runner_report *rep, void *data);

struct runner;

/*
 * A worker for an instrument; it works on its own copy of the
 * configuration, whose simulated part follows each job's lens. Reports
 * are delivered on event's thread to fn.
 */
int runner_new(const struct asph_instrument_config *instrument,
	       sd_event *event, runner_report_fn fn, void *data,
	       struct runner **out);
/* Stops the current job (as runner_stop) and joins the thread. */
void runner_free(struct runner *r);

/* Starts job (ownership passes to the runner); -EBUSY while a job runs. */
int runner_start(struct runner *r, struct runner_job *job);
/* Controls of the running job; no effect when none runs. */
void runner_pause(struct runner *r);
void runner_resume(struct runner *r);
void runner_abort(struct runner *r);
/* Shutdown: stops at the next point, flushes, leaves the scan resumable. */
void runner_stop(struct runner *r);
bool runner_busy(struct runner *r);

#endif
