/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: token buckets per key. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ratelimit.h"

struct bucket {
	char key[RATELIMIT_KEY_MAX];
	unsigned tokens;
	unsigned refused;               /* since the last token taken */
	uint64_t earned_usec;           /* when the last token was earned */
	uint64_t used_usec;             /* for forgetting the oldest */
};

struct ratelimit {
	unsigned burst;
	uint64_t interval;
	size_t n, max;
	struct bucket *v;
};

int ratelimit_new(unsigned burst, uint64_t interval_usec, size_t max_keys,
		  struct ratelimit **out)
{
	struct ratelimit *rl;

	if (!burst || !interval_usec || !max_keys)
		return -EINVAL;
	rl = calloc(1, sizeof(*rl));
	if (!rl)
		return -ENOMEM;
	rl->v = calloc(max_keys, sizeof(*rl->v));
	if (!rl->v) {
		free(rl);
		return -ENOMEM;
	}
	rl->burst = burst;
	rl->interval = interval_usec;
	rl->max = max_keys;
	*out = rl;
	return 0;
}

void ratelimit_free(struct ratelimit *rl)
{
	if (!rl)
		return;
	free(rl->v);
	free(rl);
}

/* Adds what b earned up to now. */
static void refill(const struct ratelimit *rl, struct bucket *b, uint64_t now)
{
	uint64_t earned;

	if (now <= b->earned_usec)
		return;
	earned = (now - b->earned_usec) / rl->interval;
	if (earned >= rl->burst - b->tokens) {
		b->tokens = rl->burst;
		b->earned_usec = now;
	} else {
		b->tokens += (unsigned)earned;
		b->earned_usec += earned * rl->interval;
	}
}

/* key's bucket, a new full one when it has none (the oldest forgotten
 * when the table is full). */
static struct bucket *bucket_of(struct ratelimit *rl, const char *key, uint64_t now)
{
	struct bucket *b = NULL;

	for (size_t i = 0; i < rl->n; i++)
		if (!strncmp(rl->v[i].key, key, sizeof(rl->v[i].key) - 1)) {
			b = &rl->v[i];
			break;
		}
	if (!b) {
		if (rl->n < rl->max) {
			b = &rl->v[rl->n++];
		} else {
			b = &rl->v[0];
			for (size_t i = 1; i < rl->n; i++)
				if (rl->v[i].used_usec < b->used_usec)
					b = &rl->v[i];
		}
		*b = (struct bucket){ .tokens = rl->burst, .earned_usec = now };
		snprintf(b->key, sizeof(b->key), "%s", key);
	}
	refill(rl, b, now);
	b->used_usec = now;
	return b;
}

bool ratelimit_take(struct ratelimit *rl, const char *key, uint64_t now_usec,
		    unsigned *suppressed)
{
	struct bucket *b = bucket_of(rl, key, now_usec);

	if (!b->tokens) {
		b->refused++;
		return false;
	}
	b->tokens--;
	if (suppressed)
		*suppressed = b->refused;
	b->refused = 0;
	return true;
}

bool ratelimit_allows(struct ratelimit *rl, const char *key, uint64_t now_usec)
{
	return bucket_of(rl, key, now_usec)->tokens > 0;
}

uint64_t ratelimit_wait(struct ratelimit *rl, const char *key, uint64_t now_usec)
{
	struct bucket *b = bucket_of(rl, key, now_usec);

	if (b->tokens)
		return 0;
	return b->earned_usec + rl->interval - now_usec;
}
