/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread. Each handler returns 0 with a result, or a protocol
 * error code with a detail in call->why.
 */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asph-proto.h"
#include "config.h"
#include "estimate.h"
#include "jobspec.h"
#include "log.h"
#include "ratelimit.h"
#include "rpc.h"
#include "turns.h"
#include "util-hash.h"
#include "util-time.h"
#include "util-mem.h"

/* Wrong tokens a peer (an address) may send at once, and of one claimed
 * prefix from anywhere, then one per interval: past that, the answer to a
 * wrong token waits until the interval is up. A right token is never held
 * back, so that one guesser behind a shared address (a proxy, a NAT)
 * cannot lock its users out; a guesser's pace is one guess per interval on
 * each of its connections, which max_clients_per_user bounds. */
#define HELLO_FAILURES_BURST 5
#define HELLO_FAILURE_INTERVAL_USEC (2 * 1000000ull)
/* The characters of a presented token that make its claimed prefix. */
#define TOKEN_PREFIX 12
/* Refusals logged per peer at once, then one per interval (the rest are
 * counted into the next line that is logged). */
#define REFUSALS_LOGGED_BURST 10
#define REFUSAL_LOG_INTERVAL_USEC (1000000ull)
/* Peers whose counts are kept at once. */
#define RATE_KEYS 256
/* The computations (tasks.h) of one owner at once: a plan checked or
 * estimated, running or waiting for a thread. */
#define TASKS_PER_OWNER 2
/* A step of a listing (job.list, queue.get): jobs read from the store a
 * few at a time (each is read, parsed and written: tens of microseconds)
 * until about this much time has passed. */
#define LIST_STEP_USEC 1000
#define LIST_READ 8

struct rpc {
	sd_event *event;
	uint64_t started_usec;
	struct jobs *jobs;
	const struct instruments *instruments;
	struct events *events;
	const struct access *access;
	struct tokens *tokens;
	struct tasks *tasks;
	struct backups *backups;
	struct monitor *monitor;
	const struct settings_limits *limits;
	size_t n_sessions;
	uint64_t requests;
	struct ratelimit *hello_failures;       /* per peer key */
	struct ratelimit *prefix_failures;      /* per claimed token prefix */
	struct ratelimit *refusals_logged;      /* per peer key */
};

/* How the element of a line answered now goes on. */
enum element {
	ELEMENT_NEXT,           /* none started: the next one is taken */
	ELEMENT_WAITING,        /* a task computes its answer */
	ELEMENT_READY,          /* its answer is in reply */
	ELEMENT_LISTING,        /* its answer is a listing, made a step at a time */
};

/* A listing's answer: the response up to the array, the jobs a step at a
 * time, then the closing "]}}". */
struct listing {
	struct jobs_cursor *cursor;
	char *head;
	bool head_out;
	size_t items;
};

struct rpc_line {
	struct rpc *rpc;
	struct rpc_session *s;
	json_t *msg;            /* the request, the batch, or an error answer */
	bool batch;
	bool parsed;            /* msg is a request or batch to answer */
	size_t next;            /* the batch element answered next */
	size_t written;         /* bytes of answer so far, notifications' too */
	bool opened;            /* a batch's "[" is out */
	void (*ready)(void *data);
	void *ready_data;
	/* The element being answered over several steps. */
	enum element state;
	json_t *id;             /* its id */
	bool notification;      /* its answer is counted, not sent */
	json_t *reply;          /* ELEMENT_READY */
	struct task *task;      /* ELEMENT_WAITING: a computation */
	sd_event_source *delay; /* ELEMENT_WAITING: an answer held back */
	void *pending;          /* ELEMENT_WAITING: the method's, freed with it */
	void (*pending_free)(void *pending);
	struct listing *listing;
};

struct call {
	struct rpc *rpc;
	struct rpc_session *s;
	struct rpc_line *line;  /* the line it is part of */
	struct proto_why why;
	json_t *data;           /* more members of an error's data, or NULL */
	/* The answer comes later: a task computes it (deferred), or it is
	 * the result given and a list of jobs made a step at a time. */
	bool deferred;
	struct listing *listing;
};

typedef int (*method_fn)(struct call *c, json_t *params, json_t **result);

/* An answer that comes later (the lines, below). */
static void defer(struct call *c, void *pending, void (*free_fn)(void *pending));
static int defer_answer(struct call *c, int code, uint64_t wait);
static void line_answer(struct rpc_line *l, struct call *c, int code, json_t *result);

int rpc_new(const struct rpc_setup *setup, struct rpc **out)
{
	struct rpc *rpc = calloc(1, sizeof(*rpc));

	if (!rpc)
		return -ENOMEM;
	*rpc = (struct rpc){
		.event = setup->event, .started_usec = setup->started_usec,
		.jobs = setup->jobs, .instruments = setup->instruments, .events = setup->events,
		.access = setup->access, .tokens = setup->tokens, .tasks = setup->tasks,
		.limits = setup->limits, .backups = setup->backups, .monitor = setup->monitor,
	};
	if (ratelimit_new(HELLO_FAILURES_BURST, HELLO_FAILURE_INTERVAL_USEC, RATE_KEYS,
			  &rpc->hello_failures) < 0 ||
	    ratelimit_new(HELLO_FAILURES_BURST, HELLO_FAILURE_INTERVAL_USEC, RATE_KEYS,
			  &rpc->prefix_failures) < 0 ||
	    ratelimit_new(REFUSALS_LOGGED_BURST, REFUSAL_LOG_INTERVAL_USEC, RATE_KEYS,
			  &rpc->refusals_logged) < 0) {
		rpc_free(rpc);
		return -ENOMEM;
	}
	*out = rpc;
	return 0;
}

void rpc_free(struct rpc *rpc)
{
	if (!rpc)
		return;
	ratelimit_free(rpc->hello_failures);
	ratelimit_free(rpc->prefix_failures);
	ratelimit_free(rpc->refusals_logged);
	free(rpc);
}

void rpc_set_access(struct rpc *rpc, const struct access *access)
{
	rpc->access = access;
}

void rpc_session_open(struct rpc *rpc, struct rpc_session *s)
{
	if (s->open)
		return;
	s->open = true;
	if (!s->owner[0])       /* (a hello before may have set the token's) */
		snprintf(s->owner, sizeof(s->owner), "%s", s->peer.key);
	rpc->n_sessions++;
}

void rpc_session_close(struct rpc *rpc, struct rpc_session *s)
{
	if (!s->open)
		return;
	events_unsubscribe(rpc->events, &s->events);
	backups_release(rpc->backups, s);
	s->open = false;
	rpc->n_sessions--;
}

size_t rpc_sessions(const struct rpc *rpc)
{
	return rpc->n_sessions;
}

bool rpc_peer_operator(const struct rpc *rpc, const struct peer *p)
{
	return !p->tcp && access_is_operator(rpc->access, p, NULL);
}

bool rpc_session_valid(const struct rpc *rpc, const struct rpc_session *s)
{
	return !s->peer.tcp || !s->grant.valid || access_grant_current(rpc->access, &s->grant);
}

static uint64_t loop_usec(const struct rpc *rpc)
{
	uint64_t now = 0;

	sd_event_now(rpc->event, CLOCK_MONOTONIC, &now);
	return now;
}

/* ------------------------------------------------------------ helpers */

static int fail(struct call *c, int code, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));

