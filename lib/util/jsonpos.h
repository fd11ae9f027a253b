/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Where a value sits in JSON text. jansson reports positions of syntax
 * errors only; for errors found after parsing (wrong type, out of range)
 * this scanner finds the line and column of a member so that the message
 * can point at it. Internal.
 */
#ifndef ASPH_JSONPOS_H
#define ASPH_JSONPOS_H

#include <stdarg.h>
#include <stddef.h>

#include "asph/error.h"

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

/* JSON text and where it came from (a file name, "<stdin>", ...), for
 * messages that point into it. */
struct json_source {
	const char *text;       /* NULL: not read yet, no line or column */
	size_t len;
	const char *name;
};

/* Sets err's location (asph_error_locate()) to the member at dotted in the
 * source: its name, the member's line and column (unknown when dotted is
 * NULL or not found) and dotted as the field. Returns code. */
int json_error_locate(struct asph_error *err, int code,
		      const struct json_source *src, const char *dotted);

/* asph_error_set_at() where the member at dotted stands in the source. */
int json_error_set_at(struct asph_error *err, int code,
		      const struct json_source *src, const char *dotted,
		      const char *fmt, ...) __attribute__((format(printf, 5, 6)));

#ifdef __clang_analyzer__
#define json_error_set_at(err, code, ...) (json_error_set_at(err, code, __VA_ARGS__), (code))
#endif

#endif
