/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The methods (daemon/rpc*.c) over sessions without sockets: the errors of
 * the job queue come back as the documented protocol codes with their
 * detail, the sessions and their subscriptions are counted once however
 * they end, and every line is counted as a request.
 */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <syslog.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph-proto.h"
#include "log.h"
#include "rmtree.h"
#include "rpc.h"

struct fixture {
	char dir[64];
	struct settings *settings;
	sd_event *event;
	struct events *events;
	struct instruments *ins;
	struct access *access;
	struct jobs *jobs;
	struct rpc *rpc;
	struct rpc_session root, reader;
};

static void as(struct rpc_session *s, uid_t uid, const char *name)
{
	s->peer.uid = uid;
	s->peer.gid = uid;
	snprintf(s->peer.name, sizeof(s->peer.name), "%s", name);
	snprintf(s->peer.key, sizeof(s->peer.key), "uid %u", (unsigned)uid);
	s->authenticated = true;
}

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));
	struct job_actor root = { .uid = 0, .name = "root" };
	struct asph_error err;

	log_setup(LOG_CRIT);
	snprintf(f->dir, sizeof(f->dir), "/tmp/test-rpc-XXXXXX");
	assert_non_null(mkdtemp(f->dir));
	assert_int_equal(settings_defaults(&f->settings), 0);
	f->settings->limits.max_queue = 2;
	f->settings->limits.max_subscriptions = 2;
	f->settings->limits.reserved_subscriptions = 0;
	f->settings->limits.max_plan_points = 4000;
	asph_error_clear(&err);
	assert_int_equal(sd_event_new(&f->event), 0);
	assert_int_equal(events_new(&f->events), 0);
	assert_int_equal(instruments_load(f->settings, &f->ins, &err), 0);
	assert_int_equal(access_load(f->settings, &f->access, NULL, NULL), 0);
	assert_int_equal(jobs_new(&(struct jobs_setup){
				.event = f->event, .state_dir = f->dir, .instruments = f->ins,
				.events = f->events, .limits = &f->settings->limits,
			 }, &f->jobs, &err), 0);
	/* No scan runs here. */
	assert_int_equal(jobs_queue_stop(f->jobs, false, &root, NULL), 0);
	assert_int_equal(rpc_new(&(struct rpc_setup){
				.event = f->event, .jobs = f->jobs, .instruments = f->ins,
				.events = f->events, .access = f->access,
				.limits = &f->settings->limits,
			 }, &f->rpc), 0);
	as(&f->root, 0, "root");
	as(&f->reader, 65534, "nobody");
	rpc_session_open(f->rpc, &f->root);
	rpc_session_open(f->rpc, &f->reader);
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;

	rpc_session_close(f->rpc, &f->root);
	rpc_session_close(f->rpc, &f->reader);
	rpc_free(f->rpc);
	jobs_free(f->jobs);
	access_free(f->access);
	instruments_free(f->ins);
	events_free(f->events);
	settings_free(f->settings);
	sd_event_unref(f->event);
	assert_int_equal(rmtree(f->dir), 0);
	free(f);
	return 0;
}

/* The answer to one line. */
static json_t *line(struct fixture *f, struct rpc_session *s, const char *text)
{
	return rpc_handle_line(f->rpc, s, text, strlen(text));
}

/* A request's result (which must come), as a new reference. */
static json_t *result_of(struct fixture *f, struct rpc_session *s, const char *text)
{
	json_t *r = line(f, s, text), *res;

	assert_non_null(r);
	res = json_object_get(r, "result");
	if (!res)
		fail_msg("%s: %s", text, json_dumps(r, 0));
	json_incref(res);
	json_decref(r);
	return res;
}