static int fail(struct call *c, int code, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	proto_why_vset(&c->why, fmt, ap);
	va_end(ap);
	return code;
}

/* The protocol's answer to an error of jobs.h. */
static int job_error(struct call *c, int r, const struct asph_error *err)
{
	static const struct {
		int errno_code, code;
	} map[] = {
		{ -ENOENT, PROTO_NO_SUCH_JOB },
		{ -ENODEV, PROTO_NO_SUCH_INSTRUMENT },
		{ -EINVAL, PROTO_INVALID_STATE },
		{ -ENOBUFS, PROTO_LIMIT_REACHED },
		{ -EDQUOT, PROTO_LIMIT_REACHED },
		{ -ENODATA, PROTO_NO_RESULT },
		{ -EPERM, PROTO_INVALID_PATH },
		{ -EBUSY, PROTO_INSTRUMENT_LOCKED },
		{ -ENOMEM, PROTO_INTERNAL_ERROR },
	};
	int code = PROTO_STORAGE_ERROR;

	for (size_t i = 0; i < ARRAY_SIZE(map); i++)
		if (map[i].errno_code == r)
			code = map[i].code;
	/* Who holds the lock and why, for a program to show. */
	if (code == PROTO_INSTRUMENT_LOCKED && err->field[0])
		c->data = json_pack("{s:s, s:o}", "instrument", err->field,
				    "lock", instrument_lock_to_json(jobs_lock_of(c->rpc->jobs,
										  err->field)));
	return fail(c, code, "%s", err->message[0] ? err->message : strerror(-r));
}

static enum access_role role(const struct call *c)
{
	return access_role_of(c->rpc->access, &c->s->peer, &c->s->grant);
}

static bool is_operator(const struct call *c)
{
	return role(c) >= ROLE_OPERATOR;
}

/* Who a change is recorded as: the user, or over TCP the token's name. */
static struct job_actor actor(const struct call *c)
{
	const struct rpc_session *s = c->s;

	if (s->peer.tcp && s->grant.valid)
		return (struct job_actor){ .uid = -1, .name = s->grant.credential };
	return (struct job_actor){ .uid = (int64_t)(int)s->peer.uid, .name = s->peer.name };
}

/* params: only the listed members, each checked by the handler. */
static int only(struct call *c, json_t *params, const char *const *names)
{
	return proto_params_only(params, names, &c->why) < 0 ? PROTO_INVALID_PARAMS : 0;
}

static int job_id(struct call *c, json_t *params, int64_t *id)
{
	return proto_param_int(params, "id", true, 1, INT64_MAX, id, &c->why) < 0
		? PROTO_INVALID_PARAMS : 0;
}

/* The job j as the result; clears j. */
static int job_result(struct call *c, struct job_record *j, json_t **result)
{
	*result = jobs_job_to_json(c->rpc->jobs, j);
	job_record_clear(j);
	return *result ? 0 : PROTO_INTERNAL_ERROR;
}

/* The methods that change one job and answer with it. */
typedef int (*job_change_fn)(struct jobs *jobs, int64_t id, const struct job_actor *who,
			     struct job_record *out, struct asph_error *err);

