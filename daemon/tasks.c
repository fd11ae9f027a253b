/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The task pool (tasks.h). Threads take the first waiting task they may
 * (a thread beyond the unreserved ones only a privileged task), run it
 * without the lock, and post it to the mailbox; the loop hands it to
 * done() unless it was answered before (its deadline) or cancelled, and
 * frees it. Each function says which thread runs it.
 */
#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "log.h"
#include "mailbox.h"
#include "ratelimit.h"
#include "tasks.h"
#include "turns.h"

/* How long the end waits for a thread still computing. */
#define JOIN_WAIT_SEC 2

enum task_state {
	TASK_WAITING,
	TASK_RUNNING,
	TASK_ENDED,             /* posted, not yet delivered */
};

struct task {
	struct tasks *pool;
	struct task *next, *prev;       /* every task not yet delivered */
	struct task_spec spec;
	char owner[RATELIMIT_KEY_MAX];
	enum task_state state;          /* under the pool's lock */
	atomic_bool cancelled;          /* the thread looks at it */
	bool answered;                  /* done() called, or cancelled: loop only */
	int result;
};

struct tasks {
	struct mailbox *mailbox;
	sd_event_source *timer;         /* the nearest deadline */
	pthread_t *threads;
	unsigned n_threads, started, reserved;

	pthread_mutex_t lock;           /* what follows */
	pthread_cond_t cond;
	bool quit;
	unsigned exited;                /* threads that have quit */
	struct task *first, *last;
	unsigned waiting, running_plain;
};

/* ------------------------------------------------------------- threads */

bool task_cancelled(const struct task *task)
{
	/* NULL: run inline, by a caller without a pool (tests) */
	return task && atomic_load(&task->cancelled);
}

/* Under the lock: the first task a thread may take now, or NULL. */
static struct task *next_task(struct tasks *t)
{
	bool plain_ok = t->running_plain < t->n_threads - t->reserved;

	for (struct task *k = t->first; k; k = k->next)
		if (k->state == TASK_WAITING && (k->spec.privileged || plain_ok))
			return k;
	return NULL;
}

static void *worker(void *data)
{
	struct tasks *t = data;
	struct task *k;

	pthread_mutex_lock(&t->lock);
	for (;;) {
		while (!t->quit && !(k = next_task(t)))
			pthread_cond_wait(&t->cond, &t->lock);
		if (t->quit)
			break;
		k->state = TASK_RUNNING;
		t->waiting--;
		if (!k->spec.privileged)
			t->running_plain++;
		pthread_mutex_unlock(&t->lock);

		int r = task_cancelled(k) ? -ECANCELED : k->spec.run(k->spec.work, k);

		pthread_mutex_lock(&t->lock);
		k->result = r;
		k->state = TASK_ENDED;
		if (!k->spec.privileged)
			t->running_plain--;
		/* A thread kept for privileged tasks may have waited for this. */
		pthread_cond_broadcast(&t->cond);
		pthread_mutex_unlock(&t->lock);
		mailbox_post(t->mailbox, &k);   /* k is the loop's from here */
		pthread_mutex_lock(&t->lock);
	}
	t->exited++;
	pthread_cond_broadcast(&t->cond);
	pthread_mutex_unlock(&t->lock);
	return NULL;
}

/* ---------------------------------------------------------------- loop */

/* Under the lock. */
static void unlink_task(struct tasks *t, struct task *k)
{
	if (k->prev)
		k->prev->next = k->next;
	else
		t->first = k->next;
	if (k->next)
		k->next->prev = k->prev;
	else
		t->last = k->prev;
	k->next = k->prev = NULL;
}

static void task_free(struct task *k)
{
	if (k->spec.free)
		k->spec.free(k->spec.work);
	free(k);
}

static void arm_timer(struct tasks *t)
{
	uint64_t at = UINT64_MAX;

	pthread_mutex_lock(&t->lock);
	for (struct task *k = t->first; k; k = k->next)
		if (!k->answered && k->spec.deadline_usec < at)
			at = k->spec.deadline_usec;
	pthread_mutex_unlock(&t->lock);
	if (at == UINT64_MAX) {
		sd_event_source_set_enabled(t->timer, SD_EVENT_OFF);
		return;
	}
	sd_event_source_set_time(t->timer, at);
	sd_event_source_set_enabled(t->timer, SD_EVENT_ONESHOT);
}

/* A task its thread is done with. */
static void deliver(void *msg, void *data)
{
	struct tasks *t = data;
	struct task *k = *(struct task **)msg;

	pthread_mutex_lock(&t->lock);
	unlink_task(t, k);
	pthread_mutex_unlock(&t->lock);
	if (!k->answered) {
		k->answered = true;
		k->spec.done(k->spec.work, k->result, k->spec.data);
	}
	task_free(k);
	arm_timer(t);
}

static void drop(void *msg, void *data)
{
	task_free(*(struct task **)msg);
}

/* The first task not answered whose deadline has passed, marked
 * answered (a waiting one taken off the list), or NULL. */
static struct task *take_overdue(struct tasks *t, uint64_t now, bool *waiting)
{
	struct task *k;

	pthread_mutex_lock(&t->lock);
	for (k = t->first; k; k = k->next)
		if (!k->answered && k->spec.deadline_usec <= now)
			break;
	if (k) {
		k->answered = true;
		*waiting = k->state == TASK_WAITING;
		if (*waiting) {
			unlink_task(t, k);
			t->waiting--;
		} else {
			atomic_store(&k->cancelled, true);
		}
	}
	pthread_mutex_unlock(&t->lock);
	return k;
}

