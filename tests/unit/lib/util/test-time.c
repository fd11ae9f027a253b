/* SPDX-License-Identifier: GPL-3.0-or-later */
/* util-time.h: the clocks and ISO 8601. Expected dates are calendar.timegm()
 * values (Python), not this code's output. */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <cmocka.h>

#include "util-time.h"

static void test_iso8601(void **state)
{
	char buf[ISO8601_SIZE];
	/* 2024-02-29T23:59:59Z (a leap day) and 0.987654321 s */
	const int64_t leap = 1709251199 * NS_PER_SEC + 987654321;

	iso8601_utc(leap, 0, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T23:59:59Z");
	iso8601_utc(leap, 9, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T23:59:59.987654321Z");
	/* truncated, never rounded into the next second */
	iso8601_utc(leap, 3, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T23:59:59.987Z");
	iso8601_utc(1709251199 * NS_PER_SEC + 999999999, 1, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T23:59:59.9Z");
	iso8601_utc(leap, 12, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T23:59:59.987654321Z");
	/* past 2^31 s */
	iso8601_utc(2147483648 * NS_PER_SEC + 5000, 6, buf, sizeof(buf));
	assert_string_equal(buf, "2038-01-19T03:14:08.000005Z");
	/* 1 ns before 1970 is in 1969's last second, not in 1970's first */
	iso8601_utc(-1, 9, buf, sizeof(buf));
	assert_string_equal(buf, "1969-12-31T23:59:59.999999999Z");
	iso8601_utc(-1, 0, buf, sizeof(buf));
	assert_string_equal(buf, "1969-12-31T23:59:59Z");
	/* the basic format of file names: whole seconds, truncated */
	iso8601_basic_utc(leap, buf, sizeof(buf));
	assert_string_equal(buf, "20240229T235959Z");
	iso8601_basic_utc(-1, buf, sizeof(buf));
	assert_string_equal(buf, "19691231T235959Z");
	/* a buffer too small gets a truncated, terminated text */
	char small[8];
	iso8601_utc(leap, 9, small, sizeof(small));
	assert_string_equal(small, "2024-02");
}

/* Local time with its offset: the zones are POSIX TZ rules, so the test
 * needs no time zone database. */
static void test_iso8601_local(void **state)
{
	char buf[ISO8601_SIZE];
	const int64_t leap = 1709251199 * NS_PER_SEC + 987654321;  /* 2024-02-29T23:59:59Z */

	setenv("TZ", "UTC0", 1);
	tzset();
	iso8601_local(leap, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T23:59:59+00:00");
	setenv("TZ", "CET-1", 1);
	tzset();
	iso8601_local(leap, buf, sizeof(buf));
	assert_string_equal(buf, "2024-03-01T00:59:59+01:00");
	setenv("TZ", "NST+3:30", 1);
	tzset();
	iso8601_local(leap, buf, sizeof(buf));
	assert_string_equal(buf, "2024-02-29T20:29:59-03:30");
	unsetenv("TZ");
	tzset();
}

static void test_iso8601_parse_zoned(void **state)
{
	const int64_t t = 1709251199 * NS_PER_SEC;     /* 2024-02-29T23:59:59Z */
	static const char *const same[] = { "2024-02-29T23:59:59Z", "2024-03-01T00:59:59+01:00",
					    "2024-03-01T00:59:59+0100", "2024-02-29T20:29:59-03:30" };
	static const char *const bad[] = { "2024-02-29T23:59:59", "2024-02-29", "2024-02-29T23:59:59+1",
					   "2024-02-29T23:59:59+01:0", "2024-02-29T23:59:59+24:00",
					   "2024-02-29T23:59:59+01:00x", "2024-02-29T23:59:59 Z", "" };
	int64_t ns;

	for (size_t i = 0; i < sizeof(same) / sizeof(same[0]); i++) {
		ns = 0;
		assert_int_equal(iso8601_parse_zoned(same[i], &ns), 0);
		assert_int_equal(ns, t);
	}
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
		assert_int_equal(iso8601_parse_zoned(bad[i], &ns), -EINVAL);
}

static void test_timespec(void **state)
{
	struct timespec ts = timespec_from_ns(-1500000000);

	assert_int_equal(ts.tv_sec, -2);
	assert_int_equal(ts.tv_nsec, 500000000);
	assert_int_equal(ns_from_timespec(&ts), -1500000000);
	ts = timespec_from_ns(3 * NS_PER_SEC + 7);
	assert_int_equal(ts.tv_sec, 3);
	assert_int_equal(ts.tv_nsec, 7);
	assert_int_equal(ns_from_timespec(&ts), 3 * NS_PER_SEC + 7);
}

static void test_clocks(void **state)
{
	time_t before = time(NULL);
	int64_t now = now_realtime_ns();
	time_t after = time(NULL);

	/* time() truncates; the wall clock reading lies between the two */
	assert_true(now / NS_PER_SEC >= before && now / NS_PER_SEC <= after);

	uint64_t a = now_monotonic_ns();
	struct timespec pause = { 0, 2000000 };
	nanosleep(&pause, NULL);
	uint64_t b = now_monotonic_ns();
	assert_true(b - a >= 2000000);
	uint64_t ms = now_monotonic_ms();
	assert_true(ms >= b / NS_PER_MS);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_iso8601),
		cmocka_unit_test(test_iso8601_local),
		cmocka_unit_test(test_iso8601_parse_zoned),
		cmocka_unit_test(test_timespec),
		cmocka_unit_test(test_clocks),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
