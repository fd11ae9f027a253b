/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The methods of proto/README.md. Each handler returns 0 with a result, or
 * a protocol error code with a detail in call->why. Mutating methods are
 * refused before their handler runs unless the peer is an operator.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asphd.h"
#include "config.h"
#include "dirs.h"
#include "log.h"
#include "jobspec.h"
#include "time-util.h"
#include "util-mem.h"

struct call {
	struct daemon *d;
	struct client *client;
	struct proto_why why;
	json_t *data;           /* extra error data, or NULL */
};

typedef int (*method_fn)(struct call *c, json_t *params, json_t **result);

static int fail(struct call *c, int code, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));

static int fail(struct call *c, int code, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	vsnprintf(c->why.text, sizeof(c->why.text), fmt, ap);
	va_end(ap);
	return code;
}

bool client_is_operator(const struct client *c)
{
	const struct daemon *d = c->d;

	if (c->tcp)
		return c->authenticated && d->token;
	if (c->uid == 0)
		return true;
	if (!d->have_operator_group)
		return false;
	if (c->gid == d->operator_gid)
		return true;
	for (int i = 0; i < c->n_groups; i++)
		if (c->groups[i] == d->operator_gid)
			return true;
	return false;
}

/* params: only the listed members, each checked by the handler. */
static int only(struct call *c, json_t *params, const char *const *names)
{
	return proto_params_only(params, names, &c->why) < 0 ? PROTO_INVALID_PARAMS : 0;
}

