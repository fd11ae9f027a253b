/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Tasks: what a client asks for that may take long and needs no device
 * (checking a submitted job's plan, job.estimate's plan and feed-rate
 * profile, reading a scan for the web page's live map) runs on a small
 * pool of threads, so that the loop answers the other clients meanwhile.
 * The result comes back through a mailbox (mailbox.h) and is handed to the
 * task's done() on the loop.
 *
 * Each task has a deadline: a task that has not ended by then is answered
 * -ETIMEDOUT at once (done() is called), and what its thread still
 * computes is thrown away when it ends. A task can be cancelled (its
 * client left): one not started is dropped, a running one is told through
 * task_cancelled() and its result thrown away; done() is not called.
 *
 * Shares: each task counts against its owner (a uid, an address, a token:
 * the peer's quota key) from its submission until its thread is done with
 * it, past its deadline included, so that one owner cannot fill the pool
 * with computations it has given up on. The last `reserved` threads take
 * only privileged tasks (an operator's job.submit), so that readers'
 * estimates cannot hold the submissions back.
 *
 * Event loop thread, but for run() and task_cancelled().
 */
#ifndef ASPHD_TASKS_H
#define ASPHD_TASKS_H

#include <stdbool.h>
#include <stdint.h>

#include <systemd/sd-event.h>

/* Tasks waiting for a thread at once, of all owners. */
#define TASKS_MAX_WAITING 64

struct task;
struct tasks;

struct tasks_setup {
	sd_event *event;
	unsigned threads;       /* >= 1 */
	unsigned reserved;      /* of threads, for privileged tasks; < threads */
};

struct task_spec {
	const char *owner;      /* whose share it counts against (copied) */
	bool privileged;        /* may take a reserved thread */
	unsigned max_per_owner; /* the owner's tasks at once, this one included */
	uint64_t deadline_usec; /* CLOCK_MONOTONIC */
	/* On a worker thread: the work, 0 or -errno (what done() gets). It
	 * looks at task_cancelled(task) between its stages. */
	int (*run)(void *work, const struct task *task);
	/* On the loop: run()'s result, or -ETIMEDOUT at the deadline, or
	 * -ECANCELED when the pool shuts down first. Not called after
	 * tasks_cancel(). */
	void (*done)(void *work, int r, void *data);
	/* Frees work (on the loop), once neither run() nor done() needs it. */
	void (*free)(void *work);
	void *work;
	void *data;
};

int tasks_new(const struct tasks_setup *setup, struct tasks **out);
/* Cancels every task (done(-ECANCELED) for those not answered) and waits
 * a little for the threads; one still computing then is left to end with
 * the process. */
void tasks_free(struct tasks *t);

/*
 * Queues s's task; *out (may be NULL) identifies it for tasks_cancel()
 * until done() is called. -EDQUOT when its owner has max_per_owner tasks,
 * -EAGAIN when TASKS_MAX_WAITING wait already, -ENOMEM; s->work is then
 * freed (s->free) and done() not called.
 */
int tasks_submit(struct tasks *t, const struct task_spec *s, struct task **out);
/* The task's client is gone: done() will not be called. */
void tasks_cancel(struct tasks *t, struct task *task);
/* Worker thread: whether the task's result is no longer wanted (false
 * for NULL: work run inline, without a pool). */
bool task_cancelled(const struct task *task);

/* The tasks of owner waiting or running, and of all. */
unsigned tasks_of(const struct tasks *t, const char *owner);
unsigned tasks_count(const struct tasks *t);

#endif