/* A request's error code, and its detail must hold detail. */
static int error_of(struct fixture *f, struct rpc_session *s, const char *text,
		    const char *detail)
{
	json_t *r = line(f, s, text);
	json_t *e = json_object_get(r, "error");
	const char *d = json_string_value(json_object_get(json_object_get(e, "data"), "detail"));
	int code;

	if (!e)
		fail_msg("%s: no error: %s", text, json_dumps(r, 0));
	if (detail && (!d || !strstr(d, detail)))
		fail_msg("%s: the detail \"%s\" does not say \"%s\"", text, d ? d : "", detail);
	code = (int)json_integer_value(json_object_get(e, "code"));
	json_decref(r);
	return code;
}

#define SUBMIT "{\"jsonrpc\": \"2.0\", \"id\": 1, \"method\": \"job.submit\", \"params\": " \
	"{\"lens\": \"strong\", \"plan\": {\"method\": \"fermat\", \"points\": 200}%s}}"

static void test_job_errors(void **state)
{
	struct fixture *f = *state;
	char text[256];
	json_t *job;
	int64_t id;

	snprintf(text, sizeof(text), SUBMIT, "");
	job = result_of(f, &f->root, text);
	id = json_integer_value(json_object_get(job, "id"));
	assert_string_equal(json_string_value(json_object_get(job, "state")), "queued");
	json_decref(job);

	snprintf(text, sizeof(text), "{\"jsonrpc\": \"2.0\", \"id\": 2, \"method\": \"job.pause\","
		 " \"params\": {\"id\": %" PRId64 "}}", id);
	assert_int_equal(error_of(f, &f->root, text, "is queued, not running"), PROTO_INVALID_STATE);
	snprintf(text, sizeof(text), "{\"jsonrpc\": \"2.0\", \"id\": 3, \"method\": \"job.result\","
		 " \"params\": {\"id\": %" PRId64 "}}", id);
	assert_int_equal(error_of(f, &f->root, text, "is queued"), PROTO_NO_RESULT);
	assert_int_equal(error_of(f, &f->root, "{\"jsonrpc\": \"2.0\", \"id\": 4, \"method\": "
				  "\"job.get\", \"params\": {\"id\": 999}}", "no job 999"),
			 PROTO_NO_SUCH_JOB);
	snprintf(text, sizeof(text), SUBMIT, ", \"instrument\": \"nosuch\"");
	assert_int_equal(error_of(f, &f->root, text, "no instrument \"nosuch\""),
			 PROTO_NO_SUCH_INSTRUMENT);
	/* A reader may read, not change. */
	snprintf(text, sizeof(text), "{\"jsonrpc\": \"2.0\", \"id\": 5, \"method\": \"job.cancel\","
		 " \"params\": {\"id\": %" PRId64 "}}", id);
	assert_int_equal(error_of(f, &f->reader, text, "needs an operator"),
			 PROTO_PERMISSION_DENIED);
	/* The queue's limit (2). */
	snprintf(text, sizeof(text), SUBMIT, "");
	json_decref(result_of(f, &f->root, text));
	assert_int_equal(error_of(f, &f->root, text, "its limit"), PROTO_LIMIT_REACHED);
	snprintf(text, sizeof(text), "{\"jsonrpc\": \"2.0\", \"id\": 6, \"method\": \"job.cancel\","
		 " \"params\": {\"id\": %" PRId64 "}}", id);
	json_decref(result_of(f, &f->root, text));
	assert_int_equal(error_of(f, &f->root, text, "is cancelled"), PROTO_INVALID_STATE);
}

#define ESTIMATE "{\"jsonrpc\": \"2.0\", \"id\": 7, \"method\": \"job.estimate\", \"params\": " \
	"{\"lens\": \"strong\", \"plan\": {\"method\": \"fermat\", \"points\": %d}%s}}"

/* job.estimate: a reader's look ahead, queuing nothing, not stopped by a
 * full queue, refused as job.submit is. */
