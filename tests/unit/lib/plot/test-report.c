/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The report's text: cleaning, wrapping to a width cairo measures, and the
 * rounding rule of its figures. */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "config.h"
#include "asph/report.h"
#include "report-text.h"

static void test_clean(void **state)
{
	char *c = report_text_clean("a\tb\r\nc\x01\x7f" "d \xc2\x85" "e");

	/* control characters (C0, DEL, C1) become spaces; '\n' stays */
	assert_string_equal(c, "a b \nc  d  e");
	free(c);
	/* valid UTF-8 kept; each invalid byte (stray continuation, overlong,
	 * surrogate, truncated sequence) becomes U+FFFD */
	c = report_text_clean("µ λ ° \x80 \xc0\xaf \xed\xa0\x80 \xe2\x82");
	assert_string_equal(c, "µ λ ° \xef\xbf\xbd \xef\xbf\xbd\xef\xbf\xbd "
			       "\xef\xbf\xbd\xef\xbf\xbd\xef\xbf\xbd \xef\xbf\xbd\xef\xbf\xbd");
	free(c);
	/* noncharacters (valid UTF-8 that cairo refuses) become U+FFFD; the
	 * code points beside them stay */
	c = report_text_clean("\xef\xb7\x8f \xef\xb7\x90 \xef\xb7\xaf \xef\xb7\xb0 "
			      "\xef\xbf\xbd \xef\xbf\xbe \xef\xbf\xbf "
			      "\xf0\x9f\xbf\xbd \xf0\x9f\xbf\xbe \xf4\x8f\xbf\xbf");
	assert_string_equal(c, "\xef\xb7\x8f \xef\xbf\xbd \xef\xbf\xbd \xef\xb7\xb0 "
			       "\xef\xbf\xbd \xef\xbf\xbd \xef\xbf\xbd "
			       "\xf0\x9f\xbf\xbd \xef\xbf\xbd \xef\xbf\xbd");
	free(c);
	assert_null(report_text_clean(NULL));
}

#if HAVE_CAIRO
#include <cairo.h>

static cairo_t *measuring_context(enum report_face face, double size)
{
	cairo_surface_t *s = cairo_recording_surface_create(CAIRO_CONTENT_COLOR_ALPHA, NULL);
	cairo_t *cr = cairo_create(s);

	cairo_surface_destroy(s);
	report_font(cr, face, size);
	return cr;
}

/* text without its spaces and line breaks */
static char *squeezed(const char *s)
{
	char *out = malloc(strlen(s) + 1), *o = out;

	for (; *s; s++)
		if (*s != ' ' && *s != '\n')
			*o++ = *s;
	*o = '\0';
	return out;
}

/* Every line fits (cairo's own measure of the line as shown) or is one
 * character, and the lines hold the whole text: only spaces at the breaks
 * are left out. Returns the line count. */
static size_t check_wrap(cairo_t *cr, const char *text, double width, struct report_lines *l)
{
	char *joined = calloc(strlen(text) + 1, 1), *want = squeezed(text), *got;
	cairo_text_extents_t te;

	assert_int_equal(report_text_wrap(cr, text, width, l), 0);
	for (size_t i = 0; i < l->n; i++) {
		char *line = strndup(l->v[i].s, l->v[i].len);
		cairo_text_extents(cr, line, &te);
		unsigned char c = (unsigned char)line[0];
		size_t one = c < 0x80 ? 1 : c < 0xe0 ? 2 : c < 0xf0 ? 3 : 4;
		int single = l->v[i].len == one;
		if (te.x_advance > width + 1e-9 && !single)
			fail_msg("line %zu '%s' is %g wide, over %g", i, line, te.x_advance, width);
		strcat(joined, line);
		free(line);
	}
	got = squeezed(joined);
	assert_string_equal(got, want);
	free(got);
	free(want);
	free(joined);
	return l->n;
}

static struct report_lines wrapped(cairo_t *cr, const char *text, double width)
{
	struct report_lines l = { 0 };

	check_wrap(cr, text, width, &l);
	return l;
}

static int line_is(const struct report_lines *l, size_t i, const char *s)
{
	return i < l->n && l->v[i].len == strlen(s) && !memcmp(l->v[i].s, s, strlen(s));
}

static void test_wrap_words(void **state)
{
	cairo_t *cr = measuring_context(REPORT_SANS, 8);
	const char *text = "The quick brown fox jumps over the lazy dog, twice, and then "
			   "once more for the measurement report of a lens.";
	double w = report_text_width(cr, "The quick brown fox jumps", 25) + 0.01;
	struct report_lines l = wrapped(cr, text, w);

	/* at spaces, greedily: the first line is exactly what fits */
	assert_true(line_is(&l, 0, "The quick brown fox jumps"));
	assert_true(l.n >= 4);
	for (size_t i = 0; i < l.n; i++)
		assert_true(l.v[i].len > 0 && l.v[i].s[0] != ' ' && l.v[i].s[l.v[i].len - 1] != ' ');
	report_lines_release(&l);

	/* everything on one line when it fits; '\n' always breaks, and an
	 * empty paragraph is an empty line */
	l = wrapped(cr, "short\n\n  indented", 500);
	assert_int_equal(l.n, 3);
	assert_true(line_is(&l, 0, "short") && line_is(&l, 1, "") && line_is(&l, 2, "  indented"));
	report_lines_release(&l);
	l = wrapped(cr, "", 100);
	assert_int_equal(l.n, 1);
	assert_int_equal(l.v[0].len, 0);
	report_lines_release(&l);
	cairo_destroy(cr);
}

