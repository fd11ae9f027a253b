/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The worker thread of one instrument. It owns the instrument's devices
 * while a job runs; the event loop only flips controls (under the lock)
 * and receives reports through a mailbox. worker() and what it calls
 * run on the worker thread; runner_new(), the controls and on_report()
 * on the event loop thread.
 */
#include <errno.h>
#include <fcntl.h>
#include <malloc.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <jansson.h>

#include "asph-engine/executor.h"
#include "asph-driver/instrument.h"
#include "asph/plan.h"
#include "asph/points.h"
#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "log.h"
#include "mailbox.h"
#include "jobplan.h"
#include "result.h"
#include "runner.h"
#include "tolplan.h"
#include "util-mem.h"
#include "util-time.h"

#define INSTRUMENT_TIMEOUT_MS 10000

struct runner {
	struct asph_config *own;        /* this worker's copy of the instrument */
	struct asph_instrument_config *ic;    /* own's: its lens follows the job */
	runner_report_fn fn;
	void *data;
	struct mailbox *mailbox;        /* reports for the loop */
	pthread_t thread;
	bool thread_started;

	pthread_mutex_t lock;
	pthread_cond_t cond;
	/* under lock */
	struct runner_job *job;         /* waiting or running */
	bool running, quit;
	bool want_pause, want_abort, want_stop;
	struct asph_scan *scan;
};

void runner_job_free(struct runner_job *j)
{
	if (!j)
		return;
	free(j->spec);
	if (j->dir_fd >= 0)
		close(j->dir_fd);
	free(j->scan_path);
	free(j->result_dir);
	free(j->metadata);
	free(j);
}

/* ------------------------------------------------------------ reports */

static void post(struct runner *r, struct runner_report *rep)
{
	/* When memory is out the report is lost (its result freed), as it
	 * was when the loop could not hold it. */
	mailbox_post(r->mailbox, rep);
}

static void on_report(void *msg, void *data)
{
	struct runner *r = data;

	r->fn(msg, r->data);
}

/* Reports nobody will read: free what they own. */
static void drop_report(void *msg, void *data)
{
	struct runner_report *rep = msg;

	free(rep->result);
}

/* Only the newest progress matters to the loop. */
static bool replaces(const void *last, const void *msg)
{
	const struct runner_report *a = last, *b = msg;

	return (b->kind == RUNNER_PROGRESS || b->kind == RUNNER_UNCERTAINTY ||
		b->kind == RUNNER_PLANNING) && a->kind == b->kind;
}

static void on_progress(const struct asph_scan_progress *p, void *data)
{
	struct runner *r = data;
	struct runner_report rep = {
		.kind = RUNNER_PROGRESS,
		.done = p->done,
		.total = p->total,
		.rate = p->rate,
		.eta_s = p->eta_s,
	};

	pthread_mutex_lock(&r->lock);
	rep.job = r->job ? r->job->id : 0;
	pthread_mutex_unlock(&r->lock);
	post(r, &rep);
}

/* ---------------------------------------------------------- the job */

struct run {
	struct runner *r;
	struct runner_job *job;
	struct job_plan jp;             /* parsed spec, surface, plan */
	struct asph_instrument *inst;
	struct asph_scanfile *recovered;        /* a resumed scan as it was */
	struct asph_error err;
	struct runner_report *final;
	uint64_t trials_start_ns, trials_post_ns;       /* the Monte Carlo's */
	char *spec;             /* the plan chosen for the tolerance, or NULL */
	char *choice;           /* and why (tolplan.h) */
};

/* The final report is posted by the worker once the runner is idle again,
 * so that the loop may start the next job as soon as it reads it. */
static void done(struct run *run, enum runner_outcome outcome, char *result)
{
	struct runner_report *rep = run->final;

	*rep = (struct runner_report){
		.kind = RUNNER_DONE,
		.job = run->job->id,
		.outcome = outcome,
		.result = result,
	};
	if (outcome == RUNNER_FAILED)
		asph_error_format(&run->err, rep->reason, sizeof(rep->reason));
}

/* The plan the scan's header records: with the plan chosen for the job's
 * tolerance, how it was chosen ("for_tolerance"), so that the result, and
 * asph replay of the scan, tell it (lib/characterize reads it back). */
