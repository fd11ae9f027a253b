/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Time, the one way the tree reads and writes it: now on the wall clock and
 * on the monotonic clock, in ns, and ISO 8601 in UTC. Internal header. */
#ifndef ASPH_UTIL_TIME_H
#define ASPH_UTIL_TIME_H

#include <stdint.h>
#include <stddef.h>
#include <time.h>

#define NS_PER_SEC 1000000000LL
#define NS_PER_MS 1000000LL

static inline int64_t ns_from_timespec(const struct timespec *ts)
{
	return (int64_t)ts->tv_sec * NS_PER_SEC + ts->tv_nsec;
}

/* ns may be negative (before 1970): tv_nsec stays in [0, 1e9). */
static inline struct timespec timespec_from_ns(int64_t ns)
{
	struct timespec ts = { .tv_sec = (time_t)(ns / NS_PER_SEC),
			       .tv_nsec = (long)(ns % NS_PER_SEC) };

	if (ts.tv_nsec < 0) {
		ts.tv_nsec += NS_PER_SEC;
		ts.tv_sec--;
	}
	return ts;
}

/* CLOCK_REALTIME: when something happened, for people and records. */
static inline int64_t now_realtime_ns(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_REALTIME, &ts);
	return ns_from_timespec(&ts);
}

/* CLOCK_MONOTONIC: intervals, deadlines and reading timestamps. */
static inline uint64_t now_monotonic_ns(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ns_from_timespec(&ts);
}

static inline uint64_t now_monotonic_ms(void)
{
	return now_monotonic_ns() / (uint64_t)NS_PER_MS;
}

/* Sleeps about ns (a signal may end it early). */
static inline void sleep_ns(uint64_t ns)
{
	struct timespec ts = timespec_from_ns((int64_t)ns);

	nanosleep(&ts, NULL);
}

static inline void msleep(unsigned ms)
{
	sleep_ns((uint64_t)ms * (uint64_t)NS_PER_MS);
}

/* Room for any ISO 8601 text below, nanoseconds and the widest year. */
#define ISO8601_SIZE 48

/*
 * realtime ns as ISO 8601 UTC: "2024-05-01T12:34:56Z", or with digits (1 to
 * 9) of the second's fraction, "2024-05-01T12:34:56.123456789Z"; truncated,
 * never rounded up into the next second. A time gmtime cannot express comes
 * out as "@ns", never as a wrong date.
 */
void iso8601_utc(int64_t ns, int digits, char *buf, size_t size);

/* realtime ns in ISO 8601's basic format, for file names:
 * "20240501T123456Z" (whole seconds, truncated); "@ns" as above. */
void iso8601_basic_utc(int64_t ns, char *buf, size_t size);

/*
 * realtime ns as ISO 8601 in the local time zone (TZ, else /etc/localtime)
 * with its offset, to the second: "2024-05-01T14:34:56+02:00" (UTC gives
 * "+00:00"). What a person reads on a report; "@ns" as iso8601_utc().
 */
void iso8601_local(int64_t ns, char *buf, size_t size);

/* "2027-01-31T12:00:00Z" or "2027-01-31" (midnight UTC) as realtime ns:
 * 0, -EINVAL for any other text, -ERANGE for a time out of range. */
int iso8601_parse_utc(const char *text, int64_t *ns);

/* A time with its zone, as a person gives one: "2027-01-31T14:00:00+01:00",
 * "...-0330" or "...Z", as realtime ns: 0, -EINVAL for any other text
 * (a time without a zone is ambiguous), -ERANGE out of range. */
int iso8601_parse_zoned(const char *text, int64_t *ns);

#endif
