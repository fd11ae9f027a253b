/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The report's text (lib/plot/report-text.c): what a client names a part,
 * lot, serial or label reaches the PDF through it. Cleaning gives text
 * cairo takes (shown on a recording surface, cairo's status stays
 * success), and cleaning it again changes nothing; the wrap at a width
 * from the first byte loses nothing but spaces at its breaks, and every
 * line fits or is one character.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"
#include "fuzz.h"
#include "report-text.h"

#if HAVE_CAIRO
/* text without its spaces and line breaks */
static char *squeezed(const char *s, size_t n)
{
	char *out = malloc(n + 1), *o = out;

	if (!out)
		return NULL;
	for (size_t i = 0; i < n; i++)
		if (s[i] != ' ' && s[i] != '\n')
			*o++ = s[i];
	*o = '\0';
	return out;
}

static void check_wrap(const char *clean, double width)
{
	cairo_surface_t *surface = cairo_recording_surface_create(CAIRO_CONTENT_COLOR_ALPHA, NULL);
	cairo_t *cr = cairo_create(surface);
	struct report_lines l = { 0 };
	size_t total = 0;

	cairo_surface_destroy(surface);
	report_font(cr, REPORT_MONO, 7);
	if (report_text_wrap(cr, clean, width, &l) < 0)
		fuzz_die("the wrap ran out of memory");
	char *joined = malloc(strlen(clean) + 1);
	if (!joined)
		fuzz_die("out of memory");
	for (size_t i = 0; i < l.n; i++) {
		unsigned char c = (unsigned char)l.v[i].s[0];
		size_t one = c < 0x80 ? 1 : c < 0xe0 ? 2 : c < 0xf0 ? 3 : 4;
		double w = report_text_width(cr, l.v[i].s, l.v[i].len);
		if (w > width + 1e-9 && l.v[i].len != one)
			fuzz_die("line %zu is %g wide, over %g", i, w, width);
		memcpy(joined + total, l.v[i].s, l.v[i].len);
		total += l.v[i].len;
		char *line = strndup(l.v[i].s, l.v[i].len);
		cairo_move_to(cr, 0, 10);
		cairo_show_text(cr, line);
		free(line);
	}
	if (cairo_status(cr) != CAIRO_STATUS_SUCCESS)
		fuzz_die("cairo refuses a line: %s", cairo_status_to_string(cairo_status(cr)));
	char *a = squeezed(clean, strlen(clean)), *b = squeezed(joined, total);
	if (!a || !b || strcmp(a, b))
		fuzz_die("the lines do not hold the text");
	free(a);
	free(b);
	free(joined);
	report_lines_release(&l);
	cairo_destroy(cr);
}
#endif

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	char *text = malloc(size + 1);

	if (!text || size == 0) {
		free(text);
		return 0;
	}
	memcpy(text, data + 1, size - 1);
	text[size - 1] = '\0';
	char *clean = report_text_clean(text);
	char *again = clean ? report_text_clean(clean) : NULL;
	if (!clean || !again)
		fuzz_die("out of memory");
	if (strcmp(clean, again))
		fuzz_die("cleaning clean text changed it");
#if HAVE_CAIRO
	/* from one character's width to a page's */
	check_wrap(clean, 1 + 2 * (double)data[0]);
#endif
	free(again);
	free(clean);
	free(text);
	return 0;
}
