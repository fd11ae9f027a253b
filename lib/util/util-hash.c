/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <nettle/base16.h>

#include "util-hash.h"

void digest_hex(const uint8_t *digest, size_t n, char *hex)
{
	base16_encode_update(hex, n, digest);
	hex[2 * n] = '\0';
}

void sha256_hex_of(struct sha256_ctx *h, char hex[SHA256_HEX_SIZE])
{
	uint8_t d[SHA256_DIGEST_SIZE];

	sha256_digest(h, sizeof(d), d);
	digest_hex(d, sizeof(d), hex);
}

void sha256_hex(const void *data, size_t n, char hex[SHA256_HEX_SIZE])
{
	struct sha256_ctx h;

	sha256_init(&h);
	sha256_update(&h, n, data);
	sha256_hex_of(&h, hex);
}

void md5_hex(const void *data, size_t n, char hex[MD5_HEX_SIZE])
{
	struct md5_ctx h;
	uint8_t d[MD5_DIGEST_SIZE];

	md5_init(&h);
	md5_update(&h, n, data);
	md5_digest(&h, sizeof(d), d);
	digest_hex(d, sizeof(d), hex);
}
