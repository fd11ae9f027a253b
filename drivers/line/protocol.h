/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The bytes of a line dialogue, without I/O: splitting what a device sends
 * into replies (terminators, continued lines), expanding command templates
 * and matching replies against patterns (docs/driver-line.md). Pure, so
 * that the fuzz targets reach all of it. Internal to drivers/line/.
 */
#ifndef ASPH_LINE_PROTOCOL_H
#define ASPH_LINE_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>

#include "asph/error.h"

#define LINE_REPLY_MAX 1024     /* one reply, continuation lines joined */

/* ------------------------------------------------------------ replies */

/* Bytes received and not yet taken as replies. */
struct line_reader {
	char buf[4 * LINE_REPLY_MAX];
	size_t len;
};

/*
 * Takes the next whole reply out of r: the bytes up to the terminator,
 * without it. A line that ends in continuation just before the
 * terminator (GCS: a space) goes on with the next line; the lines are
 * joined with "\n", each without its continuation. 1 and the reply in
 * out when there is one, 0 when the reply is incomplete, -EPROTO with a
 * reason for a reply longer than LINE_REPLY_MAX or with bytes that are
 * not printable text (a garbled line). An empty continuation disables
 * continued lines.
 */
int line_reader_take(struct line_reader *r, const char *terminator,
		     const char *continuation, char *out, size_t size,
		     struct asph_error *err);

/* Appends n received bytes; -EPROTO when the buffer would overflow (a
 * device that sends without ever ending a line). */
int line_reader_add(struct line_reader *r, const char *bytes, size_t n,
		    struct asph_error *err);

/* What is left: a partial line, for the error that reports it. */
void line_reader_pending(const struct line_reader *r, char *out, size_t size);
void line_reader_clear(struct line_reader *r);

/* ---------------------------------------------------- templates, patterns */

/* What placeholders stand for. */
struct line_vars {
	const char *axis_ids[3];        /* {a0} {a1} {a2} */
	int axis;                       /* {axis}, {target}: this axis, or -1 */
	double target[3];               /* {target}, {t0} .. {t2} */
	double speed;                   /* {speed} */
	int decimals;                   /* of numbers in commands */
};

/* What a matched reply carried. */
struct line_match {
	bool has_pos[3], has_value, has_code, has_text;
	double pos[3];                  /* {pos} of the axis, {p0} .. {p2} */
	double value;                   /* {value} */
	long code;                      /* {code} (decimal) or {hex} */
	char text[128];                 /* {text} */
};

/* Where a placeholder may stand. */
enum line_text_kind {
	LINE_TEXT_COMMAND = 0,
	LINE_TEXT_PATTERN,
};

/*
 * Checks a template or pattern: escapes (\n \r \t \\ \{ \xHH) and
 * placeholders known for its kind. *per_axis: it names one axis ({axis},
 * {target}, {pos}). -EINVAL with the reason (err->column is the byte in
 * text, 1-based).
 */
int line_text_check(const char *text, enum line_text_kind kind, bool *per_axis,
		    struct asph_error *err);

/* Expands a checked command template into out (without terminator);
 * -ENOSPC when it does not fit, -EINVAL for a number that is not
 * finite. */
int line_expand(const char *tmpl, const struct line_vars *v, char *out, size_t size,
		struct asph_error *err);

/* Matches a whole reply against a checked pattern; true when it matches,
 * with what it carried in m. Numbers are decimal with an optional sign,
 * point and exponent; no spaces inside. */
bool line_match(const char *pattern, const char *reply, const struct line_vars *v,
		struct line_match *m);

/* Copies s into out with bytes that are not printable as \xHH, for
 * messages (out is always terminated). */
void line_printable(const char *s, char *out, size_t size);

/* Decodes \n \r \t \\ \xHH of a terminator ("\r\n" -> CR LF); -EINVAL for
 * anything else or an empty result. */
int line_unescape(const char *text, char *out, size_t size);

#endif
