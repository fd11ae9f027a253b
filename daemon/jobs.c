/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The queue: jobs wait in the store ordered by priority, then submission;
 * each idle instrument takes its first queued job. Every state change goes
 * through jobs_set_state(), which records it and tells the subscribers.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "asphd.h"
#include "dirs.h"
#include "log.h"
#include "time-util.h"
#include "util-mem.h"

/* Progress reaches the store at most this often (a restart resumes from
 * the scan file, not from this number). */
#define PROGRESS_STORE_NS 5000000000ull

static json_t *time_json(int64_t ns)
{
	char buf[32];

	if (ns <= 0)
		return json_null();
	iso8601_utc(ns, buf, sizeof(buf));
	return json_string(buf);
}

int jobs_init(struct daemon *d)
{
	_cleanup_free_ char *v = NULL;
	int n = store_recover(d->store, realtime_now_ns());

	if (n < 0)
		return n;
	if (n > 0)
		log_notice("%d job(s) were interrupted when the daemon stopped; "
			   "resume or re-queue them", n);
	d->queue_running = true;
	if (store_meta_get(d->store, "queue.running", &v) == 0)
		d->queue_running = strcmp(v, "0") != 0;
	return store_count(d->store, d->counts);
}

json_t *job_to_json(struct daemon *d, const struct job_record *j)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(j->spec, 0, NULL);
	struct instrument *in = j->state == JOB_RUNNING || j->state == JOB_PAUSED
		? instrument_of_job(d, j->id) : NULL;
	int64_t done = in ? in->done : j->points_done;
	int64_t total = in && in->total ? in->total : j->points_total;
	json_t *lens = json_object_get(spec, "lens");
	json_t *o;

	o = json_pack("{s:I, s:s, s:s?, s:s, s:I, s:{s:I, s:s?}, s:O?, s:O?, s:O?,"
		      " s:o, s:o, s:o, s:{s:I, s:I, s:f, s:f}, s:s?, s:I, s:b}",
		"id", (json_int_t)j->id,
		"state", job_state_name(j->state),
		"label", j->label,
		"instrument", j->instrument,
		"priority", (json_int_t)j->priority,
		"submitter", "uid", (json_int_t)j->uid, "name", j->user,
		"lens", json_object_get(lens, "name"),
		"plan", json_object_get(spec, "plan"),
		"fit", json_object_get(spec, "fit"),
		"submitted", time_json(j->submitted_ns),
		"started", time_json(j->started_ns),
		"finished", time_json(j->finished_ns),
		"progress", "done", (json_int_t)done, "total", (json_int_t)total,
		"rate", in ? in->rate : 0.0, "eta_s", in ? in->eta_s : -1.0,
		"reason", j->reason,
		"attempts", (json_int_t)j->attempts,
		"resumable", j->resume);
	return o;
}

int jobs_set_state(struct daemon *d, struct job_record *j, enum job_state s,
		   const char *reason, int64_t actor)
{
	enum job_state old = j->state;
	int r = store_set_state(d->store, j->id, s, reason, actor, realtime_now_ns());

	if (r == -ENOSPC && store_release_reserve(d->store) == 0) {
		log_job(LOG_WARNING, j->id, "the state directory is full: using the store's reserve "
			"to record the state %s", job_state_name(s));
		r = store_set_state(d->store, j->id, s, reason, actor, realtime_now_ns());
	}
	if (r < 0) {
		log_job(LOG_ERR, j->id, "cannot record the state %s: %s", job_state_name(s),
			strerror(-r));
		return r;
	}
	d->counts[old]--;
	d->counts[s]++;
	j->state = s;
	if (reason && reason != j->reason) {
		free(j->reason);
		j->reason = strdup(reason);
	}
	log_job(s == JOB_FAILED ? LOG_WARNING : LOG_INFO, j->id, "%s -> %s%s%s",
		job_state_name(old), job_state_name(s), reason ? ": " : "", reason ? reason : "");
	server_broadcast(d, EVENT_JOB, j->id, "job.state",
			 json_pack("{s:I, s:s, s:s, s:s?, s:s}", "job", (json_int_t)j->id,
				   "state", job_state_name(s), "previous", job_state_name(old),
				   "reason", reason, "instrument", j->instrument));
	daemon_update_status(d);
	return 0;
}

