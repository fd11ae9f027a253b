/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The job state machine (daemon/jobs*.c) against a job store in a temporary
 * state directory, with real workers measuring through mock instruments
 * and no sockets: every transition, with its record, count, history and
 * event, and every refused transition, which changes nothing.
 */
#include <dirent.h>
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <syslog.h>
#include <unistd.h>

#include <cmocka.h>

#include "jobs.h"
#include "jobspec.h"
#include "log.h"
#include "rmtree.h"
#include "util-mem.h"

/* fast and faulty measure without waiting (faulty fails at its tenth
 * point); slow1 and slow2 in real time, about 1000 points a second, so
 * that a scan of SLOW_POINTS runs for as long as a test needs it to. */
#define MOCK(name, tf, probe_extra)                                            \
	"{\"name\": \"" name "\", \"stage\": {\"driver\": \"mock\", \"options\":" \
	" {\"time_factor\": " tf "}}, \"probe\": {\"driver\": \"mock\", "        \
	"\"options\": {\"time_factor\": " tf probe_extra "}}}"
static const char instruments_json[] =
	"{\"instruments\": [" MOCK("fast", "0", "") ", " MOCK("slow1", "0.02", "") ", "
	MOCK("slow2", "0.02", "") ", " MOCK("faulty", "0", ", \"fail_after\": 10") "]}";
#define FAST_POINTS 60
#define SLOW_POINTS 40000

static const struct job_actor root = { .uid = 0, .name = "root" };
static const struct job_actor anna = { .uid = 1013, .name = "anna" };

struct seen {
	char method[32];
	int64_t job;
	char state[16], previous[16];
	char reason[256];
};

struct fixture {
	char dir[64];
	struct settings *settings;
	struct settings_limits limits;
	sd_event *event;
	struct events *events;
	struct instruments *ins;
	struct jobs *jobs;
	struct seen seen[512];
	size_t n_seen;
	int stopped;
};

static void copy(char *dst, size_t size, json_t *v)
{
	snprintf(dst, size, "%s", json_is_string(v) ? json_string_value(v)
				  : json_is_null(v) ? "null" : "");
}

/* The watch: every event, in order. */
static void record(const struct event *ev, void *data)
{
	struct fixture *f = data;
	struct seen *s;

	assert_true(f->n_seen < ARRAY_SIZE(f->seen));
	s = &f->seen[f->n_seen++];
	snprintf(s->method, sizeof(s->method), "%s", ev->method);
	s->job = json_integer_value(json_object_get(ev->params, "job"));
	copy(s->state, sizeof(s->state), json_object_get(ev->params, "state"));
	copy(s->previous, sizeof(s->previous), json_object_get(ev->params, "previous"));
	copy(s->reason, sizeof(s->reason), json_object_get(ev->params, "reason"));
}

static void start_jobs(struct fixture *f)
{
	struct asph_error err;

	asph_error_clear(&err);
	if (jobs_new(&(struct jobs_setup){
			.event = f->event, .state_dir = f->dir, .instruments = f->ins,
			.events = f->events, .limits = &f->limits,
		     }, &f->jobs, &err) < 0)
		fail_msg("jobs_new: %s", err.message);
}

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));
	struct asph_error err;

	log_setup(LOG_CRIT);
	snprintf(f->dir, sizeof(f->dir), "/tmp/test-jobs-XXXXXX");
	assert_non_null(mkdtemp(f->dir));
	assert_int_equal(settings_defaults(&f->settings), 0);
	f->settings->instruments_json = strdup(instruments_json);
	f->limits = f->settings->limits;
	asph_error_clear(&err);
	if (instruments_load(f->settings, &f->ins, &err) < 0)
		fail_msg("instruments: %s", err.message);
	assert_int_equal(sd_event_new(&f->event), 0);
	assert_int_equal(events_new(&f->events), 0);
	assert_true(events_watch_add(f->events, EVENT_ALL, record, f, NULL) > 0);
	start_jobs(f);
	/* A new store's queue runs; these tests start it when they mean to. */
	assert_int_equal(jobs_queue_stop(f->jobs, false, &root, NULL), 0);
	f->n_seen = 0;
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;
	jobs_free(f->jobs);
	events_free(f->events);
	instruments_free(f->ins);
	settings_free(f->settings);
	sd_event_unref(f->event);
	assert_int_equal(rmtree(f->dir), 0);
	free(f);
	return 0;
}

/* ---------------------------------------------------------- helpers */

