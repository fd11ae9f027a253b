/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include "account.h"
#include "dirs.h"
#include "log.h"
#include "util-fs.h"
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

static const struct fs_owners *daemon_owners(struct fs_owners *o)
{
	*o = (struct fs_owners){ .uid = geteuid(), .gid = getegid() };
	return o;
}

/* Opens dir through trusted steps; what says what for in the log. */
static int open_trusted_dir(const char *dir, const char *what)
{
	struct fs_owners o;
	struct asph_error err;
	char buf[1024];
	int fd;

	asph_error_clear(&err);
	fd = fs_open_trusted(dir, daemon_owners(&o), O_RDONLY | O_DIRECTORY, &err);
	if (fd < 0 && fd != -ENOENT)
		log_error("%s: refusing %s", asph_error_format(&err, buf, sizeof(buf)), what);
	return fd;
}

/* dir's parent, trusted, then dir in it (made with mode if missing). */
static int make_in_trusted_parent(const char *dir, mode_t mode, const char *what)
{
	_cleanup_free_ char *a = strdup(dir), *b = strdup(dir);
	_cleanup_close_ int parent = -1;
	const char *base;
	int fd;

	if (!a || !b)
		return -ENOMEM;
	parent = open_trusted_dir(dirname(a), what);
	if (parent < 0) {
		if (parent == -ENOENT)
			log_error("%s: the directory above it does not exist: refusing %s",
				  dir, what);
		return parent;
	}
	base = basename(b);
	fd = fs_mkdir_beneath(parent, base, mode);
	if (fd < 0)
		log_error("cannot create %s: %s", dir, strerror(-fd));
	return fd;
}

int dirs_open_state(const char *dir)
{
	static const char what[] = "it as the state directory";
	_cleanup_close_ int fd = open_trusted_dir(dir, what);
	struct statvfs vfs;
	struct stat st;

	if (fd == -ENOENT)
		fd = make_in_trusted_parent(dir, DIRS_DIR_MODE, what);
	if (fd < 0)
		return fd;
	if (fstat(fd, &st) < 0 || !S_ISDIR(st.st_mode)) {
		log_error("%s is not a directory", dir);
		return -ENOTDIR;
	}
	if (dirs_check_private(dir, &st, false, what) < 0)
		return -EPERM;
	if (fstatvfs(fd, &vfs) == 0 && (vfs.f_flag & ST_RDONLY)) {
		log_error("the state directory %s is on a read-only file system", dir);
		return -EROFS;
	}
	/* Jobs, scans and results are the daemon's; readers ask the socket. */
	if ((st.st_mode & 0027) && st.st_uid == geteuid()) {
		if (fchmod(fd, st.st_mode & 07750) == 0)
			log_notice("%s was open to other users (mode %04o): now %04o", dir,
				   (unsigned)(st.st_mode & 07777), (unsigned)(st.st_mode & 07750));
		else
			log_warning("%s is open to other users (mode %04o): %s", dir,
				    (unsigned)(st.st_mode & 07777), strerror(errno));
	}
	return steal_fd(fd);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(DIR *, closedir)

/* What of st lets someone other than root and the daemon's user write it,
 * or NULL. */
static const char *others_write(const struct stat *st)
{
	if (st->st_uid != 0 && st->st_uid != geteuid())
		return "belongs to another user";
	if (st->st_mode & S_IWOTH)
		return "is writable by every user";
	if ((st->st_mode & S_IWGRP) && st->st_gid != getegid() && st->st_gid != 0)
		return "is writable by a group other than the daemon's";
	return NULL;
}

int dirs_check_page(const char *root, struct asph_error *err)
{
	struct fs_owners o;
	_cleanup_close_ int fd = fs_open_trusted(root, daemon_owners(&o), O_RDONLY | O_DIRECTORY,
						 err);
	_cleanup_(closedirp) DIR *d = NULL;
	const struct dirent *e;
	const char *why;
	struct stat st;

	if (fd < 0)
		return fd;
	if (fstat(fd, &st) < 0)
		return asph_error_set(err, -errno, "%s: %s", root, strerror(errno));
	if ((why = others_write(&st)))
		return asph_error_set(err, -EPERM, "%s %s: the page's files must come from root "
				      "or the daemon's user only", root, why);
	d = fdopendir(fd);
	if (!d)
		return asph_error_set(err, -errno, "%s: %s", root, strerror(errno));
	fd = -1;        /* (the DIR has it) */
	while ((e = readdir(d))) {
		if (e->d_name[0] == '.')
			continue;       /* (never served) */
		if (fstatat(dirfd(d), e->d_name, &st, AT_SYMLINK_NOFOLLOW) < 0)
			return asph_error_set(err, -errno, "%s/%s: %s", root, e->d_name,
					      strerror(errno));
		if (S_ISREG(st.st_mode) && (why = others_write(&st)))
			return asph_error_set(err, -EPERM, "%s/%s %s: the page's files must come "
					      "from root or the daemon's user only", root,
					      e->d_name, why);
	}
	return 0;
}

int dirs_check_socket_dir(const char *socket_path)
{
	static const char what[] = "to put the socket there";
	_cleanup_free_ char *copy = strdup(socket_path);
	_cleanup_close_ int fd = -1;
	struct stat st;
	char *dir;

	if (!copy)
		return -ENOMEM;
	dir = dirname(copy);
	fd = open_trusted_dir(dir, what);
	if (fd == -ENOENT)
		fd = make_in_trusted_parent(dir, 0755, what);
	if (fd < 0)
		return fd;
	if (fstat(fd, &st) < 0)
		return -errno;
	return dirs_check_private(dir, &st, true, what);
}

char *dirs_job_path(const char *state_dir, int64_t id)
{
	char *p = NULL;

	if (asprintf(&p, "%s/jobs/%" PRId64, state_dir, id) < 0)
		return NULL;
	return p;
}

int dirs_open_job(int state_fd, int64_t id, bool create)
{
	_cleanup_close_ int jobs = -1;
	char name[24];

	snprintf(name, sizeof(name), "%" PRId64, id);
	if (!create) {
		char rel[32];
		snprintf(rel, sizeof(rel), "jobs/%s", name);
		return fs_open_beneath(state_fd, rel, O_RDONLY | O_DIRECTORY, 0);
	}
	jobs = fs_mkdir_beneath(state_fd, "jobs", DIRS_DIR_MODE);
	if (jobs < 0)
		return jobs;
	return fs_mkdir_beneath(jobs, name, DIRS_DIR_MODE);
}

int64_t dirs_last_job(int state_fd)
{
	int fd = fs_open_beneath(state_fd, "jobs", O_RDONLY | O_DIRECTORY, 0);
	int64_t last = 0;
	struct dirent *e;
	DIR *d;

	if (fd == -ENOENT)
		return 0;
	if (fd < 0)
		return fd;
	d = fdopendir(fd);
	if (!d) {
		close(fd);
		return -errno;
	}
	while ((e = readdir(d))) {
		size_t n = strlen(e->d_name);
		if (n == 0 || n > 18 || e->d_name[0] == '0' || strspn(e->d_name, "0123456789") != n)
			continue;
		int64_t id = strtoll(e->d_name, NULL, 10);
		if (id > last)
			last = id;
	}
	closedir(d);
	return last;
}

int dirs_free_mb(int fd, uint64_t *mb)
{
	struct statvfs vfs;

	if (fstatvfs(fd, &vfs) < 0)
		return -errno;
	*mb = (uint64_t)vfs.f_bavail * vfs.f_frsize / (1024 * 1024);
	return 0;
}
