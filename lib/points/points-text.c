/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Delimited text: comma, semicolon, tab or blank separated columns, with or
 * without a header naming x, y, z and their units, as spreadsheets,
 * profilometers and asphere machines export them. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "readers.h"
#include "util-mem.h"
#include "util-number.h"
#include "util-utf8.h"

#define BLANK_SEP ' '

struct text_layout {
	char sep;               /* ',', ';', '\t', or BLANK_SEP: runs of blanks */
	bool decimal_comma;     /* a ',' in a number is its decimal point */
	int count;              /* columns */
	int col[3];             /* the columns of x, y, z */
	int ivalue;             /* the value column, or -1 */
	double scale[3];        /* mm per unit of x, y, z */
	char unit[3][16];
	char value_name[32];
};

/* One line and where it is, for messages. */
struct text_line {
	const char *s;
	size_t len;
	int no;
	const char *source;
};

static const char axis_name[3][2] = { "x", "y", "z" };

static bool is_blank(char c)
{
	return c == ' ' || c == '\t' || c == '\r';
}

/* The separator a line uses: a tab, else a semicolon, else a comma, else
 * blanks. */
static char line_separator(const struct text_line *l)
{
	if (memchr(l->s, '\t', l->len))
		return '\t';
	if (memchr(l->s, ';', l->len))
		return ';';
	if (memchr(l->s, ',', l->len))
		return ',';
	return BLANK_SEP;
}

/* One field: its text at [b, e) without the blanks around it and without
 * the double quotes of a quoted field (R and spreadsheets quote the header:
 * "x","y","z"), and where the next one starts. */
struct field {
	size_t b, e, next;
};

/* The field at pos: 1, 0 when the line has no more, or a negative errno. */
static int next_field(const struct text_line *l, char sep, size_t pos, struct field *f,
		      struct asph_error *err)
{
	size_t p = pos, q, len = l->len;

	if (pos > len)
		return 0;
	while (p < len && is_blank(l->s[p]))
		p++;
	if (sep == BLANK_SEP && p == len)
		return 0;
	if (p < len && l->s[p] == '"') {
		/* a quote inside is doubled ("") */
		for (q = p + 1; q < len; q++) {
			if (l->s[q] == '"' && q + 1 < len && l->s[q + 1] == '"')
				q++;
			else if (l->s[q] == '"')
				break;
		}
		if (q >= len)
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)p + 1, NULL,
						 "text: a quote that does not close");
		f->b = p + 1;
		f->e = q;
		for (q++; q < len && is_blank(l->s[q]) && l->s[q] != sep; q++)
			;
		if (q < len && l->s[q] != sep)
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)q + 1, NULL,
						 "text: text after the closing quote");
		f->next = q < len ? q + 1 : len + 1;
		return 1;
	}
	if (sep == BLANK_SEP) {
		for (q = p; q < len && !is_blank(l->s[q]); q++)
			;
		f->b = p;
		f->e = q;
		f->next = q;
		return 1;
	}
	for (q = p; q < len && l->s[q] != sep; q++)
		;
	f->b = p;
	f->e = q;
	while (f->e > f->b && is_blank(l->s[f->e - 1]))
		f->e--;
	f->next = q + 1;
	return 1;
}

/* The number in [b, e): 0, or -EINVAL when it is not one. A decimal comma
 * is read as a point where the separator leaves no doubt; a number with
 * both is refused (a thousands separator cannot be told from a decimal). */
static int parse_number(const char *s, size_t n, bool decimal_comma, double *v)
{
	char tmp[128], *stop;

	if (n == 0 || n >= sizeof(tmp))
		return -EINVAL;
	/* the common case without a copy or the locale; the rest (blanks
	 * before it, a decimal comma) as strtod() reads it */
	if (parse_double(s, n, v) == n)
		return 0;
	memcpy(tmp, s, n);
	tmp[n] = '\0';
	if (decimal_comma) {
		char *comma = strchr(tmp, ',');
		if (comma && (strchr(tmp, '.') || strchr(comma + 1, ',')))
			return -EINVAL;
		if (comma)
			*comma = '.';
	}
	*v = strtod(tmp, &stop);
	return *stop ? -EINVAL : 0;
}

