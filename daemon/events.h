/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What happens in the daemon, told to whoever watches. A module that
 * changes state calls the builder of its notification (proto/README.md,
 * "Events"); the builder hands it to every watch on the list, in the order
 * they were added. Consumers add themselves: main.c plugs in the socket
 * server and the systemd status line, and a later consumer (an MQTT
 * publisher, a web page) adds its own watch without any builder knowing.
 * Nothing here calls a consumer by name.
 *
 * The subscriptions of clients (the classes and job a connection asked
 * for with events.subscribe) are counted here too, and only here: each
 * subscription records whether it counts, so ending one twice is harmless.
 *
 * Event loop thread.
 */
#ifndef ASPHD_EVENTS_H
#define ASPHD_EVENTS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "job.h"

/* Classes of events, as a client subscribes to them. */
enum event_class {
	EVENT_JOB = 1u << 0,            /* job.state */
	EVENT_PROGRESS = 1u << 1,       /* job.progress */
	EVENT_INSTRUMENT = 1u << 2,     /* instrument.fault, instrument.lock */
	EVENT_QUEUE = 1u << 3,          /* queue.state */
};
#define EVENT_ALL (EVENT_JOB | EVENT_PROGRESS | EVENT_INSTRUMENT | EVENT_QUEUE)

/* The classes' names, bit k named by [k], NULL-terminated: "job",
 * "progress", "instrument", "queue". */
extern const char *const event_class_names[];

/* One notification, valid while the watches are told. */
struct event {
	enum event_class class;
	int64_t job;            /* the job it is about, 0 for none */
	const char *method;     /* "job.state", ...: the notification's name */
	json_t *params;         /* borrowed: a watch that keeps it takes a reference */
};

typedef void (*event_watch_fn)(const struct event *ev, void *data);
typedef void (*event_destroy_fn)(void *data);

struct events;

int events_new(struct events **out);
/* Removes every watch (calling its destroy) and frees e. */
void events_free(struct events *e);

/*
 * Adds fn to the watch list for the classes given (EVENT_*); destroy (may
 * be NULL) is called with data when the watch is removed. Returns the
 * watch's id (> 0) or -ENOMEM. A watch may add and remove watches, itself
 * included, while it is told: one removed is not told again, one added is
 * told from the next event on.
 */
int events_watch_add(struct events *e, unsigned classes, event_watch_fn fn, void *data,
		     event_destroy_fn destroy);
/* 0, or -ENOENT when there is no such watch. */
int events_watch_remove(struct events *e, int id);

/* --- the builders, one per notification */

/* job.state: job id went from previous (< 0: a new job) to state, on
 * instrument; reason may be NULL; verdict ("pass", "fail", "undecided")
 * is NULL unless a completed job had a tolerance. */
void events_job_state(struct events *e, int64_t id, enum job_state state, int previous,
		      const char *reason, const char *instrument, const char *verdict);
/* job.progress of job id on instrument, doing a (its progress object:
 * activity_progress_to_json()). */
struct instrument_activity;
void events_job_progress(struct events *e, int64_t id, const char *instrument,
			 const struct instrument_activity *a);
/* instrument.fault: a driver fault on instrument ended job id. */
void events_instrument_fault(struct events *e, const char *instrument, int64_t id,
			     const char *reason);
/* instrument.lock: instrument was locked (lock) or unlocked (NULL). */
struct instrument_lock;
void events_instrument_lock(struct events *e, const char *instrument,
			    const struct instrument_lock *lock);
/* queue.state: the queue was started or stopped. */
void events_queue_state(struct events *e, bool running);

/* --- the subscriptions of clients */

/* Written by events.c only: read it, never set it. */
struct event_subscription {
	unsigned classes;       /* EVENT_*; 0: not subscribed */
	int64_t job;            /* only this job's job and progress events; 0: all */
	const char *owner;      /* whom it counts against (the quota's owner,
				   which must outlive it) */
};

/* What a subscription that starts is counted against. */
struct event_quota {
	const char *owner;      /* the subscriber: "uid N", "tcp ADDRESS" */
	bool operator;          /* may take the subscriptions kept for operators */
	unsigned max;           /* subscriptions in all */
	unsigned per_owner;     /* of one owner */
	unsigned reserved;      /* the last ones of max, for operators */
};

/*
 * Sets s to classes and job; classes 0 ends it (as events_unsubscribe). A
 * subscription that starts counts against q: -EUSERS when max are counted
 * (for one that is not an operator's: max - reserved), -EDQUOT when its
 * owner has per_owner already (s is then unchanged).
 */
int events_subscribe(struct events *e, struct event_subscription *s, unsigned classes,
		     int64_t job, const struct event_quota *q);
/* Ends s; ending an ended subscription changes nothing. */
void events_unsubscribe(struct events *e, struct event_subscription *s);
/* Whether ev is one that s asked for. */
bool events_subscription_matches(const struct event_subscription *s, const struct event *ev);
/* The number of subscriptions counted, in all and of one owner. */
size_t events_subscriptions(const struct events *e);
size_t events_subscriptions_of(const struct events *e, const char *owner);

#endif