static char *job_metadata(const struct job_record *j)
{
	char submitted[32];
	json_t *m;
	char *s;

	iso8601_utc(j->submitted_ns, submitted, sizeof(submitted));
	m = json_pack("{s:I, s:s?, s:{s:I, s:s?}, s:s, s:I, s:I}", "job", (json_int_t)j->id,
		      "label", j->label, "submitted_by", "uid", (json_int_t)j->uid,
		      "name", j->user, "submitted", submitted,
		      "started_ns", (json_int_t)j->started_ns,
		      "attempt", (json_int_t)j->attempts);
	s = m ? json_dumps(m, JSON_COMPACT) : NULL;
	json_decref(m);
	return s;
}

/* A restarted job keeps the earlier attempt's recording aside. */
static void set_aside(const char *scan, int64_t attempt)
{
	_cleanup_free_ char *old = NULL;
	struct stat st;

	if (stat(scan, &st) < 0)
		return;
	if (asprintf(&old, "%.*s-attempt%" PRId64 ".asphscan",
		     (int)(strlen(scan) - strlen(".asphscan")), scan, attempt) < 0)
		return;
	if (rename(scan, old) < 0)
		log_warning("cannot keep %s: %s", scan, strerror(errno));
}

static int start_job(struct daemon *d, struct instrument *in, struct job_record *j)
{
	_cleanup_free_ char *dir = dirs_job_path(d->state_dir, j->id);
	struct runner_job *rj;
	int r;

	if (!dir)
		return -ENOMEM;
	/* Room to record how this job ends, even if it fills the disk. */
	store_renew_reserve(d->store);
	r = dirs_make_job(d->state_dir, j->id);
	if (r < 0) {
		char reason[512];
		snprintf(reason, sizeof(reason), "cannot create the job directory %s: %s", dir,
			 strerror(-r));
		log_job(LOG_ERR, j->id, "%s", reason);
		j->finished_ns = realtime_now_ns();
		return jobs_set_state(d, j, JOB_FAILED, reason, 0);
	}
	rj = calloc(1, sizeof(*rj));
	if (!rj)
		return -ENOMEM;
	if (!j->started_ns)
		j->started_ns = realtime_now_ns();
	j->attempts++;
	j->finished_ns = 0;
	free(j->scan_path);
	if (asprintf(&j->scan_path, "jobs/%" PRId64 "/scan.asphscan", j->id) < 0)
		j->scan_path = NULL;
	rj->id = j->id;
	rj->spec = strdup(j->spec);
	rj->result_dir = strdup(dir);
	rj->metadata = job_metadata(j);
	rj->resume = j->resume;
	rj->max_points = d->config->limits.max_plan_points;
	rj->progress_interval_ms = d->config->limits.progress_interval_ms;
	if (asprintf(&rj->scan_path, "%s/scan.asphscan", dir) < 0)
		rj->scan_path = NULL;
	if (!rj->spec || !rj->result_dir || !rj->metadata || !rj->scan_path || !j->scan_path) {
		runner_job_free(rj);
		return -ENOMEM;
	}
	if (!j->resume && j->attempts > 1)
		set_aside(rj->scan_path, j->attempts - 1);
	/* From here on the scan file, once it exists, is what a later run
	 * continues. */
	j->resume = true;
	r = store_update(d->store, j);
	if (r < 0) {
		runner_job_free(rj);
		return r;
	}
	in->job = j->id;
	in->paused = false;
	in->done = j->points_done;
	in->total = j->points_total;
	in->rate = 0;
	in->eta_s = -1;
	in->last_progress_store_ns = 0;
	free(in->fault);
	in->fault = NULL;
	r = runner_start(in->runner, rj);
	if (r < 0) {
		in->job = 0;
		runner_job_free(rj);
		return r;
	}
	log_job(LOG_INFO, j->id, "starting on %s (attempt %" PRId64 "%s)", in->name,
		j->attempts, rj->resume ? ", resuming the recorded scan" : "");
	return jobs_set_state(d, j, JOB_RUNNING, NULL, 0);
}

void jobs_schedule(struct daemon *d)
{
	if (!d->queue_running || d->shutting_down)
		return;
	for (size_t i = 0; i < d->n_instruments; i++) {
		struct instrument *in = &d->instruments[i];
		struct job_record j;

		if (in->job || runner_busy(in->runner))
			continue;
		if (store_next(d->store, in->name, &j) < 0)
			continue;
		if (start_job(d, in, &j) < 0)
			log_job(LOG_ERR, j.id, "cannot start");
		job_record_clear(&j);
	}
}

