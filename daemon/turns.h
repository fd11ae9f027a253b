/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Turns: the work of every client, taken in the order it came, a slice at
 * a time. A client with requests waiting (a socket connection, a request
 * of the web listener) queues its turn; one deferred source, one priority
 * below the sockets, runs the first turn for one slice (about
 * TURN_SLICE_USEC of requests, or one step of a long answer), and a turn
 * with work left queues again, last. So one batch, one long answer or one
 * busy client cannot hold the loop, and every client is served between two
 * slices of another's, whichever listener it came through.
 *
 * A turn that starts a new line is fresh: the fresh turns go before those
 * that go on with a line begun (up to TURN_FRESH_RUN of them in a row),
 * so that a short request waits for a few slices, not for a slice of each
 * of the many long answers being made. Event loop thread.
 */
#ifndef ASPHD_TURNS_H
#define ASPHD_TURNS_H

#include <stdbool.h>
#include <stdint.h>

#include <systemd/sd-event.h>

/* One turn: requests answered until this much time has passed (the one
 * that passes it is finished), at most this many. */
#define TURN_SLICE_USEC 2000
#define TURN_SLICE_STEPS 64
/* Fresh turns run in a row at most before a turn that goes on. */
#define TURN_FRESH_RUN 8

struct turn {
	struct turn *next, *prev;       /* turns.c's */
	bool queued;                    /* turns.c's */
	bool fresh;                     /* turns.c's: in the fresh queue */
	/* One slice of the owner's work; it calls turns_queue() again when
	 * work is left. */
	void (*run)(void *data);
	void *data;
};

struct turns;

int turns_new(sd_event *event, struct turns **out);
void turns_free(struct turns *t);

/* turn waits for its turn, last of the fresh ones or of those that go on
 * (nothing when it waits already). */
void turns_queue(struct turns *t, struct turn *turn, bool fresh);
/* turn no longer waits (nothing when it does not). */
void turns_remove(struct turns *t, struct turn *turn);
/* Whether any turn waits. */
bool turns_waiting(const struct turns *t);

/* CLOCK_MONOTONIC now in microseconds: the time a slice has taken, not
 * the loop's time of its last wake-up. */
uint64_t turns_now_usec(void);

#endif