static void test_job_estimate(void **state)
{
	struct fixture *f = *state;
	char text[256];
	json_t *est, *list;

	snprintf(text, sizeof(text), SUBMIT, "");
	json_decref(result_of(f, &f->root, text));
	json_decref(result_of(f, &f->root, text));
	assert_int_equal(error_of(f, &f->root, text, "its limit"), PROTO_LIMIT_REACHED);
	snprintf(text, sizeof(text), ESTIMATE, 200, "");
	est = result_of(f, &f->reader, text);
	assert_int_equal(json_integer_value(json_object_get(est, "points")), 200);
	assert_true(json_is_number(json_object_get(est, "estimate_s")) ||
		    json_is_null(json_object_get(est, "estimate_s")));
	json_decref(est);
	list = result_of(f, &f->root, "{\"jsonrpc\": \"2.0\", \"id\": 8, \"method\": "
			 "\"queue.get\"}");
	assert_int_equal(json_array_size(json_object_get(list, "jobs")), 2);
	json_decref(list);
	/* The plan's limit (4000 points) and an unknown instrument, as for a submit. */
	snprintf(text, sizeof(text), ESTIMATE, 5000, "");
	assert_int_equal(error_of(f, &f->reader, text, "4000"), PROTO_LIMIT_REACHED);
	snprintf(text, sizeof(text), ESTIMATE, 200, ", \"instrument\": \"nosuch\"");
	assert_int_equal(error_of(f, &f->reader, text, "no instrument \"nosuch\""),
			 PROTO_NO_SUCH_INSTRUMENT);
}

static void test_sessions_and_requests(void **state)
{
	struct fixture *f = *state;
	const char *status = "{\"jsonrpc\": \"2.0\", \"id\": 1, \"method\": \"daemon.status\"}";
	struct rpc_session third = { 0 };
	json_t *st, *r;

	assert_int_equal(rpc_sessions(f->rpc), 2);
	as(&third, 1000, "anna");
	rpc_session_open(f->rpc, &third);
	rpc_session_open(f->rpc, &third);
	assert_int_equal(rpc_sessions(f->rpc), 3);
	rpc_session_close(f->rpc, &third);
	rpc_session_close(f->rpc, &third);
	assert_int_equal(rpc_sessions(f->rpc), 2);

	/* Lines that are not JSON, notifications and batches count too. */
	r = line(f, &f->root, "{nope");
	assert_int_equal(json_integer_value(json_object_get(json_object_get(r, "error"), "code")),
			 PROTO_PARSE_ERROR);
	json_decref(r);
	assert_null(line(f, &f->root, "{\"jsonrpc\": \"2.0\", \"method\": \"version\"}"));
	r = line(f, &f->root, "[]");
	assert_int_equal(json_integer_value(json_object_get(json_object_get(r, "error"), "code")),
			 PROTO_INVALID_REQUEST);
	json_decref(r);
	st = result_of(f, &f->root, status);
	assert_int_equal(json_integer_value(json_object_get(st, "clients")), 2);
	assert_int_equal(json_integer_value(json_object_get(st, "requests")), 4);
	assert_string_equal(json_string_value(json_object_get(st, "status")), "idle, queue stopped");
	json_decref(st);
}

static void test_subscriptions(void **state)
{
	struct fixture *f = *state;
	const char *sub = "{\"jsonrpc\": \"2.0\", \"id\": 1, \"method\": \"events.subscribe\"}";
	const char *unsub = "{\"jsonrpc\": \"2.0\", \"id\": 2, \"method\": \"events.unsubscribe\"}";
	struct rpc_session third = { 0 };
	char batch[256];

	as(&third, 1000, "anna");
	rpc_session_open(f->rpc, &third);
	json_decref(result_of(f, &f->root, sub));
	json_decref(result_of(f, &f->reader, sub));
	assert_int_equal(error_of(f, &third, sub, "the limit"), PROTO_LIMIT_REACHED);
	/* A connection dropped inside a batch [subscribe, ..., unsubscribe]:
	 * the batch goes on after its session closed, and the count stays
	 * right. */
	rpc_session_close(f->rpc, &f->reader);
	assert_int_equal(events_subscriptions(f->events), 1);
	snprintf(batch, sizeof(batch), "[%s, %s, %s]", unsub, sub, unsub);
	json_decref(line(f, &f->reader, batch));
	assert_int_equal(events_subscriptions(f->events), 1);
	json_decref(result_of(f, &third, sub));
	assert_int_equal(events_subscriptions(f->events), 2);
	rpc_session_close(f->rpc, &third);
	assert_int_equal(events_subscriptions(f->events), 1);
}