static void test_wrap_long_tokens(void **state)
{
	cairo_t *cr = measuring_context(REPORT_MONO, 7);
	/* a hash: no break opportunity, cut where the width ends */
	const char *hex = "3373ed06bca6c99be9e5f9869c7e6f2ae8df6fc572e9e121c47f48f73f413763";
	double w = report_text_width(cr, "0123456789", 10) + 0.01;
	struct report_lines l = wrapped(cr, hex, w);

	assert_int_equal(l.n, 7);
	for (size_t i = 0; i + 1 < l.n; i++)
		assert_int_equal(l.v[i].len, 10);
	report_lines_release(&l);

	/* compact JSON: after the commas and colons, never inside a number */
	const char *json = "{\"name\":\"mock\",\"stage\":{\"driver\":\"mock\",\"options\":"
			   "{\"speed\":20.0,\"travel_xy\":-2.0868000000000001e-5}}}";
	w = report_text_width(cr, "{\"name\":\"mock\",\"stage\":{\"dri", 28);
	l = wrapped(cr, json, w);
	assert_true(line_is(&l, 0, "{\"name\":\"mock\",\"stage\":"));
	for (size_t i = 0; i < l.n; i++) {
		char last = l.v[i].s[l.v[i].len - 1];
		assert_true(i + 1 == l.n || strchr(",:}", last));
	}
	report_lines_release(&l);

	/* a width narrower than one character still moves on, one a line,
	 * and never splits a UTF-8 sequence */
	l = wrapped(cr, "µλ°²", 1);
	assert_int_equal(l.n, 4);
	assert_true(line_is(&l, 0, "µ") && line_is(&l, 3, "²"));
	report_lines_release(&l);
	cairo_destroy(cr);
}

/* A space wins over a later punctuation when the line is then more than
 * half full; else the punctuation does. */
static void test_wrap_prefers_spaces(void **state)
{
	cairo_t *cr = measuring_context(REPORT_MONO, 7);
	double w = report_text_width(cr, "0123456789", 10) * 3.3;
	struct report_lines l = wrapped(cr, "alpha beta gamma delta,epsilon,zeta", w);

	assert_true(line_is(&l, 0, "alpha beta gamma"));
	report_lines_release(&l);
	w = report_text_width(cr, "0123456789", 10) * 3;
	l = wrapped(cr, "ab cdefghijklmnop,qrstuvwxyz,0123", w);
	assert_true(line_is(&l, 0, "ab cdefghijklmnop,qrstuvwxyz,"));
	report_lines_release(&l);
	cairo_destroy(cr);
}

/* cairo shows every cleaned text: a noncharacter left in would put the
 * context in an error state (CAIRO_STATUS_INVALID_STRING) and end the
 * drawing of the whole report. */
static void test_clean_text_shown(void **state)
{
	static const char *const texts[] = {
		"lot \xef\xbf\xbe", "\xef\xb7\x90 serial", "\xf4\x8f\xbf\xbf",
		"\xf0\x9f\xbf\xbe part", "a\x80" "b\xed\xa0\x80", "plain",
	};

	for (size_t i = 0; i < sizeof(texts) / sizeof(texts[0]); i++) {
		cairo_t *cr = measuring_context(REPORT_SANS, 8);
		char *c = report_text_clean(texts[i]);
		cairo_move_to(cr, 0, 10);
		cairo_show_text(cr, c);
		assert_int_equal(cairo_status(cr), CAIRO_STATUS_SUCCESS);
		free(c);
		cairo_destroy(cr);
	}
}
#endif

static void test_noise_floor(void **state)
{
	/* 1000 rounding steps of the radius, in nm */
	assert_true(fabs(asph_report_noise_floor_nm(20) - 1000 * DBL_EPSILON * 20 * 1e6) <
		    1e-12 * asph_report_noise_floor_nm(20));
	assert_true(asph_report_noise_floor_nm(20) < 1e-5);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_clean),
#if HAVE_CAIRO
		cmocka_unit_test(test_wrap_words),
		cmocka_unit_test(test_wrap_long_tokens),
		cmocka_unit_test(test_wrap_prefers_spaces),
		cmocka_unit_test(test_clean_text_shown),
#endif
		cmocka_unit_test(test_noise_floor),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
