/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread: what is read of the jobs. A job, listings and
 * cursors through them, the history, a job as JSON, its result and its
 * files, the counts, what each instrument does, the status line.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph-proto.h"
#include "dirs.h"
#include "jobs-internal.h"
#include "store.h"
#include "util-fs.h"
#include "util-mem.h"

static const struct slot *slot_of_job_const(const struct jobs *jobs, int64_t id)
{
	return jobs_slot_of_job((struct jobs *)jobs, id);
}

/* ---------------------------------------------------------- reading */

int jobs_get(struct jobs *jobs, int64_t id, struct job_record *out, struct asph_error *err)
{
	return jobs_load(jobs, id, out, err);
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

	return json_pack("{s:I, s:s, s:s?, s:s, s:I, s:{s:I, s:s?}, s:O?, s:O, s:O*, s:O?, s:O?,"
			 " s:s?, s:o, s:o, s:o, s:o, s:s?, s:I, s:b, s:s?, s:s?, s:s?}",
		"id", (json_int_t)j->id,
		"state", job_state_name(j->state),
		"label", j->label,
		"instrument", j->instrument,
		"priority", (json_int_t)j->priority,
		"submitter", "uid", (json_int_t)j->uid, "name", j->user,
		"lens", json_object_get(lens, "name"),
		/* a job of measured data has none, and says what it measured */
		"plan", json_object_get(spec, "plan") ? json_object_get(spec, "plan") : json_null(),
		"measured", json_object_get(spec, "measured"),
		"fit", json_object_get(spec, "fit"),
		"tolerance", json_object_get(spec, "tolerance"),
		"verdict", jobs_verdict(j, verdict),
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
	int r = jobs_load(jobs, id, &j, err);

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
	int r = jobs_load(jobs, id, &j, err), fd;

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
