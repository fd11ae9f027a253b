/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "sha256.h"

static void hex(const uint8_t d[32], char out[65])
{
	for (int i = 0; i < 32; i++)
		snprintf(out + 2 * i, 3, "%02x", d[i]);
}

static void digest_of(const void *data, size_t n, char out[65])
{
	struct sha256 c;
	uint8_t d[32];

	sha256_init(&c);
	sha256_update(&c, data, n);
	sha256_final(&c, d);
	hex(d, out);
}

/* FIPS 180-4 / NIST CAVS example vectors. */
static void test_vectors(void **state)
{
	char h[65];
	static const char two_blocks[] = "abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq";

	digest_of("", 0, h);
	assert_string_equal(h, "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
	digest_of("abc", 3, h);
	assert_string_equal(h, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
	digest_of(two_blocks, strlen(two_blocks), h);
	assert_string_equal(h, "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
}

/* One million 'a' fed in uneven pieces, so that every path of update()
 * (partial block, whole blocks, remainder) is taken. */
static void test_million_in_pieces(void **state)
{
	static uint8_t buf[1000];
	struct sha256 c;
	uint8_t d[32];
	char h[65];
	size_t left = 1000000, step = 1;

	memset(buf, 'a', sizeof(buf));
	sha256_init(&c);
	while (left > 0) {
		size_t n = step < left ? step : left;
		sha256_update(&c, buf, n);
		left -= n;
		step = step * 7 % 997 + 1;
	}
	sha256_final(&c, d);
	hex(d, h);
	assert_string_equal(h, "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

/* 775 bytes (a padding boundary past 12 blocks) as hex, against
 * Python's hashlib of the same bytes. */
static void test_hex(void **state)
{
	char h[65];
	uint8_t data[775];

	for (int i = 0; i < 768; i++)
		data[i] = (uint8_t)(i % 256);
	memset(data + 768, 'x', 7);
	sha256_hex(data, sizeof(data), h);
	assert_string_equal(h, "c2f9a54d69fa65b391e265b8a6496acb9278830607f9581ee4d3596ecf02e90e");
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_vectors),
		cmocka_unit_test(test_million_in_pieces),
		cmocka_unit_test(test_hex),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