static int64_t submit_to(struct fixture *f, const char *instrument, int points,
			 int64_t priority)
{
	char params[128];
	json_t *p, *spec = NULL;
	struct proto_why why;
	uint64_t n = 0;
	struct job_record j;
	int64_t id;

	snprintf(params, sizeof(params),
		 "{\"lens\": \"strong\", \"plan\": {\"method\": \"fermat\", \"points\": %d}}", points);
	p = json_loads(params, 0, NULL);
	assert_int_equal(jobspec_from_params(p, &(struct jobspec_limits){
			.max_points = f->limits.max_plan_points,
			.max_point_terms = f->limits.max_plan_point_terms }, &spec, &n, &why), 0);
	char *text = json_dumps(spec, JSON_COMPACT);
	struct job_submission sub = {
		.spec = text, .points = (int64_t)n, .instrument = instrument,
		.priority = priority, .label = "part-17",
	};
	assert_int_equal(jobs_submit(f->jobs, &sub, &anna, &j, NULL), 0);
	assert_int_equal(j.state, JOB_QUEUED);
	assert_string_equal(j.instrument, instrument ? instrument : "fast");
	assert_int_equal(j.uid, anna.uid);
	id = j.id;
	job_record_clear(&j);
	free(text);
	json_decref(spec);
	json_decref(p);
	return id;
}

static struct job_record get(struct fixture *f, int64_t id)
{
	struct job_record j;

	assert_int_equal(jobs_get(f->jobs, id, &j, NULL), 0);
	return j;
}

static enum job_state state_of(struct fixture *f, int64_t id)
{
	struct job_record j = get(f, id);
	enum job_state s = j.state;

	job_record_clear(&j);
	return s;
}

/* Runs the event loop (the workers' reports) until job id is in none of
 * the states of mask, and returns the state it is in then. */
static enum job_state run_while(struct fixture *f, int64_t id, unsigned mask)
{
	enum job_state s;

	while ((1u << (s = state_of(f, id))) & mask)
		assert_true(sd_event_run(f->event, UINT64_MAX) >= 0);
	return s;
}

#define BUSY (1u << JOB_QUEUED | 1u << JOB_RUNNING | 1u << JOB_PAUSED)

/* Runs the event loop until the worker of job id has its plan (its total
 * is known): a scan that is measuring. */
static void run_until_measuring(struct fixture *f, size_t instrument, int64_t id)
{
	const struct instrument_activity *a = jobs_activity(f->jobs, instrument);

	assert_int_equal(a->job, id);
	while (a->done == 0)
		assert_true(sd_event_run(f->event, UINT64_MAX) >= 0);
}

static int64_t count(struct fixture *f, enum job_state s)
{
	return jobs_counts(f->jobs)[s];
}

static int ignore(const struct job_record *j, void *data)
{
	return 0;
}

/* The counts agree with the store, state by state. */
static void assert_counts(struct fixture *f)
{
	for (int s = 0; s < JOB_N_STATES; s++) {
		struct store_filter one = { .uid = STORE_ANY_UID, .states = 1u << s, .limit = 1 };
		int64_t n = -1;

		assert_int_equal(jobs_list(f->jobs, &one, ignore, NULL, &n, NULL), 0);
		assert_int_equal(count(f, (enum job_state)s), n);
	}
}

struct ids {
	int64_t v[8];
	size_t n;
};

static int collect(const struct job_record *j, void *data)
{
	struct ids *ids = data;

	if (ids->n < ARRAY_SIZE(ids->v))
		ids->v[ids->n++] = j->id;
	return 0;
}

/* The queue, in the order it runs. */
static struct ids queue_of(struct fixture *f)
{
	struct ids ids = { 0 };

	assert_int_equal(jobs_list_queue(f->jobs, collect, &ids, NULL), 0);
	return ids;
}

/* The last job.state event of job id. */
static const struct seen *last_state_event(struct fixture *f, int64_t id)
{
	for (size_t i = f->n_seen; i-- > 0;)
		if (!strcmp(f->seen[i].method, "job.state") && f->seen[i].job == id)
			return &f->seen[i];
	return NULL;
}

static void assert_event(struct fixture *f, int64_t id, const char *previous, const char *state)
{
	const struct seen *s = last_state_event(f, id);

	assert_non_null(s);
	assert_string_equal(s->previous, previous);
	assert_string_equal(s->state, state);
}

struct history {
	enum job_state states[16];
	int64_t actors[16];
	size_t n;
};

static int add_history(const struct store_event *e, void *data)
{
	struct history *h = data;

	if (h->n < ARRAY_SIZE(h->states)) {
		h->states[h->n] = e->state;
		h->actors[h->n] = e->actor_uid;
	}
	h->n++;
	return 0;
}

static struct history history_of(struct fixture *f, int64_t id)
{
	struct history h = { 0 };

	assert_int_equal(jobs_history(f->jobs, id, add_history, &h, NULL), 0);
	return h;
}

/* ------------------------------------------------------- transitions */

