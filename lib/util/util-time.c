/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>

#include "util-time.h"

void iso8601_utc(int64_t ns, int digits, char *buf, size_t size)
{
	struct timespec ts = timespec_from_ns(ns);
	struct tm tm;
	char day[32];
	long frac = ts.tv_nsec;

	if (!gmtime_r(&ts.tv_sec, &tm) ||
	    !strftime(day, sizeof(day), "%Y-%m-%dT%H:%M:%S", &tm)) {
		snprintf(buf, size, "@%lld", (long long)ns);
		return;
	}
	if (digits <= 0) {
		snprintf(buf, size, "%sZ", day);
		return;
	}
	if (digits > 9)
		digits = 9;
	for (int d = digits; d < 9; d++)
		frac /= 10;
	snprintf(buf, size, "%s.%0*ldZ", day, digits, frac);
}
