/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Files compiled into a program: the line driver's built-in profiles and
 * the web page, so that a program finds them wherever it was built or
 * installed. scripts/embed-files writes each table at build time from the
 * files of a source folder (meson runs it); directories the user names
 * only override them. Internal.
 */
#ifndef ASPH_EMBEDDED_H
#define ASPH_EMBEDDED_H

#include <stddef.h>
#include <string.h>

struct embedded_file {
	const char *name;               /* the file's name, without a folder */
	const unsigned char *data;      /* its bytes, then a NUL */
	size_t size;                    /* without the NUL */
};

/* The file called name in a table of n, sorted by name; NULL if none. */
static inline const struct embedded_file *
embedded_file_find(const struct embedded_file *files, size_t n, const char *name)
{
	for (size_t i = 0; i < n; i++)
		if (!strcmp(files[i].name, name))
			return &files[i];
	return NULL;
}

#endif
