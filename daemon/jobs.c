/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the queue, the transitions of jobs, the workers. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asph-proto.h"
#include "dirs.h"
#include "jobs.h"
#include "locks-store.h"
#include "log.h"
#include "runner.h"
#include "store.h"
#include "util-fs.h"
#include "util-time.h"
#include "util-mem.h"

/* Progress reaches the store at most this often (a restart resumes from
 * the scan file, not from this number). */
#define PROGRESS_STORE_NS 5000000000ull
/* What a recorded point takes on disk with its share of the result files
 * (a scan record of 56 bytes, a line of residuals.csv): for the disk guard
 * (limits.min_free_disk_mb). */
#define JOB_BYTES_PER_POINT 160

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

static void on_report(const struct runner_report *rep, void *data);
static int retry_schedule(sd_event_source *s, uint64_t usec, void *data);

/* ---------------------------------------------------------- set up */

static int open_store(struct jobs *jobs, struct asph_error *err)
{
	_cleanup_free_ char *path = NULL;
	_cleanup_free_ char *v = NULL;
	int64_t last;
	int n, r;

	jobs->state_fd = dirs_open_state(jobs->state_dir);
	if (jobs->state_fd < 0)
		return asph_error_set(err, jobs->state_fd, "%s: cannot use it as the state "
				      "directory", jobs->state_dir);
	if (asprintf(&path, "%s/jobs.sqlite", jobs->state_dir) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = store_open(path, &jobs->store, err);
	if (r < 0)
		return r;
	/* A job's folder is never taken by another job: after a store is put
	 * back from a backup, its next jobs start after every folder. */
	last = dirs_last_job(jobs->state_fd);
	r = last > 0 ? store_skip_ids(jobs->store, last) : (int)last;
	if (r < 0)
		return asph_error_set(err, r, "%s: cannot read the job folders: %s", jobs->state_dir,
				      strerror(-r));
	if (r > 0)
		log_notice("the state directory has job folders up to %" PRId64 " that the job store "
			   "does not know (a store put back from a backup?): new jobs start after them",
			   last);
	n = store_recover(jobs->store, now_realtime_ns());
	if (n < 0)
		return asph_error_set(err, n, "%s: cannot mark the interrupted jobs: %s", path,
				      strerror(-n));
	if (n > 0)
		log_notice("%d job(s) were interrupted when the daemon stopped; "
			   "resume or re-queue them", n);
	jobs->queue_running = true;
	if (store_meta_get(jobs->store, "queue.running", &v) == 0)
		jobs->queue_running = strcmp(v, "0") != 0;
	r = store_count(jobs->store, jobs->counts);
	if (r < 0)
		return asph_error_set(err, r, "%s: cannot count the jobs: %s", path, strerror(-r));
	return 0;
}

static int start_workers(struct jobs *jobs, const struct instruments *ins,
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

/* ------------------------------------------------------------ locks */

static void lock_release(struct slot *sl)
{
	free(sl->lock.holder);
	free(sl->lock.reason);
	sl->lock = (struct instrument_lock){ 0 };
	sl->act.lock = NULL;
}

static int lock_take(struct slot *sl, const struct store_lock *l)
{
	struct instrument_lock lk = {
		.holder = strdup(l->holder), .holder_uid = l->holder_uid,
		.reason = strdup(l->reason), .since_ns = l->since_ns, .pause = l->pause,
		.paused_job = l->paused_job,
	};

	if (!lk.holder || !lk.reason) {
		free(lk.holder);
		free(lk.reason);
		return -ENOMEM;
	}
	lock_release(sl);
	sl->lock = lk;
	sl->act.lock = &sl->lock;
	return 0;
}

static struct slot *slot_of_instrument(struct jobs *jobs, const char *name)
{
	for (size_t i = 0; i < jobs->n_slots; i++)
		if (!strcmp(jobs->slots[i].in->name, name))
			return &jobs->slots[i];
	return NULL;
}

static int restore_lock(const struct store_lock *l, void *data)
{
	struct jobs *jobs = data;
	struct slot *sl = slot_of_instrument(jobs, l->instrument);

	if (!sl) {
		log_warning("a lock on instrument %s, which is no longer configured, is ignored",
			    l->instrument);
		return 0;
	}
	log_notice("instrument %s is locked by %s since the last run: %s", l->instrument,
		   l->holder, l->reason);
	return lock_take(sl, l);
}

/* The locks outlive a restart. */
static int load_locks(struct jobs *jobs, struct asph_error *err)
{
	int r = store_lock_list(jobs->store, restore_lock, jobs);

	return r < 0 ? asph_error_set(err, r, "cannot read the instrument locks: %s",
				      strerror(-r)) : 0;
}

static bool lock_held_by(const struct instrument_lock *l, const struct job_actor *who)
{
	return who && l->holder_uid == who->uid && !strcmp(l->holder, who->name);
}

/* -EBUSY when sl is locked by someone other than who: err says by whom and
 * why, its field names the instrument. */
static int check_lock(const struct slot *sl, const struct job_actor *who,
		      struct asph_error *err)
{
	char since[ISO8601_SIZE];

	if (!sl || !sl->act.lock || lock_held_by(&sl->lock, who))
		return 0;
	iso8601_utc(sl->lock.since_ns, 0, since, sizeof(since));
	asph_error_set(err, -EBUSY, "instrument %s is locked by %s since %s: %s",
		       sl->in->name, sl->lock.holder, since, sl->lock.reason);
	asph_error_locate(err, NULL, 0, 0, sl->in->name);
	return -EBUSY;
}

int jobs_new(const struct jobs_setup *setup, struct jobs **out, struct asph_error *err)
{
	struct jobs *jobs = calloc(1, sizeof(*jobs));
	int r;

	if (!jobs)
		return asph_error_set(err, -ENOMEM, "out of memory");
	jobs->event = setup->event;
	jobs->events = setup->events;
	jobs->limits = setup->limits;
	jobs->state_fd = -1;
	jobs->state_dir = strdup(setup->state_dir);
	r = jobs->state_dir ? 0 : asph_error_set(err, -ENOMEM, "out of memory");
	if (r == 0)
		r = open_store(jobs, err);
	if (r == 0)
		r = start_workers(jobs, setup->instruments, err);
	if (r == 0)
		r = load_locks(jobs, err);
	if (r == 0 && sd_event_add_time(jobs->event, &jobs->retry, CLOCK_MONOTONIC, UINT64_MAX,
					0, retry_schedule, jobs) < 0)
		r = asph_error_set(err, -ENOMEM, "out of memory");
	if (r < 0) {
		jobs_free(jobs);
		return r;
	}
	*out = jobs;
	return 0;
}

void jobs_free(struct jobs *jobs)
{
	if (!jobs)
		return;
	for (size_t i = 0; i < jobs->n_slots; i++) {
		runner_free(jobs->slots[i].runner);
		free(jobs->slots[i].fault);
		free(jobs->slots[i].cancel_by);
		lock_release(&jobs->slots[i]);
	}
	free(jobs->slots);
	sd_event_source_disable_unref(jobs->retry);
	store_close(jobs->store);
	if (jobs->state_fd >= 0)
		close(jobs->state_fd);
	free(jobs->state_dir);
	free(jobs);
}

/* ---------------------------------------------------------- helpers */

static struct slot *slot_of_job(struct jobs *jobs, int64_t id)
{
	for (size_t i = 0; i < jobs->n_slots; i++)
		if (jobs->slots[i].act.job == id)
			return &jobs->slots[i];
	return NULL;
}

static const struct slot *slot_of_instrument_name(const struct jobs *jobs, const char *name)
{
	return slot_of_instrument((struct jobs *)jobs, name);
}

static const struct slot *slot_of_job_const(const struct jobs *jobs, int64_t id)
{
	return slot_of_job((struct jobs *)jobs, id);
}

static void set_fault(struct slot *sl, const char *fault)
{
	free(sl->fault);
	sl->fault = fault ? strdup(fault) : NULL;
	sl->act.fault = sl->fault;
}

/* The end of a change of j with outcome r: j goes to out (may be NULL)
 * when it succeeded, else it is cleared. Returns r. */
static int hand_over(struct job_record *j, int r, struct job_record *out)
{
	if (r == 0 && out)
		*out = *j;
	else
		job_record_clear(j);
	return r;
}

static int refuse_state(const struct job_record *j, const char *what, struct asph_error *err)
{
	return asph_error_set(err, -EINVAL, "job %" PRId64 " is %s%s", j->id,
			      job_state_name(j->state), what);
}

/*
 * A store write that must not be lost to a full disk, such as how a job
 * ended: on -ENOSPC the store's reserve is given up once and the write
 * tried again.
 */
static int write_essential(struct jobs *jobs, int64_t id, const char *what,
			   int (*write)(struct store *s, const void *arg), const void *arg)
{
	int r = write(jobs->store, arg);

	if (r == -ENOSPC && store_release_reserve(jobs->store) == 0) {
		log_job(LOG_WARNING, id, "the state directory is full: using the store's reserve "
			"to record %s", what);
		r = write(jobs->store, arg);
	}
	return r;
}

struct transition {
	const struct job_record *j;
	enum job_state state;
	const char *reason;
	const struct job_actor *who;    /* NULL: the daemon */
};

static int write_transition(struct store *s, const void *arg)
{
	const struct transition *t = arg;

	return store_transition(s, t->j, t->state, t->reason, t->who ? t->who->uid : 0,
				t->who ? t->who->name : NULL, now_realtime_ns());
}

/* The overall verdict of a completed job's result ("pass", "fail",
 * "undecided") in buf, or NULL when it had no tolerance. */
static const char *job_verdict(const struct job_record *j, char buf[16])
{
	_cleanup_(json_decrefp) json_t *res = NULL;
	const char *v;

	if (j->state != JOB_COMPLETED || !j->result)
		return NULL;
	res = json_loads(j->result, 0, NULL);
	v = json_string_value(json_object_get(json_object_get(json_object_get(res, "summary"),
							      "verdict"), "overall"));
	if (!v)
		return NULL;
	snprintf(buf, 16, "%s", v);
	return buf;
}

/*
 * The one place a job changes state: j (with its other columns as they
 * are in j) is recorded in the new state, counted, logged and told to the
 * watchers. reason may be NULL.
 */
static int transition(struct jobs *jobs, struct job_record *j, enum job_state s,
		      const char *reason, const struct job_actor *who, struct asph_error *err)
{
	struct transition t = { .j = j, .state = s, .reason = reason, .who = who };
	enum job_state old = j->state;
	char what[64], verdict[16];
	int r;

	snprintf(what, sizeof(what), "the state %s", job_state_name(s));
	r = write_essential(jobs, j->id, what, write_transition, &t);
	if (r < 0) {
		log_job(LOG_ERR, j->id, "cannot record the state %s: %s", job_state_name(s),
			strerror(-r));
		return asph_error_set(err, r, "cannot record the state %s of job %" PRId64 ": %s",
				      job_state_name(s), j->id, strerror(-r));
	}
	jobs->counts[old]--;
	jobs->counts[s]++;
	j->state = s;
	/* As the store keeps it: a return to the queue clears the reason. */
	if (reason || s == JOB_QUEUED) {
		free(j->reason);
		j->reason = reason ? strdup(reason) : NULL;
	}
	log_job(s == JOB_FAILED ? LOG_WARNING : LOG_INFO, j->id, "%s -> %s%s%s%s%s",
		job_state_name(old), job_state_name(s), reason ? ": " : "", reason ? reason : "",
		who ? " by " : "", who ? who->name : "");
	events_job_state(jobs->events, j->id, s, (int)old, reason, j->instrument,
			 s == JOB_COMPLETED ? job_verdict(j, verdict) : NULL);
	return 0;
}

/* Reads job id for a change. */
static int load(struct jobs *jobs, int64_t id, struct job_record *j, struct asph_error *err)
{
	int r = store_get(jobs->store, id, j);

	if (r == -ENOENT)
		return asph_error_set(err, r, "no job %" PRId64, id);
	if (r < 0)
		return asph_error_set(err, r, "cannot read job %" PRId64 ": %s", id, strerror(-r));
	return 0;
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
	r = transition(jobs, j, JOB_FAILED, reason, NULL, NULL);
	return r < 0 ? r : 1;
}

/* The disk space a recording of points (and its result files) takes. */
static uint64_t job_disk_mb(int64_t points)
{
	return ((uint64_t)(points > 0 ? points : 0) * JOB_BYTES_PER_POINT >> 20) + 1;
}

/* Whether the state directory has room for points more, and what it keeps
 * free (limits.min_free_disk_mb, 0: no check): 0, or -EDQUOT with why. */
static int check_room(const struct jobs *jobs, int64_t points, char *why, size_t size)
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
	if (check_room(jobs, j->points_total - (j->resume ? j->points_done : 0), reason,
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
	return transition(jobs, j, JOB_RUNNING, NULL, NULL, NULL);
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

static int retry_schedule(sd_event_source *s, uint64_t usec, void *data)
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
	transition(jobs, &j, next, reason, next == JOB_CANCELLED && cancel_by ? &canceller : NULL,
		   NULL);
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

/* ---------------------------------------------------------- changes */

static int queue_length(const struct jobs *jobs)
{
	return (int)(jobs->counts[JOB_QUEUED] + jobs->counts[JOB_RUNNING] +
		     jobs->counts[JOB_PAUSED] + jobs->counts[JOB_INTERRUPTED]);
}

int jobs_check_instrument(const struct jobs *jobs, const char *instrument,
			  struct asph_error *err)
{
	if (instrument && !slot_of_instrument_name(jobs, instrument))
		return asph_error_set(err, -ENODEV, "no instrument \"%s\"", instrument);
	return 0;
}

int jobs_check_submit(const struct jobs *jobs, const char *instrument, struct asph_error *err)
{
	int r = jobs_check_instrument(jobs, instrument, err);

	if (r < 0)
		return r;
	if (queue_length(jobs) >= (int)jobs->limits->max_queue)
		return asph_error_set(err, -ENOBUFS, "the queue holds %u jobs, its limit",
				      jobs->limits->max_queue);
	return 0;
}

int jobs_submit(struct jobs *jobs, const struct job_submission *sub,
		const struct job_actor *who, struct job_record *out, struct asph_error *err)
{
	const char *instrument = sub->instrument ? sub->instrument : jobs->slots[0].in->name;
	struct job_record j = {
		.state = JOB_QUEUED, .priority = sub->priority, .label = (char *)sub->label,
		.instrument = (char *)instrument, .uid = who->uid, .user = (char *)who->name,
		.spec = (char *)sub->spec, .points_total = sub->points,
		.part = (char *)sub->part, .lot = (char *)sub->lot, .serial = (char *)sub->serial,
	};
	char why[320];
	int r = jobs_check_submit(jobs, instrument, err);

	if (r == 0)
		r = check_lock(slot_of_instrument_name(jobs, instrument), who, err);
	if (r < 0)
		return r;
	if (check_room(jobs, sub->points, why, sizeof(why)) < 0)
		return asph_error_set(err, -EDQUOT, "%s", why);
	r = store_insert(jobs->store, &j, now_realtime_ns());
	if (r < 0)
		return asph_error_set(err, r, "cannot store the job: %s", strerror(-r));
	jobs->counts[JOB_QUEUED]++;
	log_job(LOG_INFO, j.id, "submitted by %s (uid %" PRId64 ") for %s", who->name, who->uid,
		instrument);
	events_job_state(jobs->events, j.id, JOB_QUEUED, -1, NULL, instrument, NULL);
	r = out ? load(jobs, j.id, out, err) : 0;
	jobs_schedule(jobs);
	return r;
}

int jobs_cancel(struct jobs *jobs, int64_t id, const struct job_actor *who,
		struct job_record *out, struct asph_error *err)
{
	struct job_record j;
	struct slot *sl;
	int r = load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = check_lock(slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		return hand_over(&j, r, out);
	switch (j.state) {
	case JOB_QUEUED:
	case JOB_INTERRUPTED:
		j.finished_ns = now_realtime_ns();
		r = transition(jobs, &j, JOB_CANCELLED, NULL, who, err);
		break;
	case JOB_RUNNING:
	case JOB_PAUSED:
		/* The worker stops the scan; its report ends the job, cancelled
		 * whatever stop was asked before (job_end()). */
		sl = slot_of_job(jobs, j.id);
		if (sl) {
			sl->cancel = true;
			sl->cancel_uid = who->uid;
			free(sl->cancel_by);
			sl->cancel_by = who->name ? strdup(who->name) : NULL;
			runner_abort(sl->runner);
		}
		log_job(LOG_INFO, j.id, "cancel requested by %s", who->name);
		break;
	default:
		r = refuse_state(&j, "", err);
	}
	return hand_over(&j, r, out);
}

/* Back to the queue; with restart a new recording. */
static int requeue(struct jobs *jobs, struct job_record *j, bool restart,
		   const struct job_actor *who, struct asph_error *err)
{
	if (restart)
		j->resume = false;
	j->finished_ns = 0;
	return transition(jobs, j, JOB_QUEUED, NULL, who, err);
}

/* running <-> paused: recorded first, then the worker is told, so that a
 * change the store cannot keep does not happen. */
static int set_paused(struct jobs *jobs, struct job_record *j, struct slot *sl, bool pause,
		      const char *reason, const struct job_actor *who, struct asph_error *err)
{
	int r = transition(jobs, j, pause ? JOB_PAUSED : JOB_RUNNING, reason, who, err);

	if (r < 0)
		return r;
	sl->act.paused = pause;
	if (pause)
		runner_pause(sl->runner);
	else
		runner_resume(sl->runner);
	return 0;
}

/* Pauses a running job, or (!pause) resumes a paused one or queues an
 * interrupted one to continue. */
static int pause_or_resume(struct jobs *jobs, int64_t id, bool pause,
			   const struct job_actor *who, struct job_record *out,
			   struct asph_error *err)
{
	struct job_record j;
	struct slot *sl;
	int r = load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = check_lock(slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		return hand_over(&j, r, out);
	sl = slot_of_job(jobs, j.id);
	if (sl && j.state == (pause ? JOB_RUNNING : JOB_PAUSED))
		r = set_paused(jobs, &j, sl, pause, NULL, who, err);
	else if (!pause && j.state == JOB_INTERRUPTED)
		r = requeue(jobs, &j, false, who, err);
	else
		r = refuse_state(&j, pause ? ", not running" : "", err);
	if (r == 0 && !pause)
		jobs_schedule(jobs);
	return hand_over(&j, r, out);
}

int jobs_pause(struct jobs *jobs, int64_t id, const struct job_actor *who,
	       struct job_record *out, struct asph_error *err)
{
	return pause_or_resume(jobs, id, true, who, out, err);
}

int jobs_resume(struct jobs *jobs, int64_t id, const struct job_actor *who,
		struct job_record *out, struct asph_error *err)
{
	return pause_or_resume(jobs, id, false, who, out, err);
}

int jobs_requeue(struct jobs *jobs, int64_t id, bool restart, const struct job_actor *who,
		 struct job_record *out, struct asph_error *err)
{
	struct job_record j;
	int r = load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = check_lock(slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		return hand_over(&j, r, out);
	if (j.state != JOB_FAILED && j.state != JOB_INTERRUPTED && j.state != JOB_CANCELLED &&
	    !(j.state == JOB_COMPLETED && restart))
		r = refuse_state(&j, j.state == JOB_COMPLETED ? " (re-queue it with restart)" : "",
				 err);
	else
		r = requeue(jobs, &j, restart || j.state == JOB_COMPLETED, who, err);
	if (r == 0)
		jobs_schedule(jobs);
	return hand_over(&j, r, out);
}

struct ids {
	int64_t *v;
	size_t n, cap;
};

static int collect_id(const struct job_record *j, void *data)
{
	struct ids *ids = data;

	if (ids->n == ids->cap) {
		size_t cap = ids->cap ? 2 * ids->cap : 64;
		int64_t *v = realloc(ids->v, cap * sizeof(*v));
		if (!v)
			return -ENOMEM;
		ids->v = v;
		ids->cap = cap;
	}
	ids->v[ids->n++] = j->id;
	return 0;
}

/* Moves id within ids (the queue in order) to pos; returns where it went. */
static size_t reorder(struct ids *ids, int64_t id, int64_t pos)
{
	size_t from = 0;

	while (from < ids->n && ids->v[from] != id)
		from++;
	memmove(ids->v + from, ids->v + from + 1, (ids->n - from - 1) * sizeof(*ids->v));
	ids->n--;
	if ((size_t)pos > ids->n)
		pos = (int64_t)ids->n;
	memmove(ids->v + pos + 1, ids->v + pos, (ids->n - (size_t)pos) * sizeof(*ids->v));
	ids->v[pos] = id;
	ids->n++;
	return (size_t)pos;
}

/* Writes the queue's order as ids has it, j (the moved job) included. */
static int renumber(struct jobs *jobs, const struct ids *ids, struct job_record *j)
{
	int r = store_begin(jobs->store);

	for (size_t k = 0; r == 0 && k < ids->n; k++) {
		struct job_record q;
		if (ids->v[k] == j->id) {
			j->seq = (int64_t)k + 1;
			r = store_update(jobs->store, j);
		} else if ((r = store_get(jobs->store, ids->v[k], &q)) == 0) {
			q.seq = (int64_t)k + 1;
			r = store_update(jobs->store, &q);
			job_record_clear(&q);
		}
	}
	if (r == 0)
		r = store_commit(jobs->store);
	if (r < 0)
		store_rollback(jobs->store);
	return r;
}

int jobs_move(struct jobs *jobs, int64_t id, int64_t position, const struct job_actor *who,
	      struct asph_error *err)
{
	struct store_filter f = { .uid = STORE_ANY_UID, .states = 1u << JOB_QUEUED, .queue_order = true };
	struct ids ids = { 0 };
	struct job_record j, other;
	size_t pos;
	int r = load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = check_lock(slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		goto out;
	if (j.state != JOB_QUEUED) {
		r = refuse_state(&j, ", not queued", err);
		goto out;
	}
	r = store_list(jobs->store, &f, collect_id, &ids, NULL);
	if (r < 0) {
		r = asph_error_set(err, r, "cannot read the queue: %s", strerror(-r));
		goto out;
	}
	pos = reorder(&ids, j.id, position);
	/* The neighbour's priority keeps the order "priority, then sequence". */
	if (ids.n > 1 && store_get(jobs->store, ids.v[pos + 1 < ids.n ? pos + 1 : pos - 1],
				   &other) == 0) {
		j.priority = other.priority;
		job_record_clear(&other);
	}
	r = renumber(jobs, &ids, &j);
	if (r < 0) {
		r = asph_error_set(err, r, "cannot reorder the queue: %s", strerror(-r));
		goto out;
	}
	log_job(LOG_INFO, j.id, "moved to position %zu by %s", pos, who->name);
out:
	free(ids.v);
	job_record_clear(&j);
	return r;
}

static int set_queue_running(struct jobs *jobs, bool running, struct asph_error *err)
{
	int r = store_meta_set(jobs->store, "queue.running", running ? "1" : "0");

	if (r < 0)
		return asph_error_set(err, r, "cannot record that the queue %s: %s",
				      running ? "runs" : "stopped", strerror(-r));
	jobs->queue_running = running;
	events_queue_state(jobs->events, running);
	return 0;
}

int jobs_queue_start(struct jobs *jobs, const struct job_actor *who, struct asph_error *err)
{
	int r = set_queue_running(jobs, true, err);

	if (r < 0)
		return r;
	log_info("queue started by %s", who->name);
	jobs_schedule(jobs);
	return 0;
}

int jobs_queue_stop(struct jobs *jobs, bool abort, const struct job_actor *who,
		    struct asph_error *err)
{
	int r = set_queue_running(jobs, false, err);

	if (r < 0)
		return r;
	log_info("queue stopped by %s%s", who->name, abort ? ", running scans stopped" : "");
	for (size_t i = 0; abort && i < jobs->n_slots; i++)
		if (jobs->slots[i].act.job)
			runner_stop(jobs->slots[i].runner);
	return 0;
}

/* A lock that asks for it pauses the running job of sl (not one whose
 * points are all recorded): 1 when it did. */
static int pause_for_lock(struct jobs *jobs, struct slot *sl, const struct job_actor *who,
			  struct asph_error *err)
{
	char reason[600];
	struct job_record j;
	int r;

	if (!sl->act.job || sl->act.paused || sl->act.characterizing)
		return 0;
	r = load(jobs, sl->act.job, &j, err);
	if (r < 0)
		return r;
	snprintf(reason, sizeof(reason), "instrument %s locked by %s: %s", sl->in->name,
		 who->name, sl->lock.reason);
	r = j.state == JOB_RUNNING ? set_paused(jobs, &j, sl, true, reason, who, err) : 0;
	if (r == 0 && j.state == JOB_PAUSED)
		r = 1;
	job_record_clear(&j);
	return r;
}

static int write_lock(struct jobs *jobs, struct slot *sl, struct asph_error *err)
{
	struct store_lock l = {
		.instrument = sl->in->name, .holder = sl->lock.holder,
		.holder_uid = sl->lock.holder_uid, .reason = sl->lock.reason,
		.since_ns = sl->lock.since_ns, .pause = sl->lock.pause,
		.paused_job = sl->lock.paused_job,
	};
	int r = store_lock_set(jobs->store, &l);

	return r < 0 ? asph_error_set(err, r, "cannot record the lock of %s: %s", sl->in->name,
				      strerror(-r)) : 0;
}

int jobs_lock(struct jobs *jobs, const char *instrument, const char *reason, bool pause,
	      const struct job_actor *who, struct asph_error *err)
{
	struct slot *sl = slot_of_instrument(jobs, instrument);
	bool renewed;
	struct store_lock l = {
		.instrument = instrument, .holder = who->name, .holder_uid = who->uid,
		.reason = reason, .since_ns = now_realtime_ns(), .pause = pause,
	};
	int r;

	if (!sl)
		return asph_error_set(err, -ENODEV, "no instrument \"%s\"", instrument);
	r = check_lock(sl, who, err);
	if (r < 0)
		return r;
	renewed = sl->act.lock != NULL;
	if (renewed) {
		/* The holder changes the reason or the pause: the lock keeps its start. */
		l.since_ns = sl->lock.since_ns;
		l.paused_job = sl->lock.paused_job;
	}
	r = lock_take(sl, &l);
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	r = write_lock(jobs, sl, err);
	if (r < 0) {
		lock_release(sl);
		return r;
	}
	log_notice("instrument %s %slocked by %s%s: %s", instrument, renewed ? "re-" : "",
		   who->name, pause ? " (pausing its job)" : "", reason);
	if (pause) {
		int64_t job = sl->act.job;
		r = pause_for_lock(jobs, sl, who, err);
		if (r < 0)
			return r;
		if (r > 0 && sl->lock.paused_job != job) {
			sl->lock.paused_job = job;
			write_lock(jobs, sl, NULL);
		}
	}
	events_instrument_lock(jobs->events, instrument, &sl->lock);
	return 0;
}

/*
 * The job a lock paused runs again when the lock goes: resumed if it still
 * waits, re-queued where it stopped if someone stopped it meanwhile (a
 * queue.stop with abort makes it interrupted): it was held for the lock,
 * not given up. A re-queued job waits for the queue to run.
 */
static void resume_after_lock(struct jobs *jobs, struct slot *sl, int64_t id,
			      const struct job_actor *who)
{
	struct job_record j;

	if (!id || load(jobs, id, &j, NULL) < 0)
		return;
	if (j.state == JOB_PAUSED && sl->act.job == id && sl->act.paused) {
		set_paused(jobs, &j, sl, false, NULL, who, NULL);
	} else if (j.state == JOB_INTERRUPTED) {
		log_job(LOG_NOTICE, id, "re-queued at the end of the lock of %s: it was paused by "
			"the lock and stopped meanwhile", sl->in->name);
		requeue(jobs, &j, !j.resume, who, NULL);
	}
	job_record_clear(&j);
}

int jobs_unlock(struct jobs *jobs, const char *instrument, bool force,
		const struct job_actor *who, struct asph_error *err)
{
	struct slot *sl = slot_of_instrument(jobs, instrument);
	int64_t paused;
	int r;

	if (!sl)
		return asph_error_set(err, -ENODEV, "no instrument \"%s\"", instrument);
	if (!sl->act.lock)
		return asph_error_set(err, -EINVAL, "instrument %s is not locked", instrument);
	if (!force && (r = check_lock(sl, who, err)) < 0)
		return r;
	r = store_lock_clear(jobs->store, instrument);
	if (r < 0)
		return asph_error_set(err, r, "cannot record the end of the lock of %s: %s",
				      instrument, strerror(-r));
	log_notice("instrument %s unlocked by %s%s (locked by %s: %s)", instrument, who->name,
		   lock_held_by(&sl->lock, who) ? "" : ", forced", sl->lock.holder, sl->lock.reason);
	paused = sl->lock.paused_job;
	lock_release(sl);
	events_instrument_lock(jobs->events, instrument, NULL);
	resume_after_lock(jobs, sl, paused, who);
	jobs_schedule(jobs);
	return 0;
}

const struct instrument_lock *jobs_lock_of(const struct jobs *jobs, const char *instrument)
{
	const struct slot *sl = slot_of_instrument_name(jobs, instrument);

	return sl ? sl->act.lock : NULL;
}

/* ---------------------------------------------------------- reading */

int jobs_get(struct jobs *jobs, int64_t id, struct job_record *out, struct asph_error *err)
{
	return load(jobs, id, out, err);
}

int jobs_list(struct jobs *jobs, const struct store_filter *f, store_job_fn fn, void *data,
	      int64_t *total, struct asph_error *err)
{
	int r = store_list(jobs->store, f, fn, data, total);

	return r < 0 ? asph_error_set(err, r, "cannot read the jobs: %s", strerror(-r)) : 0;
}

int jobs_count(struct jobs *jobs, const struct store_filter *f, int64_t *out,
	       struct asph_error *err)
{
	int r = store_total(jobs->store, f, out);

	return r < 0 ? asph_error_set(err, r, "cannot read the jobs: %s", strerror(-r)) : 0;
}

int jobs_list_queue(struct jobs *jobs, store_job_fn fn, void *data, struct asph_error *err)
{
	struct store_filter f = {
		.uid = STORE_ANY_UID,
		.states = 1u << JOB_QUEUED | 1u << JOB_RUNNING | 1u << JOB_PAUSED,
		.queue_order = true,
	};
	int r = store_list(jobs->store, &f, fn, data, NULL);

	return r < 0 ? asph_error_set(err, r, "cannot read the queue: %s", strerror(-r)) : 0;
}

struct jobs_cursor {
	struct jobs *jobs;
	struct store_filter f;          /* its strings are copies */
	char *strings[6];
	int64_t left;                   /* of f's limit; -1: no limit */
	bool started, ended;
	/* the last job given */
	int64_t last_id, last_priority, last_seq;
	/* for the callback */
	store_job_fn fn;
	void *data;
	size_t given;
};

void jobs_cursor_free(struct jobs_cursor *c)
{
	if (!c)
		return;
	for (size_t i = 0; i < ARRAY_SIZE(c->strings); i++)
		free(c->strings[i]);
	free(c);
}

/* A copy of the filter's string *s, kept in c. */
static int keep_string(struct jobs_cursor *c, size_t i, const char **s)
{
	if (!*s)
		return 0;
	c->strings[i] = strdup(*s);
	*s = c->strings[i];
	return *s ? 0 : -ENOMEM;
}

int jobs_cursor_new(struct jobs *jobs, const struct store_filter *f, struct jobs_cursor **out)
{
	struct jobs_cursor *c = calloc(1, sizeof(*c));
	int r = 0;

	if (!c)
		return -ENOMEM;
	c->jobs = jobs;
	if (f) {
		c->f = *f;
	} else {
		c->f = (struct store_filter){
			.uid = STORE_ANY_UID,
			.states = 1u << JOB_QUEUED | 1u << JOB_RUNNING | 1u << JOB_PAUSED,
			.queue_order = true,
		};
	}
	c->left = c->f.limit > 0 ? c->f.limit : -1;
	r |= keep_string(c, 0, &c->f.instrument);
	r |= keep_string(c, 1, &c->f.label);
	r |= keep_string(c, 2, &c->f.user);
	r |= keep_string(c, 3, &c->f.part);
	r |= keep_string(c, 4, &c->f.lot);
	r |= keep_string(c, 5, &c->f.serial);
	if (r < 0) {
		jobs_cursor_free(c);
		return -ENOMEM;
	}
	*out = c;
	return 0;
}

static int cursor_entry(const struct job_record *j, void *data)
{
	struct jobs_cursor *c = data;

	c->last_id = j->id;
	c->last_priority = j->priority;
	c->last_seq = j->seq;
	c->given++;
	return c->fn(j, c->data);
}

/* Up to max jobs of f from the store, through the cursor's callback. */
static int cursor_read(struct jobs_cursor *c, struct store_filter *f, size_t max,
		       struct asph_error *err)
{
	int r;

	f->limit = (int64_t)max;
	r = store_list(c->jobs->store, f, cursor_entry, c, NULL);
	return r < 0 ? asph_error_set(err, r, "cannot read the jobs: %s", strerror(-r)) : 0;
}

int jobs_cursor_next(struct jobs_cursor *c, size_t max, store_job_fn fn, void *data,
		     struct asph_error *err)
{
	struct store_filter f = c->f;
	int64_t priority = c->last_priority;
	int r;

	if (c->ended || c->left == 0)
		return 0;
	if (c->left > 0 && (int64_t)max > c->left)
		max = (size_t)c->left;
	c->fn = fn;
	c->data = data;
	c->given = 0;
	if (!c->started) {
		r = cursor_read(c, &f, max, err);
	} else if (!f.queue_order) {
		/* newest first: below the last id */
		f.offset = 0;
		f.before_id = c->last_id;
		r = cursor_read(c, &f, max, err);
	} else {
		/* the rest of the last job's priority, then the lower ones */
		f.offset = 0;
		f.after = true;
		f.after_priority = priority;
		f.after_seq = c->last_seq;
		f.after_id = c->last_id;
		r = cursor_read(c, &f, max, err);
		if (r == 0 && c->given < max) {
			f.after = false;
			f.below = true;
			r = cursor_read(c, &f, max - c->given, err);
		}
	}
	if (r < 0)
		return r;
	c->started = true;
	if (c->left > 0)
		c->left -= (int64_t)c->given;
	c->ended = c->given < max || c->left == 0;
	return c->ended ? 0 : 1;
}

int jobs_history(struct jobs *jobs, int64_t id, store_event_fn fn, void *data,
		 struct asph_error *err)
{
	int r = store_history(jobs->store, id, fn, data);

	return r < 0 ? asph_error_set(err, r, "cannot read the history of job %" PRId64 ": %s",
				      id, strerror(-r)) : 0;
}

json_t *jobs_job_to_json(const struct jobs *jobs, const struct job_record *j)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(j->spec, 0, NULL);
	const struct slot *sl = j->state == JOB_RUNNING || j->state == JOB_PAUSED
		? slot_of_job_const(jobs, j->id) : NULL;
	const struct instrument_activity *a = sl ? &sl->act : NULL;
	int64_t done = a ? a->done : j->points_done;
	int64_t total = a && a->total ? a->total : j->points_total;
	json_t *lens = json_object_get(spec, "lens");
	json_t *progress;
	char verdict[16];

	/* a job that does not run has no phase */
	if (a) {
		struct instrument_activity now = *a;
		now.done = done;
		now.total = total;
		progress = activity_progress_to_json(&now);
	} else {
		progress = json_pack("{s:I, s:I, s:f, s:f, s:n, s:n}", "done", (json_int_t)done,
				     "total", (json_int_t)total, "rate", 0.0, "eta_s", -1.0,
				     "phase", "trials");
	}

	return json_pack("{s:I, s:s, s:s?, s:s, s:I, s:{s:I, s:s?}, s:O?, s:O?, s:O?, s:O?, s:s?,"
			 " s:o, s:o, s:o, s:o, s:s?, s:I, s:b, s:s?, s:s?, s:s?}",
		"id", (json_int_t)j->id,
		"state", job_state_name(j->state),
		"label", j->label,
		"instrument", j->instrument,
		"priority", (json_int_t)j->priority,
		"submitter", "uid", (json_int_t)j->uid, "name", j->user,
		"lens", json_object_get(lens, "name"),
		"plan", json_object_get(spec, "plan"),
		"fit", json_object_get(spec, "fit"),
		"tolerance", json_object_get(spec, "tolerance"),
		"verdict", job_verdict(j, verdict),
		"submitted", proto_time_json(j->submitted_ns),
		"started", proto_time_json(j->started_ns),
		"finished", proto_time_json(j->finished_ns),
		"progress", progress,
		"reason", j->reason,
		"attempts", (json_int_t)j->attempts,
		"resumable", j->resume,
		"part", j->part, "lot", j->lot, "serial", j->serial);
}

int jobs_result(struct jobs *jobs, int64_t id, json_t **out, struct asph_error *err)
{
	_cleanup_free_ char *dir = NULL;
	struct job_record j;
	json_t *res;
	int r = load(jobs, id, &j, err);

	if (r < 0)
		return r;
	if (j.state != JOB_COMPLETED || !j.result) {
		r = asph_error_set(err, -ENODATA, "job %" PRId64 " is %s", j.id,
				   job_state_name(j.state));
		job_record_clear(&j);
		return r;
	}
	res = json_loads(j.result, 0, NULL);
	dir = dirs_job_path(jobs->state_dir, j.id);
	job_record_clear(&j);
	if (!res || !dir) {
		json_decref(res);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	json_object_set_new(res, "dir", json_string(dir));
	*out = res;
	return 0;
}

/* Whether name is among the files of a result (JSON text). */
static bool result_has_file(const char *result, const char *name)
{
	_cleanup_(json_decrefp) json_t *r = json_loads(result, 0, NULL);
	const char *key;
	json_t *v;

	json_object_foreach(json_object_get(r, "files"), key, v)
		if (json_is_string(v) && !strcmp(json_string_value(v), name))
			return true;
	return false;
}

int jobs_result_file(struct jobs *jobs, int64_t id, const char *name, int *out,
		     struct asph_error *err)
{
	_cleanup_close_ int dir = -1;
	struct job_record j;
	int r = load(jobs, id, &j, err), fd;

	if (r < 0)
		return r;
	if (j.state != JOB_COMPLETED || !j.result) {
		r = asph_error_set(err, -ENODATA, "job %" PRId64 " is %s", j.id,
				   job_state_name(j.state));
	} else if (!result_has_file(j.result, name)) {
		r = asph_error_set(err, -EPERM, "\"%.64s\" is not a file of job %" PRId64
				   "'s result", name, j.id);
	}
	job_record_clear(&j);
	if (r < 0)
		return r;
	dir = dirs_open_job(jobs->state_fd, id, false);
	fd = dir < 0 ? dir : fs_open_beneath(dir, name, O_RDONLY, 0);
	if (fd < 0)
		return asph_error_set(err, fd, "%s of job %" PRId64 ": %s", name, id,
				      fd == -ELOOP ? "a symbolic link: not read" : strerror(-fd));
	*out = fd;
	return 0;
}

bool jobs_queue_running(const struct jobs *jobs)
{
	return jobs->queue_running;
}

const int64_t *jobs_counts(const struct jobs *jobs)
{
	return jobs->counts;
}

const struct instrument_activity *jobs_activity(const struct jobs *jobs, size_t i)
{
	return i < jobs->n_slots ? &jobs->slots[i].act : NULL;
}

void jobs_status_text(const struct jobs *jobs, char *buf, size_t size)
{
	size_t n = 0;

	buf[0] = '\0';
	for (size_t i = 0; i < jobs->n_slots && n < size; i++) {
		const struct instrument_activity *a = &jobs->slots[i].act;
		if (!a->job)
			continue;
		n += (size_t)snprintf(buf + n, size - n, "%s%s job %" PRId64 ": %d %%",
				      n ? ", " : "", a->paused ? "paused" : a->planning ? "planning"
				      : a->characterizing ? "characterizing" : "measuring", a->job,
				      a->total > 0 ? (int)(100 * a->done / a->total) : 0);
		if (n < size && a->characterizing && a->trials_planned > 0)
			n += (size_t)snprintf(buf + n, size - n, ", uncertainty %" PRId64 "/%" PRId64
					      " trials", a->trials_done, a->trials_planned);
	}
	if (!buf[0])
		snprintf(buf, size, "%s", jobs->stopping ? "stopping"
			 : jobs->queue_running ? "idle" : "idle, queue stopped");
}