static void test_submit(void **state)
{
	struct fixture *f = *state;
	struct asph_error err;
	int64_t a = submit_to(f, NULL, FAST_POINTS, 0);
	struct job_record j = get(f, a);

	assert_int_equal(j.state, JOB_QUEUED);
	assert_string_equal(j.label, "part-17");
	assert_int_equal(j.points_total, FAST_POINTS);
	assert_true(j.submitted_ns > 0);
	assert_int_equal(j.started_ns, 0);
	job_record_clear(&j);
	assert_int_equal(count(f, JOB_QUEUED), 1);
	assert_counts(f);
	/* A new job: no previous state. */
	assert_event(f, a, "null", "queued");
	struct history h = history_of(f, a);
	assert_int_equal(h.n, 1);
	assert_int_equal(h.states[0], JOB_QUEUED);
	assert_int_equal(h.actors[0], anna.uid);

	/* Refused: an instrument nobody configured; a full queue. */
	struct job_submission sub = { .spec = "{}", .instrument = "nosuch" };
	asph_error_clear(&err);
	assert_int_equal(jobs_submit(f->jobs, &sub, &anna, NULL, &err), -ENODEV);
	assert_non_null(strstr(err.message, "nosuch"));
	f->limits.max_queue = 1;
	assert_int_equal(jobs_check_submit(f->jobs, NULL, NULL), -ENOBUFS);
	sub.instrument = NULL;
	asph_error_clear(&err);
	assert_int_equal(jobs_submit(f->jobs, &sub, &anna, NULL, &err), -ENOBUFS);
	assert_non_null(strstr(err.message, "limit"));
	assert_int_equal(count(f, JOB_QUEUED), 1);
	assert_counts(f);
}

static void test_run_to_completion(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "fast", FAST_POINTS, 0);
	json_t *res = NULL;
	char status[128];

	assert_int_equal(jobs_result(f->jobs, a, &res, NULL), -ENODATA);
	jobs_status_text(f->jobs, status, sizeof(status));
	assert_string_equal(status, "idle, queue stopped");
	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_true(jobs_queue_running(f->jobs));
	/* Started at once on the idle instrument. */
	assert_int_equal(state_of(f, a), JOB_RUNNING);
	assert_event(f, a, "queued", "running");
	assert_int_equal(jobs_activity(f->jobs, 0)->job, a);
	assert_int_equal(run_while(f, a, BUSY), JOB_COMPLETED);
	assert_event(f, a, "running", "completed");

	struct job_record j = get(f, a);
	assert_int_equal(j.attempts, 1);
	assert_true(j.started_ns > 0 && j.finished_ns >= j.started_ns);
	assert_int_equal(j.points_done, FAST_POINTS);
	assert_false(j.resume);
	job_record_clear(&j);
	assert_int_equal(jobs_activity(f->jobs, 0)->job, 0);
	assert_int_equal(jobs_activity(f->jobs, 0)->points_measured, FAST_POINTS);
	assert_int_equal(jobs_result(f->jobs, a, &res, NULL), 0);
	assert_non_null(json_object_get(res, "summary"));
	assert_non_null(strstr(json_string_value(json_object_get(res, "dir")), f->dir));
	json_decref(res);
	struct history h = history_of(f, a);
	assert_int_equal(h.n, 3);
	assert_int_equal(h.states[1], JOB_RUNNING);
	assert_int_equal(h.states[2], JOB_COMPLETED);
	jobs_status_text(f->jobs, status, sizeof(status));
	assert_string_equal(status, "idle");
	assert_counts(f);
}

static void test_cancel_queued(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "fast", FAST_POINTS, 0);
	struct job_record j;

	assert_int_equal(jobs_cancel(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_CANCELLED);
	assert_true(j.finished_ns > 0);
	job_record_clear(&j);
	assert_int_equal(state_of(f, a), JOB_CANCELLED);
	assert_event(f, a, "queued", "cancelled");
	struct history h = history_of(f, a);
	assert_int_equal(h.n, 2);
	assert_int_equal(h.actors[1], root.uid);
	assert_int_equal(count(f, JOB_CANCELLED), 1);
	assert_int_equal(count(f, JOB_QUEUED), 0);
	assert_counts(f);
}

