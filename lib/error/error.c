/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "asph/error.h"

/* The analyzers' view of them (asph/error.h) is not the functions. */
#undef asph_error_set
#undef asph_error_set_at

void asph_error_clear(struct asph_error *err)
{
	if (err)
		memset(err, 0, sizeof(*err));
}

int asph_error_set(struct asph_error *err, int code, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	asph_error_vset_at(err, code, NULL, 0, 0, NULL, fmt, ap);
	va_end(ap);
	return code;
}

void asph_error_locate(struct asph_error *err, const char *source, int line,
		       int column, const char *field)
{
	if (!err)
		return;
	/* copying a part onto itself would overlap */
	if (source && source != err->source)
		snprintf(err->source, sizeof(err->source), "%s", source);
	if (line > 0)
		err->line = line;
	if (column > 0)
		err->column = column;
	if (field && field != err->field)
		snprintf(err->field, sizeof(err->field), "%s", field);
}

int asph_error_vset_at(struct asph_error *err, int code, const char *source,
		       int line, int column, const char *field, const char *fmt,
		       va_list ap)
{
	char msg[sizeof(err->message)];

	if (!err)
		return code;
	/* formatted aside first: the arguments may be err's own strings */
	vsnprintf(msg, sizeof(msg), fmt, ap);
	asph_error_locate(err, source, line, column, field);
	/* up to its end only: the bytes past it stay as they were (a
	 * cleared error's zeros), not the stack's leftovers */
	memcpy(err->message, msg, strlen(msg) + 1);
	err->code = code;
	return code;
}

int asph_error_set_at(struct asph_error *err, int code, const char *source,
		      int line, int column, const char *field, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	asph_error_vset_at(err, code, source, line, column, field, fmt, ap);
	va_end(ap);
	return code;
}

const char *asph_error_format(const struct asph_error *err, char *buf,
			      size_t size)
{
	size_t n = 0;

	if (size == 0)
		return buf;
	buf[0] = '\0';
	if (!err)
		return buf;
#define APPEND(...)                                                        \
	do {                                                               \
		if (n < size) {                                            \
			int w_ = snprintf(buf + n, size - n, __VA_ARGS__); \
			if (w_ > 0)                                        \
				n += (size_t)w_;                           \
		}                                                          \
	} while (0)
	if (err->source[0]) {
		APPEND("%s:", err->source);
		if (err->line > 0)
			APPEND("%d:", err->line);
		if (err->column > 0)
			APPEND("%d:", err->column);
		APPEND(" ");
	}
	if (err->field[0])
		APPEND("%s: ", err->field);
	APPEND("%s", err->message[0] ? err->message : "unknown error");
#undef APPEND
	return buf;
}
