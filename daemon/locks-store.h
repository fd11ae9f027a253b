/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The operator locks of instruments in the store (store.h), which the
 * queue (jobs-locks.c) takes and gives back, so that a lock outlives a
 * restart.
 * Event loop thread.
 */
#ifndef ASPHD_LOCKS_STORE_H
#define ASPHD_LOCKS_STORE_H

#include <stdbool.h>
#include <stdint.h>

struct store;

struct store_lock {
	const char *instrument;
	const char *holder;     /* a user or token name */
	int64_t holder_uid;
	const char *reason;
	int64_t since_ns;
	bool pause;             /* a running job is paused while it holds */
	int64_t paused_job;     /* the job the lock paused, 0: none */
};
typedef int (*store_lock_fn)(const struct store_lock *l, void *data);
int store_lock_set(struct store *s, const struct store_lock *l);
int store_lock_clear(struct store *s, const char *instrument);
int store_lock_list(struct store *s, store_lock_fn fn, void *data);

#endif