static char *header_plan(const struct run *run)
{
	json_t *plan, *choice;
	char *text;

	if (!run->choice)
		return strdup(run->jp.plan_json);
	plan = json_loads(run->jp.plan_json, 0, NULL);
	choice = json_loads(run->choice, 0, NULL);
	if (!json_is_object(plan) || !json_is_object(choice)) {
		json_decref(plan);
		json_decref(choice);
		return NULL;
	}
	if (json_object_set_new(plan, "for_tolerance", choice) < 0) {	/* takes choice */
		json_decref(plan);
		return NULL;
	}
	text = json_dumps(plan, JSON_COMPACT);
	json_decref(plan);
	return text;
}

static int open_writer(struct run *run, uint64_t *start,
		       struct asph_scanfile_writer **w)
{
	struct runner_job *job = run->job;
	struct asph_scanfile_writer_options wo = { 0 };
	_cleanup_free_ char *instrument = NULL, *plan = NULL;
	struct asph_scanfile_header_info info;
	struct stat st;
	bool exists;
	int r;

	*start = 0;
	/* Never through a symlink: what is in the folder is looked at through
	 * its descriptor; a fresh recording is created exclusively. */
	exists = fstatat(job->dir_fd, RUNNER_SCAN_FILE, &st, AT_SYMLINK_NOFOLLOW) == 0;
	if (exists && !S_ISREG(st.st_mode) && job->resume)
		return asph_error_set(&run->err, -ELOOP, "%s is not a regular file: refusing to "
				      "continue it", job->scan_path);
	if (job->resume && exists) {
		wo.flags = ASPH_SCANFILE_REOPEN_ENDED;
		r = asph_scan_reopen_at(job->dir_fd, RUNNER_SCAN_FILE, run->jp.plan, &wo, w, start,
					&run->recovered, &run->err);
		if (r < 0)
			return r;
		log_job(LOG_INFO, job->id, "resuming the scan at plan point %" PRIu64, *start);
		return 0;
	}
	r = asph_instrument_config_to_json(run->r->ic, &instrument);
	if (r < 0)
		return asph_error_set(&run->err, r, "cannot describe the instrument");
	info.prescription = run->jp.prescription_json;
	plan = header_plan(run);
	if (!plan)
		return asph_error_set(&run->err, -ENOMEM, "out of memory");
	info.plan = plan;
	info.instrument = instrument;
	info.metadata = job->metadata;
	if (exists && unlinkat(job->dir_fd, RUNNER_SCAN_FILE, 0) < 0)
		return asph_error_set(&run->err, -errno, "%s: cannot replace it: %s",
				      job->scan_path, strerror(errno));
	return asph_scanfile_writer_create_at(job->dir_fd, RUNNER_SCAN_FILE, &info, &wo, w,
					      &run->err);
}

/* Runs the executor; returns its code. */
static int measure(struct run *run)
{
	struct runner *r = run->r;
	struct asph_scanfile_writer *w = NULL;
	struct asph_scan_options so = {
		.flags = ASPH_SCAN_ABORT_RESUMABLE | ASPH_SCAN_STREAM,
		.progress = on_progress,
		.progress_data = r,
		.progress_interval_ns = (uint64_t)run->job->progress_interval_ms * 1000000u,
		/* Short sweeps keep progress, pause and stop prompt. */
		.stream_batch = 256,
	};
	struct asph_scan *scan = NULL;
	int rc;

	/* a simulated part is the lens the job measures, unless configured */
	rc = asph_instrument_config_set_lens(r->ic, run->jp.prescription_json, &run->err);
	if (rc < 0)
		return rc;
	rc = asph_instrument_open(r->ic, INSTRUMENT_TIMEOUT_MS, &run->inst, &run->err);
	if (rc < 0)
		return rc;
	rc = open_writer(run, &so.start_index, &w);
	if (rc == -EALREADY && run->job->resume) {
		/* The daemon stopped after the scan's last point and before its
		 * result: there is nothing left to measure. */
		log_job(LOG_INFO, run->job->id, "the recorded scan is complete: characterizing it");
		asph_error_clear(&run->err);
		return 0;
	}
	if (rc < 0)
		return rc;
	so.recovered = run->recovered;
	rc = asph_scan_new(run->inst, run->jp.surface, run->jp.plan->xyz, run->jp.plan->n,
			   &so, &scan, &run->err);
	if (rc < 0) {
		asph_scanfile_writer_close(w, NULL);
		return rc;
	}
	pthread_mutex_lock(&r->lock);
	r->scan = scan;
	if (r->want_abort || r->want_stop)
		asph_scan_abort(scan);
	else if (r->want_pause)
		asph_scan_pause(scan);
	pthread_mutex_unlock(&r->lock);

	rc = asph_scan_run(scan, w, &run->err);

	pthread_mutex_lock(&r->lock);
	r->scan = NULL;
	pthread_mutex_unlock(&r->lock);
	asph_scan_free(scan);
	return rc;
}

