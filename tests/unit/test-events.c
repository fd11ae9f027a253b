/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The event sink (daemon/events.c): watches are told in the order they
 * were added, only of their classes, and may add and remove watches while
 * they are told; each builder's notification carries the documented
 * params; subscriptions are counted once however often they end.
 */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "events.h"
#include "instruments.h"

struct log {
	char text[512];
	int destroyed;
};

struct watcher {
	struct log *log;
	char name;
	struct events *e;
	int remove_id;          /* removed when this one is told, or 0 */
	int added;              /* the id of a watch it added, or 0 */
};

static void told(const struct event *ev, void *data)
{
	struct watcher *w = data;
	size_t n = strlen(w->log->text);

	snprintf(w->log->text + n, sizeof(w->log->text) - n, "%c:%s ", w->name, ev->method);
	if (w->remove_id) {
		assert_int_equal(events_watch_remove(w->e, w->remove_id), 0);
		w->remove_id = 0;
	}
}

static void destroyed(void *data)
{
	struct watcher *w = data;

	w->log->destroyed++;
}

static void test_order_and_classes(void **state)
{
	struct events *e;
	struct log log = { 0 };
	struct watcher a = { &log, 'a' }, b = { &log, 'b' }, c = { &log, 'c' };

	assert_int_equal(events_new(&e), 0);
	assert_true(events_watch_add(e, EVENT_ALL, told, &a, destroyed) > 0);
	assert_true(events_watch_add(e, EVENT_QUEUE, told, &b, destroyed) > 0);
	assert_true(events_watch_add(e, EVENT_JOB | EVENT_PROGRESS, told, &c, NULL) > 0);
	events_queue_state(e, true);
	events_job_state(e, 3, JOB_RUNNING, JOB_QUEUED, NULL, "m", NULL);
	events_job_progress(e, 3, "m",
			    &(struct instrument_activity){ .job = 3, .done = 1, .total = 2,
							   .rate = 3.0, .eta_s = 4.0 });
	events_instrument_fault(e, "m", 3, "why");
	assert_string_equal(log.text, "a:queue.state b:queue.state a:job.state c:job.state "
			    "a:job.progress c:job.progress a:instrument.fault ");
	events_free(e);
	/* Each watch's destroy, once. */
	assert_int_equal(log.destroyed, 2);
}

static void test_remove_while_told(void **state)
{
	struct events *e;
	struct log log = { 0 };
	struct watcher a = { &log, 'a' }, b = { &log, 'b' }, c = { &log, 'c' };
	int ib, ic;

	assert_int_equal(events_new(&e), 0);
	assert_true(events_watch_add(e, EVENT_ALL, told, &a, destroyed) > 0);
	ib = events_watch_add(e, EVENT_ALL, told, &b, destroyed);
	ic = events_watch_add(e, EVENT_ALL, told, &c, destroyed);
	/* a removes c before c is told; b removes itself. */
	a.e = b.e = e;
	a.remove_id = ic;
	b.remove_id = ib;
	events_queue_state(e, false);
	assert_string_equal(log.text, "a:queue.state b:queue.state ");
	assert_int_equal(log.destroyed, 2);
	log.text[0] = '\0';
	events_queue_state(e, false);
	assert_string_equal(log.text, "a:queue.state ");
	assert_int_equal(events_watch_remove(e, ib), -ENOENT);
	assert_int_equal(events_watch_remove(e, 999), -ENOENT);
	events_free(e);
	assert_int_equal(log.destroyed, 3);
}

struct adder {
	struct events *e;
	struct watcher *late;
	int added;
	int n;
};

static void add_one(const struct event *ev, void *data)
{
	struct adder *ad = data;

	ad->n++;
	if (!ad->added)
		ad->added = events_watch_add(ad->e, EVENT_ALL, told, ad->late, NULL);
}

static void test_add_while_told(void **state)
{
	struct events *e;
	struct log log = { 0 };
	struct watcher late = { &log, 'l' };
	struct adder ad = { .late = &late };

	assert_int_equal(events_new(&e), 0);
	ad.e = e;
	/* Enough watches that adding one moves the list. */
	for (int i = 0; i < 4; i++)
		assert_true(events_watch_add(e, EVENT_ALL, add_one, &ad, NULL) > 0);
	events_queue_state(e, true);
	assert_int_equal(ad.n, 4);
	/* Added during the event: told from the next one on. */
	assert_string_equal(log.text, "");
	events_queue_state(e, true);
	assert_string_equal(log.text, "l:queue.state ");
	events_free(e);
}

