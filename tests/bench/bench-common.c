/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "bench-common.h"

double bench_now(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int cmp_double(const void *a, const void *b)
{
	double x = *(const double *)a, y = *(const double *)b;

	return (x > y) - (x < y);
}

double bench_median(void (*fn)(void *ctx), void *ctx, int repeat)
{
	double t[64];

	if (repeat < 1)
		repeat = 1;
	if (repeat > 64)
		repeat = 64;
	for (int i = 0; i < repeat; i++) {
		double t0 = bench_now();
		fn(ctx);
		t[i] = bench_now() - t0;
	}
	qsort(t, (size_t)repeat, sizeof(t[0]), cmp_double);
	return t[repeat / 2];
}

int bench_report(const char *name, double seconds, double baseline,
		 double target_ratio)
{
	double ratio = seconds / baseline;
	int miss = target_ratio > 0 && ratio > target_ratio;

	printf("%-40s %10.4f s  ratio %8.3f", name, seconds, ratio);
	if (target_ratio > 0)
		printf("  (target <= %g): %s", target_ratio, miss ? "MISS" : "PASS");
	printf("\n");
	fflush(stdout);
	return miss;
}

size_t bench_size(size_t dflt)
{
	const char *s = getenv("ASPH_BENCH_N");

	if (s && *s) {
		char *end;
		unsigned long long v = strtoull(s, &end, 10);
		if (*end == '\0' && v > 0)
			return (size_t)v;
	}
	return dflt;
}
