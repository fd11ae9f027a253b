/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread: the workers. A queued job started on its instrument
 * (its folder, the disk guard, the worker's copy of what it needs), the
 * queue scheduled, the workers' reports (progress, the search of a plan,
 * the characterization, the end), a running job paused and resumed, and
 * the shutdown.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "dirs.h"
#include "jobs-internal.h"
#include "log.h"
#include "runner.h"
#include "store.h"
#include "util-time.h"
#include "util-mem.h"

/* Progress reaches the store at most this often (a restart resumes from
 * the scan file, not from this number). */
#define PROGRESS_STORE_NS 5000000000ull
/* What a recorded point takes on disk with its share of the result files
 * (a scan record of 56 bytes, a line of residuals.csv): for the disk guard
 * (limits.min_free_disk_mb). */
#define JOB_BYTES_PER_POINT 160

static void on_report(const struct runner_report *rep, void *data);

int jobs_start_workers(struct jobs *jobs, const struct instruments *ins,
		       struct asph_error *err)
{
	jobs->n_slots = instruments_count(ins);
	jobs->slots = calloc(jobs->n_slots, sizeof(*jobs->slots));
	if (!jobs->slots)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < jobs->n_slots; i++) {
		struct slot *sl = &jobs->slots[i];
		int r;

		sl->jobs = jobs;
		sl->in = instruments_get(ins, i);
		sl->act.eta_s = -1;
		r = runner_new(sl->in->config, jobs->event, on_report, sl, &sl->runner);
		if (r < 0)
			return asph_error_set(err, r, "instrument %s: cannot start its worker: %s",
					      sl->in->name, strerror(-r));
	}
	return 0;
}

static void set_fault(struct slot *sl, const char *fault)
{
	free(sl->fault);
	sl->fault = fault ? strdup(fault) : NULL;
	sl->act.fault = sl->fault;
}

/* ---------------------------------------------------------- starting */

static char *job_metadata(const struct job_record *j)
{
	char submitted[32];
	json_t *m;
	char *s;

	iso8601_utc(j->submitted_ns, 0, submitted, sizeof(submitted));
	m = json_pack("{s:I, s:s?, s:s?, s:s?, s:s?, s:{s:I, s:s?}, s:s, s:I, s:I}",
		      "job", (json_int_t)j->id, "label", j->label, "part", j->part, "lot", j->lot,
		      "serial", j->serial, "submitted_by", "uid", (json_int_t)j->uid,
		      "name", j->user, "submitted", submitted,
		      "started_ns", (json_int_t)j->started_ns,
		      "attempt", (json_int_t)j->attempts);
	s = m ? json_dumps(m, JSON_COMPACT) : NULL;
	json_decref(m);
	return s;
}

/* A restarted job keeps the earlier attempt's recording aside. */
static void set_aside(int dir_fd, int64_t id, int64_t attempt)
{
	char old[64];
	struct stat st;

	if (fstatat(dir_fd, RUNNER_SCAN_FILE, &st, AT_SYMLINK_NOFOLLOW) < 0)
		return;
	snprintf(old, sizeof(old), "scan-attempt%" PRId64 ".asphscan", attempt);
	if (renameat(dir_fd, RUNNER_SCAN_FILE, dir_fd, old) < 0)
		log_job(LOG_WARNING, id, "cannot keep the scan of attempt %" PRId64 ": %s",
			attempt, strerror(errno));
}

/* What the worker needs for j, whose folder is dir (dir_fd, taken). */
static struct runner_job *runner_job_of(struct jobs *jobs, const struct job_record *j,
					const char *dir, int dir_fd)
{
	struct runner_job *rj = calloc(1, sizeof(*rj));

	if (!rj) {
		close(dir_fd);
		return NULL;
	}
	rj->id = j->id;
	rj->dir_fd = dir_fd;
	rj->spec = strdup(j->spec);
	rj->result_dir = strdup(dir);
	rj->metadata = job_metadata(j);
	rj->resume = j->resume;
	rj->max_points = jobs->limits->max_plan_points;
	rj->progress_interval_ms = jobs->limits->progress_interval_ms;
	if (asprintf(&rj->scan_path, "%s/" RUNNER_SCAN_FILE, dir) < 0)
		rj->scan_path = NULL;
	if (!rj->spec || !rj->result_dir || !rj->metadata || !rj->scan_path) {
		runner_job_free(rj);
		return NULL;
	}
	return rj;
}

