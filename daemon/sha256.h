/* SPDX-License-Identifier: GPL-3.0-or-later */
/* SHA-256 (FIPS 180-4) of recorded scans, for the provenance of results. */
#ifndef ASPHD_SHA256_H
#define ASPHD_SHA256_H

#include <stddef.h>
#include <stdint.h>

struct sha256 {
	uint32_t h[8];
	uint64_t length;        /* bytes hashed */
	uint8_t block[64];
	size_t fill;
};

void sha256_init(struct sha256 *c);
void sha256_update(struct sha256 *c, const void *data, size_t n);
void sha256_final(struct sha256 *c, uint8_t digest[32]);

/* The lower-case hex digest (65 bytes with the NUL) of n bytes. */
void sha256_hex(const void *data, size_t n, char hex[65]);

#endif
