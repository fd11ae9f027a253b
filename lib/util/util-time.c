/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdio.h>
#include <string.h>

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

void iso8601_basic_utc(int64_t ns, char *buf, size_t size)
{
	struct timespec ts = timespec_from_ns(ns);
	struct tm tm;

	if (!gmtime_r(&ts.tv_sec, &tm) || !strftime(buf, size, "%Y%m%dT%H%M%SZ", &tm))
		snprintf(buf, size, "@%lld", (long long)ns);
}

int iso8601_parse_utc(const char *text, int64_t *ns)
{
	static const char *const forms[] = { "%Y-%m-%dT%H:%M:%SZ", "%Y-%m-%d" };
	struct tm tm;

	for (size_t i = 0; i < sizeof(forms) / sizeof(forms[0]); i++) {
		const char *end;
		memset(&tm, 0, sizeof(tm));
		end = strptime(text, forms[i], &tm);
		if (end && !*end) {
			time_t t = timegm(&tm);
			if (t == (time_t)-1 || t > INT64_MAX / NS_PER_SEC)
				return -ERANGE;
			*ns = (int64_t)t * NS_PER_SEC;
			return 0;
		}
	}
	return -EINVAL;
}