/* j cannot start, for reason: it fails (1), or stays queued when even that
 * cannot be recorded (< 0). */
static int fail_to_start(struct jobs *jobs, struct job_record *j, const char *reason)
{
	int r;

	log_job(LOG_ERR, j->id, "%s", reason);
	j->finished_ns = now_realtime_ns();
	r = jobs_transition(jobs, j, JOB_FAILED, reason, NULL, NULL);
	return r < 0 ? r : 1;
}

/* The disk space a recording of points (and its result files) takes. */
static uint64_t job_disk_mb(int64_t points)
{
	return ((uint64_t)(points > 0 ? points : 0) * JOB_BYTES_PER_POINT >> 20) + 1;
}

/* Whether the state directory has room for points more, and what it keeps
 * free (limits.min_free_disk_mb, 0: no check): 0, or -EDQUOT with why. */
int jobs_check_room(const struct jobs *jobs, int64_t points, char *why, size_t size)
{
	uint64_t free_mb, need = job_disk_mb(points), keep = jobs->limits->min_free_disk_mb;

	/* 0: no guard; a disk that fills is met as it comes (write_essential()). */
	if (!keep || dirs_free_mb(jobs->state_fd, &free_mb) < 0 || free_mb >= need + keep)
		return 0;
	snprintf(why, size, "the state directory has %" PRIu64 " MiB free: a recording of "
		 "%" PRId64 " points takes about %" PRIu64 " MiB, and limits.min_free_disk_mb "
		 "keeps %" PRIu64 " MiB free", free_mb, points, need, keep);
	return -EDQUOT;
}

/* Starts j on sl: 0, 1 when j failed to start (recorded), < 0 when it could
 * not even be failed (it stays queued). */
static int start_job(struct jobs *jobs, struct slot *sl, struct job_record *j)
{
	_cleanup_free_ char *dir = dirs_job_path(jobs->state_dir, j->id);
	struct runner_job *rj;
	char reason[512];
	int r, fd;

	if (!dir)
		return -ENOMEM;
	if (jobs_check_room(jobs, j->points_total - (j->resume ? j->points_done : 0), reason,
			    sizeof(reason)) < 0)
		return fail_to_start(jobs, j, reason);
	/* Room to record how this job ends, even if it fills the disk. */
	store_renew_reserve(jobs->store);
	fd = dirs_open_job(jobs->state_fd, j->id, true);
	if (fd < 0) {
		snprintf(reason, sizeof(reason), "cannot create the job directory %s: %s", dir,
			 fd == -ELOOP ? "it is a symbolic link" : strerror(-fd));
		return fail_to_start(jobs, j, reason);
	}
	if (!j->started_ns)
		j->started_ns = now_realtime_ns();
	j->attempts++;
	j->finished_ns = 0;
	free(j->scan_path);
	if (asprintf(&j->scan_path, "jobs/%" PRId64 "/" RUNNER_SCAN_FILE, j->id) < 0)
		j->scan_path = NULL;
	if (!j->resume && j->attempts > 1)
		set_aside(fd, j->id, j->attempts - 1);
	rj = runner_job_of(jobs, j, dir, fd);
	if (!rj || !j->scan_path) {
		runner_job_free(rj);
		return -ENOMEM;
	}
	/* From here on the scan file, once it exists, is what a later run
	 * continues. */
	j->resume = true;
	r = store_update(jobs->store, j);
	if (r < 0) {
		runner_job_free(rj);
		return r;
	}
	sl->act = (struct instrument_activity){
		.job = j->id, .done = j->points_done, .total = j->points_total, .eta_s = -1,
		.points_measured = sl->act.points_measured,
	};
	sl->last_progress_store_ns = 0;
	sl->counted = j->points_done;
	sl->cancel = false;
	set_fault(sl, NULL);
	r = runner_start(sl->runner, rj);
	if (r < 0) {
		sl->act.job = 0;
		runner_job_free(rj);
		return r;
	}
	log_job(LOG_INFO, j->id, "starting on %s (attempt %" PRId64 "%s)", sl->in->name,
		j->attempts, rj->resume ? ", resuming the recorded scan" : "");
	return jobs_transition(jobs, j, JOB_RUNNING, NULL, NULL, NULL);
}

/*
 * Starts the first queued job of sl. One that cannot start fails and the
 * next is taken at once, so that a job whose folder cannot be made does
 * not stall the queue. Returns false when the store could not be read or
 * written: the queue is tried again later.
 */