static void job_progress(struct instrument *in, const struct runner_report *rep)
{
	struct daemon *d = in->d;
	uint64_t now = (uint64_t)realtime_now_ns();

	in->done = (int64_t)rep->done;
	in->total = (int64_t)rep->total;
	in->rate = rep->rate;
	in->eta_s = rep->eta_s;
	if (now - in->last_progress_store_ns > PROGRESS_STORE_NS || rep->kind == RUNNER_STARTED) {
		store_set_progress(d->store, rep->job, in->done, in->total);
		in->last_progress_store_ns = now;
	}
	server_broadcast(d, EVENT_PROGRESS, rep->job, "job.progress",
			 json_pack("{s:I, s:s, s:I, s:I, s:f, s:f}", "job", (json_int_t)rep->job,
				   "instrument", in->name, "done", (json_int_t)in->done,
				   "total", (json_int_t)in->total, "rate", in->rate,
				   "eta_s", in->eta_s));
	daemon_update_status(d);
}

static void job_done(struct instrument *in, const struct runner_report *rep)
{
	struct daemon *d = in->d;
	struct job_record j;
	enum job_state next;
	const char *reason = NULL;

	in->job = 0;
	in->paused = false;
	if (store_get(d->store, rep->job, &j) < 0) {
		log_job(LOG_ERR, rep->job, "finished, but is gone from the store");
		free(rep->result);
		return;
	}
	j.points_done = in->done;
	switch (rep->outcome) {
	case RUNNER_COMPLETED:
		next = JOB_COMPLETED;
		j.result = rep->result;
		j.resume = false;
		j.points_done = in->total;
		j.finished_ns = realtime_now_ns();
		break;
	case RUNNER_FAILED:
		next = JOB_FAILED;
		reason = rep->reason;
		j.finished_ns = realtime_now_ns();
		free(in->fault);
		in->fault = strdup(rep->reason);
		server_broadcast(d, EVENT_INSTRUMENT, 0, "instrument.fault",
				 json_pack("{s:s, s:I, s:s}", "instrument", in->name,
					   "job", (json_int_t)j.id, "reason", rep->reason));
		break;
	case RUNNER_ABORTED:
		next = JOB_CANCELLED;
		j.finished_ns = realtime_now_ns();
		break;
	case RUNNER_STOPPED:
	default:
		next = JOB_INTERRUPTED;
		reason = d->shutting_down ? "the daemon stopped during the scan"
					  : "the queue was stopped";
		break;
	}
	int r = store_update(d->store, &j);
	if (r == -ENOSPC && store_release_reserve(d->store) == 0) {
		log_job(LOG_WARNING, j.id, "the state directory is full: using the store's reserve "
			"to record how the job ended");
		r = store_update(d->store, &j);
	}
	if (r < 0)
		log_job(LOG_ERR, j.id, "cannot record the result: %s", strerror(-r));
	jobs_set_state(d, &j, next, reason, 0);
	job_record_clear(&j);
	if (d->shutting_down) {
		for (size_t i = 0; i < d->n_instruments; i++)
			if (d->instruments[i].job)
				return;
		sd_event_exit(d->event, d->exit_code);
		return;
	}
	jobs_schedule(d);
}

void jobs_runner_report(struct instrument *in, const struct runner_report *rep)
{
	switch (rep->kind) {
	case RUNNER_STARTED:
	case RUNNER_PROGRESS:
		if (rep->job == in->job)
			job_progress(in, rep);
		break;
	case RUNNER_PAUSED:
	case RUNNER_RESUMED:
		break;
	case RUNNER_DONE:
		job_done(in, rep);
		break;
	}
}

void jobs_shutdown(struct daemon *d)
{
	bool busy = false;

	d->shutting_down = true;
	for (size_t i = 0; i < d->n_instruments; i++) {
		struct instrument *in = &d->instruments[i];
		if (in->job) {
			log_job(LOG_INFO, in->job, "stopping the scan for shutdown");
			runner_stop(in->runner);
			busy = true;
		}
	}
	if (!busy)
		sd_event_exit(d->event, d->exit_code);
}
