/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Token buckets per key (daemon/ratelimit.c): a burst, then one token per
 * interval, counted refusals, keys apart, and a table that forgets the key
 * used longest ago when full. Times are given, not read.
 */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include <cmocka.h>

#include "ratelimit.h"

#define SEC 1000000ull

static void test_burst_then_rate(void **state)
{
	struct ratelimit *rl;
	unsigned left_out = 99;
	uint64_t t = 1000 * SEC;

	assert_int_equal(ratelimit_new(3, 2 * SEC, 4, &rl), 0);
	for (int i = 0; i < 3; i++) {
		assert_true(ratelimit_take(rl, "tcp 192.0.2.7", t, &left_out));
		assert_int_equal(left_out, 0);
	}
	/* Empty: refused and counted, 2 s until the next token. */
	assert_false(ratelimit_allows(rl, "tcp 192.0.2.7", t));
	assert_false(ratelimit_take(rl, "tcp 192.0.2.7", t, &left_out));
	assert_false(ratelimit_take(rl, "tcp 192.0.2.7", t + SEC, &left_out));
	assert_int_equal(ratelimit_wait(rl, "tcp 192.0.2.7", t + SEC), SEC);
	/* At 2 s one token, with the two refusals before it. */
	assert_true(ratelimit_take(rl, "tcp 192.0.2.7", t + 2 * SEC, &left_out));
	assert_int_equal(left_out, 2);
	assert_false(ratelimit_take(rl, "tcp 192.0.2.7", t + 3 * SEC, NULL));
	/* A long quiet time refills to the burst, no more. */
	for (int i = 0; i < 3; i++)
		assert_true(ratelimit_take(rl, "tcp 192.0.2.7", t + 100 * SEC, NULL));
	assert_false(ratelimit_take(rl, "tcp 192.0.2.7", t + 100 * SEC, NULL));
	/* Over 60 s of steady tries: 30 tokens, one every 2 s. */
	int taken = 0;
	for (uint64_t u = 0; u < 60 * SEC; u += SEC / 10)
		taken += ratelimit_take(rl, "tcp 192.0.2.7", t + 101 * SEC + u, NULL);
	assert_in_range(taken, 29, 31);
	ratelimit_free(rl);
}

static void test_keys_apart_and_forgotten(void **state)
{
	struct ratelimit *rl;
	uint64_t t = 5 * SEC;
	char key[32];

	assert_int_equal(ratelimit_new(1, 10 * SEC, 2, &rl), 0);
	assert_true(ratelimit_take(rl, "uid 1000", t, NULL));
	assert_false(ratelimit_take(rl, "uid 1000", t, NULL));
	assert_true(ratelimit_take(rl, "uid 1001", t + 1, NULL));
	/* The table holds 2: a third key forgets uid 1000 (used first). */
	assert_true(ratelimit_take(rl, "uid 1002", t + 2, NULL));
	assert_true(ratelimit_allows(rl, "uid 1000", t + 3));
	assert_false(ratelimit_allows(rl, "uid 1002", t + 4));
	for (int i = 0; i < 100; i++) {
		snprintf(key, sizeof(key), "tcp 198.51.100.%d", i);
		assert_true(ratelimit_take(rl, key, t + 10 + (uint64_t)i, NULL));
	}
	assert_int_equal(ratelimit_new(0, SEC, 1, &rl), -EINVAL);
	assert_int_equal(ratelimit_new(1, 0, 1, &rl), -EINVAL);
	ratelimit_free(rl);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_burst_then_rate),
		cmocka_unit_test(test_keys_apart_and_forgotten),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