/* Whether the job was cancelled (result_build() asks between its steps). */
static bool abort_wanted(void *data)
{
	struct runner *r = data;
	bool yes;

	pthread_mutex_lock(&r->lock);
	yes = r->want_abort;
	pthread_mutex_unlock(&r->lock);
	return yes;
}

/* The Monte Carlo's progress, at most every progress_interval_ms as the
 * scan's, its start and its end always. */
static void on_trials(void *data, size_t done, size_t planned, bool last)
{
	struct run *run = data;
	uint64_t now = now_monotonic_ns();
	uint64_t interval = (uint64_t)run->job->progress_interval_ms * 1000000u;
	struct runner_report rep = {
		.kind = RUNNER_UNCERTAINTY, .job = run->job->id, .done = done, .total = planned,
		.eta_s = -1,
	};
	double elapsed;

	if (done == 0 && !last)
		run->trials_start_ns = now;
	else if (!last && now - run->trials_post_ns < interval)
		return;
	run->trials_post_ns = now;
	elapsed = (double)(now - run->trials_start_ns) * 1e-9;
	if (done > 0 && elapsed > 0) {
		rep.rate = (double)done / elapsed;
		rep.eta_s = (double)(planned - done) / rep.rate;
	}
	post(run->r, &rep);
}

/* Cancelled, or the daemon stops: the search ends (it starts again when
 * the job is resumed). */
static bool search_stopped(void *data)
{
	struct runner *r = data;
	bool yes;

	pthread_mutex_lock(&r->lock);
	yes = r->want_abort || r->want_stop;
	pthread_mutex_unlock(&r->lock);
	return yes;
}

static bool search_cancelled(void *data)
{
	const struct run *run = data;

	return search_stopped(run->r);
}

/* A plan characterized: a log line and the job's progress. */
static void search_step(void *data, const struct asph_plan_search_status *st)
{
	struct run *run = data;
	struct runner_report rep = {
		.kind = RUNNER_PLANNING, .job = run->job->id, .done = st->characterizations,
		.total = st->budget, .eta_s = -1,
	};
	char line[256];

	tolplan_step_format(st, line, sizeof(line));
	log_job(LOG_INFO, run->job->id, "plan for the tolerance: %s", line);
	post(run->r, &rep);
}

/* The plan for the job's tolerance, when it asks for one: run->spec. */
static int choose_plan(struct run *run)
{
	const struct tolplan_hooks hooks = { .cancelled = search_cancelled, .step = search_step,
					     .data = run };
	struct runner_report rep = { .kind = RUNNER_PLANNING, .job = run->job->id, .eta_s = -1,
				     .total = ASPH_PLAN_SEARCH_DEFAULT_BUDGET };
	int rc;

	if (!tolplan_wanted(run->job->spec))
		return 0;
	post(run->r, &rep);
	rc = tolplan_choose(run->job->spec, run->job->max_points, run->r->ic, &hooks, &run->spec,
			    &run->choice, &run->err);
	if (rc == 0) {
		char line[256];
		tolplan_choice_format(run->choice, line, sizeof(line));
		log_job(LOG_INFO, run->job->id, "plan for the tolerance chosen: %s", line);
	}
	return rc;
}