/* Collects what a line writes, step by step. */
struct written {
	char text[1 << 16];
	size_t len;
	size_t writes;
};

static int take(const char *text, size_t len, void *data)
{
	struct written *w = data;

	assert_true(w->len + len < sizeof(w->text));
	memcpy(w->text + w->len, text, len);
	w->len += len;
	w->text[w->len] = '\0';
	w->writes++;
	return 0;
}

/* A batch is answered a request per step, and past max_response_bytes the
 * rest is refused unrun: a notification there is not carried out. */
static void test_batch_budget(void **state)
{
	struct fixture *f = *state;
	static struct written w;
	char batch[4096], one[128];
	struct rpc_line *l;
	json_t *answers, *a;
	size_t n = 0, i, answered = 0, refused = 0, steps = 0;
	int r;

	f->settings->limits.max_response_bytes = 4096;
	n += (size_t)snprintf(batch + n, sizeof(batch) - n, "[");
	for (int k = 1; k <= 12; k++) {
		snprintf(one, sizeof(one),
			 "{\"jsonrpc\": \"2.0\", \"id\": %d, \"method\": \"driver.list\"}", k);
		n += (size_t)snprintf(batch + n, sizeof(batch) - n, "%s, ", one);
	}
	/* Notifications last: queue.start (the queue is stopped) must not run. */
	snprintf(batch + n, sizeof(batch) - n,
		 "{\"jsonrpc\": \"2.0\", \"method\": \"queue.start\"}]");
	assert_int_equal(rpc_line_new(f->rpc, &f->root, batch, strlen(batch), &l), 0);
	memset(&w, 0, sizeof(w));
	while ((r = rpc_line_step(l, take, &w)) > 0) {
		size_t seen = 0;
		steps++;
		/* Each step has written exactly one more answer. */
		for (const char *p = w.text; (p = strstr(p, "\"jsonrpc\"")); p++)
			seen++;
		assert_int_equal(seen, steps);
	}
	assert_int_equal(r, 0);
	rpc_line_free(l);
	assert_int_equal(steps + 1, 13);
	assert_true(w.text[w.len - 1] == '\n');
	answers = json_loads(w.text, 0, NULL);
	assert_non_null(answers);
	assert_int_equal(json_array_size(answers), 12);
	json_array_foreach(answers, i, a) {
		json_t *e = json_object_get(a, "error");
		assert_int_equal(json_integer_value(json_object_get(a, "id")), (json_int_t)i + 1);
		if (!e) {
			assert_int_equal(refused, 0);   /* answered ones come first */
			answered++;
			continue;
		}
		refused++;
		assert_int_equal(json_integer_value(json_object_get(e, "code")),
				 PROTO_RESPONSE_TOO_LARGE);
		assert_non_null(strstr(json_string_value(json_object_get(json_object_get(e, "data"),
									  "detail")),
				       "max_response_bytes"));
	}
	/* Each driver.list answer is a few kB: the first passes 4096. */
	assert_true(answered >= 1 && answered < 4);
	assert_int_equal(answered + refused, 12);
	json_decref(answers);
	assert_false(jobs_queue_running(f->jobs));
}

/* Notifications spend max_response_bytes as requests do: the answers
 * they would have had are counted, so that a request after a dozen
 * driver.list notifications is refused unrun, and so is queue.start. */
