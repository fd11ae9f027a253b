/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The configured instruments (each a stage and a probe driver with their
 * options) and the driver registry they come from. Loaded once from the
 * settings and not changed afterwards; what an instrument is doing is the
 * job queue's to say (jobs.h), here only described. Event loop thread.
 */
#ifndef ASPHD_INSTRUMENTS_H
#define ASPHD_INSTRUMENTS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "asph/error.h"
#include "settings.h"

struct asph_instrument_config;

struct instrument {
	char *name;
	json_t *description;    /* the drivers and every option (instrument.list) */
	const struct asph_instrument_config *config;
};

/* An operator's lock on an instrument (instrument.lock). */
struct instrument_lock {
	char *holder;           /* the user or token name */
	int64_t holder_uid;     /* -1 over TCP */
	char *reason;
	int64_t since_ns;
	bool pause;             /* its running job pauses while it holds */
	int64_t paused_job;     /* the job it paused, 0: none */
};

/* The lock as the protocol shows it: holder, uid, reason, since, pause;
 * null when l is NULL. */
json_t *instrument_lock_to_json(const struct instrument_lock *l);

/* What an instrument is doing: written by the job queue (jobs-run.c, jobs-locks.c). */
struct instrument_activity {
	int64_t job;            /* running or paused job, 0 if none */
	bool paused;
	bool planning;          /* its plan is searched for its tolerance
				   (done of total: characterizations) */
	bool characterizing;    /* its scan is recorded, the result being made */
	int64_t done, total;    /* live progress of that job: plan points */
	double rate, eta_s;     /* points/s; s left of the phase, -1: unknown */
	/* The Monte Carlo uncertainty of the characterization, once it runs
	 * (trials_planned > 0): trials done of those planned so far, the
	 * trials per second since it started. */
	int64_t trials_done, trials_planned;
	double trials_rate;
	const char *fault;      /* the last driver fault, or NULL */
	const struct instrument_lock *lock;     /* NULL: not locked */
	int64_t points_measured;        /* since the daemon started, all jobs */
};

struct instruments;

/*
 * The driver registry (built-in drivers and plugins) and the instruments
 * of s (the one "mock" instrument when s names none). An error in the
 * instruments names its place in the settings file.
 */
int instruments_load(const struct settings *s, struct instruments **out, struct asph_error *err);
void instruments_free(struct instruments *ins);

size_t instruments_count(const struct instruments *ins);
const struct instrument *instruments_get(const struct instruments *ins, size_t i);
/* The index of the instrument called name, or -ENOENT. */
int instruments_find(const struct instruments *ins, const char *name);

/* "idle", "measuring", "paused" or "fault". */
const char *instrument_state_name(const struct instrument_activity *a);
/* The phase of a's job: "measuring" (paused included), "characterizing",
 * "uncertainty" (the Monte Carlo of the characterization runs). */
const char *activity_phase(const struct instrument_activity *a);
/* The progress object of proto/README.md for a's running job: done,
 * total, rate, eta_s, phase and trials (null but in phase "uncertainty"). */
json_t *activity_progress_to_json(const struct instrument_activity *a);
/* The instrument object of proto/README.md. */
json_t *instrument_to_json(const struct instrument *in, const struct instrument_activity *a);
/* driver.list's result: the registry as asph drivers --json prints it. */
json_t *drivers_to_json(const struct instruments *ins);

#endif