static bool schedule_slot(struct jobs *jobs, struct slot *sl)
{
	int64_t tries = jobs->counts[JOB_QUEUED];

	/* No job starts on a locked instrument. */
	while (!sl->act.lock && !sl->act.job && !runner_busy(sl->runner) && tries-- > 0) {
		struct job_record j;
		int r = store_next(jobs->store, sl->in->name, &j);

		if (r == -ENOENT)
			return true;
		if (r < 0)
			return false;
		r = start_job(jobs, sl, &j);
		if (r < 0)
			log_job(LOG_ERR, j.id, "cannot start: %s", strerror(-r));
		job_record_clear(&j);
		if (r < 0)
			return false;
	}
	return true;
}

/* After a store error the queue is tried again this much later. */
#define SCHEDULE_RETRY_USEC (5 * 1000000ull)

void jobs_schedule(struct jobs *jobs)
{
	bool retry = false;
	uint64_t now;

	if (!jobs->queue_running || jobs->stopping)
		return;
	for (size_t i = 0; i < jobs->n_slots; i++)
		retry |= !schedule_slot(jobs, &jobs->slots[i]);
	if (retry && sd_event_now(jobs->event, CLOCK_MONOTONIC, &now) >= 0) {
		sd_event_source_set_time(jobs->retry, now + SCHEDULE_RETRY_USEC);
		sd_event_source_set_enabled(jobs->retry, SD_EVENT_ONESHOT);
	}
}

int jobs_retry_schedule(sd_event_source *s, uint64_t usec, void *data)
{
	jobs_schedule(data);
	return 0;
}

/* ---------------------------------------------------------- the workers */

static void job_progress(struct slot *sl, const struct runner_report *rep)
{
	struct jobs *jobs = sl->jobs;
	uint64_t now = (uint64_t)now_realtime_ns();

	/* Points measured: what the progress passes beyond what was counted
	 * (from where the job started, for a resumed one where its last run
	 * had got to; the executor's last report is never coalesced away). */
	sl->act.planning = false;
	if (rep->kind == RUNNER_PROGRESS && (int64_t)rep->done > sl->counted) {
		sl->act.points_measured += (int64_t)rep->done - sl->counted;
		sl->counted = (int64_t)rep->done;
	}
	sl->act.done = (int64_t)rep->done;
	sl->act.total = (int64_t)rep->total;
	sl->act.rate = rep->rate;
	sl->act.eta_s = rep->eta_s;
	if (now - sl->last_progress_store_ns > PROGRESS_STORE_NS || rep->kind == RUNNER_STARTED) {
		store_set_progress(jobs->store, rep->job, sl->act.done, sl->act.total);
		sl->last_progress_store_ns = now;
	}
	events_job_progress(jobs->events, rep->job, sl->in->name, &sl->act);
}

/* The plan for the job's tolerance is searched (tolplan.h): the
 * characterizations run of the search's budget, shown but not stored (the
 * job's points are not known yet). */
static void job_planning(struct slot *sl, const struct runner_report *rep)
{
	struct instrument_activity *a = &sl->act;

	a->planning = true;
	a->done = (int64_t)rep->done;
	a->total = (int64_t)rep->total;
	a->rate = 0;
	a->eta_s = -1;
	events_job_progress(sl->jobs->events, rep->job, sl->in->name, a);
}

/* The recorded scan is being characterized: no points move any more;
 * then its Monte Carlo, if any, counts trials. */
static void job_characterizing(struct slot *sl, const struct runner_report *rep)
{
	struct instrument_activity *a = &sl->act;

	a->characterizing = true;
	a->rate = 0;
	a->eta_s = -1;
	if (rep->kind == RUNNER_UNCERTAINTY) {
		a->trials_done = (int64_t)rep->done;
		a->trials_planned = (int64_t)rep->total;
		a->trials_rate = rep->rate;
		a->eta_s = rep->eta_s;
	}
	events_job_progress(sl->jobs->events, rep->job, sl->in->name, a);
}

static bool any_running(const struct jobs *jobs)
{
	for (size_t i = 0; i < jobs->n_slots; i++)
		if (jobs->slots[i].act.job)
			return true;
	return false;
}

/*
 * What a job becomes when its worker reports outcome. A cancel that was
 * accepted while the job ran wins over how the scan ended, unless it
 * failed (a fault must show): a cancel after queue.stop's abort, or while
 * the recorded points were characterized, or after the last point but
 * before the loop heard of it, still cancels.
 */
