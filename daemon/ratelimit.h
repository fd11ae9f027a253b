/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Token buckets per key: how often one peer (a uid, a TCP address) may do
 * something that costs the daemon or its log, such as a failed hello or a
 * refused request. Each key holds up to burst tokens and earns one every
 * interval; the table keeps at most max_keys keys and forgets the one
 * used longest ago when it is full (a forgotten key starts with a full
 * bucket again: the table bounds memory, not an attacker with more keys
 * than it holds, which the per-peer connection quotas bound instead).
 * Times are CLOCK_MONOTONIC microseconds, given by the caller. Event loop
 * thread.
 */
#ifndef ASPHD_RATELIMIT_H
#define ASPHD_RATELIMIT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* A key: "uid 1000", "tcp 192.0.2.7", "tcp 2001:db8:1:2::/64", ... */
#define RATELIMIT_KEY_MAX 64

struct ratelimit;

/* -EINVAL for a zero burst, interval or max_keys; -ENOMEM. */
int ratelimit_new(unsigned burst, uint64_t interval_usec, size_t max_keys,
		  struct ratelimit **out);
void ratelimit_free(struct ratelimit *rl);

/*
 * Takes a token of key at now. True when there was one; then *suppressed
 * (may be NULL) gets how many times key was refused since its last token,
 * for a log line that says how many it left out. False when the bucket is
 * empty (the refusal is counted).
 */
bool ratelimit_take(struct ratelimit *rl, const char *key, uint64_t now_usec,
		    unsigned *suppressed);

/* Whether key has a token at now, without taking it. */
bool ratelimit_allows(struct ratelimit *rl, const char *key, uint64_t now_usec);

/* Microseconds until key earns its next token (0 when it has one). */
uint64_t ratelimit_wait(struct ratelimit *rl, const char *key, uint64_t now_usec);

#endif
