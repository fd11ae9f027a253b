/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The methods of the daemon and the session: hello (with the check of a
 * token, which web.c's /metrics shares), version, daemon.status,
 * daemon.health, events.subscribe and events.unsubscribe.
 *
 * Event loop thread.
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "asph-proto.h"
#include "config.h"
#include "log.h"
#include "ratelimit.h"
#include "rpc-internal.h"
#include "util-hash.h"
#include "util-mem.h"

/* The characters of a presented token that make its claimed prefix. */
#define TOKEN_PREFIX 12

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
	uint64_t now = rpc_loop_usec(rpc), wait;
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
		return wait ? rpc_defer_answer(c, code, wait) : code;
	/* A connection that took one of the last reserved_clients before it
	 * said who it is keeps it only as an operator or admin. */
	if (s->open && s->grant.role < ROLE_OPERATOR &&
	    c->rpc->n_sessions + c->rpc->limits->reserved_clients > c->rpc->limits->max_clients) {
		s->grant = (struct access_grant){ 0 };
		return rpc_fail(c, PROTO_TOO_MANY_CLIENTS, "the last %u of limits.max_clients (%u) "
				"are kept for operators and admins: this token is a viewer's",
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

int rpc_method_hello(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "client", "token", NULL };
	const char *token = NULL, *client = NULL;
	struct rpc_session *s = c->s;
	int code = rpc_only(c, params, names);

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
		"operator", rpc_is_operator(c), "role", access_role_name(rpc_role(c)),
		"token", s->peer.tcp && s->grant.valid ? s->grant.credential : NULL);
	return 0;
}

int rpc_method_version(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = rpc_only(c, params, names);

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

int rpc_method_daemon_status(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct rpc *rpc = c->rpc;
	char status[128];
	uint64_t now;
	int code = rpc_only(c, params, names);

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
int rpc_method_daemon_health(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	json_t *reasons;
	int code = rpc_only(c, params, names);

	if (code)
		return code;
	reasons = monitor_health(c->rpc->monitor);
	if (!reasons)
		return PROTO_INTERNAL_ERROR;
	*result = json_pack("{s:s, s:o}", "status", json_array_size(reasons) ? "degraded" : "ok",
			    "reasons", reasons);
	return 0;
}

/* ------------------------------------------------------------ events */

int rpc_method_events_subscribe(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "events", "job", NULL };
	const struct settings_limits *l = c->rpc->limits;
	const struct peer *p = &c->s->peer;
	struct event_quota q = {
		/* a user's from whichever address and listener (rpc.h) */
		.owner = c->s->owner, .operator = rpc_is_operator(c), .max = l->max_subscriptions,
		/* root has no quota of its own, as for connections */
		.per_owner = !p->tcp && p->uid == 0 ? l->max_subscriptions
						    : l->max_subscriptions_per_user,
		.reserved = l->reserved_subscriptions,
	};
	unsigned mask = EVENT_ALL;
	int64_t job = 0;
	json_t *list;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_flags(params, "events", false, event_class_names, &mask,
			      &c->why) == -EINVAL ||
	    proto_param_int(params, "job", false, 1, INT64_MAX, &job, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	/* A batch may go on after its connection was dropped: nothing is
	 * sent there any more, so nothing is counted for it. */
	if (!c->s->open)
		return rpc_fail(c, PROTO_INVALID_REQUEST, "the connection is closed");
	r = events_subscribe(c->rpc->events, &c->s->events, mask, job, &q);
	if (r == -EDQUOT)
		return rpc_fail(c, PROTO_LIMIT_REACHED, "%s has %u subscriptions, "
				"limits.max_subscriptions_per_user", q.owner, q.per_owner);
	if (r == -EUSERS && !q.operator && l->reserved_subscriptions)
		return rpc_fail(c, PROTO_LIMIT_REACHED, "%zu clients are subscribed; the last %u "
				"of limits.max_subscriptions (%u) are kept for operators",
				events_subscriptions(c->rpc->events), q.reserved, q.max);
	if (r < 0)
		return rpc_fail(c, PROTO_LIMIT_REACHED, "%u clients are subscribed, the limit "
				"(limits.max_subscriptions)", q.max);
	list = json_array();
	for (int k = 0; list && event_class_names[k]; k++)
		if (mask & (1u << k))
			json_array_append_new(list, json_string(event_class_names[k]));
	*result = json_pack("{s:o, s:o}", "events", list, "job", job ? json_integer(job) : json_null());
	return 0;
}

int rpc_method_events_unsubscribe(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = rpc_only(c, params, names);

	if (code)
		return code;
	events_unsubscribe(c->rpc->events, &c->s->events);
	*result = json_object();
	return 0;
}
