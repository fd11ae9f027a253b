/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Digests as the tree writes them: nettle's SHA-256 and MD5, in lower-case
 * hex (what sha256sum and md5sum print). Internal header. */
#ifndef ASPH_UTIL_HASH_H
#define ASPH_UTIL_HASH_H

#include <stddef.h>
#include <stdint.h>

#include <nettle/md5.h>
#include <nettle/sha2.h>

#define SHA256_HEX_SIZE (2 * SHA256_DIGEST_SIZE + 1)
#define MD5_HEX_SIZE (2 * MD5_DIGEST_SIZE + 1)

/* n digest bytes as 2n hex digits and a NUL. */
void digest_hex(const uint8_t *digest, size_t n, char *hex);

/* The hex digest of a finished SHA-256 context (it is reset for reuse). */
void sha256_hex_of(struct sha256_ctx *h, char hex[SHA256_HEX_SIZE]);

/* The hex digest of n bytes. */
void sha256_hex(const void *data, size_t n, char hex[SHA256_HEX_SIZE]);
void md5_hex(const void *data, size_t n, char hex[MD5_HEX_SIZE]);

#endif