static int get_job(struct call *c, json_t *params, struct job_record *j)
{
	int64_t id;
	int r;

	if (proto_param_int(params, "id", true, 1, INT64_MAX, &id, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	r = store_get(c->d->store, id, j);
	if (r == -ENOENT)
		return fail(c, PROTO_NO_SUCH_JOB, "no job %" PRId64, id);
	if (r < 0)
		return fail(c, PROTO_STORAGE_ERROR, "cannot read job %" PRId64, id);
	return 0;
}

static int job_result_json(struct call *c, const struct job_record *j, json_t **result)
{
	*result = job_to_json(c->d, j);
	return *result ? 0 : PROTO_INTERNAL_ERROR;
}

/* ------------------------------------------------------------ daemon */

static int m_hello(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "client", "token", NULL };
	const char *token = NULL, *client = NULL;
	struct daemon *d = c->d;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_string(params, "client", false, 128, &client, &c->why) == -EINVAL ||
	    proto_param_string(params, "token", false, 512, &token, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (c->client->tcp && !c->client->authenticated) {
		/* Constant time in the token's length. */
		size_t n = d->token ? strlen(d->token) : 0, m = token ? strlen(token) : 0;
		unsigned diff = (unsigned)(n != m) | (unsigned)!token;
		for (size_t i = 0; token && i < n; i++)
			diff |= (unsigned)(d->token[i] ^ (i < m ? token[i] : 0));
		if (diff)
			return fail(c, PROTO_PERMISSION_DENIED, "wrong token");
		c->client->authenticated = true;
	}
	*result = json_pack("{s:s, s:s, s:{s:i, s:i}, s:{s:I, s:s, s:b}}",
		"server", "asphd", "version", ASPH_VERSION,
		"protocol", "major", PROTO_VERSION_MAJOR, "minor", PROTO_VERSION_MINOR,
		"peer", "uid", (json_int_t)(int)c->client->uid, "name", c->client->name,
		"operator", client_is_operator(c->client));
	return 0;
}

static int m_version(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	*result = json_pack("{s:s, s:s, s:{s:i, s:i}}", "server", "asphd",
			    "version", ASPH_VERSION, "protocol", "major", PROTO_VERSION_MAJOR,
			    "minor", PROTO_VERSION_MINOR);
	return 0;
}

static json_t *counts_json(struct daemon *d)
{
	json_t *o = json_object();

	for (int s = 0; o && s < JOB_N_STATES; s++)
		json_object_set_new(o, job_state_name((enum job_state)s),
				    json_integer(d->counts[s]));
	return o;
}

static int m_daemon_status(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct daemon *d = c->d;
	json_t *inst;
	uint64_t now;
	int code = only(c, params, names);

	if (code)
		return code;
	inst = json_array();
	for (size_t i = 0; inst && i < d->n_instruments; i++) {
		struct instrument *in = &d->instruments[i];
		json_array_append_new(inst, json_pack("{s:s, s:s, s:o}", "name", in->name,
			"state", instrument_state(in),
			"job", in->job ? json_integer(in->job) : json_null()));
	}
	sd_event_now(d->event, CLOCK_MONOTONIC, &now);
	*result = json_pack("{s:s, s:i, s:f, s:s, s:{s:b}, s:o, s:o, s:I, s:I}",
		"version", ASPH_VERSION, "pid", (int)getpid(),
		"uptime_s", (double)(now - d->started_usec) / 1e6,
		"status", d->status_text,
		"queue", "running", d->queue_running,
		"jobs", counts_json(d), "instruments", inst,
		"clients", (json_int_t)d->n_clients, "requests", (json_int_t)d->requests);
	return 0;
}

/* -------------------------------------------------------------- jobs */

static int queue_length(struct daemon *d)
{
	return (int)(d->counts[JOB_QUEUED] + d->counts[JOB_RUNNING] + d->counts[JOB_PAUSED] +
		     d->counts[JOB_INTERRUPTED]);
}

static int m_job_submit(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "lens", "plan", "fit", "instrument", "priority",
					     "label", NULL };
	struct daemon *d = c->d;
	struct job_record j = { 0 };
	const char *instrument = d->instruments[0].name, *label = NULL;
	int64_t priority = 0;
	json_t *spec = NULL;
	uint64_t points = 0;
	int code = only(c, params, names);

	if (code)
		return code;
	if (!params || !json_object_get(params, "lens"))
		return fail(c, PROTO_INVALID_PARAMS, "missing parameter \"lens\"");
	if (proto_param_string(params, "instrument", false, 63, &instrument, &c->why) == -EINVAL ||
	    proto_param_string(params, "label", false, d->config->limits.max_label_bytes, &label,
			       &c->why) == -EINVAL ||
	    proto_param_int(params, "priority", false, -1000, 1000, &priority, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (!instrument_find(d, instrument))
		return fail(c, PROTO_NO_SUCH_INSTRUMENT, "no instrument \"%s\"", instrument);
	if (queue_length(d) >= (int)d->config->limits.max_queue)
		return fail(c, PROTO_LIMIT_REACHED, "the queue holds %u jobs, its limit",
			    d->config->limits.max_queue);
	code = jobspec_from_params(params, d->config->limits.max_plan_points, &spec, &points, &c->why);
	if (code)
		return code;
	j.state = JOB_QUEUED;
	j.priority = priority;
	j.label = (char *)label;
	j.instrument = (char *)instrument;
	j.uid = (int64_t)(int)c->client->uid;
	j.user = c->client->name;
	j.spec = json_dumps(spec, JSON_COMPACT);
	j.points_total = (int64_t)points;
	json_decref(spec);
	if (!j.spec)
		return PROTO_INTERNAL_ERROR;
	int r = store_insert(d->store, &j, realtime_now_ns());
	if (r < 0) {
		free(j.spec);
		return fail(c, PROTO_STORAGE_ERROR, "cannot store the job: %s", strerror(-r));
	}
	d->counts[JOB_QUEUED]++;
	log_job(LOG_INFO, j.id, "submitted by %s (uid %d) for %s", c->client->name,
		(int)c->client->uid, instrument);
	server_broadcast(d, EVENT_JOB, j.id, "job.state",
			 json_pack("{s:I, s:s, s:n, s:n, s:s}", "job", (json_int_t)j.id,
				   "state", "queued", "previous", "reason",
				   "instrument", instrument));
	code = job_result_json(c, &j, result);
	free(j.spec);
	jobs_schedule(d);
	return code;
}

static int history_entry(const struct store_event *e, void *data)
{
	json_t *list = data;
	char buf[32];

	iso8601_utc(e->t_ns, buf, sizeof(buf));
	return json_array_append_new(list, json_pack("{s:s, s:s, s:s?, s:I}", "time", buf,
		"state", job_state_name(e->state), "reason", e->reason,
		"actor_uid", (json_int_t)e->actor_uid)) < 0 ? -ENOMEM : 0;
}

static int m_job_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "history", NULL };
	struct job_record j;
	bool history = false;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_bool(params, "history", false, &history, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	code = get_job(c, params, &j);
	if (code)
		return code;
	code = job_result_json(c, &j, result);
	if (!code && history) {
		json_t *h = json_array();
		store_history(c->d->store, j.id, history_entry, h);
		json_object_set_new(*result, "history", h);
	}
	job_record_clear(&j);
	return code;
}

struct list_ctx {
	struct daemon *d;
	json_t *jobs;
};

static int list_entry(const struct job_record *j, void *data)
{
	struct list_ctx *l = data;

	return json_array_append_new(l->jobs, job_to_json(l->d, j)) < 0 ? -ENOMEM : 0;
}

static const char *const state_list[] = {
	"queued", "running", "paused", "completed", "failed", "cancelled", "interrupted", NULL
};

static int m_job_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "states", "instrument", "label", "uid", "mine",
					     "offset", "limit", NULL };
	struct store_filter f = { .uid = -1, .limit = 100 };
	struct list_ctx l = { .d = c->d };
	bool mine = false;
	int64_t total = 0;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_flags(params, "states", false, state_list, &f.states, &c->why) == -EINVAL ||
	    proto_param_string(params, "instrument", false, 63, &f.instrument, &c->why) == -EINVAL ||
	    proto_param_string(params, "label", false, 4096, &f.label, &c->why) == -EINVAL ||
	    proto_param_int(params, "uid", false, 0, UINT32_MAX, &f.uid, &c->why) == -EINVAL ||
	    proto_param_bool(params, "mine", false, &mine, &c->why) == -EINVAL ||
	    proto_param_int(params, "offset", false, 0, INT64_MAX, &f.offset, &c->why) == -EINVAL ||
	    proto_param_int(params, "limit", false, 1, 1000, &f.limit, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (mine)
		f.uid = (int64_t)(int)c->client->uid;
	l.jobs = json_array();
	if (!l.jobs)
		return PROTO_INTERNAL_ERROR;
	if (store_list(c->d->store, &f, list_entry, &l, &total) < 0) {
		json_decref(l.jobs);
		return fail(c, PROTO_STORAGE_ERROR, "cannot read the jobs");
	}
	*result = json_pack("{s:o, s:I, s:I, s:I}", "jobs", l.jobs, "total", (json_int_t)total,
			    "offset", (json_int_t)f.offset, "limit", (json_int_t)f.limit);
	return 0;
}

static int actor(struct call *c)
{
	return (int)c->client->uid;
}

static int m_job_cancel(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct job_record j;
	struct instrument *in;
	int code = only(c, params, names);

	if (code || (code = get_job(c, params, &j)))
		return code;
	switch (j.state) {
	case JOB_QUEUED:
	case JOB_INTERRUPTED:
		j.finished_ns = realtime_now_ns();
		store_update(c->d->store, &j);
		jobs_set_state(c->d, &j, JOB_CANCELLED, NULL, actor(c));
		break;
	case JOB_RUNNING:
	case JOB_PAUSED:
		in = instrument_of_job(c->d, j.id);
		if (in)
			runner_abort(in->runner);
		log_job(LOG_INFO, j.id, "cancel requested by %s", c->client->name);
		break;
	default:
		code = fail(c, PROTO_INVALID_STATE, "job %" PRId64 " is %s", j.id,
			    job_state_name(j.state));
	}
	if (!code)
		code = job_result_json(c, &j, result);
	job_record_clear(&j);
	return code;
}

static int m_job_pause(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct job_record j;
	struct instrument *in;
	int code = only(c, params, names);

	if (code || (code = get_job(c, params, &j)))
		return code;
	in = instrument_of_job(c->d, j.id);
	if (j.state != JOB_RUNNING || !in) {
		code = fail(c, PROTO_INVALID_STATE, "job %" PRId64 " is %s, not running", j.id,
			    job_state_name(j.state));
	} else {
		runner_pause(in->runner);
		in->paused = true;
		jobs_set_state(c->d, &j, JOB_PAUSED, NULL, actor(c));
		code = job_result_json(c, &j, result);
	}
	job_record_clear(&j);
	return code;
}

static int requeue(struct call *c, struct job_record *j, bool restart)
{
	if (restart)
		j->resume = false;
	j->finished_ns = 0;
	if (store_update(c->d->store, j) < 0)
		return fail(c, PROTO_STORAGE_ERROR, "cannot update job %" PRId64, j->id);
	jobs_set_state(c->d, j, JOB_QUEUED, NULL, actor(c));
	return 0;
}

static int m_job_resume(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct job_record j;
	struct instrument *in;
	int code = only(c, params, names);

	if (code || (code = get_job(c, params, &j)))
		return code;
	in = instrument_of_job(c->d, j.id);
	if (j.state == JOB_PAUSED && in) {
		runner_resume(in->runner);
		in->paused = false;
		jobs_set_state(c->d, &j, JOB_RUNNING, NULL, actor(c));
	} else if (j.state == JOB_INTERRUPTED) {
		code = requeue(c, &j, false);
	} else {
		code = fail(c, PROTO_INVALID_STATE, "job %" PRId64 " is %s", j.id,
			    job_state_name(j.state));
	}
	if (!code)
		code = job_result_json(c, &j, result);
	job_record_clear(&j);
	if (!code)
		jobs_schedule(c->d);
	return code;
}

static int m_job_requeue(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "restart", NULL };
	struct job_record j;
	bool restart = false;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_bool(params, "restart", false, &restart, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if ((code = get_job(c, params, &j)))
		return code;
	if (j.state != JOB_FAILED && j.state != JOB_INTERRUPTED && j.state != JOB_CANCELLED &&
	    !(j.state == JOB_COMPLETED && restart))
		code = fail(c, PROTO_INVALID_STATE, "job %" PRId64 " is %s", j.id,
			    job_state_name(j.state));
	else
		code = requeue(c, &j, restart || j.state == JOB_COMPLETED);
	if (!code)
		code = job_result_json(c, &j, result);
	job_record_clear(&j);
	if (!code)
		jobs_schedule(c->d);
	return code;
}

static int m_job_result(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct job_record j;
	_cleanup_free_ char *dir = NULL;
	json_t *res;
	int code = only(c, params, names);

	if (code || (code = get_job(c, params, &j)))
		return code;
	if (j.state != JOB_COMPLETED || !j.result) {
		code = fail(c, PROTO_NO_RESULT, "job %" PRId64 " is %s", j.id,
			    job_state_name(j.state));
		job_record_clear(&j);
		return code;
	}
	res = json_loads(j.result, 0, NULL);
	dir = dirs_job_path(c->d->state_dir, j.id);
	if (!res || !dir) {
		json_decref(res);
		job_record_clear(&j);
		return PROTO_INTERNAL_ERROR;
	}
	json_object_set_new(res, "dir", json_string(dir));
	*result = res;
	job_record_clear(&j);
	return 0;
}

/* ------------------------------------------------------------- queue */

static int queue_json(struct call *c, json_t **result)
{
	struct store_filter f = {
		.uid = -1,
		.states = 1u << JOB_QUEUED | 1u << JOB_RUNNING | 1u << JOB_PAUSED,
		.queue_order = true,
	};
	struct list_ctx l = { .d = c->d, .jobs = json_array() };

	if (!l.jobs)
		return PROTO_INTERNAL_ERROR;
	if (store_list(c->d->store, &f, list_entry, &l, NULL) < 0) {
		json_decref(l.jobs);
		return fail(c, PROTO_STORAGE_ERROR, "cannot read the queue");
	}
	*result = json_pack("{s:b, s:o}", "running", c->d->queue_running, "jobs", l.jobs);
	return 0;
}

static int m_queue_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	return code ? code : queue_json(c, result);
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

/* Moves a queued job to position (0 = runs next among queued jobs). The
 * moved job takes the priority of the job it lands before (or after, at
 * the end), so that the order stays "priority, then sequence". */
static int m_queue_move(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "position", NULL };
	struct store_filter f = { .uid = -1, .states = 1u << JOB_QUEUED, .queue_order = true };
	struct ids ids = { 0 };
	struct job_record j, other;
	int64_t pos;
	size_t k, from = SIZE_MAX;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_int(params, "position", true, 0, INT64_MAX, &pos, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	if ((code = get_job(c, params, &j)))
		return code;
	if (j.state != JOB_QUEUED) {
		code = fail(c, PROTO_INVALID_STATE, "job %" PRId64 " is %s, not queued", j.id,
			    job_state_name(j.state));
		goto out;
	}
	if (store_list(c->d->store, &f, collect_id, &ids, NULL) < 0) {
		code = fail(c, PROTO_STORAGE_ERROR, "cannot read the queue");
		goto out;
	}
	for (k = 0; k < ids.n; k++)
		if (ids.v[k] == j.id)
			from = k;
	memmove(ids.v + from, ids.v + from + 1, (ids.n - from - 1) * sizeof(*ids.v));
	ids.n--;
	if ((size_t)pos > ids.n)
		pos = (int64_t)ids.n;
	memmove(ids.v + pos + 1, ids.v + pos, (ids.n - (size_t)pos) * sizeof(*ids.v));
	ids.v[pos] = j.id;
	ids.n++;
	/* Neighbour's priority, then renumber the whole queue. */
	if (ids.n > 1 && store_get(c->d->store, ids.v[pos + 1 < (int64_t)ids.n ? pos + 1 : pos - 1],
				   &other) == 0) {
		j.priority = other.priority;
		job_record_clear(&other);
	}
	store_begin(c->d->store);
	for (k = 0; k < ids.n; k++) {
		struct job_record q;
		if (ids.v[k] == j.id) {
			j.seq = (int64_t)k + 1;
			store_update(c->d->store, &j);
		} else if (store_get(c->d->store, ids.v[k], &q) == 0) {
			q.seq = (int64_t)k + 1;
			store_update(c->d->store, &q);
			job_record_clear(&q);
		}
	}
	if (store_commit(c->d->store) < 0) {
		store_rollback(c->d->store);
		code = fail(c, PROTO_STORAGE_ERROR, "cannot reorder the queue");
		goto out;
	}
	log_job(LOG_INFO, j.id, "moved to position %" PRId64 " by %s", pos, c->client->name);
	code = queue_json(c, result);
out:
	free(ids.v);
	job_record_clear(&j);
	return code;
}

static void set_queue_running(struct daemon *d, bool running)
{
	d->queue_running = running;
	store_meta_set(d->store, "queue.running", running ? "1" : "0");
	server_broadcast(d, EVENT_QUEUE, 0, "queue.state",
			 json_pack("{s:b}", "running", running));
	daemon_update_status(d);
}

static int m_queue_start(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	set_queue_running(c->d, true);
	log_info("queue started by %s", c->client->name);
	jobs_schedule(c->d);
	return queue_json(c, result);
}

static int m_queue_stop(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "abort", NULL };
	bool abort_running = false;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_bool(params, "abort", false, &abort_running, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	set_queue_running(c->d, false);
	log_info("queue stopped by %s%s", c->client->name,
		 abort_running ? ", running scans stopped" : "");
	if (abort_running)
		for (size_t i = 0; i < c->d->n_instruments; i++)
			if (c->d->instruments[i].job)
				runner_stop(c->d->instruments[i].runner);
	return queue_json(c, result);
}

/* ------------------------------------------------------- instruments */

static int m_instrument_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	json_t *list;
	int code = only(c, params, names);

	if (code)
		return code;
	list = json_array();
	for (size_t i = 0; list && i < c->d->n_instruments; i++)
		json_array_append_new(list, instrument_to_json(&c->d->instruments[i]));
	*result = json_pack("{s:o}", "instruments", list);
	return 0;
}

