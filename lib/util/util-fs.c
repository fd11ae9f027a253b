/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#if __has_include(<linux/openat2.h>)
#include <linux/openat2.h>
#endif

#include "util-fs.h"
#include "util-mem.h"

#define MAX_LINKS 40

/* Whether name is one plain component: not empty, ".", ".." or with "/". */
static bool plain_name(const char *name)
{
	return name[0] && strcmp(name, ".") && strcmp(name, "..") && !strchr(name, '/');
}

int fs_open_beneath_walk(int dirfd, const char *path, int flags, mode_t mode)
{
	_cleanup_free_ char *copy = strdup(path);
	_cleanup_close_ int dir = -1;
	char *save = NULL, *comp, *next;
	int at = dirfd;

	if (!copy)
		return -ENOMEM;
	if (path[0] == '/')
		return -EXDEV;
	comp = strtok_r(copy, "/", &save);
	if (!comp)
		return -EINVAL;
	for (;;) {
		next = strtok_r(NULL, "/", &save);
		if (!strcmp(comp, ".."))
			return -EXDEV;
		if (!next)
			break;
		if (strcmp(comp, ".")) {
			int fd = openat(at, comp, O_PATH | O_NOFOLLOW | O_CLOEXEC);
			struct stat st;
			if (fd < 0)
				return -errno;
			if (fstat(fd, &st) < 0 || !S_ISDIR(st.st_mode)) {
				int r = S_ISLNK(st.st_mode) ? -ELOOP : -ENOTDIR;
				close(fd);
				return r;
			}
			if (dir >= 0)
				close(dir);
			at = dir = fd;
		}
		comp = next;
	}
	int fd = openat(at, comp, flags | O_NOFOLLOW | O_CLOEXEC, mode);
	if (fd < 0) {
		/* O_NOFOLLOW with O_DIRECTORY says ENOTDIR for a symlink. */
		int r = -errno;
		struct stat st;
		if (fstatat(at, comp, &st, AT_SYMLINK_NOFOLLOW) == 0 && S_ISLNK(st.st_mode))
			return -ELOOP;
		return r;
	}
	return fd;
}

/* Whether path has a ".." component (openat2 would take one that stays
 * beneath; the walk takes none: neither does either, so they agree). */
static bool has_dotdot(const char *path)
{
	for (const char *p = path; (p = strstr(p, "..")); p += 2)
		if ((p == path || p[-1] == '/') && (p[2] == '/' || !p[2]))
			return true;
	return false;
}

int fs_open_beneath(int dirfd, const char *path, int flags, mode_t mode)
{
	if (path[0] == '/' || has_dotdot(path))
		return -EXDEV;
#if defined(SYS_openat2) && defined(RESOLVE_BENEATH)
	struct open_how how = {
		.flags = (uint64_t)(flags | O_CLOEXEC),
		.mode = (flags & (O_CREAT | O_TMPFILE)) ? mode : 0,
		.resolve = RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS | RESOLVE_NO_MAGICLINKS,
	};
	long fd = syscall(SYS_openat2, dirfd, path, &how, sizeof(how));

	if (fd >= 0)
		return (int)fd;
	/* ENOSYS: an older kernel; EPERM: a system call filter (a real EPERM
	 * comes back from the walk as well). */
	if (errno != ENOSYS && errno != EPERM)
		return -errno;
#endif
	return fs_open_beneath_walk(dirfd, path, flags, mode);
}

int fs_mkdir_beneath(int dirfd, const char *name, mode_t mode)
{
	int fd;

	if (!plain_name(name))
		return -EINVAL;
	if (mkdirat(dirfd, name, mode) < 0 && errno != EEXIST)
		return -errno;
	fd = fs_open_beneath(dirfd, name, O_RDONLY | O_DIRECTORY, 0);
	if (fd == -ENOTDIR) {
		struct stat st;
		if (fstatat(dirfd, name, &st, AT_SYMLINK_NOFOLLOW) == 0 && S_ISLNK(st.st_mode))
			return -ELOOP;
	}
	return fd;
}

/* ".NAME.XXXXXX" with six random characters. */
static void temp_name(const char *name, char *buf, size_t size)
{
	static const char chars[] = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789";
	unsigned char r[6];
	char suffix[7];

	/* Unique is enough (O_EXCL refuses a name taken): without
	 * getrandom() the clock will do. */
	if (getrandom(r, sizeof(r), GRND_NONBLOCK) != (ssize_t)sizeof(r)) {
		struct timespec ts;
		clock_gettime(CLOCK_MONOTONIC, &ts);
		uint64_t v = (uint64_t)ts.tv_nsec ^ ((uint64_t)ts.tv_sec << 30) ^ (uint64_t)getpid();
		for (size_t i = 0; i < sizeof(r); i++, v >>= 8)
			r[i] = (unsigned char)v;
	}
	for (size_t i = 0; i < sizeof(r); i++)
		suffix[i] = chars[r[i] % (sizeof(chars) - 1)];
	suffix[6] = '\0';
	snprintf(buf, size, ".%.200s.%s", name, suffix);
}

