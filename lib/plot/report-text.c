/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The report's text: cleaned, wrapped, and its figures rounded. */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/report.h"
#include "report-text.h"

/* The length of the valid UTF-8 sequence at s (1 to 4), its code point in
 * *code, or 0 when it is not one: a stray continuation byte, a truncated or
 * overlong sequence, a surrogate, or past U+10FFFF. */
static size_t utf8_valid_length(const unsigned char *s, uint32_t *code)
{
	uint32_t c;
	size_t n;

	*code = s[0];
	if (s[0] < 0x80)
		return 1;
	if (s[0] >= 0xc2 && s[0] <= 0xdf)
		n = 2, c = s[0] & 0x1f;
	else if (s[0] >= 0xe0 && s[0] <= 0xef)
		n = 3, c = s[0] & 0x0f;
	else if (s[0] >= 0xf0 && s[0] <= 0xf4)
		n = 4, c = s[0] & 0x07;
	else
		return 0;
	for (size_t k = 1; k < n; k++) {
		if ((s[k] & 0xc0) != 0x80)
			return 0;
		c = c << 6 | (s[k] & 0x3f);
	}
	if ((n == 3 && c < 0x800) || (n == 4 && (c < 0x10000 || c > 0x10ffff)) ||
	    (c >= 0xd800 && c <= 0xdfff))
		return 0;
	*code = c;
	return n;
}

/* A C1 control character (U+0080 to U+009F), as two bytes of UTF-8. */
static int is_c1_control(const unsigned char *s, size_t n)
{
	return n == 2 && s[0] == 0xc2 && s[1] < 0xa0;
}

/* A noncharacter (U+FDD0 to U+FDEF, and the last two code points of every
 * plane, U+FFFE, U+FFFF, U+1FFFE, ...): valid UTF-8, but cairo refuses a
 * string holding one (CAIRO_STATUS_INVALID_STRING), and its error would
 * end the drawing of the whole report. */
static int is_noncharacter(uint32_t c)
{
	return (c >= 0xfdd0 && c <= 0xfdef) || (c & 0xfffe) == 0xfffe;
}

char *report_text_clean(const char *text)
{
	const unsigned char *s = (const unsigned char *)text;
	char *out, *o;

	if (!text)
		return NULL;
	/* U+FFFD takes 3 bytes where the invalid byte took 1. */
	out = malloc(3 * strlen(text) + 1);
	if (!out)
		return NULL;
	o = out;
	while (*s) {
		uint32_t c;
		size_t n = utf8_valid_length(s, &c);
		if (n == 0 || is_noncharacter(c)) {
			/* a noncharacter's 3 or 4 bytes become U+FFFD's 3 */
			memcpy(o, "\xef\xbf\xbd", 3);
			o += 3;
			s += n ? n : 1;
		} else if ((n == 1 && ((*s < 0x20 && *s != '\n') || *s == 0x7f)) ||
			   is_c1_control(s, n)) {
			*o++ = ' ';
			s += n;
		} else {
			memcpy(o, s, n);
			o += n;
			s += n;
		}
	}
	*o = '\0';
	return out;
}

void report_lines_release(struct report_lines *l)
{
	free(l->v);
	l->v = NULL;
	l->n = l->cap = 0;
}

double asph_report_noise_floor_nm(double radius_mm)
{
	return 1000 * DBL_EPSILON * fabs(radius_mm) * 1e6;
}

#if HAVE_CAIRO

void report_font(cairo_t *cr, enum report_face face, double size)
{
	cairo_select_font_face(cr, face == REPORT_MONO ? "DejaVu Sans Mono" : "DejaVu Sans",
			       CAIRO_FONT_SLANT_NORMAL,
			       face == REPORT_SANS_BOLD ? CAIRO_FONT_WEIGHT_BOLD
							: CAIRO_FONT_WEIGHT_NORMAL);
	cairo_set_font_size(cr, size);
	cairo_set_source_rgb(cr, 0, 0, 0);
}

