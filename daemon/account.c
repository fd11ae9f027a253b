/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The user and group databases through the reentrant lookups: the
 * daemon has worker threads, and getpwuid() and friends share one static
 * buffer. */
#include <errno.h>
#include <grp.h>
#include <pwd.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "account.h"
#include "util-mem.h"

int account_lookup(account_lookup_fn *lookup, const void *key, void *entry, size_t size,
		   char **buf)
{
	_cleanup_free_ char *b = NULL;

	if (size == 0)
		size = 1024;
	if (size > ACCOUNT_BUFFER_MAX)
		size = ACCOUNT_BUFFER_MAX;
	for (;;) {
		/* nothing in b is kept from one try to the next */
		free(b);
		b = malloc(size);
		if (!b)
			return -ENOMEM;
		bool found = false;
		int r = lookup(key, entry, b, size, &found);
		if (r == 0 && found) {
			*buf = steal_ptr(b);
			return 0;
		}
		/* not found is 0 and no entry for glibc; POSIX also allows these */
		if (r == 0 || r == ENOENT || r == ESRCH)
			return -ENOENT;
		if (r != ERANGE)
			return r > 0 ? -r : -EIO;
		if (size > ACCOUNT_BUFFER_MAX / 2)
			return -ERANGE;
		size *= 2;
	}
}

/* The system's suggestion for the first buffer (sysconf name), or 0. */
static size_t size_hint(int name)
{
	long n = sysconf(name);

	return n > 0 ? (size_t)n : 0;
}

static int by_uid(const void *key, void *entry, char *buf, size_t size, bool *found)
{
	struct passwd *res = NULL;
	int r = getpwuid_r(*(const uid_t *)key, entry, buf, size, &res);

	*found = res != NULL;
	return r;
}

static int by_gid(const void *key, void *entry, char *buf, size_t size, bool *found)
{
	struct group *res = NULL;
	int r = getgrgid_r(*(const gid_t *)key, entry, buf, size, &res);

	*found = res != NULL;
	return r;
}

static int by_group_name(const void *key, void *entry, char *buf, size_t size, bool *found)
{
	struct group *res = NULL;
	int r = getgrnam_r(key, entry, buf, size, &res);

	*found = res != NULL;
	return r;
}

int account_user_name(uid_t uid, char *name, size_t size)
{
	_cleanup_free_ char *buf = NULL;
	struct passwd pw;
	int r = account_lookup(by_uid, &uid, &pw, size_hint(_SC_GETPW_R_SIZE_MAX), &buf);

	if (r == 0)
		snprintf(name, size, "%s", pw.pw_name);
	return r;
}

int account_group_name(gid_t gid, char *name, size_t size)
{
	_cleanup_free_ char *buf = NULL;
	struct group gr;
	int r = account_lookup(by_gid, &gid, &gr, size_hint(_SC_GETGR_R_SIZE_MAX), &buf);

	if (r == 0)
		snprintf(name, size, "%s", gr.gr_name);
	return r;
}

int account_group_id(const char *name, gid_t *gid)
{
	_cleanup_free_ char *buf = NULL;
	struct group gr;
	int r = account_lookup(by_group_name, name, &gr, size_hint(_SC_GETGR_R_SIZE_MAX), &buf);

	if (r == 0)
		*gid = gr.gr_gid;
	return r;
}
