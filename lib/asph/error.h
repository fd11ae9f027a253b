/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_ERROR_H
#define ASPH_ERROR_H

#include <stdarg.h>
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Functions that can fail return 0 or a negative errno. When a person has to
 * read why, they also fill an optional struct asph_error: what went wrong and
 * where (a file with line and column, a field, or both). Every part is
 * optional: an empty string or 0 means "not known".
 */
struct asph_error {
	int code;              /* the negative errno that was returned */
	char source[256];      /* file name, or "<preset>", "<stdin>", ... */
	int line;              /* 1-based, 0 if not applicable */
	int column;            /* 1-based, 0 if not applicable */
	char field[128];       /* e.g. "A.6", "aperture_diameter" */
	char message[512];
};

/* Clears err (a NULL err is allowed everywhere). */
void asph_error_clear(struct asph_error *err);

/* Sets code and message; returns code so callers can write
 * `return asph_error_set(err, -EINVAL, "...")`. */
int asph_error_set(struct asph_error *err, int code, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));

/* Static analyzers see one file at a time: tell them that the result is
 * code, so `return asph_error_set(err, -EINVAL, ...)` is known to fail. */
#ifdef __clang_analyzer__
#define asph_error_set(err, code, ...) (asph_error_set(err, code, __VA_ARGS__), (code))
#endif

/* Sets the location parts; any may be NULL/0 to leave them as they are. */
void asph_error_locate(struct asph_error *err, const char *source, int line,
		       int column, const char *field);

/* asph_error_set() and asph_error_locate() in one call: the message and
 * where. The arguments may point into err itself (to re-word a message). */
int asph_error_set_at(struct asph_error *err, int code, const char *source,
		      int line, int column, const char *field, const char *fmt, ...)
	__attribute__((format(printf, 7, 8)));
int asph_error_vset_at(struct asph_error *err, int code, const char *source,
		       int line, int column, const char *field, const char *fmt,
		       va_list ap) __attribute__((format(printf, 7, 0)));

#ifdef __clang_analyzer__
#define asph_error_set_at(err, code, ...) (asph_error_set_at(err, code, __VA_ARGS__), (code))
#endif

/* "source:line:column: field: message" with absent parts left out.
 * Returns buf. */
const char *asph_error_format(const struct asph_error *err, char *buf,
			      size_t size);

#ifdef __cplusplus
}
#endif

#endif
