/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Reading a whole text file into memory and writing all of a buffer to a
 * descriptor, the one way the tree does each. Internal. */
#ifndef ASPH_FILEIO_H
#define ASPH_FILEIO_H

#include <stddef.h>

#include "asph/error.h"

/*
 * Reads all of path ("-" for stdin) into a malloc'd, NUL-terminated buffer.
 * A file longer than limit bytes is refused with -EFBIG (never cut short).
 * Errors name the file (or "<stdin>").
 */
int file_read_all(const char *path, size_t limit, char **out, size_t *len,
		  struct asph_error *err);
/* The same from an open descriptor, to its end; source names it in
 * errors. */
int fd_read_all(int fd, size_t limit, const char *source, char **out, size_t *len,
		struct asph_error *err);

/* All n bytes of p to fd (a pipe, a file), through EINTR and short writes:
 * 0 or -errno (-EIO when the descriptor takes nothing). */
int fd_write_all(int fd, const void *p, size_t n);

#endif
