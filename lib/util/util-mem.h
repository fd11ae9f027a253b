/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Scope-bound cleanup, shared by every part of the tree. Internal header. */
#ifndef ASPH_UTIL_MEM_H
#define ASPH_UTIL_MEM_H

#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>
#include <errno.h>
#include <stdint.h>

#define _cleanup_(f) __attribute__((cleanup(f)))

static inline void freep(void *p)
{
	free(*(void **)p);
}

static inline void fclosep(FILE **f)
{
	if (*f)
		fclose(*f);
}

static inline void closep(int *fd)
{
	if (*fd >= 0) {
		int saved = errno;
		close(*fd);
		errno = saved;
	}
}

/* Defines fn##p() that calls fn on a non-NULL pointer, for _cleanup_().
 * (jansson already provides json_decrefp for json_t *.) */
#define DEFINE_TRIVIAL_CLEANUP_FUNC(type, fn)         \
	/* type is a type name: no parentheses */  \
	static inline void fn##p(type *p) /* NOLINT(bugprone-macro-parentheses) */ \
	{                                             \
		if (*p)                               \
			fn(*p);                       \
	}

#define _cleanup_free_ _cleanup_(freep)
#define _cleanup_fclose_ _cleanup_(fclosep)
#define _cleanup_close_ _cleanup_(closep)

/* Hands ownership out of a _cleanup_ variable. */
#define steal_ptr(ptr_)                        \
	__extension__({                                     \
		__typeof__(ptr_) *p_ = &(ptr_); \
		__typeof__(ptr_) v_ = *p_;      \
		*p_ = NULL;                    \
		v_;                            \
	})

#define steal_fd(fd_)              \
	__extension__({                         \
		int *p_ = &(fd_);  \
		int v_ = *p_;      \
		*p_ = -1;          \
		v_;                \
	})

/* Asks the kernel to back the whole 2 MiB pages inside the block p of n
 * bytes with transparent huge pages (when its setting is "madvise" or
 * "always"): an array of millions of points then takes one page fault per
 * 2 MiB instead of one per 4 KiB. Nothing changes for blocks under 3 MiB,
 * or where the kernel declines; the block is freed as before. */
void mem_advise_huge(void *p, size_t n);

#define ARRAY_SIZE(a) (sizeof(a) / sizeof((a)[0]))

/* Grows the array *p of *cap elements of size bytes to hold at least need,
 * doubling from first: 0, or -ENOMEM (the array is then unchanged). */
static inline int array_grow(void **p, size_t *cap, size_t need, size_t size, size_t first)
{
	size_t c = *cap ? *cap : first;
	void *n;

	if (*cap >= need)
		return 0;
	while (c < need) {
		if (c > SIZE_MAX / 2)
			return -ENOMEM;
		c *= 2;
	}
	if (c > SIZE_MAX / size)
		return -ENOMEM;
	n = realloc(*p, c * size);
	if (!n)
		return -ENOMEM;
	*p = n;
	*cap = c;
	return 0;
}

#endif
