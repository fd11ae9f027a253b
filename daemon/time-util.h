/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The daemon's clock: the wall-clock time and its ISO 8601 UTC form. Every
 * file of the daemon takes the time from here, so that moving to a shared
 * time header is one edit. Safe from any thread.
 */
#ifndef ASPHD_TIME_UTIL_H
#define ASPHD_TIME_UTIL_H

#include <stddef.h>
#include <stdint.h>
#include <time.h>

/* Nanoseconds since the epoch (CLOCK_REALTIME). */
static inline int64_t realtime_now_ns(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_REALTIME, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/* The second of ns as "2026-11-21T08:44:20Z"; size 21 or more holds it. */
static inline void iso8601_utc(int64_t ns, char *buf, size_t size)
{
	time_t t = (time_t)(ns / 1000000000);
	struct tm tm;

	gmtime_r(&t, &tm);
	strftime(buf, size, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

#endif