double report_text_width(cairo_t *cr, const char *s, size_t len)
{
	cairo_text_extents_t te;
	char small[64];
	char *buf = len < sizeof(small) ? small : malloc(len + 1);

	if (!buf)
		return INFINITY;
	memcpy(buf, s, len);
	buf[len] = '\0';
	cairo_text_extents(cr, buf, &te);
	if (buf != small)
		free(buf);
	return te.x_advance;
}

static int lines_add(struct report_lines *l, const char *s, size_t len)
{
	if (l->n == l->cap) {
		size_t cap = l->cap ? 2 * l->cap : 16;
		struct report_line *v = realloc(l->v, cap * sizeof(*v));
		if (!v)
			return -ENOMEM;
		l->v = v;
		l->cap = cap;
	}
	l->v[l->n++] = (struct report_line){ s, len };
	return 0;
}

/* The byte length of the (clean) character at s. */
static size_t char_length(const char *s)
{
	uint32_t c;
	size_t n = utf8_valid_length((const unsigned char *)s, &c);

	return n ? n : 1;
}

/* The advance of one character, with ASCII's looked up once per text. */
struct advances {
	cairo_t *cr;
	double ascii[128];
};

static double char_advance(struct advances *a, const char *s, size_t n)
{
	unsigned char c = (unsigned char)s[0];

	if (n > 1)
		return report_text_width(a->cr, s, n);
	if (a->ascii[c] < 0)
		a->ascii[c] = report_text_width(a->cr, s, 1);
	return a->ascii[c];
}

static int breaks_after(char c)
{
	return c && strchr(",;:/=&|)]}", c) != NULL;
}

/* Where one line of s[i, len) ends and the next begins. */
struct cut {
	size_t end, next;
};

/*
 * The line from s[i]: up to the last space that fits when that leaves the
 * line more than half full, else up to the last punctuation that fits (a
 * long JSON or path text), else up to the last character that fits.
 */
static struct cut line_cut(struct advances *a, const char *s, size_t i, size_t len, double width)
{
	struct cut space = { 0, 0 }, punct = { 0, 0 };
	double w = 0, w_space = 0;
	size_t k = i;

	while (k < len) {
		size_t n = char_length(s + k);
		double adv = char_advance(a, s + k, n);
		if (w + adv > width && k > i)
			break;
		w += adv;
		k += n;
		if (s[k - n] == ' ') {
			space = (struct cut){ k - n, k };
			w_space = w;
		} else if (n == 1 && breaks_after(s[k - n])) {
			punct = (struct cut){ k, k };
		}
	}
	if (k >= len)
		return (struct cut){ len, len };
	if (s[k] == ' ')
		return (struct cut){ k, k };
	if (space.next > i && (w_space > width / 2 || punct.next <= space.next))
		return space;
	if (punct.next > i)
		return punct;
	if (space.next > i)
		return space;
	return (struct cut){ k, k };
}

/* One paragraph s[0, len) (no '\n'). */
static int wrap_paragraph(struct advances *a, const char *s, size_t len, double width,
			  struct report_lines *out)
{
	size_t i = 0;

	do {
		struct cut c = line_cut(a, s, i, len, width);
		size_t end = c.end;
		while (end > i && s[end - 1] == ' ')
			end--;
		if (lines_add(out, s + i, end - i) < 0)
			return -ENOMEM;
		i = c.next;
		while (i < len && s[i] == ' ')
			i++;
	} while (i < len);
	return 0;
}

int report_text_wrap(cairo_t *cr, const char *text, double width, struct report_lines *out)
{
	struct advances a = { .cr = cr };
	const char *p = text;

	for (size_t c = 0; c < 128; c++)
		a.ascii[c] = -1;
	for (;;) {
		const char *end = strchrnul(p, '\n');
		int r = wrap_paragraph(&a, p, (size_t)(end - p), width, out);
		if (r < 0)
			return r;
		if (!*end)
			return 0;
		p = end + 1;
	}
}

#endif