static void characterize(struct run *run)
{
	struct runner_job *job = run->job;
	struct result_source src = {
		.job = job->id, .dir_fd = job->dir_fd, .dir = job->result_dir,
		.metadata = job->metadata, .cancelled = abort_wanted, .cancelled_data = run->r,
		.trials = on_trials, .trials_data = run,
	};
	struct runner_report rep = { .kind = RUNNER_CHARACTERIZING, .job = job->id, .eta_s = -1 };
	char *result = NULL;
	int rc;

	post(run->r, &rep);
	rc = result_build(&src, &run->jp, run->r->ic, &result, &run->err);
	if (rc == -ECANCELED)
		done(run, RUNNER_ABORTED, NULL);
	else
		done(run, rc < 0 ? RUNNER_FAILED : RUNNER_COMPLETED, result);
}

/*
 * A job of measured data (jobspec.h, "measured"): no plan and no device;
 * its data, copied into its folder when it was submitted, characterized
 * as the scan of a measured job is.
 */
static bool run_measured(struct runner *r, struct runner_job *job, struct runner_report *final)
{
	struct run run = { .r = r, .job = job, .final = final };
	struct runner_report rep = { .kind = RUNNER_CHARACTERIZING, .job = job->id, .eta_s = -1 };
	_cleanup_(json_decrefp) json_t *spec = json_loads(job->spec, 0, NULL);
	json_t *m = json_object_get(spec, "measured");
	const char *units = json_string_value(json_object_get(m, "units"));
	const char *name = json_string_value(json_object_get(m, "file"));
	struct asph_points_read_options ro = { 0 };
	struct result_source src = {
		.job = job->id, .dir_fd = job->dir_fd, .dir = job->result_dir,
		.metadata = job->metadata, .cancelled = abort_wanted, .cancelled_data = r,
	};
	char *result = NULL;
	int rc;

	if (!m)
		return false;
	asph_error_clear(&run.err);
	rc = job_plan_build_part(job->spec, &run.jp, &run.err);
	if (rc == 0 && (!name || asph_points_format_parse(json_string_value(
				json_object_get(m, "format")), &ro.format) < 0 ||
			(units && asph_points_unit_parse(units, &ro.unit_mm) < 0)))
		rc = asph_error_set(&run.err, -EINVAL, "the stored measured data's description "
				    "is damaged");
	if (rc == 0) {
		post(r, &rep);
		rc = result_build_measured(&src, &run.jp, &ro, name, &result, &run.err);
	}
	if (rc == -ECANCELED)
		done(&run, RUNNER_ABORTED, NULL);
	else
		done(&run, rc < 0 ? RUNNER_FAILED : RUNNER_COMPLETED, result);
	job_plan_release(&run.jp);
	return true;
}

static void run_job(struct runner *r, struct runner_job *job, struct runner_report *final)
{
	struct run run = { .r = r, .job = job, .final = final };
	struct runner_report rep = { .kind = RUNNER_STARTED, .job = job->id, .eta_s = -1 };
	bool stop;
	int rc;

	if (run_measured(r, job, final))
		return;
	asph_error_clear(&run.err);
	rc = choose_plan(&run);
	if (rc == 0)
		rc = job_plan_build(run.spec ? run.spec : job->spec, job->max_points, &run.jp,
				    &run.err);
	if (rc < 0) {
		stop = search_stopped(r);
		done(&run, rc != -ECANCELED ? RUNNER_FAILED :
		     stop && !abort_wanted(r) ? RUNNER_STOPPED : RUNNER_ABORTED, NULL);
		job_plan_release(&run.jp);
		free(run.spec);
		free(run.choice);
		return;
	}
	rep.total = run.jp.plan->n;
	post(r, &rep);
	rc = measure(&run);
	asph_instrument_close(run.inst);
	asph_scanfile_free(run.recovered);
	/* measured: the characterization reads the points from the scan, and
	 * the plan's (24 bytes each) need not stay beside it */
	asph_plan_free(steal_ptr(run.jp.plan));
	pthread_mutex_lock(&r->lock);
	stop = r->want_stop;
	pthread_mutex_unlock(&r->lock);
	if (rc == -ECANCELED)
		done(&run, stop ? RUNNER_STOPPED : RUNNER_ABORTED, NULL);
	else if (rc < 0)
		done(&run, RUNNER_FAILED, NULL);
	else
		characterize(&run);
	job_plan_release(&run.jp);
	free(run.spec);
	free(run.choice);
}