static int m_instrument_status(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", NULL };
	const char *name;
	struct instrument *in;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	in = instrument_find(c->d, name);
	if (!in)
		return fail(c, PROTO_NO_SUCH_INSTRUMENT, "no instrument \"%s\"", name);
	*result = instrument_to_json(in);
	return 0;
}

static int m_driver_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	*result = json_pack("{s:o}", "drivers", drivers_to_json(c->d));
	return 0;
}

/* ------------------------------------------------------------ events */

static const char *const event_names[] = { "job", "progress", "instrument", "queue", NULL };

static int m_events_subscribe(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "events", "job", NULL };
	struct client *cl = c->client;
	unsigned mask = EVENT_JOB | EVENT_PROGRESS | EVENT_INSTRUMENT | EVENT_QUEUE;
	int64_t job = 0;
	json_t *list;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_flags(params, "events", false, event_names, &mask, &c->why) == -EINVAL ||
	    proto_param_int(params, "job", false, 1, INT64_MAX, &job, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (!cl->events && mask) {
		if (c->d->n_subscribed >= c->d->config->limits.max_subscriptions)
			return fail(c, PROTO_LIMIT_REACHED, "%u clients are subscribed, the limit",
				    c->d->config->limits.max_subscriptions);
		c->d->n_subscribed++;
	} else if (cl->events && !mask) {
		c->d->n_subscribed--;
	}
	cl->events = mask;
	cl->event_job = job;
	list = json_array();
	for (int k = 0; list && event_names[k]; k++)
		if (mask & (1u << k))
			json_array_append_new(list, json_string(event_names[k]));
	*result = json_pack("{s:o, s:o}", "events", list, "job", job ? json_integer(job) : json_null());
	return 0;
}

