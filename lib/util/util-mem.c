/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdint.h>
#include <sys/mman.h>

#include "util-mem.h"

/* The size of a transparent huge page on x86-64 and on arm64 with 4 KiB
 * pages; elsewhere the advice covers fewer pages or none, and costs nothing. */
#define HUGE_PAGE ((uintptr_t)2 << 20)

/* Below this a block seldom holds a whole huge page (an array of 10^5
 * points, say), and those few faults are not worth the system call. */
#define HUGE_MIN ((size_t)3 << 20)

void mem_advise_huge(void *p, size_t n)
{
	uintptr_t start, end;

	if (!p || n < HUGE_MIN)
		return;
	start = ((uintptr_t)p + HUGE_PAGE - 1) & ~(HUGE_PAGE - 1);
	end = ((uintptr_t)p + n) & ~(HUGE_PAGE - 1);
	if (start >= end)
		return;
	/* Advice only: a kernel without transparent huge pages, or with them
	 * off, refuses it and the block stays as it was. */
	(void)madvise((void *)start, end - start, MADV_HUGEPAGE);
}
