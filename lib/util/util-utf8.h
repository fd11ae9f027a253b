/* SPDX-License-Identifier: GPL-3.0-or-later */
/* UTF-8, the one decoder of the tree (RFC 3629). Internal header. */
#ifndef ASPH_UTIL_UTF8_H
#define ASPH_UTIL_UTF8_H

#include <stddef.h>
#include <stdint.h>

/* The length (1 to 4) of the valid UTF-8 sequence at s, which holds at most
 * len bytes, with its code point in *code (may be NULL); 0 when there is
 * none: a stray continuation byte, a truncated or overlong sequence, a
 * surrogate, or past U+10FFFF. */
size_t utf8_sequence(const unsigned char *s, size_t len, uint32_t *code);

/* Whether the n bytes at s are UTF-8 text. */
int utf8_valid(const char *s, size_t n);

#endif