static void copy_text(char *dst, size_t size, const char *s, size_t n)
{
	snprintf(dst, size, "%.*s", (int)(n < size ? n : size - 1), s);
}

/* A header name: "x" with an optional unit, "x [mm]", "x(mm)", "X/mm",
 * "x_um", "x mm": the axis (0-2), -1 for another column, or -EINVAL for an
 * axis with a unit in brackets or after a slash that is not one. */
static int header_axis(const char *s, size_t n, double *scale, char unit[16])
{
	size_t k = 0, r, e = n;
	char rest[32];

	while (k < n && !strchr("[(/_ \t", s[k]))
		k++;
	if (k != 1 || !strchr("xyzXYZ", s[0]))
		return -1;
	int axis = (s[0] | 0x20) - 'x';
	for (r = k; r < n && is_blank(s[r]); r++)
		;
	char open = r < n ? s[r] : '\0';
	if (open == '[' || open == '(' || open == '/' || open == '_')
		r++;
	while (r < n && is_blank(s[r]))
		r++;
	if ((open == '[' && e > r && s[e - 1] == ']') || (open == '(' && e > r && s[e - 1] == ')'))
		e--;
	while (e > r && is_blank(s[e - 1]))
		e--;
	*scale = 0;
	unit[0] = '\0';
	if (r >= e)
		return axis;
	copy_text(rest, sizeof(rest), s + r, e - r);
	if (asph_points_unit_parse(rest, scale) < 0)
		return open == '[' || open == '(' || open == '/' ? -EINVAL : -1;
	copy_text(unit, 16, rest, strlen(rest));
	return axis;
}

/* A header: 1 when l names x, y and z (the layout then holds the columns
 * and units), 0 when it does not, or a negative errno. */
static int try_header(const struct text_line *l, struct text_layout *t, struct asph_error *err)
{
	struct field f = { .next = 0 };
	int col = 0, r;

	t->sep = line_separator(l);
	t->col[0] = t->col[1] = t->col[2] = t->ivalue = -1;
	int last_axis = -1, not_utf8 = -1;
	size_t not_utf8_at = 0;

	while ((r = next_field(l, t->sep, f.next, &f, err)) > 0) {
		double scale;
		char unit[16], name[64];
		if (not_utf8 < 0 && !utf8_valid(l->s + f.b, f.e - f.b)) {
			not_utf8 = col;
			not_utf8_at = f.b;
		}
		copy_text(name, sizeof(name), l->s + f.b, f.e - f.b);
		/* blank separated, "x [mm]" is two fields: the unit goes with
		 * the axis before it */
		if (t->sep == BLANK_SEP && last_axis >= 0 && !t->unit[last_axis][0] &&
		    (name[0] == '[' || name[0] == '(')) {
			char joined[80];
			snprintf(joined, sizeof(joined), "%s %s", axis_name[last_axis], name);
			if (header_axis(joined, strlen(joined), &scale, unit) != last_axis)
				return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, name,
							 "text: an unknown unit (nm, um, mm, cm, m, in)");
			t->scale[last_axis] = scale;
			snprintf(t->unit[last_axis], sizeof(t->unit[last_axis]), "%s", unit);
			last_axis = -1;
			continue;
		}
		int axis = header_axis(l->s + f.b, f.e - f.b, &scale, unit);
		last_axis = axis >= 0 ? axis : -1;
		if (axis == -EINVAL)
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, name,
						 "text: an unknown unit (nm, um, mm, cm, m, in)");
		if (axis >= 0 && t->col[axis] >= 0)
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, name,
						 "text: two columns name %s", axis_name[axis]);
		if (axis >= 0) {
			t->col[axis] = col;
			t->scale[axis] = scale;
			snprintf(t->unit[axis], sizeof(t->unit[axis]), "%s", unit);
		} else if (t->ivalue < 0 && name[0] && parse_number(name, strlen(name), false, &scale) < 0) {
			t->ivalue = col;
			snprintf(t->value_name, sizeof(t->value_name), "%.31s", name);
		}
		col++;
	}
	if (r < 0)
		return r;
	t->count = col;
	/* A header with a column's name its writer garbled (or wrote in
	 * Latin-1): which column holds what cannot be told with certainty.
	 * (A preamble line in Latin-1 names no axes and is passed over.) */
	if (t->col[0] >= 0 && t->col[2] >= 0 && not_utf8 >= 0)
		return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)not_utf8_at + 1, NULL,
					 "text: the header's field %d is not UTF-8 text (save the file as UTF-8)",
					 not_utf8 + 1);
	/* x and z without y: a line profile along x, as a tactile
	 * profilometer exports one (y = 0) */
	return t->col[0] >= 0 && t->col[2] >= 0;
}