static json_t *kept;

static void keep(const struct event *ev, void *data)
{
	json_decref(kept);
	kept = json_incref(ev->params);
	assert_int_equal(ev->class, *(unsigned *)data);
}

static void test_builders(void **state)
{
	struct events *e;
	unsigned class = EVENT_JOB;

	assert_int_equal(events_new(&e), 0);
	assert_true(events_watch_add(e, EVENT_ALL, keep, &class, NULL) > 0);
	json_t *want = json_pack("{s:i, s:s, s:n, s:n, s:s, s:n}", "job", 7, "state", "queued",
				 "previous", "reason", "instrument", "bench", "verdict");

	events_job_state(e, 7, JOB_QUEUED, -1, NULL, "bench", NULL);
	assert_true(json_equal(kept, want));
	json_decref(want);
	events_job_state(e, 7, JOB_FAILED, JOB_RUNNING, "stalled", "bench", NULL);
	assert_string_equal(json_string_value(json_object_get(kept, "previous")), "running");
	assert_string_equal(json_string_value(json_object_get(kept, "reason")), "stalled");
	assert_true(json_is_null(json_object_get(kept, "verdict")));
	events_job_state(e, 7, JOB_COMPLETED, JOB_RUNNING, NULL, "bench", "undecided");
	assert_string_equal(json_string_value(json_object_get(kept, "verdict")), "undecided");
	class = EVENT_PROGRESS;
	struct instrument_activity act = { .job = 7, .done = 10, .total = 40, .rate = 2.5,
					   .eta_s = -1 };
	events_job_progress(e, 7, "bench", &act);
	assert_int_equal(json_integer_value(json_object_get(kept, "job")), 7);
	assert_string_equal(json_string_value(json_object_get(kept, "instrument")), "bench");
	assert_int_equal(json_integer_value(json_object_get(kept, "done")), 10);
	assert_int_equal(json_integer_value(json_object_get(kept, "total")), 40);
	assert_true(json_real_value(json_object_get(kept, "rate")) == 2.5);
	assert_true(json_real_value(json_object_get(kept, "eta_s")) == -1);
	assert_string_equal(json_string_value(json_object_get(kept, "phase")), "measuring");
	assert_true(json_is_null(json_object_get(kept, "trials")));
	/* the recorded scan characterized, then its Monte Carlo */
	act.characterizing = true;
	events_job_progress(e, 7, "bench", &act);
	assert_string_equal(json_string_value(json_object_get(kept, "phase")), "characterizing");
	assert_true(json_is_null(json_object_get(kept, "trials")));
	act.trials_done = 50;
	act.trials_planned = 250;
	act.trials_rate = 12.5;
	events_job_progress(e, 7, "bench", &act);
	assert_string_equal(json_string_value(json_object_get(kept, "phase")), "uncertainty");
	json_t *trials = json_object_get(kept, "trials");
	assert_int_equal(json_integer_value(json_object_get(trials, "done")), 50);
	assert_int_equal(json_integer_value(json_object_get(trials, "planned")), 250);
	assert_true(json_real_value(json_object_get(trials, "rate")) == 12.5);
	assert_int_equal(json_object_size(kept), 8);
	class = EVENT_INSTRUMENT;
	events_instrument_fault(e, "bench", 7, "stalled");
	assert_int_equal(json_object_size(kept), 3);
	class = EVENT_QUEUE;
	events_queue_state(e, false);
	assert_true(json_is_false(json_object_get(kept, "running")));
	json_decref(kept);
	kept = NULL;
	events_free(e);
}

