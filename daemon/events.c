/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the watch list, the builders, the subscriptions. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "events.h"
#include "instruments.h"
#include "util-mem.h"

const char *const event_class_names[] = { "job", "progress", "instrument", "queue", NULL };

struct watch {
	int id;
	unsigned classes;
	event_watch_fn fn;      /* NULL: removed while the list was told */
	void *data;
	event_destroy_fn destroy;
};

/* The subscriptions of one owner. */
struct owner_count {
	char key[64];
	size_t n;
};

struct events {
	struct watch *watches;
	size_t n, cap;
	int next_id;
	unsigned notifying;     /* depth of nested notifications */
	bool stale;             /* removed watches wait for the end of it */
	size_t n_subscribed;
	struct owner_count *owners;     /* those with one or more */
	size_t n_owners, cap_owners;
};

int events_new(struct events **out)
{
	struct events *e = calloc(1, sizeof(*e));

	if (!e)
		return -ENOMEM;
	*out = e;
	return 0;
}

static void watch_destroy(struct watch *w)
{
	if (w->destroy)
		w->destroy(w->data);
}

void events_free(struct events *e)
{
	if (!e)
		return;
	for (size_t i = 0; i < e->n; i++)
		if (e->watches[i].fn)
			watch_destroy(&e->watches[i]);
	free(e->watches);
	free(e->owners);
	free(e);
}

int events_watch_add(struct events *e, unsigned classes, event_watch_fn fn, void *data,
		     event_destroy_fn destroy)
{
	if (e->n == e->cap) {
		size_t cap = e->cap ? 2 * e->cap : 4;
		struct watch *w = realloc(e->watches, cap * sizeof(*w));
		if (!w)
			return -ENOMEM;
		e->watches = w;
		e->cap = cap;
	}
	e->watches[e->n++] = (struct watch){
		.id = ++e->next_id, .classes = classes, .fn = fn, .data = data, .destroy = destroy,
	};
	return e->next_id;
}

/* Drops the watches removed while the list was told. */
static void prune(struct events *e)
{
	size_t k = 0;

	for (size_t i = 0; i < e->n; i++)
		if (e->watches[i].fn)
			e->watches[k++] = e->watches[i];
	e->n = k;
	e->stale = false;
}

int events_watch_remove(struct events *e, int id)
{
	for (size_t i = 0; i < e->n; i++) {
		struct watch *w = &e->watches[i];
		if (w->id != id || !w->fn)
			continue;
		watch_destroy(w);
		w->fn = NULL;
		if (e->notifying)
			e->stale = true;
		else
			prune(e);
		return 0;
	}
	return -ENOENT;
}

static bool wanted(const struct events *e, unsigned class)
{
	for (size_t i = 0; i < e->n; i++)
		if (e->watches[i].fn && (e->watches[i].classes & class))
			return true;
	return false;
}

/* Tells the watches of ev's class; steals params. */
static void notify(struct events *e, enum event_class class, int64_t job, const char *method,
		   json_t *params)
{
	struct event ev = { .class = class, .job = job, .method = method, .params = params };
	size_t n = e->n;

	if (!params)
		return;
	e->notifying++;
	/* By index: a watch may add others, which moves the array. */
	for (size_t i = 0; i < n; i++) {
		struct watch w = e->watches[i];
		if (w.fn && (w.classes & class))
			w.fn(&ev, w.data);
	}
	if (--e->notifying == 0 && e->stale)
		prune(e);
	json_decref(params);
}

void events_job_state(struct events *e, int64_t id, enum job_state state, int previous,
		      const char *reason, const char *instrument, const char *verdict)
{
	if (!wanted(e, EVENT_JOB))
		return;
	notify(e, EVENT_JOB, id, "job.state",
	       json_pack("{s:I, s:s, s:o, s:s?, s:s, s:s?}", "job", (json_int_t)id,
			 "state", job_state_name(state),
			 "previous", previous < 0 ? json_null()
				     : json_string(job_state_name((enum job_state)previous)),
			 "reason", reason, "instrument", instrument, "verdict", verdict));
}

