/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread: the operator locks of the instruments. Taken and
 * given back (instrument.lock, instrument.unlock), restored at the start,
 * the pause of the locked instrument's job and its resumption, and the
 * refusal of another's change on a locked instrument.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "jobs-internal.h"
#include "locks-store.h"
#include "log.h"
#include "util-time.h"

/* ------------------------------------------------------------ locks */

void jobs_lock_release(struct slot *sl)
{
	free(sl->lock.holder);
	free(sl->lock.reason);
	sl->lock = (struct instrument_lock){ 0 };
	sl->act.lock = NULL;
}

static int lock_take(struct slot *sl, const struct store_lock *l)
{
	struct instrument_lock lk = {
		.holder = strdup(l->holder), .holder_uid = l->holder_uid,
		.reason = strdup(l->reason), .since_ns = l->since_ns, .pause = l->pause,
		.paused_job = l->paused_job,
	};

	if (!lk.holder || !lk.reason) {
		free(lk.holder);
		free(lk.reason);
		return -ENOMEM;
	}
	jobs_lock_release(sl);
	sl->lock = lk;
	sl->act.lock = &sl->lock;
	return 0;
}

static int restore_lock(const struct store_lock *l, void *data)
{
	struct jobs *jobs = data;
	struct slot *sl = jobs_slot_of_instrument(jobs, l->instrument);

	if (!sl) {
		log_warning("a lock on instrument %s, which is no longer configured, is ignored",
			    l->instrument);
		return 0;
	}
	log_notice("instrument %s is locked by %s since the last run: %s", l->instrument,
		   l->holder, l->reason);
	return lock_take(sl, l);
}

/* The locks outlive a restart. */
int jobs_load_locks(struct jobs *jobs, struct asph_error *err)
{
	int r = store_lock_list(jobs->store, restore_lock, jobs);

	return r < 0 ? asph_error_set(err, r, "cannot read the instrument locks: %s",
				      strerror(-r)) : 0;
}

static bool lock_held_by(const struct instrument_lock *l, const struct job_actor *who)
{
	return who && l->holder_uid == who->uid && !strcmp(l->holder, who->name);
}

/* -EBUSY when sl is locked by someone other than who: err says by whom and
 * why, its field names the instrument. */
int jobs_check_lock(const struct slot *sl, const struct job_actor *who,
		    struct asph_error *err)
{
	char since[ISO8601_SIZE];

	if (!sl || !sl->act.lock || lock_held_by(&sl->lock, who))
		return 0;
	iso8601_utc(sl->lock.since_ns, 0, since, sizeof(since));
	asph_error_set(err, -EBUSY, "instrument %s is locked by %s since %s: %s",
		       sl->in->name, sl->lock.holder, since, sl->lock.reason);
	asph_error_locate(err, NULL, 0, 0, sl->in->name);
	return -EBUSY;
}

/* A lock that asks for it pauses the running job of sl (not one whose
 * points are all recorded): 1 when it did. */
static int pause_for_lock(struct jobs *jobs, struct slot *sl, const struct job_actor *who,
			  struct asph_error *err)
{
	char reason[600];
	struct job_record j;
	int r;

	if (!sl->act.job || sl->act.paused || sl->act.characterizing)
		return 0;
	r = jobs_load(jobs, sl->act.job, &j, err);
	if (r < 0)
		return r;
	snprintf(reason, sizeof(reason), "instrument %s locked by %s: %s", sl->in->name,
		 who->name, sl->lock.reason);
	r = j.state == JOB_RUNNING ? jobs_set_paused(jobs, &j, sl, true, reason, who, err) : 0;
	if (r == 0 && j.state == JOB_PAUSED)
		r = 1;
	job_record_clear(&j);
	return r;
}

static int write_lock(struct jobs *jobs, struct slot *sl, struct asph_error *err)
{
	struct store_lock l = {
		.instrument = sl->in->name, .holder = sl->lock.holder,
		.holder_uid = sl->lock.holder_uid, .reason = sl->lock.reason,
		.since_ns = sl->lock.since_ns, .pause = sl->lock.pause,
		.paused_job = sl->lock.paused_job,
	};
	int r = store_lock_set(jobs->store, &l);

	return r < 0 ? asph_error_set(err, r, "cannot record the lock of %s: %s", sl->in->name,
				      strerror(-r)) : 0;
}