static enum job_state job_end(const struct slot *sl, enum runner_outcome outcome)
{
	switch (outcome) {
	case RUNNER_COMPLETED:
		return sl->cancel ? JOB_CANCELLED : JOB_COMPLETED;
	case RUNNER_FAILED:
		return JOB_FAILED;
	case RUNNER_ABORTED:
		return JOB_CANCELLED;
	case RUNNER_STOPPED:
	default:
		return sl->cancel ? JOB_CANCELLED : JOB_INTERRUPTED;
	}
}

static void job_done(struct slot *sl, const struct runner_report *rep)
{
	struct jobs *jobs = sl->jobs;
	struct job_record j;
	enum job_state next = job_end(sl, rep->outcome);
	_cleanup_free_ char *cancel_by = steal_ptr(sl->cancel_by);
	struct job_actor canceller = { .uid = sl->cancel_uid, .name = cancel_by };
	const char *reason = NULL;

	sl->act.job = 0;
	sl->act.paused = sl->act.characterizing = sl->act.planning = false;
	sl->cancel = false;
	if (store_get(jobs->store, rep->job, &j) < 0) {
		log_job(LOG_ERR, rep->job, "finished, but is gone from the store");
		free(rep->result);
		return;
	}
	j.points_done = sl->act.done;
	switch (next) {
	case JOB_COMPLETED:
		/* A job run again (requeue with restart) had a result before. */
		free(j.result);
		j.result = rep->result;
		j.resume = false;
		j.points_done = sl->act.total;
		j.finished_ns = now_realtime_ns();
		break;
	case JOB_FAILED:
		reason = rep->reason;
		j.finished_ns = now_realtime_ns();
		set_fault(sl, rep->reason);
		events_instrument_fault(jobs->events, sl->in->name, j.id, rep->reason);
		break;
	case JOB_CANCELLED:
		/* Its recording stays: a requeue continues (or characterizes) it. */
		free(rep->result);
		j.finished_ns = now_realtime_ns();
		break;
	case JOB_INTERRUPTED:
	default:
		reason = jobs->stopping ? "the daemon stopped during the scan"
					: "the queue was stopped";
		break;
	}
	/* A cancel is the canceller's, though the worker's report ends it. */
	jobs_transition(jobs, &j, next, reason,
			next == JOB_CANCELLED && cancel_by ? &canceller : NULL, NULL);
	job_record_clear(&j);
	if (jobs->stopping) {
		if (!any_running(jobs) && jobs->stopped)
			jobs->stopped(jobs->stopped_data);
		return;
	}
	jobs_schedule(jobs);
}

static void on_report(const struct runner_report *rep, void *data)
{
	struct slot *sl = data;

	switch (rep->kind) {
	case RUNNER_PLANNING:
		if (rep->job == sl->act.job)
			job_planning(sl, rep);
		break;
	case RUNNER_STARTED:
	case RUNNER_PROGRESS:
		if (rep->job == sl->act.job)
			job_progress(sl, rep);
		break;
	case RUNNER_CHARACTERIZING:
	case RUNNER_UNCERTAINTY:
		if (rep->job == sl->act.job)
			job_characterizing(sl, rep);
		break;
	case RUNNER_PAUSED:
	case RUNNER_RESUMED:
		break;
	case RUNNER_DONE:
		job_done(sl, rep);
		break;
	}
}

void jobs_shutdown(struct jobs *jobs, void (*stopped)(void *data), void *data)
{
	jobs->stopping = true;
	jobs->stopped = stopped;
	jobs->stopped_data = data;
	for (size_t i = 0; i < jobs->n_slots; i++) {
		struct slot *sl = &jobs->slots[i];
		if (sl->act.job) {
			log_job(LOG_INFO, sl->act.job, "stopping the scan for shutdown");
			runner_stop(sl->runner);
		}
	}
	if (!any_running(jobs) && stopped)
		stopped(data);
}

/* running <-> paused: recorded first, then the worker is told, so that a
 * change the store cannot keep does not happen. */
int jobs_set_paused(struct jobs *jobs, struct job_record *j, struct slot *sl, bool pause,
		    const char *reason, const struct job_actor *who, struct asph_error *err)
{
	int r = jobs_transition(jobs, j, pause ? JOB_PAUSED : JOB_RUNNING, reason, who, err);

	if (r < 0)
		return r;
	sl->act.paused = pause;
	if (pause)
		runner_pause(sl->runner);
	else
		runner_resume(sl->runner);
	return 0;
}
