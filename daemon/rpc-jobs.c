/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The methods of the jobs and their queue: job.submit and job.estimate
 * (the plan checked on a task's thread), job.get, job.list, the changes of
 * a job, job.result, job.file, and queue.*.
 *
 * Event loop thread.
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph-proto.h"
#include "estimate.h"
#include "jobspec.h"
#include "rpc-internal.h"
#include "turns.h"
#include "util-mem.h"
#include "util-time.h"

/* The computations (tasks.h) of one owner at once: a plan checked or
 * estimated, running or waiting for a thread. */
#define TASKS_PER_OWNER 2

/* -------------------------------------------------------------- jobs */

/* What a job.submit or job.estimate keeps while its plan is checked. */
struct check {
	struct rpc_line *line;
	bool submit;                    /* queue the job once it is checked */
	struct job_submission sub;      /* its strings are copies */
	char *strings[5];
	struct job_actor who;
	char *who_name;
	int64_t timeout_ms;
};

static void check_free(void *data)
{
	struct check *k = data;

	if (!k)
		return;
	for (size_t i = 0; i < ARRAY_SIZE(k->strings); i++)
		free(k->strings[i]);
	free(k->who_name);
	free(k);
}

/* *s as a copy kept in k. */
static int check_keep(struct check *k, size_t i, const char **s)
{
	if (!*s)
		return 0;
	k->strings[i] = strdup(*s);
	*s = k->strings[i];
	return *s ? 0 : -ENOMEM;
}

/* The parameters job.submit and job.estimate share, read into sub (the
 * cheap checks: the plan is checked by a task). check is the refusal to
 * give before anything is computed. */
static int submission_from_params(struct call *c, json_t *params,
				  int (*check)(const struct jobs *, const char *,
					       struct asph_error *),
				  struct job_submission *sub)
{
	static const char *const names[] = { "lens", "plan", "measured", "fit", "tolerance",
					     "instrument", "priority", "label", "part", "lot",
					     "serial", NULL };
	const struct settings_limits *lim = c->rpc->limits;
	struct asph_error err;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (!params || !json_object_get(params, "lens"))
		return rpc_fail(c, PROTO_INVALID_PARAMS, "missing parameter \"lens\"");
	if (!json_object_get(params, "plan") && !json_object_get(params, "measured"))
		return rpc_fail(c, PROTO_INVALID_PARAMS, "missing parameter \"plan\" (or "
				"\"measured\", the job's data)");
	if (proto_param_string(params, "instrument", false, 63, &sub->instrument,
			       &c->why) == -EINVAL ||
	    proto_param_string(params, "label", false, lim->max_label_bytes, &sub->label,
			       &c->why) == -EINVAL ||
	    proto_param_int(params, "priority", false, -1000, 1000, &sub->priority,
			    &c->why) == -EINVAL ||
	    proto_param_string(params, "part", false, lim->max_label_bytes, &sub->part,
			       &c->why) == -EINVAL ||
	    proto_param_string(params, "lot", false, lim->max_label_bytes, &sub->lot,
			       &c->why) == -EINVAL ||
	    proto_param_string(params, "serial", false, lim->max_label_bytes, &sub->serial,
			       &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	asph_error_clear(&err);
	r = check(c->rpc->jobs, sub->instrument, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : 0;
}

/* The job checked: queued (job.submit), or its estimate answered. */
static void check_answer(struct check *k, struct estimate *e)
{
	struct rpc_line *l = k->line;
	struct call c = { .rpc = l->rpc, .s = l->s, .line = l };
	_cleanup_free_ char *text = NULL;
	struct asph_error err;
	struct job_record j;
	json_t *result = NULL, *t = e->timed ? json_real(e->seconds) : json_null();
	int code = 0, r;

	if (!k->submit) {
		result = json_pack("{s:o, s:I}", "estimate_s", t, "points", (json_int_t)e->points);
		if (result && e->choice)
			json_object_set(result, "plan_for_tolerance", e->choice);
		rpc_line_answer(l, &c, result ? 0 : PROTO_INTERNAL_ERROR, result);
		return;
	}
	text = json_dumps(e->spec, JSON_COMPACT);
	k->sub.spec = text;
	k->sub.points = (int64_t)e->points;
	if (e->data_fd >= 0) {
		k->sub.data_fd = e->data_fd;
		k->sub.data_name = e->data_name;
	}
	asph_error_clear(&err);
	r = text ? jobs_submit(l->rpc->jobs, &k->sub, &k->who, &j, &err) : -ENOMEM;
	if (r < 0) {
		code = rpc_job_error(&c, r, &err);
	} else if ((code = rpc_job_result(&c, &j, &result)) == 0) {
		json_object_set_new(result, "estimate_s", t);
		t = NULL;
	}
	json_decref(t);
	rpc_line_answer(l, &c, code, result);
}

/* A task's done(): the plan checked, or its deadline passed. */
static void check_done(void *work, int r, void *data)
{
	struct check *k = data;
	struct estimate *e = work;
	struct rpc_line *l = k->line;
	struct call c = { .rpc = l->rpc, .s = l->s, .line = l };

	if (r == -ETIMEDOUT) {
		rpc_fail(&c, PROTO_REQUEST_TIMEOUT, "checking the plan took longer than "
			 "limits.request_timeout_ms (%" PRId64 " ms)%s", k->timeout_ms,
			 k->submit ? ": nothing was queued" : "");
		rpc_line_answer(l, &c, PROTO_REQUEST_TIMEOUT, NULL);
	} else if (r < 0 || e->code) {
		int code = r < 0 ? PROTO_INTERNAL_ERROR : e->code;
		proto_why_set(&c.why, "%s", r < 0 ? strerror(-r) : e->why.text);
		rpc_line_answer(l, &c, code, NULL);
	} else {
		check_answer(k, e);
	}
}

_Static_assert(JOBSPEC_MAX_FD + 1 == RPC_SESSION_MAX_FDS,
	       "a request may name every descriptor a session holds");

/*
 * "measured": checked (cheap: names and types), then the descriptor the
 * request names, taken from those its connection passed, and for
 * job.submit the file it is copied into. 0, or the refusal (a TCP peer
 * cannot pass one).
 */
static int take_measured(struct call *c, json_t *params, bool submit, struct estimate *e)
{
	json_t *fd = json_object_get(json_object_get(params, "measured"), "fd");
	int in, data = -1;

	if (!json_object_get(params, "measured"))
		return 0;
	if (jobspec_check_measured(params, &c->why))
		return PROTO_INVALID_PARAMS;
	if (c->s->peer.tcp)
		return rpc_fail(c, PROTO_INVALID_PARAMS, "\"measured\" passes the data as a file "
				"descriptor on the daemon's unix socket: not over TCP or the web "
				"(run asphctl submit --measured on the daemon's machine)");
	in = rpc_session_take_fd(c->s, (unsigned)json_integer_value(fd));
	if (in < 0)
		return rpc_fail(c, PROTO_INVALID_PARAMS, "\"measured.fd\": no descriptor %" PRId64
				" was passed (SCM_RIGHTS, with the request's line)",
				(int64_t)json_integer_value(fd));
	if (submit && (data = jobs_open_data(c->rpc->jobs)) < 0) {
		close(in);
		return rpc_fail(c, PROTO_INTERNAL_ERROR, "cannot make room for the measured data "
				"in the state directory: %s", strerror(-data));
	}
	estimate_set_measured(e, in, data, c->rpc->limits->max_measured_bytes);
	return 0;
}

/*
 * job.submit and job.estimate: the cheap refusals at once; the plan (its
 * surface, its size against the limits, the feed-rate profile of its
 * estimate) on a task's thread, the answer when it is done.
 */
static int check_plan(struct call *c, json_t *params, bool submit)
{
	const struct settings_limits *lim = c->rpc->limits;
	const struct jobspec_limits jl = { .max_points = lim->max_plan_points,
					   .max_point_terms = lim->max_plan_point_terms };
	struct job_actor who = rpc_actor(c);
	struct check *k = calloc(1, sizeof(*k));
	struct estimate *e = NULL;
	const struct peer *p = &c->s->peer;
	int i, code, r;

	if (!k)
		return PROTO_INTERNAL_ERROR;
	code = submission_from_params(c, params, submit ? jobs_check_submit
						       : jobs_check_instrument, &k->sub);
	if (code) {
		check_free(k);
		return code;
	}
	i = k->sub.instrument ? instruments_find(c->rpc->instruments, k->sub.instrument) : 0;
	k->line = c->line;
	k->submit = submit;
	k->timeout_ms = lim->request_timeout_ms;
	k->who = who;
	k->who_name = strdup(who.name ? who.name : "");
	k->who.name = k->who_name;
	if (!k->who_name || check_keep(k, 0, &k->sub.instrument) || check_keep(k, 1, &k->sub.label) ||
	    check_keep(k, 2, &k->sub.part) || check_keep(k, 3, &k->sub.lot) ||
	    check_keep(k, 4, &k->sub.serial) ||
	    estimate_new(params, &jl, i >= 0 && (size_t)i < instruments_count(c->rpc->instruments)
			 ? instruments_get(c->rpc->instruments, (size_t)i)->config : NULL, !submit,
			 &e) < 0) {
		check_free(k);
		return PROTO_INTERNAL_ERROR;
	}
	code = take_measured(c, params, submit, e);
	if (code) {
		estimate_free(e);
		check_free(k);
		return code;
	}
	rpc_defer(c, k, check_free);
	if (!c->rpc->tasks) {           /* no pool: at once */
		check_done(e, estimate_run(e, NULL), k);
		estimate_free(e);
		return 0;
	}
	r = tasks_submit(c->rpc->tasks, &(struct task_spec){
		.owner = c->s->owner, .privileged = rpc_is_operator(c),
		/* root has no share of its own, as for connections */
		.max_per_owner = !p->tcp && p->uid == 0 ? TASKS_MAX_WAITING : TASKS_PER_OWNER,
		.deadline_usec = turns_now_usec() + (uint64_t)lim->request_timeout_ms * 1000,
		.run = estimate_run, .done = check_done, .free = estimate_free,
		.work = e, .data = k }, &c->line->task);
	if (r == 0)
		return 0;
	c->deferred = false;            /* (the line frees k) */
	if (r == -EDQUOT)
		return rpc_fail(c, PROTO_LIMIT_REACHED, "%s has %d plans being checked or "
				"estimated: wait for their answers", c->s->owner, TASKS_PER_OWNER);
	if (r == -EAGAIN)
		return rpc_fail(c, PROTO_LIMIT_REACHED, "%d plans wait to be checked: try again in "
				"a moment", TASKS_MAX_WAITING);
	return PROTO_INTERNAL_ERROR;
}

int rpc_method_job_submit(struct call *c, json_t *params, json_t **result)
{
	return check_plan(c, params, true);
}

/* What job.submit would predict for the same parameters, queuing nothing:
 * a full queue or a locked instrument does not stop a look ahead. */
int rpc_method_job_estimate(struct call *c, json_t *params, json_t **result)
{
	return check_plan(c, params, false);
}

static int history_entry(const struct store_event *e, void *data)
{
	json_t *list = data;
	char buf[32];

	iso8601_utc(e->t_ns, 0, buf, sizeof(buf));
	return json_array_append_new(list, json_pack("{s:s, s:s, s:s?, s:I, s:s?}", "time", buf,
		"state", job_state_name(e->state), "reason", e->reason,
		"actor_uid", (json_int_t)e->actor_uid, "actor", e->actor)) < 0 ? -ENOMEM : 0;
}

int rpc_method_job_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "history", NULL };
	struct asph_error err;
	struct job_record j;
	bool history = false;
	int64_t id;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_bool(params, "history", false, &history, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if ((code = rpc_job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_get(c->rpc->jobs, id, &j, &err);
	if (r < 0)
		return rpc_job_error(c, r, &err);
	code = rpc_job_result(c, &j, result);
	if (!code && history) {
		json_t *h = json_array();
		jobs_history(c->rpc->jobs, id, history_entry, h, NULL);
		json_object_set_new(*result, "history", h);
	}
	return code;
}

/* The answer is result and the jobs f selects (NULL: the queue) as its
 * "jobs", a step at a time (rpc_line_step()). */
static int list_jobs(struct call *c, const struct store_filter *f, json_t *result,
		     json_t **out)
{
	struct listing *ls = calloc(1, sizeof(*ls));

	if (!ls || !result || jobs_cursor_new(c->rpc->jobs, f, &ls->cursor) < 0) {
		free(ls);
		json_decref(result);
		return rpc_fail(c, PROTO_INTERNAL_ERROR, "out of memory");
	}
	c->listing = ls;
	*out = result;
	return 0;
}

static const char *const state_list[] = {
	"queued", "running", "paused", "completed", "failed", "cancelled", "interrupted", NULL
};

int rpc_method_job_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "states", "instrument", "label", "uid", "mine",
					     "part", "lot", "serial", "offset", "limit", NULL };
	struct store_filter f = { .uid = STORE_ANY_UID, .limit = 100 };
	struct asph_error err;
	bool mine = false;
	int64_t total = 0;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_flags(params, "states", false, state_list, &f.states, &c->why) == -EINVAL ||
	    proto_param_string(params, "instrument", false, 63, &f.instrument, &c->why) == -EINVAL ||
	    proto_param_string(params, "label", false, 4096, &f.label, &c->why) == -EINVAL ||
	    proto_param_int(params, "uid", false, 0, UINT32_MAX, &f.uid, &c->why) == -EINVAL ||
	    proto_param_bool(params, "mine", false, &mine, &c->why) == -EINVAL ||
	    proto_param_string(params, "part", false, 4096, &f.part, &c->why) == -EINVAL ||
	    proto_param_string(params, "lot", false, 4096, &f.lot, &c->why) == -EINVAL ||
	    proto_param_string(params, "serial", false, 4096, &f.serial, &c->why) == -EINVAL ||
	    proto_param_int(params, "offset", false, 0, INT64_MAX, &f.offset, &c->why) == -EINVAL ||
	    proto_param_int(params, "limit", false, 1, 1000, &f.limit, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (mine) {
		struct job_actor who = rpc_actor(c);
		f.uid = who.uid;
		/* Over TCP the token's jobs: the uid is every TCP peer's. */
		if (c->s->peer.tcp)
			f.user = who.name;
	}
	asph_error_clear(&err);
	r = jobs_count(c->rpc->jobs, &f, &total, &err);
	if (r < 0)
		return rpc_job_error(c, r, &err);
	return list_jobs(c, &f, json_pack("{s:I, s:I, s:I}", "total", (json_int_t)total,
					  "offset", (json_int_t)f.offset, "limit",
					  (json_int_t)f.limit), result);
}

int rpc_method_job_cancel(struct call *c, json_t *params, json_t **result)
{
	return rpc_change_job(c, params, jobs_cancel, result);
}

int rpc_method_job_pause(struct call *c, json_t *params, json_t **result)
{
	return rpc_change_job(c, params, jobs_pause, result);
}

int rpc_method_job_resume(struct call *c, json_t *params, json_t **result)
{
	return rpc_change_job(c, params, jobs_resume, result);
}

int rpc_method_job_requeue(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "restart", NULL };
	struct job_actor who = rpc_actor(c);
	struct asph_error err;
	struct job_record j;
	bool restart = false;
	int64_t id;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_bool(params, "restart", false, &restart, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if ((code = rpc_job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_requeue(c->rpc->jobs, id, restart, &who, &j, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : rpc_job_result(c, &j, result);
}

int rpc_method_job_result(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct asph_error err;
	int64_t id;
	int code = rpc_only(c, params, names), r;

	if (code || (code = rpc_job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_result(c->rpc->jobs, id, result, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : 0;
}

int rpc_method_job_file(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "name", "offset", "length", NULL };
	_cleanup_close_ int fd = -1;
	struct asph_error err;
	const char *name;
	int64_t id, offset, length;
	int code = rpc_only(c, params, names), r;

	if (code || (code = rpc_job_id(c, params, &id)))
		return code;
	if (proto_param_string(params, "name", true, 255, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	if ((code = rpc_chunk_params(c, params, &offset, &length)))
		return code;
	asph_error_clear(&err);
	r = jobs_result_file(c->rpc->jobs, id, name, &fd, &err);
	if (r < 0)
		return rpc_job_error(c, r, &err);
	return rpc_file_chunk(c, fd, name, offset, length, result);
}

/* ------------------------------------------------------------- queue */

static int queue_json(struct call *c, json_t **result)
{
	return list_jobs(c, NULL, json_pack("{s:b}", "running", jobs_queue_running(c->rpc->jobs)),
			 result);
}

int rpc_method_queue_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = rpc_only(c, params, names);

	return code ? code : queue_json(c, result);
}

int rpc_method_queue_move(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "position", NULL };
	struct job_actor who = rpc_actor(c);
	struct asph_error err;
	int64_t id, pos;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_int(params, "position", true, 0, INT64_MAX, &pos, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	if ((code = rpc_job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_move(c->rpc->jobs, id, pos, &who, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : queue_json(c, result);
}

int rpc_method_queue_start(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct job_actor who = rpc_actor(c);
	struct asph_error err;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	asph_error_clear(&err);
	r = jobs_queue_start(c->rpc->jobs, &who, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : queue_json(c, result);
}

int rpc_method_queue_stop(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "abort", NULL };
	struct job_actor who = rpc_actor(c);
	struct asph_error err;
	bool abort_running = false;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_bool(params, "abort", false, &abort_running, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	asph_error_clear(&err);
	r = jobs_queue_stop(c->rpc->jobs, abort_running, &who, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : queue_json(c, result);
}