void events_job_progress(struct events *e, int64_t id, const char *instrument,
			 const struct instrument_activity *a)
{
	json_t *params;

	if (!wanted(e, EVENT_PROGRESS))
		return;
	params = json_pack("{s:I, s:s}", "job", (json_int_t)id, "instrument", instrument);
	if (params && json_object_update_new(params, activity_progress_to_json(a)) < 0) {
		json_decref(params);
		params = NULL;
	}
	notify(e, EVENT_PROGRESS, id, "job.progress", params);
}

void events_instrument_fault(struct events *e, const char *instrument, int64_t id,
			     const char *reason)
{
	if (!wanted(e, EVENT_INSTRUMENT))
		return;
	notify(e, EVENT_INSTRUMENT, 0, "instrument.fault",
	       json_pack("{s:s, s:I, s:s}", "instrument", instrument, "job", (json_int_t)id,
			 "reason", reason));
}

void events_instrument_lock(struct events *e, const char *instrument,
			    const struct instrument_lock *lock)
{
	if (!wanted(e, EVENT_INSTRUMENT))
		return;
	notify(e, EVENT_INSTRUMENT, 0, "instrument.lock",
	       json_pack("{s:s, s:o}", "instrument", instrument,
			 "lock", instrument_lock_to_json(lock)));
}

void events_queue_state(struct events *e, bool running)
{
	if (!wanted(e, EVENT_QUEUE))
		return;
	notify(e, EVENT_QUEUE, 0, "queue.state", json_pack("{s:b}", "running", running));
}

/* ------------------------------------------------------ subscriptions */

static struct owner_count *owner_find(const struct events *e, const char *key)
{
	for (size_t i = 0; i < e->n_owners; i++)
		if (!strncmp(e->owners[i].key, key, sizeof(e->owners[i].key) - 1))
			return &e->owners[i];
	return NULL;
}

static int owner_add(struct events *e, const char *key)
{
	struct owner_count *o = owner_find(e, key);

	if (!o) {
		if (e->n_owners == e->cap_owners) {
			size_t cap = e->cap_owners ? 2 * e->cap_owners : 8;
			o = realloc(e->owners, cap * sizeof(*o));
			if (!o)
				return -ENOMEM;
			e->owners = o;
			e->cap_owners = cap;
		}
		o = &e->owners[e->n_owners++];
		*o = (struct owner_count){ 0 };
		snprintf(o->key, sizeof(o->key), "%s", key);
	}
	o->n++;
	return 0;
}

static void owner_remove(struct events *e, const char *key)
{
	struct owner_count *o = owner_find(e, key);

	if (o && --o->n == 0)
		*o = e->owners[--e->n_owners];
}

int events_subscribe(struct events *e, struct event_subscription *s, unsigned classes,
		     int64_t job, const struct event_quota *q)
{
	classes &= EVENT_ALL;
	if (!classes) {
		events_unsubscribe(e, s);
		s->job = job;
		return 0;
	}
	if (!s->classes) {
		const struct owner_count *o = owner_find(e, q->owner);
		unsigned open_to_all = q->max > q->reserved ? q->max - q->reserved : 0;
		if (e->n_subscribed >= (q->operator ? q->max : open_to_all))
			return -EUSERS;
		if (o && o->n >= q->per_owner)
			return -EDQUOT;
		if (owner_add(e, q->owner) < 0)
			return -ENOMEM;
		e->n_subscribed++;
		s->owner = q->owner;
	}
	s->classes = classes;
	s->job = job;
	return 0;
}

void events_unsubscribe(struct events *e, struct event_subscription *s)
{
	if (s->classes) {
		e->n_subscribed--;
		owner_remove(e, s->owner);
	}
	s->classes = 0;
	s->job = 0;
	s->owner = NULL;
}

bool events_subscription_matches(const struct event_subscription *s, const struct event *ev)
{
	if (!(s->classes & ev->class))
		return false;
	return !ev->job || !s->job || s->job == ev->job;
}

size_t events_subscriptions(const struct events *e)
{
	return e->n_subscribed;
}

size_t events_subscriptions_of(const struct events *e, const char *owner)
{
	const struct owner_count *o = owner_find(e, owner);

	return o ? o->n : 0;
}