int fs_write_file_at(int dirfd, const char *name, mode_t mode, fs_write_fn fn, void *data,
		     struct asph_error *err)
{
	char tmp[256];
	FILE *f = NULL;
	int fd = -1, r;

	if (!plain_name(name))
		return asph_error_set(err, -EINVAL, "%s: not a file name", name);
	for (int tries = 0; fd < 0 && tries < 16; tries++) {
		temp_name(name, tmp, sizeof(tmp));
		fd = openat(dirfd, tmp, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, mode);
		if (fd < 0 && errno != EEXIST)
			return asph_error_set(err, -errno, "%s: cannot create: %s", name,
					      strerror(errno));
	}
	if (fd < 0)
		return asph_error_set(err, -EEXIST, "%s: no free temporary name", name);
	f = fdopen(fd, "w");
	if (!f) {
		r = asph_error_set(err, -errno, "%s: %s", name, strerror(errno));
		close(fd);
		goto fail;
	}
	r = fn(f, data, err);
	if (r == 0 && (fflush(f) != 0 || ferror(f)))
		r = asph_error_set(err, -(errno ? errno : EIO), "%s: write error: %s", name,
				   strerror(errno ? errno : EIO));
	if (r == 0 && fsync(fileno(f)) < 0)
		r = asph_error_set(err, -errno, "%s: cannot sync: %s", name, strerror(errno));
	if (fclose(f) != 0 && r == 0)
		r = asph_error_set(err, -errno, "%s: write error: %s", name, strerror(errno));
	if (r < 0)
		goto fail;
	if (renameat(dirfd, tmp, dirfd, name) < 0) {
		r = asph_error_set(err, -errno, "%s: cannot rename into place: %s", name,
				   strerror(errno));
		goto fail;
	}
	/* The new entry durable too (EINVAL: a file system without it). */
	if (fsync(dirfd) < 0 && errno != EINVAL && errno != EBADF)
		return asph_error_set(err, -errno, "%s: cannot sync its directory: %s", name,
				      strerror(errno));
	return 0;
fail:
	unlinkat(dirfd, tmp, 0);
	return r;
}

/* ---------------------------------------------------------- trusted path */

static bool trusted_owner(const struct stat *st, const struct fs_owners *o)
{
	return st->st_uid == 0 || st->st_uid == o->uid;
}

/* A directory that another user could change under us. */
static bool writable_by_others(const struct stat *st, const struct fs_owners *o)
{
	if (st->st_mode & S_ISVTX)
		return false;
	if (st->st_mode & S_IWOTH)
		return true;
	return (st->st_mode & S_IWGRP) && st->st_gid != 0 && st->st_gid != o->gid;
}

/* systemd's rule: from an unprivileged owner to anyone else is unsafe. */
static bool unsafe_transition(const struct stat *from, const struct stat *to)
{
	return from->st_uid != 0 && from->st_uid != to->st_uid;
}

struct walk {
	const struct fs_owners *owners;
	struct asph_error *err;
	char done[PATH_MAX];            /* the path walked so far, for messages */
};

static int refuse(struct walk *w, const char *comp, int code, const char *why,
		  const struct stat *st)
{
	return asph_error_set(w->err, code, "%s%s%s: %s (uid %u, mode %04o)", w->done,
			      strcmp(w->done, "/") ? "/" : "", comp, why,
			      st ? (unsigned)st->st_uid : 0u, st ? (unsigned)(st->st_mode & 07777) : 0u);
}

static void walked(struct walk *w, const char *comp)
{
	size_t n = strlen(w->done);

	snprintf(w->done + n, sizeof(w->done) - n, "%s%s", strcmp(w->done, "/") ? "/" : "", comp);
}

/* Replaces *todo ("rest") with "target/rest". */
static int splice_link(int fd, const char *rest, char **todo)
{
	char target[PATH_MAX];
	ssize_t n = readlinkat(fd, "", target, sizeof(target) - 1);
	char *t;

	if (n < 0)
		return -errno;
	target[n] = '\0';
	if (asprintf(&t, "%s/%s", target, rest ? rest : "") < 0)
		return -ENOMEM;
	free(*todo);
	*todo = t;
	return 0;
}