static void test_notification_budget(void **state)
{
	struct fixture *f = *state;
	char batch[4096];
	json_t *answers, *e;
	size_t n = 0;

	f->settings->limits.max_response_bytes = 4096;
	n += (size_t)snprintf(batch + n, sizeof(batch) - n, "[");
	for (int k = 0; k < 12; k++)
		n += (size_t)snprintf(batch + n, sizeof(batch) - n,
				      "{\"jsonrpc\": \"2.0\", \"method\": \"driver.list\"}, ");
	snprintf(batch + n, sizeof(batch) - n,
		 "{\"jsonrpc\": \"2.0\", \"id\": 7, \"method\": \"version\"}, "
		 "{\"jsonrpc\": \"2.0\", \"method\": \"queue.start\"}]");
	answers = line(f, &f->root, batch);
	assert_non_null(answers);
	assert_int_equal(json_array_size(answers), 1);
	assert_int_equal(json_integer_value(json_object_get(json_array_get(answers, 0), "id")), 7);
	e = json_object_get(json_array_get(answers, 0), "error");
	assert_non_null(e);
	assert_int_equal(json_integer_value(json_object_get(e, "code")), PROTO_RESPONSE_TOO_LARGE);
	json_decref(answers);
	assert_false(jobs_queue_running(f->jobs));
	/* Under the budget, the request after notifications is answered. */
	snprintf(batch, sizeof(batch), "[{\"jsonrpc\": \"2.0\", \"method\": \"version\"}, "
		 "{\"jsonrpc\": \"2.0\", \"id\": 8, \"method\": \"version\"}]");
	answers = line(f, &f->root, batch);
	assert_non_null(answers);
	assert_int_equal(json_array_size(answers), 1);
	assert_non_null(json_object_get(json_array_get(answers, 0), "result"));
	json_decref(answers);
}

/* The exact sequence of the issue: a batch [events.subscribe, ...,
 * events.unsubscribe] of a client dropped in its middle (the transport
 * frees the line and closes the session), and one that runs to the end
 * and then closes: each counts once. */
static void test_batch_dropped_subscriber(void **state)
{
	struct fixture *f = *state;
	const char *batch = "[{\"jsonrpc\": \"2.0\", \"id\": 1, \"method\": \"events.subscribe\"},"
			    " {\"jsonrpc\": \"2.0\", \"id\": 2, \"method\": \"version\"},"
			    " {\"jsonrpc\": \"2.0\", \"id\": 3, \"method\": \"events.unsubscribe\"}]";
	struct rpc_session a = { 0 }, b = { 0 };
	static struct written w;
	struct rpc_line *l;

	as(&a, 1000, "anna");
	as(&b, 1001, "ben");
	rpc_session_open(f->rpc, &a);
	rpc_session_open(f->rpc, &b);
	assert_int_equal(rpc_line_new(f->rpc, &a, batch, strlen(batch), &l), 0);
	assert_int_equal(rpc_line_step(l, take, &w), 1);
	assert_int_equal(events_subscriptions(f->events), 1);
	rpc_line_free(l);
	rpc_session_close(f->rpc, &a);
	assert_int_equal(events_subscriptions(f->events), 0);
	for (int round = 0; round < 3; round++) {
		json_decref(line(f, &b, batch));
		assert_int_equal(events_subscriptions(f->events), 0);
	}
	rpc_session_close(f->rpc, &b);
	assert_int_equal(events_subscriptions(f->events), 0);
	/* Both slots are free: two new subscribers get them. */
	json_decref(result_of(f, &f->root, "{\"jsonrpc\": \"2.0\", \"id\": 1, \"method\": "
			      "\"events.subscribe\"}"));
	json_decref(result_of(f, &f->reader, "{\"jsonrpc\": \"2.0\", \"id\": 1, \"method\": "
			      "\"events.subscribe\"}"));
	assert_int_equal(events_subscriptions(f->events), 2);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_job_errors, setup, teardown),
		cmocka_unit_test_setup_teardown(test_job_estimate, setup, teardown),
		cmocka_unit_test_setup_teardown(test_sessions_and_requests, setup, teardown),
		cmocka_unit_test_setup_teardown(test_subscriptions, setup, teardown),
		cmocka_unit_test_setup_teardown(test_batch_budget, setup, teardown),
		cmocka_unit_test_setup_teardown(test_notification_budget, setup, teardown),
		cmocka_unit_test_setup_teardown(test_batch_dropped_subscriber, setup, teardown),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
