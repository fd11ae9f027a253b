/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <inttypes.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include <cmocka.h>

#include "util-mem.h"

#define MIB ((uintptr_t)1 << 20)
#define HUGE_PAGE (2 * MIB)

/* Whether the kernel's mapping holding addr carries the huge-page advice
 * ("hg" among its VmFlags in /proc/self/smaps): 1 or 0, -1 not found. */
static int advised(uintptr_t addr)
{
	FILE *f = fopen("/proc/self/smaps", "r");
	char line[512];
	bool inside = false;
	int found = -1;

	assert_non_null(f);
	while (found < 0 && fgets(line, sizeof(line), f)) {
		uintptr_t lo, hi;

		if (sscanf(line, "%" SCNxPTR "-%" SCNxPTR " ", &lo, &hi) == 2)
			inside = lo <= addr && addr < hi;
		else if (inside && !strncmp(line, "VmFlags:", 8))
			found = strstr(line, " hg") != NULL;
	}
	fclose(f);
	return found;
}

/* A fresh mapping of n bytes starting 2 MiB-aligned, NULL where the
 * kernel takes no huge-page advice at all (then the tests are skipped). */
static uint8_t *aligned_map(size_t n, void **base, size_t *len)
{
	*len = n + HUGE_PAGE;
	*base = mmap(NULL, *len, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
	assert_true(*base != MAP_FAILED);
	uintptr_t a = ((uintptr_t)*base + HUGE_PAGE - 1) & ~(HUGE_PAGE - 1);
	return (uint8_t *)a;
}

/* Only the whole 2 MiB pages inside the block get the advice: the bytes
 * before its first and after its last boundary keep the mapping's own. */
static void test_interior_only(void **state)
{
	void *base;
	size_t len;
	uint8_t *a = aligned_map(12 * MIB, &base, &len);

	if (madvise(a, HUGE_PAGE, MADV_HUGEPAGE) < 0) {
		munmap(base, len);
		skip();
	}
	madvise(a, HUGE_PAGE, MADV_NOHUGEPAGE);
	/* from 4 KiB past one boundary to 4 KiB short of the fifth after
	 * it: the three whole pages between the first and fourth */
	uint8_t *p = a + 4096;
	size_t n = 5 * HUGE_PAGE - 2 * 4096;

	mem_advise_huge(p, n);
	assert_int_equal(advised((uintptr_t)p), 0);
	assert_int_equal(advised((uintptr_t)(a + HUGE_PAGE)), 1);
	assert_int_equal(advised((uintptr_t)(a + 4 * HUGE_PAGE - 1)), 1);
	assert_int_equal(advised((uintptr_t)(a + 4 * HUGE_PAGE)), 0);
	assert_int_equal(advised((uintptr_t)(a + 5 * HUGE_PAGE - 4096)), 0);
	/* the block is as usable as before */
	memset(p, 0x5a, n);
	assert_int_equal(p[n - 1], 0x5a);
	munmap(base, len);
	(void)state;
}

/* Blocks under 3 MiB, though this one holds a whole huge page, and NULL
 * are left alone. */
static void test_small_blocks(void **state)
{
	void *base;
	size_t len;
	uint8_t *a = aligned_map(4 * MIB, &base, &len);

	mem_advise_huge(a, 3 * MIB - 1);
	assert_int_equal(advised((uintptr_t)a), 0);
	assert_int_equal(advised((uintptr_t)(a + HUGE_PAGE - 1)), 0);
	mem_advise_huge(NULL, 64 * MIB);
	munmap(base, len);
	(void)state;
}

/* On what malloc gives, written and freed as usual. */
static void test_malloc_block(void **state)
{
	size_t n = 9 * MIB;
	uint8_t *p = malloc(n);

	assert_non_null(p);
	mem_advise_huge(p, n);
	for (size_t i = 0; i < n; i += 4096)
		p[i] = (uint8_t)i;
	assert_int_equal(p[8192], 0);
	free(p);
	(void)state;
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_interior_only),
		cmocka_unit_test(test_small_blocks),
		cmocka_unit_test(test_malloc_block),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
