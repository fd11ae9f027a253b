/* SPDX-License-Identifier: GPL-3.0-or-later */
/* util-hash.h: the digests against the vectors their standards publish
 * (FIPS 180-2 appendix B for SHA-256, RFC 1321 appendix A.5 for MD5), in the
 * lower-case hex that sha256sum and md5sum print. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "util-hash.h"

static void test_sha256(void **state)
{
	const char *two_blocks = "abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq";
	char hex[SHA256_HEX_SIZE];
	struct sha256_ctx h;

	(void)state;
	sha256_hex("abc", 3, hex);
	assert_string_equal(hex, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
	sha256_hex("", 0, hex);
	assert_string_equal(hex, "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
	/* in two updates: the context's digest, as the streaming callers use it */
	sha256_init(&h);
	sha256_update(&h, 20, (const uint8_t *)two_blocks);
	sha256_update(&h, strlen(two_blocks) - 20, (const uint8_t *)two_blocks + 20);
	sha256_hex_of(&h, hex);
	assert_string_equal(hex, "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
}

static void test_md5(void **state)
{
	char hex[MD5_HEX_SIZE];

	(void)state;
	md5_hex("abc", 3, hex);
	assert_string_equal(hex, "900150983cd24fb0d6963f7d28e17f72");
	md5_hex("message digest", 14, hex);
	assert_string_equal(hex, "f96b697d7cb7938d525a2f31aaf161d0");
}

static void test_digest_hex(void **state)
{
	const uint8_t d[] = { 0x00, 0x0f, 0xa0, 0xff };
	char hex[9];

	(void)state;
	digest_hex(d, sizeof(d), hex);
	assert_string_equal(hex, "000fa0ff");
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_sha256),
		cmocka_unit_test(test_md5),
		cmocka_unit_test(test_digest_hex),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
