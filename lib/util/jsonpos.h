/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Where a value sits in JSON text. jansson reports positions of syntax
 * errors only; for errors found after parsing (wrong type, out of range)
 * this scanner finds the line and column of a member so that the message
 * can point at it. Internal.
 */
#ifndef ASPH_JSONPOS_H
#define ASPH_JSONPOS_H

#include <stddef.h>

/*
 * path: member names from the root, "[N]" for the N-th array element.
 * On success sets *line and *column (1-based, column in bytes) of the
 * member's key (or of the element) and returns 0; -ENOENT if absent.
 * Tolerates any input without reading past len.
 */
int json_locate(const char *text, size_t len, const char *const *path,
		size_t depth, int *line, int *column);

/* Convenience for a dotted path "a.b.[2].c" (no dots inside names). */
int json_locate_dotted(const char *text, size_t len, const char *dotted,
		       int *line, int *column);

#endif
