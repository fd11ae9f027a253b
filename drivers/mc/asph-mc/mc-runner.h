/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_MC_RUNNER_H
#define ASPH_MC_RUNNER_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/progress.h"
#include "asph/uncertainty.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The Monte Carlo of libasph (asph/uncertainty.h) on threads of this
 * program: what `asph fit --uncertainty` and asphd share. The trials are
 * handed out one at a time to n_threads workers, each with its own
 * asph_mc_worker allocated once per run; the caller's thread only waits,
 * asks libasph for the next block and reports progress. The result is the
 * same bit for bit for any number of threads.
 */

/*
 * Progress (asph/progress.h), called on the thread that runs
 * asph_mc_run_threads() (never on a worker) after trials complete: done of
 * planned (planned grows when the adaptive stop asks for another block). A
 * non-zero return cancels the run: no trial starts after it, those running
 * finish.
 */
typedef asph_progress_fn asph_mc_progress_fn;

struct asph_mc_threads {
	int n_threads;          /* workers, 1..256; 0 = the online processors */
	asph_mc_progress_fn progress;   /* may be NULL */
	void *progress_data;
};

/* The online processors, 1..256: the default number of workers. */
int asph_mc_default_threads(void);

/*
 * Runs mc to its end (asph_mc_next_block() until complete) and puts the
 * statistics into out. opts may be NULL (the defaults). -EINVAL for a bad
 * number of threads, -ENOMEM, -EAGAIN when a thread could not be started;
 * else what asph_mc_finish() returns: -ECANCELED when the progress
 * callback cancelled (out then holds the statistics of the trials done),
 * -EDOM when more than half of the trials failed.
 */
int asph_mc_run_threads(struct asph_mc *mc, const struct asph_mc_threads *opts,
			struct asph_mc_result *out, struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