int jobs_lock(struct jobs *jobs, const char *instrument, const char *reason, bool pause,
	      const struct job_actor *who, struct asph_error *err)
{
	struct slot *sl = jobs_slot_of_instrument(jobs, instrument);
	bool renewed;
	struct store_lock l = {
		.instrument = instrument, .holder = who->name, .holder_uid = who->uid,
		.reason = reason, .since_ns = now_realtime_ns(), .pause = pause,
	};
	int r;

	if (!sl)
		return asph_error_set(err, -ENODEV, "no instrument \"%s\"", instrument);
	r = jobs_check_lock(sl, who, err);
	if (r < 0)
		return r;
	renewed = sl->act.lock != NULL;
	if (renewed) {
		/* The holder changes the reason or the pause: the lock keeps its start. */
		l.since_ns = sl->lock.since_ns;
		l.paused_job = sl->lock.paused_job;
	}
	r = lock_take(sl, &l);
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	r = write_lock(jobs, sl, err);
	if (r < 0) {
		jobs_lock_release(sl);
		return r;
	}
	log_notice("instrument %s %slocked by %s%s: %s", instrument, renewed ? "re-" : "",
		   who->name, pause ? " (pausing its job)" : "", reason);
	if (pause) {
		int64_t job = sl->act.job;
		r = pause_for_lock(jobs, sl, who, err);
		if (r < 0)
			return r;
		if (r > 0 && sl->lock.paused_job != job) {
			sl->lock.paused_job = job;
			write_lock(jobs, sl, NULL);
		}
	}
	events_instrument_lock(jobs->events, instrument, &sl->lock);
	return 0;
}

/*
 * The job a lock paused runs again when the lock goes: resumed if it still
 * waits, re-queued where it stopped if someone stopped it meanwhile (a
 * queue.stop with abort makes it interrupted): it was held for the lock,
 * not given up. A re-queued job waits for the queue to run.
 */
static void resume_after_lock(struct jobs *jobs, struct slot *sl, int64_t id,
			      const struct job_actor *who)
{
	struct job_record j;

	if (!id || jobs_load(jobs, id, &j, NULL) < 0)
		return;
	if (j.state == JOB_PAUSED && sl->act.job == id && sl->act.paused) {
		jobs_set_paused(jobs, &j, sl, false, NULL, who, NULL);
	} else if (j.state == JOB_INTERRUPTED) {
		log_job(LOG_NOTICE, id, "re-queued at the end of the lock of %s: it was paused by "
			"the lock and stopped meanwhile", sl->in->name);
		jobs_back_to_queue(jobs, &j, !j.resume, who, NULL);
	}
	job_record_clear(&j);
}

int jobs_unlock(struct jobs *jobs, const char *instrument, bool force,
		const struct job_actor *who, struct asph_error *err)
{
	struct slot *sl = jobs_slot_of_instrument(jobs, instrument);
	int64_t paused;
	int r;

	if (!sl)
		return asph_error_set(err, -ENODEV, "no instrument \"%s\"", instrument);
	if (!sl->act.lock)
		return asph_error_set(err, -EINVAL, "instrument %s is not locked", instrument);
	if (!force && (r = jobs_check_lock(sl, who, err)) < 0)
		return r;
	r = store_lock_clear(jobs->store, instrument);
	if (r < 0)
		return asph_error_set(err, r, "cannot record the end of the lock of %s: %s",
				      instrument, strerror(-r));
	log_notice("instrument %s unlocked by %s%s (locked by %s: %s)", instrument, who->name,
		   lock_held_by(&sl->lock, who) ? "" : ", forced", sl->lock.holder, sl->lock.reason);
	paused = sl->lock.paused_job;
	jobs_lock_release(sl);
	events_instrument_lock(jobs->events, instrument, NULL);
	resume_after_lock(jobs, sl, paused, who);
	jobs_schedule(jobs);
	return 0;
}

const struct instrument_lock *jobs_lock_of(const struct jobs *jobs, const char *instrument)
{
	const struct slot *sl = jobs_slot_of_instrument_name(jobs, instrument);

	return sl ? sl->act.lock : NULL;
}
