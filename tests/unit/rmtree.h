/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The tests' temporary directories are removed with everything in them
 * without a shell: under valgrind, which follows child processes
 * (--trace-children=yes), a system("rm -rf ...") costs a second of
 * checking sh and rm each time.
 */
#ifndef ASPH_TEST_RMTREE_H
#define ASPH_TEST_RMTREE_H

#include <ftw.h>
#include <stdio.h>
#include <sys/stat.h>

static inline int rmtree_entry(const char *path, const struct stat *st, int type,
			       struct FTW *ftw)
{
	(void)st;
	(void)type;
	(void)ftw;
	return remove(path);
}

/* dir and everything beneath it, symbolic links as links: 0, or -1 with
 * errno. */
static inline int rmtree(const char *dir)
{
	return nftw(dir, rmtree_entry, 16, FTW_DEPTH | FTW_PHYS);
}

#endif
