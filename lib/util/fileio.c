/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fileio.h"
#include "util-mem.h"

static int fail(struct asph_error *err, const char *source, int code,
		const char *what)
{
	return asph_error_set_at(err, code, source, 0, 0, NULL, "%s", what);
}

/* The first size of the buffer: a regular file's size (and one byte more
 * to see its end), so that a large file is read without being copied from
 * one buffer to the next as it doubles. */
static size_t first_capacity(int fd)
{
	struct stat st;

	if (fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size >= 1 << 14 &&
	    (uintmax_t)st.st_size < SIZE_MAX / 2)
		return (size_t)st.st_size + 1;
	return 1 << 14;
}

int fd_read_all(int fd, size_t limit, const char *source, char **out, size_t *len,
		struct asph_error *err)
{
	_cleanup_free_ char *buf = NULL;
	size_t n = 0, cap = 0;

	for (;;) {
		ssize_t got;

		if (n == cap) {
			if (cap > limit)
				break;
			cap = cap ? 2 * cap : first_capacity(fd);
			/* one byte past the limit tells "exactly limit" from "more" */
			if (cap > limit + 1)
				cap = limit + 1;
			char *grown = realloc(buf, cap + 1);
			if (!grown)
				return fail(err, source, -ENOMEM, "out of memory");
			buf = grown;
			mem_advise_huge(buf, cap + 1);
		}
		got = read(fd, buf + n, cap - n);
		if (got < 0 && errno == EINTR)
			continue;
		if (got < 0)
			return fail(err, source, -errno, strerror(errno));
		if (got == 0)
			break;
		n += (size_t)got;
	}
	if (n > limit) {
		char msg[96];
		snprintf(msg, sizeof(msg), "larger than the limit of %zu bytes", limit);
		return fail(err, source, -EFBIG, msg);
	}
	buf[n] = '\0';
	*out = steal_ptr(buf);
	*len = n;
	return 0;
}

int file_read_all(const char *path, size_t limit, char **out, size_t *len,
		  struct asph_error *err)
{
	int is_stdin = !strcmp(path, "-");
	const char *source = is_stdin ? "<stdin>" : path;
	_cleanup_close_ int owned = is_stdin ? -1 : open(path, O_RDONLY | O_CLOEXEC);

	if (!is_stdin && owned < 0) {
		int e = -errno;
		return asph_error_set_at(err, e, source, 0, 0, NULL, "cannot open: %s",
					 strerror(-e));
	}
	return fd_read_all(is_stdin ? STDIN_FILENO : owned, limit, source, out, len, err);
}

int fd_write_all(int fd, const void *p, size_t n)
{
	const uint8_t *b = p;

	while (n > 0) {
		ssize_t r = write(fd, b, n);
		if (r < 0 && errno == EINTR)
			continue;
		if (r < 0)
			return -errno;
		if (r == 0)
			return -EIO;
		b += r;
		n -= (size_t)r;
	}
	return 0;
}