/* The fields of a row as numbers into v (count of them): the number of
 * fields, -EDOM with bad the first one that is not a number, or the error
 * of a field that cannot be split off. */
static int row_numbers(const struct text_line *l, char sep, bool decimal_comma, double *v,
		       int count, struct field *bad, struct asph_error *err)
{
	struct field f = { .next = 0 };
	int n = 0, r;

	while ((r = next_field(l, sep, f.next, &f, err)) > 0) {
		double x;
		/* a separator that ends the line, as European exports write */
		if (f.b == f.e && f.next > l->len && n > 0 && sep != BLANK_SEP)
			break;
		if (parse_number(l->s + f.b, f.e - f.b, decimal_comma, &x) < 0) {
			*bad = f;
			return -EDOM;
		}
		if (n < count)
			v[n] = x;
		n++;
	}
	return r < 0 ? r : n;
}

/* A row of a file whose columns a header named: x, y, z (scaled to mm) and
 * the value. */
static int header_row(const struct text_line *l, const struct text_layout *t, double xyz[3],
		      double *value, struct asph_error *err)
{
	struct field f = { .next = 0 };
	int col = 0, r;

	xyz[1] = 0;     /* a profile's, whose header names no y */
	for (; col < t->count; col++) {
		r = next_field(l, t->sep, f.next, &f, err);
		if (r < 0)
			return r;
		if (r == 0)
			break;
		int axis = col == t->col[0] ? 0 : col == t->col[1] ? 1 : col == t->col[2] ? 2 : -1;
		const char *field = axis >= 0 ? axis_name[axis] : col == t->ivalue ? t->value_name : NULL;
		if (!field)
			continue;
		char tmp[128];
		double v;
		if (f.e == f.b || f.e - f.b >= sizeof(tmp))
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, field,
						 f.e == f.b ? "text: empty value" : "text: value too long");
		copy_text(tmp, sizeof(tmp), l->s + f.b, f.e - f.b);
		if (parse_number(tmp, strlen(tmp), t->decimal_comma, &v) < 0)
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, field,
						 "text: not a number: '%s'", tmp);
		if (!isfinite(v))
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, field,
						 "text: not a finite number: '%s'", tmp);
		if (axis < 0) {
			*value = v;
			continue;
		}
		xyz[axis] = t->scale[axis] == 1 ? v : v * t->scale[axis];
		if (!isfinite(xyz[axis]))
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, field,
						 "text: '%s' %s is not a finite number of mm", tmp,
						 t->unit[axis]);
	}
	if (col < t->count) {
		/* columns past the last one read may be left out (a trailing
		 * separator in the header, unnamed columns) */
		int last = t->col[0] > t->col[1] ? t->col[0] : t->col[1];
		last = last > t->col[2] ? last : t->col[2];
		last = last > t->ivalue ? last : t->ivalue;
		if (col <= last)
			return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)l->len + 1, NULL,
						 "text: expected %d columns, found %d", t->count, col);
	} else if ((r = next_field(l, t->sep, f.next, &f, err)) != 0) {
		return r < 0 ? r : asph_error_set_at(err, -EINVAL, l->source, l->no, (int)f.b + 1, NULL,
						      "text: expected %d columns, found more", t->count);
	}
	return 0;
}

/* A row of a file without a header: three numbers x, y, z. */
static int plain_row(const struct text_line *l, const struct text_layout *t, double xyz[3],
		     struct asph_error *err)
{
	struct field bad;
	double v[3];
	int n = row_numbers(l, t->sep, t->decimal_comma, v, 3, &bad, err);