static void test_pause_resume_cancel(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", SLOW_POINTS, 0);
	struct job_record j;
	char status[128], want[64];

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	assert_int_equal(jobs_pause(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_PAUSED);
	job_record_clear(&j);
	assert_event(f, a, "running", "paused");
	assert_true(jobs_activity(f->jobs, 1)->paused);
	assert_string_equal(instrument_state_name(jobs_activity(f->jobs, 1)), "paused");
	jobs_status_text(f->jobs, status, sizeof(status));
	snprintf(want, sizeof(want), "paused job %" PRId64 ": ", a);
	assert_non_null(strstr(status, want));

	assert_int_equal(jobs_resume(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_RUNNING);
	job_record_clear(&j);
	assert_event(f, a, "paused", "running");
	assert_false(jobs_activity(f->jobs, 1)->paused);
	jobs_status_text(f->jobs, status, sizeof(status));
	snprintf(want, sizeof(want), "measuring job %" PRId64 ": ", a);
	assert_non_null(strstr(status, want));

	/* A running scan stops first: the job says running until it has. */
	assert_int_equal(jobs_cancel(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_RUNNING);
	job_record_clear(&j);
	assert_int_equal(run_while(f, a, BUSY), JOB_CANCELLED);
	assert_event(f, a, "running", "cancelled");
	j = get(f, a);
	assert_true(j.finished_ns > 0);
	assert_true(j.points_done > 0 && j.points_done < SLOW_POINTS);
	/* The recording is kept to be continued. */
	assert_true(j.resume);
	job_record_clear(&j);
	assert_int_equal(jobs_activity(f->jobs, 1)->job, 0);
	assert_counts(f);
}

static void test_cancel_paused(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", SLOW_POINTS, 0);

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	assert_int_equal(jobs_pause(f->jobs, a, &root, NULL, NULL), 0);
	assert_int_equal(jobs_cancel(f->jobs, a, &root, NULL, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_CANCELLED);
	assert_event(f, a, "paused", "cancelled");
	assert_counts(f);
}

static void test_driver_fault(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "faulty", FAST_POINTS, 0);
	const struct instrument_activity *act = jobs_activity(f->jobs, 3);
	size_t faults = 0;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_FAILED);
	assert_event(f, a, "running", "failed");
	assert_true(last_state_event(f, a)->reason[0]);
	struct job_record j = get(f, a);
	assert_non_null(j.reason);
	assert_string_equal(j.reason, last_state_event(f, a)->reason);
	assert_true(j.finished_ns > 0);
	job_record_clear(&j);
	for (size_t i = 0; i < f->n_seen; i++)
		faults += !strcmp(f->seen[i].method, "instrument.fault") && f->seen[i].job == a;
	assert_int_equal(faults, 1);
	assert_non_null(act->fault);
	assert_string_equal(instrument_state_name(act), "fault");
	assert_counts(f);
}

static void test_queue_stop_abort(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", SLOW_POINTS, 0);
	struct job_record j;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	assert_int_equal(jobs_queue_stop(f->jobs, true, &root, NULL), 0);
	assert_false(jobs_queue_running(f->jobs));
	assert_int_equal(run_while(f, a, BUSY), JOB_INTERRUPTED);
	assert_event(f, a, "running", "interrupted");
	assert_string_equal(last_state_event(f, a)->reason, "the queue was stopped");
	j = get(f, a);
	assert_true(j.resume);
	assert_int_equal(j.finished_ns, 0);
	job_record_clear(&j);

	/* Resumed: queued to continue (the queue is stopped: it waits). */
	assert_int_equal(jobs_resume(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_QUEUED);
	assert_null(j.reason);
	assert_true(j.resume);
	job_record_clear(&j);
	assert_event(f, a, "interrupted", "queued");
	assert_int_equal(state_of(f, a), JOB_QUEUED);

	/* Started again, it continues its recording: a second attempt. */
	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_int_equal(state_of(f, a), JOB_RUNNING);
	j = get(f, a);
	assert_int_equal(j.attempts, 2);
	job_record_clear(&j);
	assert_int_equal(jobs_queue_stop(f->jobs, true, &root, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_INTERRUPTED);

	/* An interrupted job can be cancelled. */
	assert_int_equal(jobs_cancel(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_CANCELLED);
	job_record_clear(&j);
	assert_event(f, a, "interrupted", "cancelled");
	assert_counts(f);
}

/* The points measured on an instrument: each plan point once, also when
 * the scan was stopped and continued (the metric asphd_points_measured_total). */
static void test_points_measured(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", 1500, 0);
	const struct instrument_activity *act = jobs_activity(f->jobs, 1);

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	assert_int_equal(jobs_queue_stop(f->jobs, true, &root, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_INTERRUPTED);
	assert_true(act->points_measured > 0 && act->points_measured < 1500);
	assert_int_equal(jobs_resume(f->jobs, a, &root, NULL, NULL), 0);
	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_COMPLETED);
	assert_int_equal(act->points_measured, 1500);
	assert_int_equal(jobs_activity(f->jobs, 0)->points_measured, 0);
}

/* queue.stop abort, then job.cancel before the scan has stopped: the
 * cancel is not lost, the job ends cancelled (not interrupted). */
static void test_cancel_after_queue_stop_abort(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", SLOW_POINTS, 0);
	struct history h;
	struct job_record j;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	assert_int_equal(jobs_queue_stop(f->jobs, true, &root, NULL), 0);
	assert_int_equal(jobs_cancel(f->jobs, a, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_RUNNING);         /* stopping: the worker decides when */
	job_record_clear(&j);
	assert_int_equal(run_while(f, a, BUSY), JOB_CANCELLED);
	assert_event(f, a, "running", "cancelled");
	h = history_of(f, a);
	assert_int_equal(h.states[h.n - 1], JOB_CANCELLED);
	for (size_t i = 0; i < h.n; i++)
		assert_int_not_equal(h.states[i], JOB_INTERRUPTED);
	j = get(f, a);
	assert_true(j.finished_ns > 0);
	/* The recording stays: re-queued, the job continues it. */
	assert_true(j.resume);
	job_record_clear(&j);
	assert_int_equal(jobs_activity(f->jobs, 1)->job, 0);
	assert_counts(f);
}

/*
 * A cancel while the recorded points are characterized: the job ends
 * cancelled, with no result, its recording kept; re-queued it is
 * characterized again and completes. The cancel is taken while the loop
 * sees the worker characterizing (its RUNNER_CHARACTERIZING report); a
 * worker fast enough to finish first still ends the job cancelled, since
 * the cancel was accepted while the job ran. 20000 points; 4000 under
 * valgrind (ASPH_UNDER_VALGRIND), where measuring and characterizing
 * 20000 twice took most of this program's time.
 */
static void test_cancel_while_characterizing(void **state)
{
	struct fixture *f = *state;
	const char *valgrind = getenv("ASPH_UNDER_VALGRIND");
	const int points = valgrind && *valgrind && strcmp(valgrind, "0") ? 4000 : 20000;
	int64_t a = submit_to(f, "fast", points, 0);
	const struct instrument_activity *act = jobs_activity(f->jobs, 0);
	char status[128];
	struct job_record j;
	bool seen = false;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	while (state_of(f, a) == JOB_RUNNING && !(seen = act->characterizing))
		assert_true(sd_event_run(f->event, UINT64_MAX) >= 0);
	if (seen) {
		jobs_status_text(f->jobs, status, sizeof(status));
		assert_non_null(strstr(status, "characterizing"));
	} else {
		print_message("the worker finished before the loop saw it characterize\n");
	}
	assert_int_equal(state_of(f, a), JOB_RUNNING);
	assert_int_equal(jobs_cancel(f->jobs, a, &root, NULL, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_CANCELLED);
	assert_event(f, a, "running", "cancelled");
	j = get(f, a);
	assert_null(j.result);
	assert_int_equal(j.points_done, points);
	job_record_clear(&j);
	assert_int_equal(jobs_result(f->jobs, a, &(json_t *){ NULL }, NULL), -ENODATA);

	/* The scan was complete: re-queued, it is characterized, not measured. */
	assert_int_equal(jobs_requeue(f->jobs, a, false, &root, NULL, NULL), 0);
	assert_int_equal(run_while(f, a, BUSY), JOB_COMPLETED);
	j = get(f, a);
	assert_non_null(j.result);
	assert_int_equal(j.attempts, 2);
	job_record_clear(&j);
	assert_counts(f);
}

static void test_requeue(void **state)
{
	struct fixture *f = *state;
	int64_t failed = submit_to(f, "faulty", FAST_POINTS, 0);
	int64_t done = submit_to(f, "fast", FAST_POINTS, 0);
	int64_t cancelled;
	struct job_record j;
	char aside[128];
	struct stat st;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_int_equal(run_while(f, failed, BUSY), JOB_FAILED);
	assert_int_equal(run_while(f, done, BUSY), JOB_COMPLETED);
	assert_int_equal(jobs_queue_stop(f->jobs, false, &root, NULL), 0);
	cancelled = submit_to(f, "fast", FAST_POINTS, 0);
	assert_int_equal(jobs_cancel(f->jobs, cancelled, &root, NULL, NULL), 0);

	/* failed -> queued: the reason goes, the recording is continued. */
	assert_int_equal(jobs_requeue(f->jobs, failed, false, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_QUEUED);
	assert_null(j.reason);
	assert_true(j.resume);
	assert_int_equal(j.finished_ns, 0);
	job_record_clear(&j);
	assert_event(f, failed, "failed", "queued");
	j = get(f, failed);
	assert_null(j.reason);
	job_record_clear(&j);

	/* cancelled -> queued, with restart: a new recording. */
	assert_int_equal(jobs_requeue(f->jobs, cancelled, true, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_QUEUED);
	assert_false(j.resume);
	job_record_clear(&j);
	assert_event(f, cancelled, "cancelled", "queued");

	/* completed -> queued only with restart. */
	assert_int_equal(jobs_requeue(f->jobs, done, false, &root, NULL, NULL), -EINVAL);
	assert_int_equal(state_of(f, done), JOB_COMPLETED);
	assert_int_equal(jobs_requeue(f->jobs, done, true, &root, &j, NULL), 0);
	assert_int_equal(j.state, JOB_QUEUED);
	assert_false(j.resume);
	job_record_clear(&j);
	assert_event(f, done, "completed", "queued");

	/* Run again: the earlier recording of a restarted job is kept aside. */
	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_int_equal(run_while(f, done, BUSY), JOB_COMPLETED);
	assert_int_equal(run_while(f, cancelled, BUSY), JOB_COMPLETED);
	assert_int_equal(run_while(f, failed, BUSY), JOB_FAILED);
	j = get(f, done);
	assert_int_equal(j.attempts, 2);
	job_record_clear(&j);
	snprintf(aside, sizeof(aside), "%s/jobs/%" PRId64 "/scan-attempt1.asphscan", f->dir, done);
	assert_int_equal(stat(aside, &st), 0);
	assert_counts(f);
}

static void test_job_folder_refused(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "fast", FAST_POINTS, 0);
	int64_t b = submit_to(f, "fast", FAST_POINTS, 0);
	int64_t c = submit_to(f, "fast", FAST_POINTS, 0);
	char path[128], target[128];
	FILE *file;
	DIR *d;
	int n = 0;

	/* A file where a's folder goes, a symlink where b's goes: neither can
	 * start. They fail at once, and the queue goes on to c without being
	 * told again (it used to wait for the next change). */
	snprintf(path, sizeof(path), "%s/jobs", f->dir);
	assert_int_equal(mkdir(path, 0755), 0);
	snprintf(path, sizeof(path), "%s/jobs/%" PRId64, f->dir, a);
	file = fopen(path, "w");
	assert_non_null(file);
	fclose(file);
	snprintf(target, sizeof(target), "%s/elsewhere", f->dir);
	assert_int_equal(mkdir(target, 0755), 0);
	snprintf(path, sizeof(path), "%s/jobs/%" PRId64, f->dir, b);
	assert_int_equal(symlink(target, path), 0);

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	assert_int_equal(state_of(f, a), JOB_FAILED);
	assert_int_equal(state_of(f, b), JOB_FAILED);
	assert_int_equal(state_of(f, c), JOB_RUNNING);
	assert_int_equal(jobs_activity(f->jobs, 0)->job, c);
	assert_event(f, a, "queued", "failed");
	assert_non_null(strstr(last_state_event(f, a)->reason, "cannot create the job directory"));
	assert_event(f, b, "queued", "failed");
	assert_non_null(strstr(last_state_event(f, b)->reason, "symbolic link"));
	assert_int_equal(run_while(f, c, BUSY), JOB_COMPLETED);
	/* Nothing was written where the link points. */
	d = opendir(target);
	assert_non_null(d);
	for (struct dirent *e; (e = readdir(d));)
		n += e->d_name[0] != '.';
	closedir(d);
	assert_int_equal(n, 0);
	assert_counts(f);
}

static void test_move(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "fast", FAST_POINTS, 5);
	int64_t b = submit_to(f, "fast", FAST_POINTS, 0);
	int64_t c = submit_to(f, "fast", FAST_POINTS, 0);
	struct asph_error err;
	struct job_record j;
	struct ids q;

	/* c first: it takes a's priority (5) and runs before it. */
	assert_int_equal(jobs_move(f->jobs, c, 0, &root, NULL), 0);
	q = queue_of(f);
	assert_int_equal(q.n, 3);
	assert_int_equal(q.v[0], c);
	assert_int_equal(q.v[1], a);
	assert_int_equal(q.v[2], b);
	j = get(f, c);
	assert_int_equal(j.priority, 5);
	job_record_clear(&j);
	/* Past the end: last, with the priority of the job before it. */
	assert_int_equal(jobs_move(f->jobs, a, 99, &root, NULL), 0);
	q = queue_of(f);
	assert_int_equal(q.v[0], c);
	assert_int_equal(q.v[1], b);
	assert_int_equal(q.v[2], a);
	j = get(f, a);
	assert_int_equal(j.priority, 0);
	job_record_clear(&j);
	/* Moving is no change of state. */
	assert_int_equal(state_of(f, a), JOB_QUEUED);
	assert_int_equal(jobs_cancel(f->jobs, b, &root, NULL, NULL), 0);
	asph_error_clear(&err);
	assert_int_equal(jobs_move(f->jobs, b, 0, &root, &err), -EINVAL);
	assert_non_null(strstr(err.message, "not queued"));
	q = queue_of(f);
	assert_int_equal(q.n, 2);
}

/* The ids a cursor of f (NULL: the queue) gives, step jobs at a time. */
static struct ids cursor_ids(struct fixture *f, const struct store_filter *flt, size_t step)
{
	struct jobs_cursor *c;
	struct ids ids = { 0 };
	int r, steps = 0;

	assert_int_equal(jobs_cursor_new(f->jobs, flt, &c), 0);
	while ((r = jobs_cursor_next(c, step, collect, &ids, NULL)) > 0)
		assert_true(++steps < 100);
	assert_int_equal(r, 0);
	assert_int_equal(jobs_cursor_next(c, step, collect, &ids, NULL), 0);   /* ended */
	jobs_cursor_free(c);
	return ids;
}

/* A listing taken a few jobs at a time gives the jobs the listing in one
 * go gives, in its order: the queue over priorities, moves and a cancelled
 * job; the newest first with a filter, an offset and a limit. */
static void test_cursor(void **state)
{
	struct fixture *f = *state;
	int64_t prio[] = { 0, 5, 0, -3, 5, 0, 2 };
	int64_t id[ARRAY_SIZE(prio)];
	struct store_filter newest = { .uid = STORE_ANY_UID, .states = 1u << JOB_QUEUED,
				       .offset = 1, .limit = 4 };
	struct ids q, c;

	for (size_t i = 0; i < ARRAY_SIZE(prio); i++)
		id[i] = submit_to(f, "fast", FAST_POINTS, prio[i]);
	assert_int_equal(jobs_move(f->jobs, id[3], 1, &root, NULL), 0);
	assert_int_equal(jobs_cancel(f->jobs, id[5], &root, NULL, NULL), 0);
	q = queue_of(f);
	assert_int_equal(q.n, ARRAY_SIZE(prio) - 1);
	for (size_t step = 1; step <= 4; step++) {
		c = cursor_ids(f, NULL, step);
		assert_int_equal(c.n, q.n);
		assert_memory_equal(c.v, q.v, q.n * sizeof(q.v[0]));
	}
	/* queued only (the cancelled one out), newest first, from the second, four */
	c = cursor_ids(f, &newest, 3);
	assert_int_equal(c.n, 4);
	assert_int_equal(c.v[0], id[4]);
	assert_int_equal(c.v[1], id[3]);
	assert_int_equal(c.v[2], id[2]);
	assert_int_equal(c.v[3], id[1]);
}

static void stopped(void *data)
{
	struct fixture *f = data;

	f->stopped++;
}

static void test_shutdown(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", SLOW_POINTS, 0);
	int64_t b = submit_to(f, "slow2", SLOW_POINTS, 0);
	char status[128];
	int64_t c;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	run_until_measuring(f, 2, b);
	assert_int_equal(jobs_pause(f->jobs, b, &root, NULL, NULL), 0);
	jobs_shutdown(f->jobs, stopped, f);
	/* From now on no job starts. */
	c = submit_to(f, "fast", FAST_POINTS, 0);
	assert_int_equal(state_of(f, c), JOB_QUEUED);
	while (!f->stopped)
		assert_true(sd_event_run(f->event, UINT64_MAX) >= 0);
	assert_int_equal(f->stopped, 1);
	assert_int_equal(state_of(f, a), JOB_INTERRUPTED);
	assert_int_equal(state_of(f, b), JOB_INTERRUPTED);
	assert_event(f, a, "running", "interrupted");
	assert_event(f, b, "paused", "interrupted");
	assert_string_equal(last_state_event(f, a)->reason, "the daemon stopped during the scan");
	jobs_status_text(f->jobs, status, sizeof(status));
	assert_string_equal(status, "stopping");
	jobs_schedule(f->jobs);
	assert_int_equal(state_of(f, c), JOB_QUEUED);
	assert_counts(f);
}

/* Jobs the store holds as running or paused when the daemon starts. */
static void test_recovery(void **state)
{
	struct fixture *f = *state;
	int64_t a = submit_to(f, "slow1", SLOW_POINTS, 0);
	struct job_record j;

	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	run_until_measuring(f, 1, a);
	/* As after a crash: the store says running, nobody measures. */
	jobs_free(f->jobs);
	f->jobs = NULL;
	start_jobs(f);
	j = get(f, a);
	assert_int_equal(j.state, JOB_INTERRUPTED);
	assert_true(j.resume);
	assert_string_equal(j.reason, "the daemon stopped during the scan");
	job_record_clear(&j);
	assert_int_equal(count(f, JOB_INTERRUPTED), 1);
	assert_int_equal(count(f, JOB_RUNNING), 0);
	/* The queue's state outlives the restart: it ran. */
	assert_true(jobs_queue_running(f->jobs));
	assert_counts(f);
}

/* ---------------------------------------------------------- refusals */

enum op { OP_PAUSE, OP_RESUME, OP_CANCEL, OP_REQUEUE, OP_RESTART, OP_MOVE, OP_N };

static int apply(struct fixture *f, enum op op, int64_t id)
{
	switch (op) {
	case OP_PAUSE:
		return jobs_pause(f->jobs, id, &root, NULL, NULL);
	case OP_RESUME:
		return jobs_resume(f->jobs, id, &root, NULL, NULL);
	case OP_CANCEL:
		return jobs_cancel(f->jobs, id, &root, NULL, NULL);
	case OP_REQUEUE:
		return jobs_requeue(f->jobs, id, false, &root, NULL, NULL);
	case OP_RESTART:
		return jobs_requeue(f->jobs, id, true, &root, NULL, NULL);
	case OP_MOVE:
		return jobs_move(f->jobs, id, 0, &root, NULL);
	default:
		return 0;
	}
}

/* Which operation each state takes (the others are refused). */
static const bool allowed[JOB_N_STATES][OP_N] = {
	[JOB_QUEUED] = { [OP_CANCEL] = true, [OP_MOVE] = true },
	[JOB_RUNNING] = { [OP_PAUSE] = true, [OP_CANCEL] = true },
	[JOB_PAUSED] = { [OP_RESUME] = true, [OP_CANCEL] = true },
	[JOB_COMPLETED] = { [OP_RESTART] = true },
	[JOB_FAILED] = { [OP_REQUEUE] = true, [OP_RESTART] = true },
	[JOB_CANCELLED] = { [OP_REQUEUE] = true, [OP_RESTART] = true },
	[JOB_INTERRUPTED] = { [OP_RESUME] = true, [OP_CANCEL] = true, [OP_REQUEUE] = true,
			      [OP_RESTART] = true },
};

static void test_refusals(void **state)
{
	struct fixture *f = *state;
	int64_t in[JOB_N_STATES];

	/* One job in each state. */
	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	in[JOB_COMPLETED] = submit_to(f, "fast", FAST_POINTS, 0);
	assert_int_equal(run_while(f, in[JOB_COMPLETED], BUSY), JOB_COMPLETED);
	in[JOB_FAILED] = submit_to(f, "faulty", FAST_POINTS, 0);
	assert_int_equal(run_while(f, in[JOB_FAILED], BUSY), JOB_FAILED);
	in[JOB_INTERRUPTED] = submit_to(f, "slow1", SLOW_POINTS, 0);
	run_until_measuring(f, 1, in[JOB_INTERRUPTED]);
	assert_int_equal(jobs_queue_stop(f->jobs, true, &root, NULL), 0);
	assert_int_equal(run_while(f, in[JOB_INTERRUPTED], BUSY), JOB_INTERRUPTED);
	assert_int_equal(jobs_queue_start(f->jobs, &root, NULL), 0);
	in[JOB_RUNNING] = submit_to(f, "slow1", SLOW_POINTS, 0);
	in[JOB_PAUSED] = submit_to(f, "slow2", SLOW_POINTS, 0);
	run_until_measuring(f, 2, in[JOB_PAUSED]);
	assert_int_equal(jobs_pause(f->jobs, in[JOB_PAUSED], &root, NULL, NULL), 0);
	assert_int_equal(jobs_queue_stop(f->jobs, false, &root, NULL), 0);
	in[JOB_QUEUED] = submit_to(f, "fast", FAST_POINTS, 0);
	in[JOB_CANCELLED] = submit_to(f, "fast", FAST_POINTS, 0);
	assert_int_equal(jobs_cancel(f->jobs, in[JOB_CANCELLED], &root, NULL, NULL), 0);
	for (int s = 0; s < JOB_N_STATES; s++)
		assert_int_equal(state_of(f, in[s]), s);

	for (int s = 0; s < JOB_N_STATES; s++) {
		for (int op = 0; op < OP_N; op++) {
			size_t events = f->n_seen, entries = history_of(f, in[s]).n;
			struct job_record before, after;

			if (allowed[s][op])
				continue;
			before = get(f, in[s]);
			if (apply(f, (enum op)op, in[s]) != -EINVAL)
				fail_msg("%s job: operation %d was not refused",
					 job_state_name((enum job_state)s), op);
			/* Nothing changed: no event, no history, the same record. */
			assert_int_equal(f->n_seen, events);
			assert_int_equal(history_of(f, in[s]).n, entries);
			after = get(f, in[s]);
			assert_int_equal(after.state, before.state);
			assert_int_equal(after.priority, before.priority);
			assert_int_equal(after.seq, before.seq);
			assert_int_equal(after.finished_ns, before.finished_ns);
			assert_int_equal(after.attempts, before.attempts);
			assert_int_equal(after.resume, before.resume);
			job_record_clear(&before);
			job_record_clear(&after);
		}
	}
	/* A job nobody submitted. */
	for (int op = 0; op < OP_N; op++)
		assert_int_equal(apply(f, (enum op)op, 9999), -ENOENT);
	assert_int_equal(jobs_get(f->jobs, 9999, &(struct job_record){ 0 }, NULL), -ENOENT);
	assert_counts(f);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_submit, setup, teardown),
		cmocka_unit_test_setup_teardown(test_run_to_completion, setup, teardown),
		cmocka_unit_test_setup_teardown(test_cancel_queued, setup, teardown),
		cmocka_unit_test_setup_teardown(test_pause_resume_cancel, setup, teardown),
		cmocka_unit_test_setup_teardown(test_cancel_paused, setup, teardown),
		cmocka_unit_test_setup_teardown(test_driver_fault, setup, teardown),
		cmocka_unit_test_setup_teardown(test_queue_stop_abort, setup, teardown),
		cmocka_unit_test_setup_teardown(test_points_measured, setup, teardown),
		cmocka_unit_test_setup_teardown(test_cancel_after_queue_stop_abort, setup, teardown),
		cmocka_unit_test_setup_teardown(test_cancel_while_characterizing, setup, teardown),
		cmocka_unit_test_setup_teardown(test_requeue, setup, teardown),
		cmocka_unit_test_setup_teardown(test_job_folder_refused, setup, teardown),
		cmocka_unit_test_setup_teardown(test_move, setup, teardown),
		cmocka_unit_test_setup_teardown(test_cursor, setup, teardown),
		cmocka_unit_test_setup_teardown(test_shutdown, setup, teardown),
		cmocka_unit_test_setup_teardown(test_recovery, setup, teardown),
		cmocka_unit_test_setup_teardown(test_refusals, setup, teardown),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
