/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The daemon's clock: the wall-clock time and its ISO 8601 UTC form. Every
 * file of the daemon takes the time from here, so that moving to a time
 * header shared with lib/ (the same two names) is one edit. Safe from any
 * thread.
 */
#ifndef ASPHD_TIME_UTIL_H
#define ASPHD_TIME_UTIL_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <time.h>

/* CLOCK_REALTIME in nanoseconds: when something happened. */
static inline int64_t now_realtime_ns(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_REALTIME, &ts);
	return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/*
 * ns as ISO 8601 UTC, "2026-11-21T08:44:20Z", or with digits (1 to 9) of
 * the second's fraction, truncated; ns is a time after 1970.
 */
static inline void iso8601_utc(int64_t ns, int digits, char *buf, size_t size)
{
	time_t t = (time_t)(ns / 1000000000);
	long frac = (long)(ns % 1000000000);
	struct tm tm;
	size_t n;

	gmtime_r(&t, &tm);
	n = strftime(buf, size, "%Y-%m-%dT%H:%M:%S", &tm);
	if (digits > 0 && digits <= 9) {
		for (int k = digits; k < 9; k++)
			frac /= 10;
		n += (size_t)snprintf(buf + n, size > n ? size - n : 0, ".%0*ld", digits, frac);
	}
	if (n < size)
		snprintf(buf + n, size - n, "Z");
}

#endif