static void *worker(void *data)
{
	struct runner *r = data;

	pthread_mutex_lock(&r->lock);
	for (;;) {
		while (!r->quit && (!r->job || r->running))
			pthread_cond_wait(&r->cond, &r->lock);
		if (r->quit)
			break;
		struct runner_job *job = r->job;
		r->running = true;
		pthread_mutex_unlock(&r->lock);

		struct runner_report final;
		run_job(r, job, &final);

		pthread_mutex_lock(&r->lock);
		r->job = NULL;
		r->running = false;
		r->want_pause = r->want_abort = r->want_stop = false;
		runner_job_free(job);
		pthread_mutex_unlock(&r->lock);
		/* A job's points, plan and characterization come and go in
		 * hundreds of MiB: give the freed pages back, in every arena,
		 * rather than hold them until the next job. */
		malloc_trim(0);
		post(r, &final);
		pthread_mutex_lock(&r->lock);
	}
	pthread_mutex_unlock(&r->lock);
	return NULL;
}

/* ---------------------------------------------------------- controls */

int runner_new(const struct asph_instrument_config *instrument,
	       sd_event *event, runner_report_fn fn, void *data,
	       struct runner **out)
{
	struct runner *r = calloc(1, sizeof(*r));
	int rc;

	if (!r)
		return -ENOMEM;
	pthread_mutex_init(&r->lock, NULL);
	pthread_cond_init(&r->cond, NULL);
	rc = asph_instrument_config_copy(instrument, &r->own, NULL);
	if (rc < 0) {
		runner_free(r);
		return rc;
	}
	r->ic = &r->own->instruments[0];
	r->fn = fn;
	r->data = data;
	rc = mailbox_new(&(struct mailbox_setup){
			.event = event, .size = sizeof(struct runner_report),
			.deliver = on_report, .drop = drop_report, .replaces = replaces,
			.data = r }, &r->mailbox);
	if (rc >= 0) {
		rc = -pthread_create(&r->thread, NULL, worker, r);
		r->thread_started = rc == 0;
	}
	if (rc < 0) {
		runner_free(r);
		return rc;
	}
	*out = r;
	return 0;
}

void runner_free(struct runner *r)
{
	if (!r)
		return;
	if (r->thread_started) {
		runner_stop(r);
		pthread_mutex_lock(&r->lock);
		r->quit = true;
		pthread_cond_broadcast(&r->cond);
		pthread_mutex_unlock(&r->lock);
		pthread_join(r->thread, NULL);
	}
	mailbox_free(r->mailbox);
	runner_job_free(r->job);
	pthread_cond_destroy(&r->cond);
	pthread_mutex_destroy(&r->lock);
	asph_config_free(r->own);
	free(r);
}

int runner_start(struct runner *r, struct runner_job *job)
{
	pthread_mutex_lock(&r->lock);
	if (r->job) {
		pthread_mutex_unlock(&r->lock);
		return -EBUSY;
	}
	r->job = job;
	r->want_pause = r->want_abort = r->want_stop = false;
	pthread_cond_broadcast(&r->cond);
	pthread_mutex_unlock(&r->lock);
	return 0;
}

void runner_pause(struct runner *r)
{
	pthread_mutex_lock(&r->lock);
	r->want_pause = true;
	if (r->scan)
		asph_scan_pause(r->scan);
	pthread_mutex_unlock(&r->lock);
}

void runner_resume(struct runner *r)
{
	pthread_mutex_lock(&r->lock);
	r->want_pause = false;
	if (r->scan)
		asph_scan_resume(r->scan);
	pthread_mutex_unlock(&r->lock);
}

static void abort_with(struct runner *r, bool stop)
{
	pthread_mutex_lock(&r->lock);
	if (r->job) {
		if (stop)
			r->want_stop = true;
		else
			r->want_abort = true;
		if (r->scan)
			asph_scan_abort(r->scan);
	}
	pthread_mutex_unlock(&r->lock);
}

void runner_abort(struct runner *r)
{
	abort_with(r, false);
}

void runner_stop(struct runner *r)
{
	abort_with(r, true);
}

bool runner_busy(struct runner *r)
{
	bool busy;

	pthread_mutex_lock(&r->lock);
	busy = r->job != NULL;
	pthread_mutex_unlock(&r->lock);
	return busy;
}
