/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread: the queue. Its set up and end, and the changes asked
 * of it (submit, cancel, pause, resume, requeue, move, the queue started
 * and stopped). jobs-internal.h tells which file does the rest and which
 * way the calls go.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "dirs.h"
#include "jobs-internal.h"
#include "log.h"
#include "store.h"
#include "util-time.h"
#include "util-mem.h"

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
		r = jobs_start_workers(jobs, setup->instruments, err);
	if (r == 0)
		r = jobs_load_locks(jobs, err);
	if (r == 0 && sd_event_add_time(jobs->event, &jobs->retry, CLOCK_MONOTONIC, UINT64_MAX,
					0, jobs_retry_schedule, jobs) < 0)
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
		jobs_lock_release(&jobs->slots[i]);
	}
	free(jobs->slots);
	sd_event_source_disable_unref(jobs->retry);
	store_close(jobs->store);
	if (jobs->state_fd >= 0)
		close(jobs->state_fd);
	free(jobs->state_dir);
	free(jobs);
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

/* ---------------------------------------------------------- changes */

static int queue_length(const struct jobs *jobs)
{
	return (int)(jobs->counts[JOB_QUEUED] + jobs->counts[JOB_RUNNING] +
		     jobs->counts[JOB_PAUSED] + jobs->counts[JOB_INTERRUPTED]);
}

int jobs_check_instrument(const struct jobs *jobs, const char *instrument,
			  struct asph_error *err)
{
	if (instrument && !jobs_slot_of_instrument_name(jobs, instrument))
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

int jobs_open_data(const struct jobs *jobs)
{
	int fd = openat(jobs->state_fd, ".", O_TMPFILE | O_WRONLY | O_CLOEXEC, DIRS_FILE_MODE);

	return fd < 0 ? -errno : fd;
}

/* The measured data's file given its name in the folder of job id, which
 * it creates: 0 or -errno (a name taken already is refused). */
static int keep_data(struct jobs *jobs, int64_t id, const struct job_submission *sub,
		     struct asph_error *err)
{
	_cleanup_close_ int dir = dirs_open_job(jobs->state_fd, id, true);
	char self[64];

	if (dir < 0)
		return asph_error_set(err, dir, "cannot create the job's folder: %s",
				      strerror(-dir));
	/* linkat(AT_EMPTY_PATH) would need CAP_DAC_READ_SEARCH: the file
	 * is named through /proc instead, as open(2) describes */
	snprintf(self, sizeof(self), "/proc/self/fd/%d", sub->data_fd);
	if (linkat(AT_FDCWD, self, dir, sub->data_name, AT_SYMLINK_FOLLOW) < 0 ||
	    fsync(dir) < 0)
		return asph_error_set(err, -errno, "cannot keep the measured data in the job's "
				      "folder: %s", strerror(errno));
	return 0;
}

/* The job stored whose data could not be kept fails, saying why. */
static void fail_unkept(struct jobs *jobs, int64_t id, const struct asph_error *why)
{
	struct job_record j;
	char reason[320];

	asph_error_format(why, reason, sizeof(reason));
	log_job(LOG_ERR, id, "%s", reason);
	if (jobs_load(jobs, id, &j, NULL) < 0)
		return;
	j.finished_ns = now_realtime_ns();
	jobs_transition(jobs, &j, JOB_FAILED, reason, NULL, NULL);
	job_record_clear(&j);
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
		r = jobs_check_lock(jobs_slot_of_instrument_name(jobs, instrument), who, err);
	if (r < 0)
		return r;
	if (jobs_check_room(jobs, sub->points, why, sizeof(why)) < 0)
		return asph_error_set(err, -EDQUOT, "%s", why);
	r = store_insert(jobs->store, &j, now_realtime_ns());
	if (r < 0)
		return asph_error_set(err, r, "cannot store the job: %s", strerror(-r));
	jobs->counts[JOB_QUEUED]++;
	if (sub->data_name && (r = keep_data(jobs, j.id, sub, err)) < 0) {
		fail_unkept(jobs, j.id, err);
		return r;
	}
	log_job(LOG_INFO, j.id, "submitted by %s (uid %" PRId64 ") for %s%s", who->name, who->uid,
		instrument, sub->data_name ? ", of measured data" : "");
	events_job_state(jobs->events, j.id, JOB_QUEUED, -1, NULL, instrument, NULL);
	r = out ? jobs_load(jobs, j.id, out, err) : 0;
	jobs_schedule(jobs);
	return r;
}

int jobs_cancel(struct jobs *jobs, int64_t id, const struct job_actor *who,
		struct job_record *out, struct asph_error *err)
{
	struct job_record j;
	struct slot *sl;
	int r = jobs_load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = jobs_check_lock(jobs_slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		return hand_over(&j, r, out);
	switch (j.state) {
	case JOB_QUEUED:
	case JOB_INTERRUPTED:
		j.finished_ns = now_realtime_ns();
		r = jobs_transition(jobs, &j, JOB_CANCELLED, NULL, who, err);
		break;
	case JOB_RUNNING:
	case JOB_PAUSED:
		/* The worker stops the scan; its report ends the job, cancelled
		 * whatever stop was asked before (job_end()). */
		sl = jobs_slot_of_job(jobs, j.id);
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

/* Pauses a running job, or (!pause) resumes a paused one or queues an
 * interrupted one to continue. */
static int pause_or_resume(struct jobs *jobs, int64_t id, bool pause,
			   const struct job_actor *who, struct job_record *out,
			   struct asph_error *err)
{
	struct job_record j;
	struct slot *sl;
	int r = jobs_load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = jobs_check_lock(jobs_slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		return hand_over(&j, r, out);
	sl = jobs_slot_of_job(jobs, j.id);
	if (sl && j.state == (pause ? JOB_RUNNING : JOB_PAUSED))
		r = jobs_set_paused(jobs, &j, sl, pause, NULL, who, err);
	else if (!pause && j.state == JOB_INTERRUPTED)
		r = jobs_back_to_queue(jobs, &j, false, who, err);
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
	int r = jobs_load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = jobs_check_lock(jobs_slot_of_instrument(jobs, j.instrument), who, err);
	if (r < 0)
		return hand_over(&j, r, out);
	if (j.state != JOB_FAILED && j.state != JOB_INTERRUPTED && j.state != JOB_CANCELLED &&
	    !(j.state == JOB_COMPLETED && restart))
		r = refuse_state(&j, j.state == JOB_COMPLETED ? " (re-queue it with restart)" : "",
				 err);
	else
		r = jobs_back_to_queue(jobs, &j, restart || j.state == JOB_COMPLETED, who, err);
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
	int r = jobs_load(jobs, id, &j, err);

	if (r < 0)
		return r;
	r = jobs_check_lock(jobs_slot_of_instrument(jobs, j.instrument), who, err);
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
