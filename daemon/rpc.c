/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The sessions, the table of the methods with the role each needs, the
 * dispatch of a request to its handler (rpc-daemon.c, rpc-jobs.c,
 * rpc-instruments.c, rpc-admin.c), and the lines: a request, a
 * notification or a batch answered a step at a time. rpc-internal.h
 * tells which way the calls go.
 *
 * Event loop thread.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph-proto.h"
#include "log.h"
#include "ratelimit.h"
#include "rpc-internal.h"
#include "turns.h"
#include "util-mem.h"

/* Refusals logged per peer at once, then one per interval (the rest are
 * counted into the next line that is logged). */
#define REFUSALS_LOGGED_BURST 10
#define REFUSAL_LOG_INTERVAL_USEC (1000000ull)
/* Peers whose counts are kept at once. */
#define RATE_KEYS 256

/* A step of a listing (job.list, queue.get): jobs read from the store a
 * few at a time (each is read, parsed and written: tens of microseconds)
 * until about this much time has passed. */
#define LIST_STEP_USEC 1000
#define LIST_READ 8
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

/* ------------------------------------------------------------ table */

/* Each method with the role it needs (proto/README.md, "Who may do what"). */
static const struct method {
	const char *name;
	method_fn fn;
	enum access_role need;
} methods[] = {
	{ "hello", rpc_method_hello, ROLE_NONE },
	{ "version", rpc_method_version, ROLE_VIEWER },
	{ "daemon.status", rpc_method_daemon_status, ROLE_VIEWER },
	{ "daemon.health", rpc_method_daemon_health, ROLE_VIEWER },
	{ "job.submit", rpc_method_job_submit, ROLE_OPERATOR },
	{ "job.estimate", rpc_method_job_estimate, ROLE_VIEWER },
	{ "job.get", rpc_method_job_get, ROLE_VIEWER },
	{ "job.list", rpc_method_job_list, ROLE_VIEWER },
	{ "job.cancel", rpc_method_job_cancel, ROLE_OPERATOR },
	{ "job.pause", rpc_method_job_pause, ROLE_OPERATOR },
	{ "job.resume", rpc_method_job_resume, ROLE_OPERATOR },
	{ "job.requeue", rpc_method_job_requeue, ROLE_OPERATOR },
	{ "job.result", rpc_method_job_result, ROLE_VIEWER },
	{ "job.file", rpc_method_job_file, ROLE_VIEWER },
	{ "queue.get", rpc_method_queue_get, ROLE_VIEWER },
	{ "queue.move", rpc_method_queue_move, ROLE_OPERATOR },
	{ "queue.start", rpc_method_queue_start, ROLE_OPERATOR },
	{ "queue.stop", rpc_method_queue_stop, ROLE_OPERATOR },
	{ "instrument.list", rpc_method_instrument_list, ROLE_VIEWER },
	{ "instrument.status", rpc_method_instrument_status, ROLE_VIEWER },
	{ "instrument.lock", rpc_method_instrument_lock, ROLE_OPERATOR },
	{ "instrument.unlock", rpc_method_instrument_unlock, ROLE_OPERATOR },
	{ "driver.list", rpc_method_driver_list, ROLE_VIEWER },
	{ "events.subscribe", rpc_method_events_subscribe, ROLE_VIEWER },
	{ "events.unsubscribe", rpc_method_events_unsubscribe, ROLE_VIEWER },
	{ "token.create", rpc_method_token_create, ROLE_ADMIN },
	{ "token.list", rpc_method_token_list, ROLE_ADMIN },
	{ "token.revoke", rpc_method_token_revoke, ROLE_ADMIN },
	{ "backup.start", rpc_method_backup_start, ROLE_ADMIN },
	{ "backup.get", rpc_method_backup_get, ROLE_ADMIN },
	{ "backup.file", rpc_method_backup_file, ROLE_ADMIN },
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

	if (!ratelimit_take(c->rpc->refusals_logged, p->key, rpc_loop_usec(c->rpc), &left_out))
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
		return rpc_fail(c, PROTO_METHOD_NOT_FOUND, "no method \"%.64s\"", m->method);
	if (!c->s->authenticated && meth->fn != rpc_method_hello)
		return rpc_fail(c, PROTO_PERMISSION_DENIED, "send \"hello\" with the token first");
	if (meth->need > ROLE_NONE && rpc_role(c) < meth->need) {
		log_refusal(c, m->method);
		if (p->tcp && c->s->grant.valid && !access_grant_current(c->rpc->access,
									 &c->s->grant))
			return rpc_fail(c, PROTO_PERMISSION_DENIED, "the token \"%s\" was revoked "
					"or has expired", c->s->grant.credential);
		if (p->tcp)
			return rpc_fail(c, PROTO_PERMISSION_DENIED, "%s needs the role %s: the "
					"token \"%s\" is a %s", m->method,
					access_role_name(meth->need), c->s->grant.credential,
					access_role_name(c->s->grant.role));
		if (meth->need == ROLE_ADMIN)
			return rpc_fail(c, PROTO_PERMISSION_DENIED, "%s needs an admin: root, or a "
					"TCP client with an admin token", m->method);
		return rpc_fail(c, PROTO_PERMISSION_DENIED,
				"%s needs an operator: %s (uid %d) is not in the operator group",
				m->method, p->name, (int)p->uid);
	}
	if (json_is_array(params) && json_array_size(params) > 0)
		return rpc_fail(c, PROTO_INVALID_PARAMS, "params must be an object");
	if (json_is_array(params))
		params = NULL;
	code = meth->fn(c, params, result);
	if (!code && !*result && !c->deferred)
		code = rpc_fail(c, PROTO_INTERNAL_ERROR, "out of memory");
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
		l->reply = rpc_make_reply(c, id, notification, rpc_fail(c, PROTO_INTERNAL_ERROR,
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
			rpc_fail(&c, code, "unknown member \"%.64s\" in request", m.unknown);
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
	*reply = rpc_make_reply(&c, m.id, notification, code, result);
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
	rpc_wait_end(l);
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