static int m_events_unsubscribe(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	if (c->client->events)
		c->d->n_subscribed--;
	c->client->events = 0;
	c->client->event_job = 0;
	*result = json_object();
	return 0;
}

/* ------------------------------------------------------------ table */

static const struct method {
	const char *name;
	method_fn fn;
	bool mutating;
} methods[] = {
	{ "hello", m_hello, false },
	{ "version", m_version, false },
	{ "daemon.status", m_daemon_status, false },
	{ "job.submit", m_job_submit, true },
	{ "job.get", m_job_get, false },
	{ "job.list", m_job_list, false },
	{ "job.cancel", m_job_cancel, true },
	{ "job.pause", m_job_pause, true },
	{ "job.resume", m_job_resume, true },
	{ "job.requeue", m_job_requeue, true },
	{ "job.result", m_job_result, false },
	{ "queue.get", m_queue_get, false },
	{ "queue.move", m_queue_move, true },
	{ "queue.start", m_queue_start, true },
	{ "queue.stop", m_queue_stop, true },
	{ "instrument.list", m_instrument_list, false },
	{ "instrument.status", m_instrument_status, false },
	{ "driver.list", m_driver_list, false },
	{ "events.subscribe", m_events_subscribe, false },
	{ "events.unsubscribe", m_events_unsubscribe, false },
};