/* Back to "/" (an absolute link, or "..") . */
static int restart(struct walk *w, int *dir, struct stat *dst)
{
	if (*dir >= 0)
		close(*dir);
	*dir = open("/", O_PATH | O_DIRECTORY | O_CLOEXEC);
	if (*dir < 0 || fstat(*dir, dst) < 0)
		return asph_error_set(w->err, -errno, "/: %s", strerror(errno));
	snprintf(w->done, sizeof(w->done), "/");
	return 0;
}

/* ".." after w->done: the rest is walked again from the directory above. */
static int climb(struct walk *w, const char *rest, char **todo, int *dir, struct stat *dst,
		 int *links)
{
	char *slash = strrchr(w->done, '/');
	char *again;

	if (++*links > MAX_LINKS)
		return asph_error_set(w->err, -ELOOP, "%s: too many steps back", w->done);
	if (slash == w->done)
		slash[1] = '\0';
	else
		*slash = '\0';
	if (asprintf(&again, "%s/%s", w->done, rest ? rest : "") < 0)
		return -ENOMEM;
	free(*todo);
	*todo = again;
	return restart(w, dir, dst);
}

int fs_open_trusted(const char *path, const struct fs_owners *owners, int flags,
		    struct asph_error *err)
{
	struct walk w = { .owners = owners, .err = err, .done = "/" };
	_cleanup_free_ char *todo = NULL;
	_cleanup_close_ int dir = -1;
	struct stat dst, st;
	int links = 0, r;

	if (!path || path[0] != '/')
		return asph_error_set(err, -EINVAL, "%s: not an absolute path", path ? path : "");
	todo = strdup(path);
	dir = open("/", O_PATH | O_DIRECTORY | O_CLOEXEC);
	if (!todo || dir < 0 || fstat(dir, &dst) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (!trusted_owner(&dst, owners) || writable_by_others(&dst, owners))
		return refuse(&w, "", -EPERM, "not in trusted hands", &dst);
	for (;;) {
		char *p = todo, *comp, *rest;
		_cleanup_close_ int fd = -1;

		while (*p == '/')
			p++;
		if (!*p)
			return asph_error_set(err, -EINVAL, "%s: names no file", path);
		comp = p;
		rest = strchr(p, '/');
		if (rest)
			*rest++ = '\0';
		while (rest && *rest == '/')
			rest++;
		if (rest && !*rest)
			rest = NULL;
		if (!strcmp(comp, "..")) {
			/* Up: walked again from "/" to the directory above. */
			r = climb(&w, rest, &todo, &dir, &dst, &links);
			if (r < 0)
				return r;
			continue;
		}
		if (!strcmp(comp, ".")) {
			if (!rest)
				return asph_error_set(err, -EINVAL, "%s: names no file", path);
			memmove(todo, rest, strlen(rest) + 1);
			continue;
		}
		fd = openat(dir, comp, O_PATH | O_NOFOLLOW | O_CLOEXEC);
		if (fd < 0 || fstat(fd, &st) < 0)
			return refuse(&w, comp, -errno, strerror(errno), NULL);
		if (!trusted_owner(&st, owners))
			return refuse(&w, comp, -EPERM, "belongs to another user", &st);
		if (unsafe_transition(&dst, &st))
			return refuse(&w, comp, -EPERM, "belongs to another user than the "
				      "directory above it, whose owner could replace it", &st);
		if (S_ISLNK(st.st_mode)) {
			if (++links > MAX_LINKS)
				return refuse(&w, comp, -ELOOP, "too many symbolic links", &st);
			_cleanup_free_ char *rest_copy = rest ? strdup(rest) : NULL;
			r = splice_link(fd, rest_copy, &todo);
			if (r < 0)
				return refuse(&w, comp, r, strerror(-r), &st);
			if (todo[0] == '/' && (r = restart(&w, &dir, &dst)) < 0)
				return r;
			continue;
		}
		if (!rest) {
			/* The last one, opened as asked: the same file as checked. */
			struct stat again;
			int out = openat(dir, comp, flags | O_NOFOLLOW | O_CLOEXEC);
			if (out < 0)
				return refuse(&w, comp, -errno, strerror(errno), &st);
			if (fstat(out, &again) < 0 || again.st_dev != st.st_dev ||
			    again.st_ino != st.st_ino) {
				close(out);
				return refuse(&w, comp, -EAGAIN, "changed while it was checked", &st);
			}
			return out;
		}
		if (!S_ISDIR(st.st_mode))
			return refuse(&w, comp, -ENOTDIR, "not a directory", &st);
		if (writable_by_others(&st, owners))
			return refuse(&w, comp, -EPERM, "other users may write it", &st);
		walked(&w, comp);
		close(dir);
		dir = steal_fd(fd);
		dst = st;
		memmove(todo, rest, strlen(rest) + 1);
	}
}
