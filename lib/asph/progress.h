/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_PROGRESS_H
#define ASPH_PROGRESS_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The progress of a long computation (a CVT plan's iterations, a fit's
 * steps, the Monte Carlo's trials), reported to the caller, who shows it:
 * libasph does no I/O. Called on the caller's thread now and then with the
 * work done so far of total, in the computation's own unit; total is an
 * upper bound where the end is not known in advance (it may grow), 0 when
 * there is none; done = total once the counted work is over and only its
 * last step (statistics, ordering) is left. A non-zero return asks the
 * computation to stop: it then returns -ECANCELED.
 */
typedef int (*asph_progress_fn)(void *data, size_t done, size_t total);

struct asph_progress {
	asph_progress_fn fn;    /* NULL: nobody asks */
	void *data;
};

#ifdef __cplusplus
}
#endif

#endif