static void test_subscriptions(void **state)
{
	struct events *e;
	struct event_subscription a = { 0 }, b = { 0 }, c = { 0 };
	struct event job3 = { .class = EVENT_JOB, .job = 3, .method = "job.state" };
	struct event job4 = { .class = EVENT_JOB, .job = 4, .method = "job.state" };
	struct event queue = { .class = EVENT_QUEUE, .method = "queue.state" };

	const struct event_quota two = { .owner = "uid 7", .max = 2, .per_owner = 2 };

	assert_int_equal(events_new(&e), 0);
	assert_int_equal(events_subscribe(e, &a, EVENT_ALL, 0, &two), 0);
	assert_int_equal(events_subscribe(e, &b, EVENT_JOB, 3, &two), 0);
	assert_int_equal(events_subscriptions(e), 2);
	/* At the limit: refused and unchanged; a change of one is no new one. */
	assert_int_equal(events_subscribe(e, &c, EVENT_QUEUE, 0, &two), -EUSERS);
	assert_int_equal(c.classes, 0);
	assert_int_equal(events_subscribe(e, &b, EVENT_JOB | EVENT_PROGRESS, 3, &two), 0);
	assert_int_equal(events_subscriptions(e), 2);
	assert_true(events_subscription_matches(&a, &job4));
	assert_true(events_subscription_matches(&b, &job3));
	assert_false(events_subscription_matches(&b, &job4));
	assert_false(events_subscription_matches(&b, &queue));
	assert_false(events_subscription_matches(&c, &queue));
	/* Ended twice (unsubscribed, then its connection dropped): counted
	 * off once. */
	events_unsubscribe(e, &b);
	events_unsubscribe(e, &b);
	assert_int_equal(events_subscriptions(e), 1);
	assert_false(events_subscription_matches(&b, &job3));
	/* No classes is an end too; classes outside EVENT_ALL are none. */
	assert_int_equal(events_subscribe(e, &a, 0, 0, &two), 0);
	assert_int_equal(events_subscriptions(e), 0);
	assert_int_equal(events_subscribe(e, &c, 1u << 12, 0, &two), 0);
	assert_int_equal(events_subscriptions(e), 0);
	events_unsubscribe(e, &c);
	assert_int_equal(events_subscriptions(e), 0);
	events_free(e);
}

/* Per owner, and the last subscriptions kept for operators. */
static void test_quotas(void **state)
{
	struct events *e;
	struct event_subscription s[6] = { { 0 } };
	struct event_quota reader = { .owner = "uid 1000", .max = 5, .per_owner = 2,
				      .reserved = 2 };
	struct event_quota other = reader, op = reader;

	other.owner = "uid 1001";
	op.owner = "uid 1002";
	op.operator = true;
	assert_int_equal(events_new(&e), 0);
	assert_int_equal(events_subscribe(e, &s[0], EVENT_ALL, 0, &reader), 0);
	assert_int_equal(events_subscribe(e, &s[1], EVENT_ALL, 0, &reader), 0);
	/* A third of the same owner: its quota. */
	assert_int_equal(events_subscribe(e, &s[2], EVENT_ALL, 0, &reader), -EDQUOT);
	assert_int_equal(events_subscriptions_of(e, "uid 1000"), 2);
	/* Another reader takes the last one open to all... */
	assert_int_equal(events_subscribe(e, &s[2], EVENT_ALL, 0, &other), 0);
	assert_int_equal(events_subscribe(e, &s[3], EVENT_JOB, 0, &other), -EUSERS);
	/* ...and an operator still gets the two kept for operators. */
	assert_int_equal(events_subscribe(e, &s[3], EVENT_JOB, 0, &op), 0);
	assert_int_equal(events_subscribe(e, &s[4], EVENT_JOB, 0, &op), 0);
	assert_int_equal(events_subscribe(e, &s[5], EVENT_JOB, 0, &op), -EUSERS);
	assert_int_equal(events_subscriptions(e), 5);
	/* Ended twice, counted off once, from its own owner. */
	events_unsubscribe(e, &s[0]);
	events_unsubscribe(e, &s[0]);
	assert_int_equal(events_subscriptions_of(e, "uid 1000"), 1);
	assert_int_equal(events_subscriptions_of(e, "uid 1002"), 2);
	assert_int_equal(events_subscriptions(e), 4);
	for (size_t i = 0; i < 6; i++)
		events_unsubscribe(e, &s[i]);
	assert_int_equal(events_subscriptions(e), 0);
	assert_int_equal(events_subscriptions_of(e, "uid 1000"), 0);
	events_free(e);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_order_and_classes),
		cmocka_unit_test(test_remove_while_told),
		cmocka_unit_test(test_add_while_told),
		cmocka_unit_test(test_builders),
		cmocka_unit_test(test_subscriptions),
		cmocka_unit_test(test_quotas),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
