/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The report's text: made valid UTF-8 for cairo, and wrapped to a width
 * measured in the font it is shown in. Internal to lib/plot and its test. */
#ifndef ASPH_REPORT_TEXT_H
#define ASPH_REPORT_TEXT_H

#include <stddef.h>

#include "config.h"

/* A copy of text that cairo can show: invalid UTF-8 and noncharacters
 * (U+FDD0 to U+FDEF, U+FFFE, U+FFFF, U+1FFFE, ...: cairo refuses them)
 * replaced by U+FFFD, control characters other than '\n' (tabs, carriage
 * returns) by a space.
 * NULL for NULL text or ENOMEM. */
char *report_text_clean(const char *text);

/* One line of a wrapped text: bytes [s, s + len). */
struct report_line {
	const char *s;
	size_t len;
};

struct report_lines {
	size_t n, cap;
	struct report_line *v;
};

void report_lines_release(struct report_lines *l);

#if HAVE_CAIRO
#include <cairo.h>

/*
 * Breaks clean text (report_text_clean()) into lines no wider than width
 * (points, in cr's current font), appended to *out (pointing into text):
 * at each '\n'; else at the last space that fits when the line is then
 * more than half full, or after the last of , ; : / = & | ) ] } that fits
 * (JSON, paths); a token wider than the line (a hash, a long name) is cut
 * after the last character that fits, and every line holds one character
 * at least. The spaces at a break are left out, the indentation of a
 * paragraph's first line is kept. An empty text is one empty line.
 * -ENOMEM.
 */
int report_text_wrap(cairo_t *cr, const char *text, double width, struct report_lines *out);

/* The advance of s[0, len) in cr's current font (what cairo_show_text()
 * moves), points. */
double report_text_width(cairo_t *cr, const char *s, size_t len);

/* The report's faces: DejaVu Sans and DejaVu Sans Mono (Debian's
 * fonts-dejavu-core; fontconfig picks the nearest sans-serif face where
 * they are missing), black. */
enum report_face {
	REPORT_SANS,
	REPORT_SANS_BOLD,
	REPORT_MONO,
};

void report_font(cairo_t *cr, enum report_face face, double size);
#endif

#endif