static const struct method *find_method(const char *name)
{
	for (size_t i = 0; i < ARRAY_SIZE(methods); i++)
		if (!strcmp(methods[i].name, name))
			return &methods[i];
	return NULL;
}

json_t *rpc_handle(struct client *cl, json_t *msg)
{
	struct call c = { .d = cl->d, .client = cl };
	struct proto_message m;
	const struct method *meth;
	const char *why = NULL;
	json_t *result = NULL, *params;
	int code;

	code = proto_check_request(msg, &m, &why);
	if (code && m.unknown)
		fail(&c, code, "unknown member \"%.64s\" in request", m.unknown);
	else if (code)
		fail(&c, code, "%s", why);
	if (code) {
		proto_utf8_clean(c.why.text);
		return proto_make_error(m.id, code, NULL, json_pack("{s:s}", "detail", c.why.text));
	}
	params = m.params;
	meth = find_method(m.method);
	if (!meth) {
		code = fail(&c, PROTO_METHOD_NOT_FOUND, "no method \"%.64s\"", m.method);
	} else if (!cl->authenticated && meth->fn != m_hello) {
		code = fail(&c, PROTO_PERMISSION_DENIED, "send \"hello\" with the token first");
	} else if (meth->mutating && !client_is_operator(cl)) {
		code = fail(&c, PROTO_PERMISSION_DENIED,
			    "%s needs an operator: %s (uid %d) is not in the operator group",
			    m.method, cl->name, (int)cl->uid);
		log_notice("refused %s to %s (uid %d)", m.method, cl->name, (int)cl->uid);
	} else if (json_is_array(params) && json_array_size(params) > 0) {
		code = fail(&c, PROTO_INVALID_PARAMS, "params must be an object");
	} else {
		if (json_is_array(params))
			params = NULL;
		code = meth->fn(&c, params, &result);
		if (!code && !result)
			code = fail(&c, PROTO_INTERNAL_ERROR, "out of memory");
	}
	if (m.kind == PROTO_KIND_NOTIFICATION) {
		json_decref(result);
		json_decref(c.data);
		return NULL;
	}
	if (code) {
		json_decref(result);
		json_t *data = c.data ? c.data : json_object();
		/* A name cut at 64 bytes may end inside a character. */
		proto_utf8_clean(c.why.text);
		if (c.why.text[0])
			json_object_set_new(data, "detail", json_string(c.why.text));
		return proto_make_error(m.id, code, NULL, data);
	}
	return proto_make_result(m.id, result);
}
