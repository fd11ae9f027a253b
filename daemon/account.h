/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The user and group databases, safe from any thread: the reentrant
 * lookups (getpwuid_r() and friends) with a buffer that grows until the
 * entry fits. Each returns 0, -ENOENT when the database has no such
 * entry, or another negative errno when the lookup itself fails.
 * Internal.
 */
#ifndef ASPHD_ACCOUNT_H
#define ASPHD_ACCOUNT_H

#include <stdbool.h>
#include <stddef.h>
#include <sys/types.h>

/* The largest buffer one lookup may take (-ERANGE beyond). */
#define ACCOUNT_BUFFER_MAX (16u << 20)

/* The name of user uid, truncated to size bytes with its NUL. */
int account_user_name(uid_t uid, char *name, size_t size);

/* The name of group gid, truncated to size bytes with its NUL. */
int account_group_name(gid_t gid, char *name, size_t size);

/* The id of the group called name. */
int account_group_id(const char *name, gid_t *gid);

/*
 * One reentrant lookup as the functions above make it: a call of
 * getXXX_r() that fills entry from buf and tells whether it found the
 * key; it returns 0 or an errno value, ERANGE when buf is too small.
 */
typedef int account_lookup_fn(const void *key, void *entry, char *buf, size_t size,
			      bool *found);

/*
 * Runs lookup with a buffer of size bytes (0: a default), doubled on
 * ERANGE up to ACCOUNT_BUFFER_MAX. On success *buf holds the strings entry
 * points into; the caller frees it.
 */
int account_lookup(account_lookup_fn *lookup, const void *key, void *entry, size_t size,
		   char **buf);

#endif
