/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The task pool (daemon/tasks.c) on a real sd-event loop and real threads:
 * a result comes back through the mailbox to done(); a deadline answers
 * -ETIMEDOUT at once while the thread goes on, and what it computes then
 * is thrown away; a cancelled task is never answered; an owner's share
 * counts a task given up on until its thread is done with it; the
 * reserved thread takes only privileged tasks; a full queue is refused.
 */
#include <errno.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "tasks.h"
#include "turns.h"

/* A gate the works wait at until the test opens it. */
static pthread_mutex_t gate_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t gate_cond = PTHREAD_COND_INITIALIZER;
static bool gate_open;
static atomic_int started, freed;

static void gate(bool open)
{
	pthread_mutex_lock(&gate_lock);
	gate_open = open;
	pthread_cond_broadcast(&gate_cond);
	pthread_mutex_unlock(&gate_lock);
}

struct work {
	int value;
	bool wait;              /* at the gate */
	int result;
	int answered;           /* done() calls */
	int r;                  /* what done() got */
};

static int run(void *data, const struct task *task)
{
	struct work *w = data;

	atomic_fetch_add(&started, 1);
	if (w->wait) {
		pthread_mutex_lock(&gate_lock);
		while (!gate_open)
			pthread_cond_wait(&gate_cond, &gate_lock);
		pthread_mutex_unlock(&gate_lock);
	}
	w->result = w->value * 2;
	return task_cancelled(task) ? -ECANCELED : 0;
}

static void done(void *data, int r, void *unused)
{
	struct work *w = data;

	w->answered++;
	w->r = r;
}

static void free_work(void *data)
{
	atomic_fetch_add(&freed, 1);
}

struct fixture {
	sd_event *event;
	struct tasks *tasks;
};

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));

	assert_int_equal(sd_event_new(&f->event), 0);
	assert_int_equal(tasks_new(&(struct tasks_setup){ .event = f->event, .threads = 2,
							   .reserved = 1 }, &f->tasks), 0);
	gate(false);
	atomic_store(&started, 0);
	atomic_store(&freed, 0);
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;

	gate(true);
	tasks_free(f->tasks);
	sd_event_unref(f->event);
	free(f);
	return 0;
}

static int submit(struct fixture *f, struct work *w, const char *owner, bool privileged,
		  uint64_t in_usec, struct task **out)
{
	return tasks_submit(f->tasks, &(struct task_spec){
		.owner = owner, .privileged = privileged, .max_per_owner = 2,
		.deadline_usec = turns_now_usec() + in_usec, .run = run, .done = done,
		.free = free_work, .work = w }, out);
}

/* Runs the loop until cond holds (or a minute passes). */
#define LOOP_UNTIL(f, cond)                                                           \
	do {                                                                          \
		uint64_t until_ = turns_now_usec() + 60000000ull;                     \
		while (!(cond) && turns_now_usec() < until_)                          \
			assert_true(sd_event_run((f)->event, 10000) >= 0);             \
		assert_true(cond);                                                    \
	} while (0)

static void test_result(void **state)
{
	struct fixture *f = *state;
	struct work w = { .value = 21 };

	assert_int_equal(submit(f, &w, "uid 1000", false, 10000000, NULL), 0);
	LOOP_UNTIL(f, w.answered);
	assert_int_equal(w.r, 0);
	assert_int_equal(w.result, 42);
	LOOP_UNTIL(f, atomic_load(&freed) == 1);
	assert_int_equal(tasks_count(f->tasks), 0);
}

static void test_deadline_and_share(void **state)
{
	struct fixture *f = *state;
	struct work slow = { .value = 1, .wait = true }, other = { .value = 2 }, third = { 0 };

	assert_int_equal(submit(f, &slow, "tcp 192.0.2.7", false, 200000, NULL), 0);
	LOOP_UNTIL(f, slow.answered);
	assert_int_equal(slow.r, -ETIMEDOUT);
	/* Given up on, it still counts against its owner while it runs. */
	assert_int_equal(tasks_of(f->tasks, "tcp 192.0.2.7"), 1);
	assert_int_equal(submit(f, &other, "tcp 192.0.2.7", false, 10000000, NULL), 0);
	assert_int_equal(submit(f, &third, "tcp 192.0.2.7", false, 10000000, NULL), -EDQUOT);
	assert_int_equal(atomic_load(&freed), 1);       /* (refused: its work freed) */
	gate(true);
	LOOP_UNTIL(f, other.answered && tasks_count(f->tasks) == 0);
	assert_int_equal(slow.answered, 1);             /* never answered twice */
	assert_int_equal(other.result, 4);
	assert_int_equal(atomic_load(&freed), 3);
}

static void test_cancel(void **state)
{
	struct fixture *f = *state;
	struct work running = { .wait = true }, waiting = { 0 };
	struct task *a, *b;

	assert_int_equal(submit(f, &running, "uid 1", false, 10000000, &a), 0);
	LOOP_UNTIL(f, atomic_load(&started) == 1);
	/* the one plain thread is busy: this one waits */
	assert_int_equal(submit(f, &waiting, "uid 2", false, 10000000, &b), 0);
	tasks_cancel(f->tasks, b);
	assert_int_equal(atomic_load(&freed), 1);       /* dropped at once */
	tasks_cancel(f->tasks, a);
	gate(true);
	LOOP_UNTIL(f, tasks_count(f->tasks) == 0);
	assert_int_equal(running.answered + waiting.answered, 0);
	assert_int_equal(atomic_load(&started), 1);
	assert_int_equal(atomic_load(&freed), 2);
}

static void test_reserved(void **state)
{
	struct fixture *f = *state;
	struct work plain1 = { .wait = true }, plain2 = { .value = 5 }, op = { .value = 7 };

	assert_int_equal(submit(f, &plain1, "uid 1", false, 10000000, NULL), 0);
	LOOP_UNTIL(f, atomic_load(&started) == 1);
	assert_int_equal(submit(f, &plain2, "uid 2", false, 10000000, NULL), 0);
	assert_int_equal(submit(f, &op, "uid 3", true, 10000000, NULL), 0);
	/* the operator's takes the reserved thread; the reader's second waits */
	LOOP_UNTIL(f, op.answered);
	assert_int_equal(op.result, 14);
	assert_int_equal(plain2.answered, 0);
	gate(true);
	LOOP_UNTIL(f, plain2.answered && plain1.answered);
	assert_int_equal(plain2.result, 10);
}

static void test_full(void **state)
{
	struct fixture *f = *state;
	static struct work w[TASKS_MAX_WAITING + 4];
	char owner[32];
	int refused = 0;

	memset(w, 0, sizeof(w));
	for (size_t i = 0; i < sizeof(w) / sizeof(w[0]); i++) {
		w[i].wait = true;
		snprintf(owner, sizeof(owner), "uid %zu", i);
		/* (privileged: both threads take them) */
		refused += submit(f, &w[i], owner, true, 10000000, NULL) == -EAGAIN;
		if (i == 1)
			LOOP_UNTIL(f, atomic_load(&started) == 2);
	}
	/* two run, TASKS_MAX_WAITING wait, the rest are refused */
	assert_int_equal(refused, 2);
	gate(true);
	LOOP_UNTIL(f, tasks_count(f->tasks) == 0);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_result, setup, teardown),
		cmocka_unit_test_setup_teardown(test_deadline_and_share, setup, teardown),
		cmocka_unit_test_setup_teardown(test_cancel, setup, teardown),
		cmocka_unit_test_setup_teardown(test_reserved, setup, teardown),
		cmocka_unit_test_setup_teardown(test_full, setup, teardown),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