static int change_job(struct call *c, json_t *params, job_change_fn change, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct job_actor who = actor(c);
	struct asph_error err;
	struct job_record j;
	int64_t id;
	int code = only(c, params, names), r;

	if (code || (code = job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = change(c->rpc->jobs, id, &who, &j, &err);
	return r < 0 ? job_error(c, r, &err) : job_result(c, &j, result);
}

/* ------------------------------------------------------------ daemon */

/* The bucket of a claimed prefix: a digest of the token's first
 * characters, so that nothing of a secret is kept in the table. */
static void prefix_key(const char *token, char key[RATELIMIT_KEY_MAX])
{
	char hex[65];

	sha256_hex(token, strnlen(token, TOKEN_PREFIX), hex);
	snprintf(key, RATELIMIT_KEY_MAX, "prefix %.16s", hex);
}

/*
 * A wrong token: counted against the peer's address and the prefix it
 * claimed; the log says it, at most as often as tries are earned. The
 * time its answer should wait: until both have a try left again (at most
 * an interval).
 */
static uint64_t wrong_token(struct rpc *rpc, const struct peer *p, const char *token,
			    const char *where)
{
	uint64_t now = loop_usec(rpc), wait;
	char key[RATELIMIT_KEY_MAX];
	unsigned left_out = 0;

	prefix_key(token ? token : "", key);
	ratelimit_take(rpc->prefix_failures, key, now, NULL);
	if (ratelimit_take(rpc->hello_failures, p->key, now, &left_out))
		log_warning("wrong token in %s from %s (%u more before it not logged)", where,
			    p->name, left_out);
	wait = ratelimit_wait(rpc->hello_failures, p->key, now);
	if (ratelimit_wait(rpc->prefix_failures, key, now) > wait)
		wait = ratelimit_wait(rpc->prefix_failures, key, now);
	return wait < HELLO_FAILURE_INTERVAL_USEC ? wait : HELLO_FAILURE_INTERVAL_USEC;
}

int rpc_check_token(struct rpc *rpc, struct rpc_session *s, const char *token,
		    const char *where, struct proto_why *why, uint64_t *wait_usec)
{
	int r = access_authenticate(rpc->access, token, &s->grant);

	*wait_usec = 0;
	if (r == -EKEYREVOKED || r == -EKEYEXPIRED) {
		log_warning("%s token \"%s\" in %s from %s", r == -EKEYREVOKED ? "revoked"
			    : "expired", s->grant.credential, where, s->peer.name);
		proto_why_set(why, "the token \"%s\" is %s", s->grant.credential,
			      r == -EKEYREVOKED ? "revoked" : "expired");
		return PROTO_PERMISSION_DENIED;
	}
	if (r < 0) {
		*wait_usec = wrong_token(rpc, &s->peer, token, where);
		proto_why_set(why, "wrong token");
		return PROTO_PERMISSION_DENIED;
	}
	return 0;
}

/* A TCP peer's hello: its token checked (a wrong one answered when the
 * pace of wrong tokens says), and its success logged. */
static int authenticate(struct call *c, const char *token)
{
	struct rpc_session *s = c->s;
	uint64_t wait;
	int code = rpc_check_token(c->rpc, s, token, "hello", &c->why, &wait);

	if (code)
		return wait ? defer_answer(c, code, wait) : code;
	/* A connection that took one of the last reserved_clients before it
	 * said who it is keeps it only as an operator or admin. */
	if (s->open && s->grant.role < ROLE_OPERATOR &&
	    c->rpc->n_sessions + c->rpc->limits->reserved_clients > c->rpc->limits->max_clients) {
		s->grant = (struct access_grant){ 0 };
		return fail(c, PROTO_TOO_MANY_CLIENTS, "the last %u of limits.max_clients (%u) are "
			    "kept for operators and admins: this token is a viewer's",
			    c->rpc->limits->reserved_clients, c->rpc->limits->max_clients);
	}
	s->authenticated = true;
	/* A user's shares follow its token, from whichever address. */
	snprintf(s->owner, sizeof(s->owner), "token %.57s", s->grant.credential);
	log_info("%s authenticated with %s (%s)", s->peer.name, s->grant.credential,
		 access_role_name(s->grant.role));
	if (s->grant.token_file)
		log_notice("%s used the deprecated token_file: give it a named token "
			   "(asphctl token create)", s->peer.name);
	return 0;
}

static int m_hello(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "client", "token", NULL };
	const char *token = NULL, *client = NULL;
	struct rpc_session *s = c->s;
	int code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_string(params, "client", false, 128, &client, &c->why) == -EINVAL ||
	    proto_param_string(params, "token", false, 512, &token, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (s->peer.tcp && !s->authenticated && ((code = authenticate(c, token)) || c->deferred))
		return code;
	*result = json_pack("{s:s, s:s, s:{s:i, s:i}, s:{s:I, s:s, s:b, s:s, s:s?}}",
		"server", "asphd", "version", ASPH_VERSION,
		"protocol", "major", PROTO_VERSION_MAJOR, "minor", PROTO_VERSION_MINOR,
		"peer", "uid", (json_int_t)(int)s->peer.uid, "name", s->peer.name,
		"operator", is_operator(c), "role", access_role_name(role(c)),
		"token", s->peer.tcp && s->grant.valid ? s->grant.credential : NULL);
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

static json_t *counts_json(const struct jobs *jobs)
{
	const int64_t *counts = jobs_counts(jobs);
	json_t *o = json_object();

	for (int s = 0; o && s < JOB_N_STATES; s++)
		json_object_set_new(o, job_state_name((enum job_state)s), json_integer(counts[s]));
	return o;
}

static json_t *instrument_states_json(const struct rpc *rpc)
{
	json_t *list = json_array();

	for (size_t i = 0; list && i < instruments_count(rpc->instruments); i++) {
		const struct instrument_activity *a = jobs_activity(rpc->jobs, i);
		json_array_append_new(list, json_pack("{s:s, s:s, s:o, s:o}",
			"name", instruments_get(rpc->instruments, i)->name,
			"state", instrument_state_name(a),
			"job", a->job ? json_integer(a->job) : json_null(),
			"lock", instrument_lock_to_json(a->lock)));
	}
	return list;
}

static int m_daemon_status(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct rpc *rpc = c->rpc;
	char status[128];
	uint64_t now;
	int code = only(c, params, names);

	if (code)
		return code;
	sd_event_now(rpc->event, CLOCK_MONOTONIC, &now);
	jobs_status_text(rpc->jobs, status, sizeof(status));
	*result = json_pack("{s:s, s:i, s:f, s:s, s:{s:b}, s:o, s:o, s:I, s:I}",
		"version", ASPH_VERSION, "pid", (int)getpid(),
		"uptime_s", (double)(now - rpc->started_usec) / 1e6,
		"status", status,
		"queue", "running", jobs_queue_running(rpc->jobs),
		"jobs", counts_json(rpc->jobs), "instruments", instrument_states_json(rpc),
		"clients", (json_int_t)rpc->n_sessions, "requests", (json_int_t)rpc->requests);
	return 0;
}

/* The findings of monitor.h's checks: ok when there are none. */
static int m_daemon_health(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	json_t *reasons;
	int code = only(c, params, names);

	if (code)
		return code;
	reasons = monitor_health(c->rpc->monitor);
	if (!reasons)
		return PROTO_INTERNAL_ERROR;
	*result = json_pack("{s:s, s:o}", "status", json_array_size(reasons) ? "degraded" : "ok",
			    "reasons", reasons);
	return 0;
}

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
	static const char *const names[] = { "lens", "plan", "fit", "tolerance", "instrument",
					     "priority", "label", "part", "lot", "serial", NULL };
	const struct settings_limits *lim = c->rpc->limits;
	struct asph_error err;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (!params || !json_object_get(params, "lens"))
		return fail(c, PROTO_INVALID_PARAMS, "missing parameter \"lens\"");
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
	return r < 0 ? job_error(c, r, &err) : 0;
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
		line_answer(l, &c, result ? 0 : PROTO_INTERNAL_ERROR, result);
		return;
	}
	text = json_dumps(e->spec, JSON_COMPACT);
	k->sub.spec = text;
	k->sub.points = (int64_t)e->points;
	asph_error_clear(&err);
	r = text ? jobs_submit(l->rpc->jobs, &k->sub, &k->who, &j, &err) : -ENOMEM;
	if (r < 0) {
		code = job_error(&c, r, &err);
	} else if ((code = job_result(&c, &j, &result)) == 0) {
		json_object_set_new(result, "estimate_s", t);
		t = NULL;
	}
	json_decref(t);
	line_answer(l, &c, code, result);
}

/* A task's done(): the plan checked, or its deadline passed. */
static void check_done(void *work, int r, void *data)
{
	struct check *k = data;
	struct estimate *e = work;
	struct rpc_line *l = k->line;
	struct call c = { .rpc = l->rpc, .s = l->s, .line = l };

	if (r == -ETIMEDOUT) {
		fail(&c, PROTO_REQUEST_TIMEOUT, "checking the plan took longer than "
		     "limits.request_timeout_ms (%" PRId64 " ms)%s", k->timeout_ms,
		     k->submit ? ": nothing was queued" : "");
		line_answer(l, &c, PROTO_REQUEST_TIMEOUT, NULL);
	} else if (r < 0 || e->code) {
		int code = r < 0 ? PROTO_INTERNAL_ERROR : e->code;
		proto_why_set(&c.why, "%s", r < 0 ? strerror(-r) : e->why.text);
		line_answer(l, &c, code, NULL);
	} else {
		check_answer(k, e);
	}
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
	struct job_actor who = actor(c);
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
	defer(c, k, check_free);
	if (!c->rpc->tasks) {           /* no pool: at once */
		check_done(e, estimate_run(e, NULL), k);
		estimate_free(e);
		return 0;
	}
	r = tasks_submit(c->rpc->tasks, &(struct task_spec){
		.owner = c->s->owner, .privileged = is_operator(c),
		/* root has no share of its own, as for connections */
		.max_per_owner = !p->tcp && p->uid == 0 ? TASKS_MAX_WAITING : TASKS_PER_OWNER,
		.deadline_usec = turns_now_usec() + (uint64_t)lim->request_timeout_ms * 1000,
		.run = estimate_run, .done = check_done, .free = estimate_free,
		.work = e, .data = k }, &c->line->task);
	if (r == 0)
		return 0;
	c->deferred = false;            /* (the line frees k) */
	if (r == -EDQUOT)
		return fail(c, PROTO_LIMIT_REACHED, "%s has %d plans being checked or estimated: "
			    "wait for their answers", c->s->owner, TASKS_PER_OWNER);
	if (r == -EAGAIN)
		return fail(c, PROTO_LIMIT_REACHED, "%d plans wait to be checked: try again in "
			    "a moment", TASKS_MAX_WAITING);
	return PROTO_INTERNAL_ERROR;
}

static int m_job_submit(struct call *c, json_t *params, json_t **result)
{
	return check_plan(c, params, true);
}

/* What job.submit would predict for the same parameters, queuing nothing:
 * a full queue or a locked instrument does not stop a look ahead. */
static int m_job_estimate(struct call *c, json_t *params, json_t **result)
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

static int m_job_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "history", NULL };
	struct asph_error err;
	struct job_record j;
	bool history = false;
	int64_t id;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_bool(params, "history", false, &history, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if ((code = job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_get(c->rpc->jobs, id, &j, &err);
	if (r < 0)
		return job_error(c, r, &err);
	code = job_result(c, &j, result);
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
		return fail(c, PROTO_INTERNAL_ERROR, "out of memory");
	}
	c->listing = ls;
	*out = result;
	return 0;
}

static const char *const state_list[] = {
	"queued", "running", "paused", "completed", "failed", "cancelled", "interrupted", NULL
};

static int m_job_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "states", "instrument", "label", "uid", "mine",
					     "part", "lot", "serial", "offset", "limit", NULL };
	struct store_filter f = { .uid = STORE_ANY_UID, .limit = 100 };
	struct asph_error err;
	bool mine = false;
	int64_t total = 0;
	int code = only(c, params, names), r;

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
		struct job_actor who = actor(c);
		f.uid = who.uid;
		/* Over TCP the token's jobs: the uid is every TCP peer's. */
		if (c->s->peer.tcp)
			f.user = who.name;
	}
	asph_error_clear(&err);
	r = jobs_count(c->rpc->jobs, &f, &total, &err);
	if (r < 0)
		return job_error(c, r, &err);
	return list_jobs(c, &f, json_pack("{s:I, s:I, s:I}", "total", (json_int_t)total,
					  "offset", (json_int_t)f.offset, "limit",
					  (json_int_t)f.limit), result);
}

