/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
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

void iso8601_local(int64_t ns, char *buf, size_t size)
{
	struct timespec ts = timespec_from_ns(ns);
	struct tm tm;
	char day[32];
	long off;

	if (!localtime_r(&ts.tv_sec, &tm) ||
	    !strftime(day, sizeof(day), "%Y-%m-%dT%H:%M:%S", &tm)) {
		snprintf(buf, size, "@%lld", (long long)ns);
		return;
	}
	off = tm.tm_gmtoff;
	snprintf(buf, size, "%s%c%02ld:%02ld", day, off < 0 ? '-' : '+', labs(off) / 3600,
		 labs(off) % 3600 / 60);
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

static int two_digits(const char *s, unsigned *v)
{
	if (s[0] < '0' || s[0] > '9' || s[1] < '0' || s[1] > '9')
		return -EINVAL;
	*v = (unsigned)(s[0] - '0') * 10 + (unsigned)(s[1] - '0');
	return 0;
}

/* "+01:00", "-0330" or "Z" as seconds east of UTC: 0, -EINVAL. */
static int zone_offset(const char *z, long *seconds)
{
	const char *p = z + 1;
	unsigned h, m;

	if (!strcmp(z, "Z")) {
		*seconds = 0;
		return 0;
	}
	if ((z[0] != '+' && z[0] != '-') || two_digits(p, &h) < 0)
		return -EINVAL;
	p += 2;
	if (*p == ':')
		p++;
	if (two_digits(p, &m) < 0 || p[2] || h > 23 || m > 59)
		return -EINVAL;
	*seconds = (z[0] == '-' ? -1 : 1) * (long)(h * 3600 + m * 60);
	return 0;
}

int iso8601_parse_zoned(const char *text, int64_t *ns)
{
	struct tm tm;
	const char *zone;
	long offset;
	time_t t;

	memset(&tm, 0, sizeof(tm));
	zone = strptime(text, "%Y-%m-%dT%H:%M:%S", &tm);
	if (!zone || zone_offset(zone, &offset) < 0)
		return -EINVAL;
	t = timegm(&tm);
	if (t == (time_t)-1 || t - offset > INT64_MAX / NS_PER_SEC || t - offset < 0)
		return -ERANGE;
	*ns = (int64_t)(t - offset) * NS_PER_SEC;
	return 0;
}
