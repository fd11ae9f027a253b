/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include "account.h"
#include "dirs.h"
#include "log.h"
#include "util-mem.h"

int dirs_check_private(const char *dir, const struct stat *st, bool sticky_ok,
		       const char *what)
{
	char name[64];

	if (st->st_uid != 0 && st->st_uid != geteuid()) {
		if (account_user_name(st->st_uid, name, sizeof(name)) < 0)
			snprintf(name, sizeof(name), "nobody known");
		log_error("%s belongs to %s (uid %u), another user: refusing %s", dir,
			  name, (unsigned)st->st_uid, what);
		return -EPERM;
	}
	if ((st->st_mode & S_IWOTH) && !(sticky_ok && (st->st_mode & S_ISVTX))) {
		log_error("%s is writable by every user: refusing %s", dir, what);
		return -EPERM;
	}
	if ((st->st_mode & S_IWGRP) && st->st_gid != getegid() &&
	    !(sticky_ok && (st->st_mode & S_ISVTX))) {
		if (account_group_name(st->st_gid, name, sizeof(name)) < 0)
			snprintf(name, sizeof(name), "unknown");
		log_error("%s is writable by the group %s (gid %u): refusing %s", dir,
			  name, (unsigned)st->st_gid, what);
		return -EPERM;
	}
	return 0;
}

int dirs_make_state(const char *dir)
{
	struct statvfs vfs;
	struct stat st;

	if (mkdir(dir, 0755) < 0 && errno != EEXIST) {
		log_error("cannot create the state directory %s: %s", dir, strerror(errno));
		return -errno;
	}
	if (stat(dir, &st) < 0 || !S_ISDIR(st.st_mode)) {
		log_error("%s is not a directory", dir);
		return -ENOTDIR;
	}
	if (dirs_check_private(dir, &st, false, "it as the state directory") < 0)
		return -EPERM;
	if (statvfs(dir, &vfs) == 0 && (vfs.f_flag & ST_RDONLY)) {
		log_error("the state directory %s is on a read-only file system", dir);
		return -EROFS;
	}
	return 0;
}

char *dirs_job_path(const char *state_dir, int64_t id)
{
	char *p = NULL;

	if (asprintf(&p, "%s/jobs/%" PRId64, state_dir, id) < 0)
		return NULL;
	return p;
}

/* Results are readable by whoever may read the socket's answers: asphctl
 * result --out copies them as the calling user. */
static bool real_dir(const char *path)
{
	struct stat st;

	return lstat(path, &st) == 0 && S_ISDIR(st.st_mode);
}

int dirs_make_job(const char *state_dir, int64_t id)
{
	_cleanup_free_ char *jobs = NULL;
	_cleanup_free_ char *dir = dirs_job_path(state_dir, id);

	if (!dir || asprintf(&jobs, "%s/jobs", state_dir) < 0)
		return -ENOMEM;
	if (mkdir(jobs, 0755) < 0 && errno != EEXIST)
		return -errno;
	if (mkdir(dir, 0755) < 0 && errno != EEXIST)
		return -errno;
	/* Never write through a symlink put in place of a folder. */
	if (!real_dir(jobs) || !real_dir(dir))
		return -ENOTDIR;
	return 0;
}