static int on_deadline(sd_event_source *s, uint64_t usec, void *data)
{
	struct tasks *t = data;
	uint64_t now = turns_now_usec();
	struct task *k;
	bool waiting;

	/* One at a time: a done() may queue or cancel others. */
	while ((k = take_overdue(t, now, &waiting))) {
		k->spec.done(k->spec.work, -ETIMEDOUT, k->spec.data);
		if (waiting)
			task_free(k);
	}
	arm_timer(t);
	return 0;
}

int tasks_new(const struct tasks_setup *setup, struct tasks **out)
{
	struct tasks *t = calloc(1, sizeof(*t));
	int r;

	if (!t)
		return -ENOMEM;
	if (!setup->threads || setup->reserved >= setup->threads) {
		free(t);
		return -EINVAL;
	}
	pthread_mutex_init(&t->lock, NULL);
	pthread_cond_init(&t->cond, NULL);
	t->n_threads = setup->threads;
	t->reserved = setup->reserved;
	t->threads = calloc(t->n_threads, sizeof(*t->threads));
	r = t->threads ? 0 : -ENOMEM;
	if (r == 0)
		r = mailbox_new(&(struct mailbox_setup){
			.event = setup->event, .size = sizeof(struct task *), .deliver = deliver,
			.drop = drop, .data = t }, &t->mailbox);
	if (r == 0)
		r = sd_event_add_time(setup->event, &t->timer, CLOCK_MONOTONIC, UINT64_MAX, 0,
				      on_deadline, t);
	if (r == 0)
		sd_event_source_set_enabled(t->timer, SD_EVENT_OFF);
	for (; r == 0 && t->started < t->n_threads; t->started++)
		r = -pthread_create(&t->threads[t->started], NULL, worker, t);
	if (r < 0) {
		tasks_free(t);
		return r;
	}
	*out = t;
	return 0;
}

/* Waits for the threads, a little; false when one still computes (then
 * none is joined: they are left to end with the process). */
static bool join_all(struct tasks *t)
{
	struct timespec until;
	bool all;
	int r = 0;

	clock_gettime(CLOCK_REALTIME, &until);
	until.tv_sec += JOIN_WAIT_SEC;
	pthread_mutex_lock(&t->lock);
	while (t->exited < t->started && r != ETIMEDOUT)
		r = pthread_cond_timedwait(&t->cond, &t->lock, &until);
	all = t->exited == t->started;
	pthread_mutex_unlock(&t->lock);
	for (unsigned i = 0; i < t->started; i++) {
		if (all)
			pthread_join(t->threads[i], NULL);
		else
			pthread_detach(t->threads[i]);
	}
	return all;
}

void tasks_free(struct tasks *t)
{
	struct task *k, *next;

	if (!t)
		return;
	pthread_mutex_lock(&t->lock);
	t->quit = true;
	for (k = t->first; k; k = next) {
		next = k->next;
		atomic_store(&k->cancelled, true);
		if (k->state == TASK_WAITING) {
			unlink_task(t, k);
			task_free(k);
		}
	}
	pthread_cond_broadcast(&t->cond);
	pthread_mutex_unlock(&t->lock);
	t->timer = sd_event_source_disable_unref(t->timer);
	if (!join_all(t)) {
		/* Its thread still uses the pool: both end with the process. */
		log_warning("a computation is still running at the end; it ends with the process");
		mailbox_close(t->mailbox);
		return;
	}
	mailbox_free(t->mailbox);       /* (drops what was posted) */
	pthread_cond_destroy(&t->cond);
	pthread_mutex_destroy(&t->lock);
	free(t->threads);
	free(t);
}

unsigned tasks_of(const struct tasks *t, const char *owner)
{
	unsigned n = 0;

	pthread_mutex_lock((pthread_mutex_t *)&t->lock);
	for (const struct task *k = t->first; k; k = k->next)
		n += !strcmp(k->owner, owner);
	pthread_mutex_unlock((pthread_mutex_t *)&t->lock);
	return n;
}

unsigned tasks_count(const struct tasks *t)
{
	unsigned n = 0;

	pthread_mutex_lock((pthread_mutex_t *)&t->lock);
	for (const struct task *k = t->first; k; k = k->next)
		n++;
	pthread_mutex_unlock((pthread_mutex_t *)&t->lock);
	return n;
}

int tasks_submit(struct tasks *t, const struct task_spec *s, struct task **out)
{
	struct task *k;
	int r = 0;

	if (tasks_of(t, s->owner) >= s->max_per_owner)
		r = -EDQUOT;
	k = r ? NULL : calloc(1, sizeof(*k));
	if (!r && !k)
		r = -ENOMEM;
	if (r < 0) {
		if (s->free)
			s->free(s->work);
		return r;
	}
	k->pool = t;
	k->spec = *s;
	snprintf(k->owner, sizeof(k->owner), "%s", s->owner);
	k->spec.owner = k->owner;
	pthread_mutex_lock(&t->lock);
	if (t->waiting >= TASKS_MAX_WAITING) {
		pthread_mutex_unlock(&t->lock);
		task_free(k);
		return -EAGAIN;
	}
	k->prev = t->last;
	if (t->last)
		t->last->next = k;
	else
		t->first = k;
	t->last = k;
	t->waiting++;
	pthread_cond_broadcast(&t->cond);
	pthread_mutex_unlock(&t->lock);
	if (out)
		*out = k;
	arm_timer(t);
	return 0;
}

void tasks_cancel(struct tasks *t, struct task *k)
{
	bool waiting;

	if (!k)
		return;
	pthread_mutex_lock(&t->lock);
	k->answered = true;
	atomic_store(&k->cancelled, true);
	waiting = k->state == TASK_WAITING;
	if (waiting) {
		unlink_task(t, k);
		t->waiting--;
	}
	pthread_mutex_unlock(&t->lock);
	if (waiting)
		task_free(k);
	arm_timer(t);
}
