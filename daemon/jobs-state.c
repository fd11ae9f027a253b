/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread: the one place a job changes state (jobs_transition()),
 * a job read for a change, and the instruments' slots.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "jobs-internal.h"
#include "log.h"
#include "store.h"
#include "util-time.h"
#include "util-mem.h"

struct slot *jobs_slot_of_instrument(struct jobs *jobs, const char *name)
{
	for (size_t i = 0; i < jobs->n_slots; i++)
		if (!strcmp(jobs->slots[i].in->name, name))
			return &jobs->slots[i];
	return NULL;
}

struct slot *jobs_slot_of_job(struct jobs *jobs, int64_t id)
{
	for (size_t i = 0; i < jobs->n_slots; i++)
		if (jobs->slots[i].act.job == id)
			return &jobs->slots[i];
	return NULL;
}

const struct slot *jobs_slot_of_instrument_name(const struct jobs *jobs, const char *name)
{
	return jobs_slot_of_instrument((struct jobs *)jobs, name);
}

/*
 * A store write that must not be lost to a full disk, such as how a job
 * ended: on -ENOSPC the store's reserve is given up once and the write
 * tried again.
 */
static int write_essential(struct jobs *jobs, int64_t id, const char *what,
			   int (*write)(struct store *s, const void *arg), const void *arg)
{
	int r = write(jobs->store, arg);

	if (r == -ENOSPC && store_release_reserve(jobs->store) == 0) {
		log_job(LOG_WARNING, id, "the state directory is full: using the store's reserve "
			"to record %s", what);
		r = write(jobs->store, arg);
	}
	return r;
}

struct transition {
	const struct job_record *j;
	enum job_state state;
	const char *reason;
	const struct job_actor *who;    /* NULL: the daemon */
};

static int write_transition(struct store *s, const void *arg)
{
	const struct transition *t = arg;

	return store_transition(s, t->j, t->state, t->reason, t->who ? t->who->uid : 0,
				t->who ? t->who->name : NULL, now_realtime_ns());
}

/* The overall verdict of a completed job's result ("pass", "fail",
 * "undecided") in buf, or NULL when it had no tolerance. */
const char *jobs_verdict(const struct job_record *j, char buf[16])
{
	_cleanup_(json_decrefp) json_t *res = NULL;
	const char *v;

	if (j->state != JOB_COMPLETED || !j->result)
		return NULL;
	res = json_loads(j->result, 0, NULL);
	v = json_string_value(json_object_get(json_object_get(json_object_get(res, "summary"),
							      "verdict"), "overall"));
	if (!v)
		return NULL;
	snprintf(buf, 16, "%s", v);
	return buf;
}

/*
 * The one place a job changes state: j (with its other columns as they
 * are in j) is recorded in the new state, counted, logged and told to the
 * watchers. reason may be NULL.
 */
int jobs_transition(struct jobs *jobs, struct job_record *j, enum job_state s,
		    const char *reason, const struct job_actor *who, struct asph_error *err)
{
	struct transition t = { .j = j, .state = s, .reason = reason, .who = who };
	enum job_state old = j->state;
	char what[64], verdict[16];
	int r;

	snprintf(what, sizeof(what), "the state %s", job_state_name(s));
	r = write_essential(jobs, j->id, what, write_transition, &t);
	if (r < 0) {
		log_job(LOG_ERR, j->id, "cannot record the state %s: %s", job_state_name(s),
			strerror(-r));
		return asph_error_set(err, r, "cannot record the state %s of job %" PRId64 ": %s",
				      job_state_name(s), j->id, strerror(-r));
	}
	jobs->counts[old]--;
	jobs->counts[s]++;
	j->state = s;
	/* As the store keeps it: a return to the queue clears the reason. */
	if (reason || s == JOB_QUEUED) {
		free(j->reason);
		j->reason = reason ? strdup(reason) : NULL;
	}
	log_job(s == JOB_FAILED ? LOG_WARNING : LOG_INFO, j->id, "%s -> %s%s%s%s%s",
		job_state_name(old), job_state_name(s), reason ? ": " : "", reason ? reason : "",
		who ? " by " : "", who ? who->name : "");
	events_job_state(jobs->events, j->id, s, (int)old, reason, j->instrument,
			 s == JOB_COMPLETED ? jobs_verdict(j, verdict) : NULL);
	return 0;
}

/* Reads job id for a change. */
int jobs_load(struct jobs *jobs, int64_t id, struct job_record *j, struct asph_error *err)
{
	int r = store_get(jobs->store, id, j);

	if (r == -ENOENT)
		return asph_error_set(err, r, "no job %" PRId64, id);
	if (r < 0)
		return asph_error_set(err, r, "cannot read job %" PRId64 ": %s", id, strerror(-r));
	return 0;
}

/* Back to the queue; with restart a new recording. */
int jobs_back_to_queue(struct jobs *jobs, struct job_record *j, bool restart,
		       const struct job_actor *who, struct asph_error *err)
{
	if (restart)
		j->resume = false;
	j->finished_ns = 0;
	return jobs_transition(jobs, j, JOB_QUEUED, NULL, who, err);
}
