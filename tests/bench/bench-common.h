/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Timing for benchmarks: every figure is reported as a ratio to a baseline
 * measured in the same run, so a loaded or slow machine shifts both. */
#ifndef ASPH_BENCH_COMMON_H
#define ASPH_BENCH_COMMON_H

#include <stddef.h>

double bench_now(void);   /* seconds, CLOCK_MONOTONIC */

/* Runs fn(ctx) `repeat` times and returns the median wall time in seconds. */
double bench_median(void (*fn)(void *ctx), void *ctx, int repeat);

/* Prints "name: X s (ratio R to baseline, target <= T): PASS|MISS" and
 * returns 1 when the ratio misses the target. */
int bench_report(const char *name, double seconds, double baseline,
		 double target_ratio);

/* Number of points from $ASPH_BENCH_N or the default. */
size_t bench_size(size_t dflt);

#endif