static int m_job_cancel(struct call *c, json_t *params, json_t **result)
{
	return change_job(c, params, jobs_cancel, result);
}

static int m_job_pause(struct call *c, json_t *params, json_t **result)
{
	return change_job(c, params, jobs_pause, result);
}

static int m_job_resume(struct call *c, json_t *params, json_t **result)
{
	return change_job(c, params, jobs_resume, result);
}

static int m_job_requeue(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "restart", NULL };
	struct job_actor who = actor(c);
	struct asph_error err;
	struct job_record j;
	bool restart = false;
	int64_t id;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_bool(params, "restart", false, &restart, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if ((code = job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_requeue(c->rpc->jobs, id, restart, &who, &j, &err);
	return r < 0 ? job_error(c, r, &err) : job_result(c, &j, result);
}

static int m_job_result(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct asph_error err;
	int64_t id;
	int code = only(c, params, names), r;

	if (code || (code = job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_result(c->rpc->jobs, id, result, &err);
	return r < 0 ? job_error(c, r, &err) : 0;
}

/* The most bytes one job.file or backup.file answer carries (before
 * base64). */
#define FILE_CHUNK_MAX (1u << 20)

/* The offset and length of a file's piece, as job.file and backup.file
 * take them. */
static int chunk_params(struct call *c, json_t *params, int64_t *offset, int64_t *length)
{
	*offset = 0;
	*length = FILE_CHUNK_MAX;
	if (proto_param_int(params, "offset", false, 0, INT64_MAX, offset, &c->why) == -EINVAL ||
	    proto_param_int(params, "length", false, 1, FILE_CHUNK_MAX, length,
			    &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	return 0;
}

/* The piece of the file fd (named name) from offset, at most length bytes,
 * as job.file and backup.file answer: name, offset, size, data (base64),
 * eof. */
static int file_chunk(struct call *c, int fd, const char *name, int64_t offset, int64_t length,
		      json_t **result)
{
	_cleanup_free_ char *buf = NULL, *data = NULL;
	struct stat st;
	ssize_t n;

	if (fstat(fd, &st) < 0 || !(buf = malloc((size_t)length)))
		return fail(c, PROTO_STORAGE_ERROR, "%s: %s", name, strerror(errno));
	n = offset < st.st_size ? pread(fd, buf, (size_t)length, (off_t)offset) : 0;
	if (n < 0)
		return fail(c, PROTO_STORAGE_ERROR, "%s: %s", name, strerror(errno));
	data = proto_base64_encode(buf, (size_t)n);
	if (!data)
		return PROTO_INTERNAL_ERROR;
	*result = json_pack("{s:s, s:I, s:I, s:s, s:b}", "name", name, "offset", (json_int_t)offset,
			    "size", (json_int_t)st.st_size, "data", data,
			    "eof", offset + n >= st.st_size);
	return 0;
}

static int m_job_file(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "name", "offset", "length", NULL };
	_cleanup_close_ int fd = -1;
	struct asph_error err;
	const char *name;
	int64_t id, offset, length;
	int code = only(c, params, names), r;

	if (code || (code = job_id(c, params, &id)))
		return code;
	if (proto_param_string(params, "name", true, 255, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	if ((code = chunk_params(c, params, &offset, &length)))
		return code;
	asph_error_clear(&err);
	r = jobs_result_file(c->rpc->jobs, id, name, &fd, &err);
	if (r < 0)
		return job_error(c, r, &err);
	return file_chunk(c, fd, name, offset, length, result);
}

/* ------------------------------------------------------------ backups */

static json_t *backup_json(const struct backup_info *b)
{
	char started[ISO8601_SIZE], finished[ISO8601_SIZE];

	iso8601_utc(b->started_ns, 0, started, sizeof(started));
	iso8601_utc(b->finished_ns, 0, finished, sizeof(finished));
	return json_pack("{s:s, s:s, s:I, s:I, s:o, s:s?, s:s?, s:s, s:s?}",
		"name", b->name, "state", backup_state_name(b->state),
		"pages_done", (json_int_t)b->pages_done, "pages_total", (json_int_t)b->pages_total,
		"size", b->state == BACKUP_DONE ? json_integer(b->size) : json_null(),
		"sha256", b->sha256, "error", b->error, "started", started,
		"finished", b->finished_ns ? finished : NULL);
}

/* This session's copy, or 107 saying there is none. */
static int session_backup(struct call *c, struct backup_info *info)
{
	if (backups_get(c->rpc->backups, c->s, info) < 0)
		return fail(c, PROTO_NO_RESULT, "this connection has made no copy of the job store: "
			    "backup.start makes one");
	return 0;
}

static int m_backup_start(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct backup_info info;
	struct asph_error err;
	int code = only(c, params, names), r;

	if (code)
		return code;
	asph_error_clear(&err);
	r = backups_start(c->rpc->backups, c->s, c->s->peer.name, &err);
	if (r == -EBUSY || r == -EDQUOT)
		return fail(c, PROTO_LIMIT_REACHED, "%s", err.message);
	if (r < 0)
		return fail(c, r == -ENOMEM ? PROTO_INTERNAL_ERROR : PROTO_STORAGE_ERROR, "%s",
			    err.message[0] ? err.message : strerror(-r));
	if ((code = session_backup(c, &info)))
		return code;
	*result = backup_json(&info);
	return 0;
}

static int m_backup_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct backup_info info;
	int code = only(c, params, names);

	if (code || (code = session_backup(c, &info)))
		return code;
	*result = backup_json(&info);
	return 0;
}

static int m_backup_file(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "offset", "length", NULL };
	struct backup_info info;
	int64_t offset, length;
	int fd = -1, code = only(c, params, names);

	if (code || (code = chunk_params(c, params, &offset, &length)) ||
	    (code = session_backup(c, &info)))
		return code;
	switch (backups_fd(c->rpc->backups, c->s, &fd)) {
	case 0:
		return file_chunk(c, fd, info.name, offset, length, result);
	case -EAGAIN:
		return fail(c, PROTO_NO_RESULT, "the copy %s is not finished: %" PRId64 " of %"
			    PRId64 " pages copied (backup.get tells when it is done)", info.name,
			    info.pages_done, info.pages_total);
	default:
		return fail(c, PROTO_STORAGE_ERROR, "the copy %s failed: %s", info.name,
			    info.error ? info.error : "?");
	}
}

/* ------------------------------------------------------------- queue */

static int queue_json(struct call *c, json_t **result)
{
	return list_jobs(c, NULL, json_pack("{s:b}", "running", jobs_queue_running(c->rpc->jobs)),
			 result);
}

static int m_queue_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	return code ? code : queue_json(c, result);
}

static int m_queue_move(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "id", "position", NULL };
	struct job_actor who = actor(c);
	struct asph_error err;
	int64_t id, pos;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_int(params, "position", true, 0, INT64_MAX, &pos, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	if ((code = job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = jobs_move(c->rpc->jobs, id, pos, &who, &err);
	return r < 0 ? job_error(c, r, &err) : queue_json(c, result);
}

static int m_queue_start(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct job_actor who = actor(c);
	struct asph_error err;
	int code = only(c, params, names), r;

	if (code)
		return code;
	asph_error_clear(&err);
	r = jobs_queue_start(c->rpc->jobs, &who, &err);
	return r < 0 ? job_error(c, r, &err) : queue_json(c, result);
}

static int m_queue_stop(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "abort", NULL };
	struct job_actor who = actor(c);
	struct asph_error err;
	bool abort_running = false;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_bool(params, "abort", false, &abort_running, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	asph_error_clear(&err);
	r = jobs_queue_stop(c->rpc->jobs, abort_running, &who, &err);
	return r < 0 ? job_error(c, r, &err) : queue_json(c, result);
}

/* ------------------------------------------------------- instruments */

static json_t *instrument_json(const struct rpc *rpc, size_t i)
{
	return instrument_to_json(instruments_get(rpc->instruments, i),
				  jobs_activity(rpc->jobs, i));
}

static int m_instrument_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	json_t *list;
	int code = only(c, params, names);

	if (code)
		return code;
	list = json_array();
	for (size_t i = 0; list && i < instruments_count(c->rpc->instruments); i++)
		json_array_append_new(list, instrument_json(c->rpc, i));
	*result = json_pack("{s:o}", "instruments", list);
	return 0;
}

static int m_instrument_status(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", NULL };
	const char *name;
	int i, code = only(c, params, names);

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	i = instruments_find(c->rpc->instruments, name);
	if (i < 0)
		return fail(c, PROTO_NO_SUCH_INSTRUMENT, "no instrument \"%s\"", name);
	*result = instrument_json(c->rpc, (size_t)i);
	return 0;
}

static int m_driver_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	*result = drivers_to_json(c->rpc->instruments);
	return 0;
}

static int lock_result(struct call *c, const char *name, json_t **result)
{
	int i = instruments_find(c->rpc->instruments, name);

	*result = i < 0 ? NULL : instrument_json(c->rpc, (size_t)i);
	return 0;
}

static int m_instrument_lock(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", "reason", "pause", NULL };
	struct job_actor who = actor(c);
	const char *name, *reason;
	struct asph_error err;
	bool pause = false;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0 ||
	    proto_param_string(params, "reason", true, c->rpc->limits->max_label_bytes, &reason,
			       &c->why) < 0 ||
	    proto_param_bool(params, "pause", false, &pause, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (!reason[0])
		return fail(c, PROTO_INVALID_PARAMS, "\"reason\" must say why the instrument is "
			    "locked");
	asph_error_clear(&err);
	r = jobs_lock(c->rpc->jobs, name, reason, pause, &who, &err);
	return r < 0 ? job_error(c, r, &err) : lock_result(c, name, result);
}

static int m_instrument_unlock(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", "force", NULL };
	struct job_actor who = actor(c);
	struct asph_error err;
	const char *name;
	bool force = false;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0 ||
	    proto_param_bool(params, "force", false, &force, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (force && role(c) < ROLE_ADMIN)
		return fail(c, PROTO_PERMISSION_DENIED, "only an admin may end another's lock "
			    "(force)");
	asph_error_clear(&err);
	r = jobs_unlock(c->rpc->jobs, name, force, &who, &err);
	if (r == -EINVAL)
		return fail(c, PROTO_INVALID_STATE, "%s", err.message);
	return r < 0 ? job_error(c, r, &err) : lock_result(c, name, result);
}

/* ------------------------------------------------------------ tokens */

static int token_error(struct call *c, int r, const struct asph_error *err)
{
	int code = r == -EINVAL || r == -EEXIST ? PROTO_INVALID_PARAMS
		 : r == -ENOENT || r == -EALREADY ? PROTO_INVALID_STATE : PROTO_STORAGE_ERROR;

	return fail(c, code, "%s", err->message);
}

static int m_token_create(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", "role", "expires", NULL };
	struct job_actor who = actor(c);
	char secret[TOKENS_SECRET_SIZE];
	const char *name, *role_name, *expires = NULL;
	enum access_role r_role;
	struct asph_error err;
	int64_t expires_ns = 0;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, TOKENS_NAME_MAX + 1, &name, &c->why) < 0 ||
	    proto_param_string(params, "role", true, 16, &role_name, &c->why) < 0 ||
	    proto_param_string(params, "expires", false, 32, &expires, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (access_role_from_name(role_name, &r_role) < 0)
		return fail(c, PROTO_INVALID_PARAMS, "\"role\" must be viewer, operator or admin");
	if (expires && iso8601_parse_utc(expires, &expires_ns) < 0)
		return fail(c, PROTO_INVALID_PARAMS, "\"expires\" must be a UTC time such as "
			    "\"2027-01-31T12:00:00Z\" or a day such as \"2027-01-31\"");
	asph_error_clear(&err);
	r = tokens_create(c->rpc->tokens, name, r_role, expires_ns, who.name, secret, &err);
	if (r < 0)
		return token_error(c, r, &err);
	*result = json_pack("{s:s, s:s, s:s?, s:s}", "name", name, "role", role_name,
			    "expires", expires, "token", secret);
	explicit_bzero(secret, sizeof(secret));
	return 0;
}

static int m_token_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	*result = tokens_to_json(c->rpc->tokens);
	return 0;
}

static int m_token_revoke(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", NULL };
	struct asph_error err;
	const char *name;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, TOKENS_NAME_MAX + 1, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	asph_error_clear(&err);
	r = tokens_revoke(c->rpc->tokens, name, &err);
	if (r < 0)
		return token_error(c, r, &err);
	*result = json_pack("{s:s, s:s}", "name", name, "state", "revoked");
	return 0;
}

/* ------------------------------------------------------------ events */

static int m_events_subscribe(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "events", "job", NULL };
	const struct settings_limits *l = c->rpc->limits;
	const struct peer *p = &c->s->peer;
	struct event_quota q = {
		/* a user's from whichever address and listener (rpc.h) */
		.owner = c->s->owner, .operator = is_operator(c), .max = l->max_subscriptions,
		/* root has no quota of its own, as for connections */
		.per_owner = !p->tcp && p->uid == 0 ? l->max_subscriptions
						    : l->max_subscriptions_per_user,
		.reserved = l->reserved_subscriptions,
	};
	unsigned mask = EVENT_ALL;
	int64_t job = 0;
	json_t *list;
	int code = only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_flags(params, "events", false, event_class_names, &mask,
			      &c->why) == -EINVAL ||
	    proto_param_int(params, "job", false, 1, INT64_MAX, &job, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	/* A batch may go on after its connection was dropped: nothing is
	 * sent there any more, so nothing is counted for it. */
	if (!c->s->open)
		return fail(c, PROTO_INVALID_REQUEST, "the connection is closed");
	r = events_subscribe(c->rpc->events, &c->s->events, mask, job, &q);
	if (r == -EDQUOT)
		return fail(c, PROTO_LIMIT_REACHED, "%s has %u subscriptions, "
			    "limits.max_subscriptions_per_user", q.owner, q.per_owner);
	if (r == -EUSERS && !q.operator && l->reserved_subscriptions)
		return fail(c, PROTO_LIMIT_REACHED, "%zu clients are subscribed; the last %u of "
			    "limits.max_subscriptions (%u) are kept for operators",
			    events_subscriptions(c->rpc->events), q.reserved, q.max);
	if (r < 0)
		return fail(c, PROTO_LIMIT_REACHED, "%u clients are subscribed, the limit "
			    "(limits.max_subscriptions)", q.max);
	list = json_array();
	for (int k = 0; list && event_class_names[k]; k++)
		if (mask & (1u << k))
			json_array_append_new(list, json_string(event_class_names[k]));
	*result = json_pack("{s:o, s:o}", "events", list, "job", job ? json_integer(job) : json_null());
	return 0;
}

static int m_events_unsubscribe(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = only(c, params, names);

	if (code)
		return code;
	events_unsubscribe(c->rpc->events, &c->s->events);
	*result = json_object();
	return 0;
}

/* ------------------------------------------------------------ table */

/* Each method with the role it needs (proto/README.md, "Who may do what"). */
static const struct method {
	const char *name;
	method_fn fn;
	enum access_role need;
} methods[] = {
	{ "hello", m_hello, ROLE_NONE },
	{ "version", m_version, ROLE_VIEWER },
	{ "daemon.status", m_daemon_status, ROLE_VIEWER },
	{ "daemon.health", m_daemon_health, ROLE_VIEWER },
	{ "job.submit", m_job_submit, ROLE_OPERATOR },
	{ "job.estimate", m_job_estimate, ROLE_VIEWER },
	{ "job.get", m_job_get, ROLE_VIEWER },
	{ "job.list", m_job_list, ROLE_VIEWER },
	{ "job.cancel", m_job_cancel, ROLE_OPERATOR },
	{ "job.pause", m_job_pause, ROLE_OPERATOR },
	{ "job.resume", m_job_resume, ROLE_OPERATOR },
	{ "job.requeue", m_job_requeue, ROLE_OPERATOR },
	{ "job.result", m_job_result, ROLE_VIEWER },
	{ "job.file", m_job_file, ROLE_VIEWER },
	{ "queue.get", m_queue_get, ROLE_VIEWER },
	{ "queue.move", m_queue_move, ROLE_OPERATOR },
	{ "queue.start", m_queue_start, ROLE_OPERATOR },
	{ "queue.stop", m_queue_stop, ROLE_OPERATOR },
	{ "instrument.list", m_instrument_list, ROLE_VIEWER },
	{ "instrument.status", m_instrument_status, ROLE_VIEWER },
	{ "instrument.lock", m_instrument_lock, ROLE_OPERATOR },
	{ "instrument.unlock", m_instrument_unlock, ROLE_OPERATOR },
	{ "driver.list", m_driver_list, ROLE_VIEWER },
	{ "events.subscribe", m_events_subscribe, ROLE_VIEWER },
	{ "events.unsubscribe", m_events_unsubscribe, ROLE_VIEWER },
	{ "token.create", m_token_create, ROLE_ADMIN },
	{ "token.list", m_token_list, ROLE_ADMIN },
	{ "token.revoke", m_token_revoke, ROLE_ADMIN },
	{ "backup.start", m_backup_start, ROLE_ADMIN },
	{ "backup.get", m_backup_get, ROLE_ADMIN },
	{ "backup.file", m_backup_file, ROLE_ADMIN },
};

static const struct method *find_method(const char *name)
{
	for (size_t i = 0; i < ARRAY_SIZE(methods); i++)
		if (!strcmp(methods[i].name, name))
			return &methods[i];
	return NULL;
}

const char *rpc_method(size_t i, enum access_role *need)
{
	if (i >= ARRAY_SIZE(methods))
		return NULL;
	*need = methods[i].need;
	return methods[i].name;
}

/* A refused mutating call is logged, at most so often per peer: a reader
 * could otherwise write the log full with notifications. */
static void log_refusal(const struct call *c, const char *method)
{
	const struct peer *p = &c->s->peer;
	unsigned left_out = 0;

	if (!ratelimit_take(c->rpc->refusals_logged, p->key, loop_usec(c->rpc), &left_out))
		return;
	if (left_out)
		log_notice("refused %s to %s (uid %d), and %u refusal(s) before it not logged",
			   method, p->name, (int)p->uid, left_out);
	else
		log_notice("refused %s to %s (uid %d)", method, p->name, (int)p->uid);
}

/* Runs the method of a valid request; returns 0 or the error code. */
static int dispatch(struct call *c, const struct proto_message *m, json_t **result)
{
	const struct method *meth = find_method(m->method);
	const struct peer *p = &c->s->peer;
	json_t *params = m->params;
	int code;

	if (!meth)
		return fail(c, PROTO_METHOD_NOT_FOUND, "no method \"%.64s\"", m->method);
	if (!c->s->authenticated && meth->fn != m_hello)
		return fail(c, PROTO_PERMISSION_DENIED, "send \"hello\" with the token first");
	if (meth->need > ROLE_NONE && role(c) < meth->need) {
		log_refusal(c, m->method);
		if (p->tcp && c->s->grant.valid && !access_grant_current(c->rpc->access,
									 &c->s->grant))
			return fail(c, PROTO_PERMISSION_DENIED, "the token \"%s\" was revoked or "
				    "has expired", c->s->grant.credential);
		if (p->tcp)
			return fail(c, PROTO_PERMISSION_DENIED, "%s needs the role %s: the token "
				    "\"%s\" is a %s", m->method, access_role_name(meth->need),
				    c->s->grant.credential, access_role_name(c->s->grant.role));
		if (meth->need == ROLE_ADMIN)
			return fail(c, PROTO_PERMISSION_DENIED, "%s needs an admin: root, or a "
				    "TCP client with an admin token", m->method);
		return fail(c, PROTO_PERMISSION_DENIED,
			    "%s needs an operator: %s (uid %d) is not in the operator group",
			    m->method, p->name, (int)p->uid);
	}
	if (json_is_array(params) && json_array_size(params) > 0)
		return fail(c, PROTO_INVALID_PARAMS, "params must be an object");
	if (json_is_array(params))
		params = NULL;
	code = meth->fn(c, params, result);
	if (!code && !*result && !c->deferred)
		code = fail(c, PROTO_INTERNAL_ERROR, "out of memory");
	return code;
}

/* ------------------------------------------------------------ lines */

struct line_writer {
	rpc_write_fn write;     /* NULL: counted only (a notification's) */
	void *data;
	size_t *written;
	int failed;
};

static int put(struct line_writer *w, const char *text, size_t len)
{
	if (w->failed || (w->write && w->write(text, len, w->data) < 0)) {
		w->failed = -ECONNRESET;
		return -1;
	}
	*w->written += len;
	return 0;
}

static int put_json(const char *buf, size_t size, void *data)
{
	return put(data, buf, size);
}

/* The answer to a request once its method has run: its result, or the
 * error code with c's detail and data. */
static json_t *answer_of(struct call *c, json_t *id, int code, json_t *result)
{
	json_t *data;

	if (!code) {
		json_decref(c->data);
		c->data = NULL;
		return proto_make_result(id, result);
	}
	json_decref(result);
	data = c->data ? c->data : json_object();
	c->data = NULL;
	/* A name cut at 64 bytes may end inside a character. */
	proto_utf8_clean(c->why.text);
	if (c->why.text[0])
		json_object_set_new(data, "detail", json_string(c->why.text));
	return proto_make_error(id, code, NULL, data);
}

/*
 * The answer to a request, or NULL for a notification: its answer is
 * made as a request's would be and only counted in the line's bytes, so
 * that notifications spend limits.max_response_bytes as requests do.
 */
static json_t *make_reply(struct call *c, json_t *id, bool notification, int code,
			  json_t *result)
{
	json_t *reply = answer_of(c, notification ? json_null() : id, code, result);

	if (!notification)
		return reply;
	if (c->line && reply)
		c->line->written += json_dumpb(reply, NULL, 0, JSON_COMPACT);
	json_decref(reply);
	return NULL;
}

static void listing_free(struct listing *ls)
{
	if (!ls)
		return;
	jobs_cursor_free(ls->cursor);
	free(ls->head);
	free(ls);
}

/*
 * A listing's answer starts: the response with result (which must not
 * hold member) dumped, its closing "}}" taken off, and member's array
 * opened. 0, or -ENOMEM.
 */
static int listing_open(struct listing *ls, json_t *id, json_t *result, const char *member)
{
	_cleanup_(json_decrefp) json_t *r = proto_make_result(id, result);
	_cleanup_free_ char *text = r ? json_dumps(r, JSON_COMPACT) : NULL;
	size_t n = text ? strlen(text) : 0;

	/* A compact response ends with the result's "}" and its own. */
	if (n < 4 || strcmp(text + n - 2, "}}"))
		return -ENOMEM;
	text[n - 2] = '\0';
	if (asprintf(&ls->head, "%s%s\"%s\":[", text, text[n - 3] == '{' ? "" : ",", member) < 0) {
		ls->head = NULL;
		return -ENOMEM;
	}
	return 0;
}

/* Makes ls from a method's call: the answer to the element of l. */
static void start_listing(struct rpc_line *l, struct call *c, json_t *id, bool notification,
			  json_t *result)
{
	struct listing *ls = steal_ptr(c->listing);

	if (listing_open(ls, id, result, "jobs") < 0) {
		listing_free(ls);
		l->reply = make_reply(c, id, notification, fail(c, PROTO_INTERNAL_ERROR,
							      "out of memory"), NULL);
		l->state = ELEMENT_READY;
		return;
	}
	l->listing = ls;
	l->state = ELEMENT_LISTING;
}

struct listing_writer {
	const struct jobs *jobs;
	struct line_writer *w;
	struct listing *ls;
};

static int listing_item(const struct job_record *j, void *data)
{
	struct listing_writer *lw = data;
	_cleanup_(json_decrefp) json_t *v = jobs_job_to_json(lw->jobs, j);

	if (!v || (lw->ls->items++ && put(lw->w, ",", 1) < 0) ||
	    json_dump_callback(v, put_json, lw->w, JSON_COMPACT) < 0)
		return lw->w->failed ? lw->w->failed : -ENOMEM;
	return 0;
}

/* One step of l's listing: 1 while jobs remain, 0 once its answer is
 * complete. An error of the store ends the array where it is (the answer
 * stays JSON), and is logged. */
static int listing_step(struct rpc_line *l, struct line_writer *w)
{
	struct listing *ls = l->listing;
	struct listing_writer lw = { .jobs = l->rpc->jobs, .w = w, .ls = ls };
	struct asph_error err;
	int r;

	if (!ls->head_out) {
		put(w, ls->head, strlen(ls->head));
		ls->head_out = true;
	}
	asph_error_clear(&err);
	uint64_t start = turns_now_usec();
	do
		r = w->failed ? 0 : jobs_cursor_next(ls->cursor, LIST_READ, listing_item, &lw, &err);
	while (r > 0 && turns_now_usec() - start < LIST_STEP_USEC);
	if (r > 0)
		return 1;
	if (r < 0 && !w->failed)
		log_error("a listing of jobs ends early: %s", err.message);
	put(w, "]}}", 3);
	return 0;
}

/* What the element of l kept while it waited goes (a task still running
 * is cancelled). */
static void wait_end(struct rpc_line *l)
{
	if (l->task)
		tasks_cancel(l->rpc->tasks, l->task);
	l->task = NULL;
	l->delay = sd_event_source_disable_unref(l->delay);
	if (l->pending_free)
		l->pending_free(l->pending);
	l->pending = NULL;
	l->pending_free = NULL;
}

/* The element of l that waited is answered: code and c's detail, or result. */
static void line_answer(struct rpc_line *l, struct call *c, int code, json_t *result)
{
	l->task = NULL;         /* (its task is done: this is its answer) */
	wait_end(l);
	l->reply = make_reply(c, l->id, l->notification, code, result);
	l->state = ELEMENT_READY;
	if (l->ready)
		l->ready(l->ready_data);
}

/* The call's element waits for pending (what its method keeps, freed with
 * free_fn when the element ends or the line is freed). */
static void defer(struct call *c, void *pending, void (*free_fn)(void *pending))
{
	c->deferred = true;
	c->line->pending = pending;
	c->line->pending_free = free_fn;
}

/* An answer given only after wait: the call's error, code. */
static int on_delay(sd_event_source *s, uint64_t usec, void *data)
{
	struct rpc_line *l = data;
	struct call c = { .rpc = l->rpc, .s = l->s, .line = l };

	proto_why_set(&c.why, "%s", (const char *)l->pending);
	line_answer(l, &c, PROTO_PERMISSION_DENIED, NULL);
	return 0;
}

static int defer_answer(struct call *c, int code, uint64_t wait)
{
	struct rpc_line *l = c->line;
	char *why;

	/* Without a transport that waits (rpc_handle_line()), at once. */
	if (!l || !l->ready || code != PROTO_PERMISSION_DENIED || !(why = strdup(c->why.text)))
		return code;
	if (sd_event_add_time_relative(c->rpc->event, &l->delay, CLOCK_MONOTONIC, wait, 0,
				       on_delay, l) < 0) {
		free(why);
		return code;
	}
	defer(c, why, free);
	return 0;
}

/* Starts the element msg of l: an answer in *reply now (NULL for a
 * notification), or one that comes later (l->state). */
static void start_element(struct rpc_line *l, json_t *msg, json_t **reply)
{
	struct call c = { .rpc = l->rpc, .s = l->s, .line = l };
	struct proto_message m;
	json_t *result = NULL;
	bool notification;
	int code;

	code = proto_check_request(msg, &m, &c.why);
	if (code) {
		if (m.unknown)
			fail(&c, code, "unknown member \"%.64s\" in request", m.unknown);
		*reply = proto_make_error(m.id, code, NULL, json_pack("{s:s}", "detail",
								       c.why.text));
		return;
	}
	notification = m.kind == PROTO_KIND_NOTIFICATION;
	/* (an answer computed at once, without a pool, needs them in dispatch) */
	l->id = json_incref(m.id);
	l->notification = notification;
	code = dispatch(&c, &m, &result);
	if (!code && (c.deferred || c.listing)) {
		if (c.listing) {
			start_listing(l, &c, m.id, notification, result);
		} else if (l->state != ELEMENT_READY) {
			/* (answered at once when there is no pool: still READY) */
			l->state = ELEMENT_WAITING;
		}
		return;
	}
	*reply = make_reply(&c, m.id, notification, code, result);
}

static json_t *error_reply(int code, const char *detail)
{
	return proto_make_error(NULL, code, NULL, json_pack("{s:s}", "detail", detail));
}

int rpc_line_new(struct rpc *rpc, struct rpc_session *s, const char *text, size_t len,
		 struct rpc_line **out)
{
	struct rpc_line *l = calloc(1, sizeof(*l));
	struct proto_why why;

	if (!l)
		return -ENOMEM;
	*l = (struct rpc_line){ .rpc = rpc, .s = s };
	rpc->requests++;
	l->msg = proto_parse(text, len, &why);
	if (!l->msg) {
		l->msg = error_reply(PROTO_PARSE_ERROR, why.text);
	} else if (json_is_array(l->msg) && json_array_size(l->msg) == 0) {
		json_decref(l->msg);
		l->msg = error_reply(PROTO_INVALID_REQUEST, "an empty batch");
	} else if (json_is_array(l->msg) && json_array_size(l->msg) > PROTO_MAX_BATCH) {
		proto_why_set(&why, "a batch of %zu requests, more than %d",
			      json_array_size(l->msg), PROTO_MAX_BATCH);
		json_decref(l->msg);
		l->msg = error_reply(PROTO_INVALID_REQUEST, why.text);
	} else {
		l->parsed = true;
		l->batch = json_is_array(l->msg);
	}
	if (!l->msg) {
		free(l);
		return -ENOMEM;
	}
	*out = l;
	return 0;
}

void rpc_line_on_ready(struct rpc_line *l, void (*ready)(void *data), void *data)
{
	l->ready = ready;
	l->ready_data = data;
}

/* The element is done with: what it kept goes. */
static void element_end(struct rpc_line *l)
{
	wait_end(l);
	json_decref(l->reply);
	l->reply = NULL;
	json_decref(l->id);
	l->id = NULL;
	listing_free(l->listing);
	l->listing = NULL;
	l->state = ELEMENT_NEXT;
}

void rpc_line_free(struct rpc_line *l)
{
	if (!l)
		return;
	element_end(l);
	json_decref(l->msg);
	free(l);
}

/*
 * The answer to a request whose turn came after the line's answers had
 * used up limits.max_response_bytes: not carried out (a notification is
 * dropped, as it would be answered by nothing).
 */
static json_t *over_budget(const struct rpc_line *l, json_t *msg)
{
	struct proto_message m;
	struct proto_why why;

	if (proto_check_request(msg, &m, &why) == 0 && m.kind == PROTO_KIND_NOTIFICATION)
		return NULL;
	proto_why_set(&why, "the answers to this line already take %zu bytes, more than "
		      "limits.max_response_bytes (%u): the request was not carried out",
		      l->written, l->rpc->limits->max_response_bytes);
	return proto_make_error(m.id, PROTO_RESPONSE_TOO_LARGE, NULL,
				json_pack("{s:s}", "detail", why.text));
}

/* Writes one answer of the line (its separator first). */
static void emit(struct rpc_line *l, struct line_writer *w, const json_t *reply)
{
	if (l->batch)
		put(w, l->opened ? "," : "[", 1);
	l->opened = true;
	if (json_dump_callback(reply, put_json, w, JSON_COMPACT) < 0 && !w->failed)
		w->failed = -ENOMEM;
}

/* The element now answered: 1 when it is, 0 when it goes on. */
static int element_step(struct rpc_line *l, struct line_writer *w, json_t *msg)
{
	_cleanup_(json_decrefp) json_t *reply = NULL;
	struct line_writer counted = *w;

	switch (l->state) {
	case ELEMENT_NEXT:
		if (!l->parsed)
			reply = json_incref(l->msg);
		else if (l->written > l->rpc->limits->max_response_bytes)
			reply = over_budget(l, msg);
		else
			start_element(l, msg, &reply);
		if (l->state == ELEMENT_NEXT) {
			if (reply)
				emit(l, w, reply);
			return 1;
		}
		/* A listing's first slice, or an answer the method had at once,
		 * goes out in this step too. */
		return l->state == ELEMENT_WAITING ? 0 : element_step(l, w, msg);
	case ELEMENT_WAITING:
		return 0;
	case ELEMENT_READY:
		if (l->reply)
			emit(l, w, l->reply);
		return 1;
	case ELEMENT_LISTING:
		counted.write = NULL;
		if (!l->notification && !l->listing->head_out) {
			if (l->batch)
				put(w, l->opened ? "," : "[", 1);
			l->opened = true;
		}
		return listing_step(l, l->notification ? &counted : w) > 0 ? 0 : 1;
	}
	return 1;
}

int rpc_line_step(struct rpc_line *l, rpc_write_fn write, void *data)
{
	struct line_writer w = { .write = write, .data = data, .written = &l->written };
	size_t n = l->batch ? json_array_size(l->msg) : 1;
	json_t *msg = l->batch ? json_array_get(l->msg, l->next) : l->msg;
	bool last;

	if (l->next >= n)
		return RPC_LINE_DONE;
	if (!element_step(l, &w, msg)) {
		if (w.failed)
			return w.failed;
		return l->state == ELEMENT_WAITING ? RPC_LINE_WAITING : RPC_LINE_MORE;
	}
	element_end(l);
	last = ++l->next == n;
	if (last && l->opened)
		put(&w, l->batch ? "]\n" : "\n", l->batch ? 2 : 1);
	if (w.failed)
		return w.failed;
	return last ? RPC_LINE_DONE : RPC_LINE_MORE;
}

bool rpc_line_open(const struct rpc_line *l)
{
	size_t n = l->batch ? json_array_size(l->msg) : 1;

	return l->opened && l->next < n;
}

/* Collects a line's answer for rpc_handle_line(). */
struct collected {
	char *text;
	size_t len, cap;
};

static int collect(const char *text, size_t len, void *data)
{
	struct collected *c = data;

	if (c->len + len + 1 > c->cap) {
		size_t cap = c->cap ? c->cap : 256;
		while (cap < c->len + len + 1)
			cap *= 2;
		char *t = realloc(c->text, cap);
		if (!t)
			return -1;
		c->text = t;
		c->cap = cap;
	}
	memcpy(c->text + c->len, text, len);
	c->len += len;
	c->text[c->len] = '\0';
	return 0;
}

json_t *rpc_handle_line(struct rpc *rpc, struct rpc_session *s, const char *line, size_t len)
{
	struct collected c = { 0 };
	struct rpc_line *l;
	json_t *reply = NULL;
	int r;

	if (rpc_line_new(rpc, s, line, len, &l) < 0)
		return NULL;
	while ((r = rpc_line_step(l, collect, &c)) == RPC_LINE_MORE)
		;
	rpc_line_free(l);
	if (r == RPC_LINE_DONE && c.text)
		reply = json_loadb(c.text, c.len, 0, NULL);
	free(c.text);
	return reply;
}