	if (n == -EDOM) {
		char tmp[64];
		copy_text(tmp, sizeof(tmp), l->s + bad.b, bad.e - bad.b);
		return asph_error_set_at(err, -EINVAL, l->source, l->no, (int)bad.b + 1, NULL,
					 "text: not a number: '%s'", tmp);
	}
	if (n < 0)
		return n;
	if (n != 3)
		return asph_error_set_at(err, -EINVAL, l->source, l->no, 1, NULL,
					 "text: a file without a header has three columns x, y, z; this row has %d",
					 n);
	for (int k = 0; k < 3; k++) {
		double mm = t->scale[k] == 1 ? v[k] : v[k] * t->scale[k];
		if (!isfinite(mm))
			return asph_error_set_at(err, -EINVAL, l->source, l->no, 0, axis_name[k],
						 "text: not a finite number");
		xyz[k] = mm;
	}
	return 0;
}

/* The fields of l split at sep. */
static int field_count(const struct text_line *l, char sep)
{
	struct field f = { .next = 0 };
	int n = 0;

	while (next_field(l, sep, f.next, &f, NULL) > 0)
		n++;
	return n;
}

enum line_kind { LINE_PREAMBLE, LINE_HEADER, LINE_DATA };

/* Before the data: a header, the first row of a file without one, or a
 * preamble line (its first field is not a number). A row whose first field
 * is a number is data, read (and refused if it cannot be) as such. */
static int classify(const struct text_line *l, struct text_layout *t, enum line_kind *kind,
		    struct asph_error *err)
{
	int r = try_header(l, t, err);
	struct field bad, first;
	double v[3];

	if (r < 0)
		return r;
	if (r > 0) {
		*kind = LINE_HEADER;
		return 0;
	}
	t->sep = line_separator(l);
	t->decimal_comma = t->sep == ';' || t->sep == '\t';
	t->count = 3;
	t->ivalue = -1;
	for (int k = 0; k < 3; k++)
		t->col[k] = k;
	r = row_numbers(l, t->sep, t->decimal_comma, v, 3, &bad, NULL);
	*kind = LINE_DATA;
	if (r < 0 && (next_field(l, t->sep, 0, &first, NULL) <= 0 ||
		      (r == -EDOM && first.b == bad.b) ||
		      parse_number(l->s + first.b, first.e - first.b, t->decimal_comma, v) < 0))
		*kind = LINE_PREAMBLE;
	return 0;
}

/* The line before the first row of a file without a header, split as the
 * rows are into as many fields, is a header that does not name x, y, z:
 * refused rather than read as a note (the columns may be anything). */
static int check_unnamed_header(const struct text_line *prev, const struct text_line *row,
				char sep, struct asph_error *err)
{
	if (!prev->s || sep == BLANK_SEP || prev->no + 1 != row->no ||
	    !memchr(prev->s, sep, prev->len) || field_count(prev, sep) != field_count(row, sep))
		return 0;
	return asph_error_set_at(err, -EINVAL, prev->source, prev->no, 1, NULL,
				 "text: the header '%.*s' does not name the columns x, y, z (a header names them x, y, z, or x and z for a profile along x, with units as in 'z [um]')",
				 (int)(prev->len > 80 ? 80 : prev->len), prev->s);
}

struct growing {
	double *xyz, *val;
	size_t n, cap;
};

/* Room for cap points in g. */
static int reserve(struct growing *g, size_t cap, struct asph_error *err)
{
	double *x = realloc(g->xyz, 3 * cap * sizeof(double));
	if (!x)
		return asph_error_set(err, -ENOMEM, "out of memory");
	g->xyz = x;
	mem_advise_huge(x, 3 * cap * sizeof(double));
	double *v = realloc(g->val, cap * sizeof(double));
	if (!v)
		return asph_error_set(err, -ENOMEM, "out of memory");
	g->val = v;
	mem_advise_huge(v, cap * sizeof(double));
	g->cap = cap;
	return 0;
}

static int grow(struct growing *g, const struct text_line *l, struct asph_error *err)
{
	if (g->n < g->cap)
		return 0;
	if (g->cap >= POINTS_MAX)
		return asph_error_set_at(err, -E2BIG, l->source, l->no, 1, NULL,
					 "text: more than %zu points", POINTS_MAX);
	return reserve(g, g->cap ? 2 * g->cap : 1024, err);
}

/* Room for as many points as the text has lines (within POINTS_MAX), so
 * that a large file's points are not copied from one array to the next as
 * it doubles. */
