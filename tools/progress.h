/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The progress of a long operation on a terminal, for asph and asphctl: one
 * line on standard error, redrawn in place, once the operation has run for
 * a second, and only when standard error is a terminal and --quiet was not
 * given: "Monte Carlo: 150/200 trials (75 %), 31.2 trials/s, 0:02 left",
 * "cvt plan: 34 of at most 100 iterations, 6.1 iterations/s, at most 0:11
 * left". A pipe or a log file gets nothing.
 */
#ifndef ASPH_TOOLS_PROGRESS_H
#define ASPH_TOOLS_PROGRESS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "asph/progress.h"

struct progress {
	FILE *out;
	bool on;                /* a terminal, and not --quiet */
	const char *what;       /* "cvt plan", "fit", "Monte Carlo" */
	const char *unit;       /* "iterations", "trials" */
	bool at_most;           /* the total is an upper bound (CVT stops
				   when its sites settle) */
	uint64_t start_ns, drawn_ns;
	/* the first report: the rate counts from there, after the setup
	 * that comes before the counted work */
	uint64_t first_ns;
	size_t first_done;
	bool counting;
	bool drawn;             /* a line is on the terminal */
};

/* Starts the clock of the operation what, counted in unit. */
void progress_start(struct progress *p, const char *what, const char *unit, bool quiet);
/* asph_progress_fn: data is a struct progress. Draws done of total (0:
 * not known in advance) with the rate and the time left. Returns 0. */
int progress_show(void *data, size_t done, size_t total);
/* The library's hook for p. */
struct asph_progress progress_hook(struct progress *p);
/* Clears the line, if one was drawn. */
void progress_stop(struct progress *p);

/* A duration for people: "0:07", "12:31", "1:02:03"; "--:--" when s is
 * not a number or negative. Returns buf. */
const char *progress_duration(double s, char *buf, size_t size);

#endif
