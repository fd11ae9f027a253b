/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the clients' turns, first come first served. */
#include <errno.h>
#include <stdlib.h>
#include <time.h>

#include "turns.h"

/* A queue of turns, in the order they came. */
struct queue {
	struct turn *first, *last;
};

struct turns {
	sd_event_source *work;
	struct queue fresh, going;
	unsigned fresh_run;             /* fresh turns run since one that went on */
};

/* The first turn waiting runs one slice (a fresh one first, but not more
 * than TURN_FRESH_RUN in a row); it queues again, last, when it has more. */
static int work(sd_event_source *s, void *data)
{
	struct turns *t = data;
	bool fresh = t->fresh.first && (t->fresh_run < TURN_FRESH_RUN || !t->going.first);
	struct turn *turn = fresh ? t->fresh.first : t->going.first;

	t->fresh_run = fresh ? t->fresh_run + 1 : 0;
	if (turn) {
		turns_remove(t, turn);
		turn->run(turn->data);
	}
	if (turns_waiting(t))
		sd_event_source_set_enabled(t->work, SD_EVENT_ONESHOT);
	return 0;
}

int turns_new(sd_event *event, struct turns **out)
{
	struct turns *t = calloc(1, sizeof(*t));
	int r;

	if (!t)
		return -ENOMEM;
	r = sd_event_add_defer(event, &t->work, work, t);
	if (r < 0) {
		free(t);
		return r;
	}
	/* Below the sockets: bytes in and out first, then the requests. */
	sd_event_source_set_priority(t->work, SD_EVENT_PRIORITY_NORMAL + 1);
	sd_event_source_set_enabled(t->work, SD_EVENT_OFF);
	*out = t;
	return 0;
}

void turns_free(struct turns *t)
{
	if (!t)
		return;
	sd_event_source_disable_unref(t->work);
	free(t);
}

void turns_queue(struct turns *t, struct turn *turn, bool fresh)
{
	struct queue *q = fresh ? &t->fresh : &t->going;

	if (turn->queued)
		return;
	turn->queued = true;
	turn->fresh = fresh;
	turn->next = NULL;
	turn->prev = q->last;
	if (q->last)
		q->last->next = turn;
	else
		q->first = turn;
	q->last = turn;
	sd_event_source_set_enabled(t->work, SD_EVENT_ONESHOT);
}

void turns_remove(struct turns *t, struct turn *turn)
{
	struct queue *q = turn->fresh ? &t->fresh : &t->going;

	if (!turn->queued)
		return;
	if (turn->prev)
		turn->prev->next = turn->next;
	else
		q->first = turn->next;
	if (turn->next)
		turn->next->prev = turn->prev;
	else
		q->last = turn->prev;
	turn->next = turn->prev = NULL;
	turn->queued = false;
}

bool turns_waiting(const struct turns *t)
{
	return t->fresh.first || t->going.first;
}

uint64_t turns_now_usec(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}