static int reserve_lines(struct growing *g, const char *text, size_t len,
			 struct asph_error *err)
{
	size_t lines = 1;

	for (const char *s = text, *end = text + len;
	     (s = memchr(s, '\n', (size_t)(end - s))) && lines < POINTS_MAX; s++)
		lines++;
	return lines > 1024 ? reserve(g, lines, err) : 0;
}

static bool is_comment(const char *s, size_t n)
{
	return n && (s[0] == '#' || s[0] == '%' || (n > 1 && s[0] == '/' && s[1] == '/'));
}

static void units_of(struct text_layout *t, const struct asph_points_read_options *o)
{
	for (int k = 0; k < 3; k++)
		if (t->scale[k] == 0)
			t->scale[k] = o && o->unit_mm > 0 ? o->unit_mm : 1;
}

int points_read_text(const char *text, size_t len, const char *source,
		     const struct asph_points_read_options *o, struct asph_points **out,
		     struct asph_points_read_info *info, struct asph_error *err)
{
	struct text_layout t = { 0 };
	struct growing g = { 0 };
	struct text_line first = { 0 }, preamble = { 0 };
	size_t pos = 0;
	int lineno = 0, started = 0, r = 0;

	/* spreadsheets' "CSV UTF-8" starts with a byte-order mark */
	if (len >= 3 && !memcmp(text, "\xef\xbb\xbf", 3))
		pos = 3;
	r = reserve_lines(&g, text, len, err);
	while (pos < len && r == 0) {
		size_t end = pos;
		while (end < len && text[end] != '\n')
			end++;
		struct text_line l = { text + pos, end - pos, ++lineno, source };
		pos = end + 1;
		while (l.len && l.s[l.len - 1] == '\r')
			l.len--;
		size_t skip = 0;
		while (skip < l.len && is_blank(l.s[skip]))
			skip++;
		if (skip == l.len || is_comment(l.s + skip, l.len - skip))
			continue;
		if (memchr(l.s, '\0', l.len)) {
			r = asph_error_set_at(err, -EINVAL, source, l.no, 1, NULL,
					      "text: binary data in a text file");
			break;
		}
		if (!first.s)
			first = l;
		if (!started) {
			enum line_kind kind;
			struct text_layout candidate = { 0 };
			if ((r = classify(&l, &candidate, &kind, err)) < 0)
				break;
			if (kind == LINE_PREAMBLE) {
				info->n_preamble++;
				preamble = l;
				continue;
			}
			if (kind == LINE_DATA &&
			    (r = check_unnamed_header(&preamble, &l, candidate.sep, err)) < 0)
				break;
			t = candidate;
			units_of(&t, o);
			started = 1;
			info->has_header = kind == LINE_HEADER;
			if (kind == LINE_HEADER) {
				t.decimal_comma = t.sep == ';' || t.sep == '\t';
				continue;
			}
		}
		if ((r = grow(&g, &l, err)) < 0)
			break;
		r = info->has_header ? header_row(&l, &t, g.xyz + 3 * g.n, g.val + g.n, err)
				     : plain_row(&l, &t, g.xyz + 3 * g.n, err);
		if (r == 0)
			g.n++;
	}
	if (r == 0 && !started && !first.s)
		r = asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
				      "text: empty file: expected a header x,y,z and points");
	else if (r == 0 && !started)
		r = asph_error_set_at(err, -EINVAL, source, first.no, 1, NULL,
				      "text: no header naming the columns x,y,z and no row of numbers (the first line is '%.*s')",
				      (int)(first.len > 80 ? 80 : first.len), first.s);
	if (r < 0) {
		free(g.xyz);
		free(g.val);
		return r;
	}
	struct asph_points *p = calloc(1, sizeof(*p));
	if (!p) {
		free(g.xyz);
		free(g.val);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	p->n = g.n;
	p->xyz = g.xyz ? g.xyz : calloc(1, sizeof(double));
	if (info->has_header && t.ivalue >= 0) {
		p->value = g.val;
		snprintf(p->value_name, sizeof(p->value_name), "%s", t.value_name);
	} else {
		free(g.val);
	}
	for (int k = 0; k < 3; k++)
		snprintf(info->units[k], sizeof(info->units[k]), "%s", t.unit[k]);
	*out = p;
	return 0;
}
