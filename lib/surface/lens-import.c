/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Lens files of other programs: OpticStudio .zmx surface blocks and CSV
 * tables of prescriptions. The file is decoded to UTF-8 (from UTF-16 with
 * its byte-order mark, or from Latin-1 when it is not UTF-8) and split into
 * lines in place; every surface is read (and the file refused as a whole
 * when any is malformed), a surface is converted when it is asked for.
 */
#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "asph/lens-import.h"
#include "fileio.h"
#include "lens-import-zmx.h"
#include "util-mem.h"

#define MAX_SURFACES 1024

struct csv_rows {
	struct asph_prescription *p;
	int *line;
	int n;
};

/* A .zmx file's lens units (UNIT): how many mm one is. */
struct zmx_unit {
	const char *name;          /* as OpticStudio writes it */
	const char *words;         /* for the note of a converted prescription */
	double mm;
};

struct asph_lens_import {
	char *name;
	enum asph_lens_format format;
	struct zsurf *surf;
	size_t n_surf, cap_surf;
	const struct zmx_unit *unit;
	struct csv_rows rows;
	/* while parsing */
	struct asph_error *err;
	char *text;               /* UTF-8, NUL-terminated */
	size_t len;
};

/* A refusal of the file's content, with where: -EINVAL. */
#define fail(im, line, col, field, ...) \
	asph_error_set_at((im)->err, -EINVAL, (im)->name, line, col, field, __VA_ARGS__)

/* ---- reading and decoding ------------------------------------------------- */

static size_t put_utf8(char *o, unsigned cp)
{
	if (cp < 0x80) {
		o[0] = (char)cp;
		return 1;
	}
	if (cp < 0x800) {
		o[0] = (char)(0xc0 | (cp >> 6));
		o[1] = (char)(0x80 | (cp & 0x3f));
		return 2;
	}
	if (cp < 0x10000) {
		o[0] = (char)(0xe0 | (cp >> 12));
		o[1] = (char)(0x80 | ((cp >> 6) & 0x3f));
		o[2] = (char)(0x80 | (cp & 0x3f));
		return 3;
	}
	o[0] = (char)(0xf0 | (cp >> 18));
	o[1] = (char)(0x80 | ((cp >> 12) & 0x3f));
	o[2] = (char)(0x80 | ((cp >> 6) & 0x3f));
	o[3] = (char)(0x80 | (cp & 0x3f));
	return 4;
}

/* UTF-16 (after its byte-order mark) to UTF-8. */
static int from_utf16(struct asph_lens_import *im, const unsigned char *b, size_t n, int big)
{
	size_t units = n / 2, o = 0;
	int line = 1;

	if (n % 2)
		return fail(im, 0, 0, NULL,
			    "UTF-16 text with an odd number of bytes: the file is truncated");
	im->text = malloc(3 * units + 1);
	if (!im->text)
		return asph_error_set(im->err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < units; i++) {
		unsigned u = big ? (unsigned)(b[2 * i] << 8 | b[2 * i + 1])
				 : (unsigned)(b[2 * i + 1] << 8 | b[2 * i]);
		if (u >= 0xd800 && u < 0xdc00 && i + 1 < units) {
			unsigned v = big ? (unsigned)(b[2 * i + 2] << 8 | b[2 * i + 3])
					 : (unsigned)(b[2 * i + 3] << 8 | b[2 * i + 2]);
			if (v >= 0xdc00 && v < 0xe000) {
				u = 0x10000 + ((u - 0xd800) << 10) + (v - 0xdc00);
				i++;
			}
		}
		if ((u >= 0xd800 && u < 0xe000) || u == 0)
			return fail(im, line, 0, NULL, "invalid UTF-16 code unit 0x%04x", u);
		line += u == '\n';
		o += put_utf8(im->text + o, u);
	}
	im->text[o] = '\0';
	im->len = o;
	return 0;
}

/* Whether b holds well-formed UTF-8 (no overlong forms, no surrogates). */
static int is_utf8(const unsigned char *b, size_t n)
{
	size_t i = 0;

	while (i < n) {
		unsigned c = b[i], need, cp;
		if (c < 0x80) {
			i++;
			continue;
		}
		if (c >= 0xc2 && c < 0xe0)
			need = 1, cp = c & 0x1f;
		else if (c >= 0xe0 && c < 0xf0)
			need = 2, cp = c & 0x0f;
		else if (c >= 0xf0 && c < 0xf5)
			need = 3, cp = c & 0x07;
		else
			return 0;
		if (n - i - 1 < need)
			return 0;
		for (unsigned k = 1; k <= need; k++) {
			if ((b[i + k] & 0xc0) != 0x80)
				return 0;
			cp = cp << 6 | (b[i + k] & 0x3f);
		}
		if ((need == 2 && (cp < 0x800 || (cp >= 0xd800 && cp < 0xe000))) ||
		    (need == 3 && (cp < 0x10000 || cp > 0x10ffff)))
			return 0;
		i += need + 1;
	}
	return 1;
}

/* Text that is not UTF-8 is Latin-1 (ISO 8859-1), as older writers and
 * lens vendors' files have it: each byte is its code point. */
static int from_latin1(struct asph_lens_import *im, const unsigned char *b, size_t n)
{
	size_t o = 0;

	im->text = malloc(2 * n + 1);
	if (!im->text)
		return asph_error_set(im->err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < n; i++)
		o += put_utf8(im->text + o, b[i]);
	im->text[o] = '\0';
	im->len = o;
	return 0;
}

static int decode(struct asph_lens_import *im, const unsigned char *b, size_t n)
{
	if (n >= 2 && b[0] == 0xff && b[1] == 0xfe)
		return from_utf16(im, b + 2, n - 2, 0);
	if (n >= 2 && b[0] == 0xfe && b[1] == 0xff)
		return from_utf16(im, b + 2, n - 2, 1);
	size_t skip = (n >= 3 && b[0] == 0xef && b[1] == 0xbb && b[2] == 0xbf) ? 3 : 0;
	if (memchr(b + skip, '\0', n - skip))
		return fail(im, 0, 0, NULL,
			    "contains NUL bytes: UTF-16 without a byte-order mark is not read");
	if (!is_utf8(b + skip, n - skip))
		return from_latin1(im, b + skip, n - skip);
	im->len = n - skip;
	im->text = malloc(im->len + 1);
	if (!im->text)
		return asph_error_set(im->err, -ENOMEM, "out of memory");
	memcpy(im->text, b + skip, im->len);
	im->text[im->len] = '\0';
	return 0;
}

/* ---- lines and tokens --------------------------------------------------- */

/* Splits the next line off the text (CR LF or LF). NULL at the end. */
static char *next_line(char **rest, int *had_newline)
{
	char *s = *rest, *nl;

	if (!s || !*s)
		return NULL;
	nl = strchr(s, '\n');
	*had_newline = nl != NULL;
	if (nl) {
		*nl = '\0';
		*rest = nl + 1;
	} else {
		*rest = s + strlen(s);
	}
	size_t l = strlen(s);
	if (l && s[l - 1] == '\r')
		s[l - 1] = '\0';
	return s;
}

#define TOKEN_MAX 128

/* Copies the next whitespace-separated token at *p into tok (truncated to
 * TOKEN_MAX - 1 bytes; the line itself is left intact); its 1-based
 * column. NULL at the end of the line. */
static char *token(const char **p, const char *line_start, char tok[TOKEN_MAX], int *col)
{
	const char *s = *p, *e;

	while (*s == ' ' || *s == '\t')
		s++;
	if (!*s)
		return NULL;
	*col = (int)(s - line_start) + 1;
	for (e = s; *e && *e != ' ' && *e != '\t'; e++)
		;
	snprintf(tok, TOKEN_MAX, "%.*s", (int)(e - s), s);
	*p = e;
	return tok;
}

static int parse_double(const char *s, double *out)
{
	char *end;

	errno = 0;
	*out = strtod(s, &end);
	return s[0] && !*end && !errno && isfinite(*out) ? 0 : -EINVAL;
}

/* A keyword's next numeric argument. */
static int number_arg(const struct asph_lens_import *im, const char **p, const char *ls, int line,
		      const char *kw, double *out)
{
	char buf[TOKEN_MAX];
	int col = 0;
	const char *t = token(p, ls, buf, &col);

	if (!t)
		return fail(im, line, (int)strlen(ls) + 1, kw, "%s without a value", kw);
	/* a number longer than the token holds would be read cut short */
	if (*p - (ls + col - 1) >= TOKEN_MAX)
		return fail(im, line, col, kw, "a value of %td characters is not a number",
			    *p - (ls + col - 1));
	if (parse_double(t, out) < 0)
		return fail(im, line, col, kw, "'%s' is not a finite number", t);
	return 0;
}

/* The next numeric argument as a value with where it stands. */
static int value_arg(const struct asph_lens_import *im, const char **p, const char *ls, int line,
		     const char *kw, struct zmx_value *out)
{
	const char *s = *p;

	while (*s == ' ' || *s == '\t')
		s++;
	out->line = line;
	out->col = (int)(s - ls) + 1;
	return number_arg(im, p, ls, line, kw, &out->v);
}

/* PARM i v and XDAT i v ...: a whole index in [lo, max], then the value. */
static int indexed_arg(const struct asph_lens_import *im, const char **p, const char *ls,
		       int line, const char *kw, const char *what, int lo, int max,
		       struct zmx_value *table)
{
	double idx;
	int r = number_arg(im, p, ls, line, kw, &idx);

	if (r < 0)
		return r;
	if (idx != floor(idx) || idx < lo || idx > max)
		return fail(im, line, 0, kw, "%s number %g is not %d..%d", what, idx, lo, max);
	return value_arg(im, p, ls, line, kw, &table[(int)idx]);
}

/* SQAP, ELAP, CLAP: the aperture and its two sizes; UDAD: a user-defined
 * aperture; OBDC: the aperture's centre. */
static int aperture_line(const struct asph_lens_import *im, struct zsurf *z, const char *p,
			 const char *ls, int line, const char *kw)
{
	static const struct { const char *kw; enum zmx_aperture_kind kind; } kinds[] = {
		{ "CLAP", ZMX_APERTURE_CIRCULAR }, { "SQAP", ZMX_APERTURE_RECTANGULAR },
		{ "ELAP", ZMX_APERTURE_ELLIPTICAL }, { "UDAD", ZMX_APERTURE_USER },
	};
	int r;

	if (!strcmp(kw, "OBDC")) {
		if ((r = value_arg(im, &p, ls, line, kw, &z->decenter[0])) < 0)
			return r;
		return value_arg(im, &p, ls, line, kw, &z->decenter[1]);
	}
	for (size_t i = 0; i < ARRAY_SIZE(kinds); i++) {
		if (strcmp(kw, kinds[i].kw))
			continue;
		z->aperture = kinds[i].kind;
		z->aperture_lines++;
		z->aperture_size[0].line = line;
		if (kinds[i].kind == ZMX_APERTURE_USER)
			return 0;
		if ((r = value_arg(im, &p, ls, line, kw, &z->aperture_size[0])) < 0)
			return r;
		return value_arg(im, &p, ls, line, kw, &z->aperture_size[1]);
	}
	return 0;
}

/* ---- .zmx ------------------------------------------------------------- */

static int zmx_surface_line(struct asph_lens_import *im, struct zsurf *z, const char *p,
			    const char *ls, int line, const char *kw)
{
	char buf[TOKEN_MAX];
	int col = 0;

	if (!strcmp(kw, "TYPE")) {
		const char *t = token(&p, ls, buf, &col);
		if (!t)
			return fail(im, line, (int)strlen(ls) + 1, "TYPE", "TYPE without a name");
		snprintf(z->type, sizeof(z->type), "%s", t);
		z->type_line = line;
		z->type_col = col;
		return 0;
	}
	if (!strcmp(kw, "CURV"))
		return value_arg(im, &p, ls, line, kw, &z->curv);
	if (!strcmp(kw, "CONI"))
		return value_arg(im, &p, ls, line, kw, &z->coni);
	if (!strcmp(kw, "DIAM")) {
		return value_arg(im, &p, ls, line, kw, &z->diam);
	}
	if (!strcmp(kw, "PARM"))
		return indexed_arg(im, &p, ls, line, kw, "parameter", 0, ZMX_MAX_PARM, z->parm);
	if (!strcmp(kw, "XDAT"))
		return indexed_arg(im, &p, ls, line, kw, "extra data", 1, ZMX_MAX_XDAT,
				   z->xdat);
	return aperture_line(im, z, p, ls, line, kw);
}

/* OpticStudio's lens units; the first is the default of a file without a
 * UNIT line. */
static const struct zmx_unit units[] = {
	{ "MM", "millimetres", 1.0 },
	{ "CM", "centimetres", 10.0 },
	{ "IN", "inches", 25.4 },
	{ "INCH", "inches", 25.4 },
	{ "M", "metres", 1000.0 },
	{ "METER", "metres", 1000.0 },
	{ "METERS", "metres", 1000.0 },
};

/* UNIT u ...: the lens units, in which every length of the file is. */
static int zmx_unit(struct asph_lens_import *im, const char *p, const char *ls, int line)
{
	char buf[TOKEN_MAX];
	int col = 0;
	const char *t = token(&p, ls, buf, &col);

	if (!t)
		return 0;
	for (size_t i = 0; i < ARRAY_SIZE(units); i++)
		if (!strcasecmp(t, units[i].name)) {
			im->unit = &units[i];
			return 0;
		}
	return fail(im, line, col, "UNIT",
		    "lens units %s: the units read are MM, CM, IN and M (millimetres, "
		    "centimetres, inches, metres)", t);
}

/* Room for one more surface, zeroed. */
static int grow_surfaces(struct asph_lens_import *im)
{
	if (im->n_surf == im->cap_surf) {
		size_t cap = im->cap_surf ? 2 * im->cap_surf : 8;
		struct zsurf *s = realloc(im->surf, cap * sizeof(*s));
		if (!s)
			return asph_error_set(im->err, -ENOMEM, "out of memory");
		im->surf = s;
		im->cap_surf = cap;
	}
	memset(&im->surf[im->n_surf], 0, sizeof(*im->surf));
	return 0;
}

/*
 * A SURF block runs to the next SURF line: its keywords are read whether
 * they are indented (as OpticStudio writes them) or not, and a file may end
 * without a newline. A surface without a TYPE line is STANDARD,
 * OpticStudio's default.
 */
static int zmx_parse(struct asph_lens_import *im)
{
	char *rest = im->text, *l;
	int line = 0, nl = 1;
	struct zsurf *cur = NULL;

	im->unit = &units[0];
	while ((l = next_line(&rest, &nl))) {
		int col = 0;
		const char *ls = l, *p = l, *kw;
		char kwbuf[TOKEN_MAX];
		line++;
		if (!(kw = token(&p, ls, kwbuf, &col)))
			continue;
		if (!strcmp(kw, "UNIT")) {
			int r = zmx_unit(im, p, ls, line);
			if (r < 0)
				return r;
		} else if (!strcmp(kw, "SURF")) {
			double num;
			int r = number_arg(im, &p, ls, line, "SURF", &num);
			if (r < 0)
				return r;
			if (num != floor(num) || num < 0 || num > INT_MAX)
				return fail(im, line, col, "SURF",
					    "bad surface number %g (a whole number, 0 to %d)", num,
					    INT_MAX);
			if (im->n_surf == MAX_SURFACES)
				return fail(im, line, col, "SURF", "more than %d surfaces",
					    MAX_SURFACES);
			for (size_t i = 0; i < im->n_surf; i++)
				if (im->surf[i].number == (int)num)
					return fail(im, line, col, "SURF",
						    "surface %d again (first at line %d): which "
						    "one is meant is not clear", (int)num,
						    im->surf[i].line);
			if ((r = grow_surfaces(im)) < 0)
				return r;
			cur = &im->surf[im->n_surf++];
			cur->number = (int)num;
			cur->line = line;
		} else if (cur) {
			int r = zmx_surface_line(im, cur, p, ls, line, kw);
			if (r < 0)
				return r;
		}
	}
	if (im->n_surf == 0)
		return fail(im, line, 0, NULL, "no SURF block: not an OpticStudio lens file");
	for (size_t i = 0; i < im->n_surf; i++) {
		struct zsurf *z = &im->surf[i];
		if (z->type[0])
			continue;
		snprintf(z->type, sizeof(z->type), "STANDARD");
		z->type_line = z->line;
		z->type_col = 1;
	}
	return 0;
}

/* An extra datum's line and column, or the TYPE line's when it is absent. */
static void xdat_where(const struct zsurf *z, int i, int *line, int *col)
{
	*line = z->xdat[i].line ? z->xdat[i].line : z->type_line;
	*col = z->xdat[i].line ? z->xdat[i].col : z->type_col;
}

/* The Q-type asphere's extra data (QED_TYPE). */
#define QED_FAMILY 1      /* 0 Qbfs, 1 Qcon */
#define QED_COUNT 2       /* the number of terms N */
#define QED_NORM 3        /* the normalization radius */
#define QED_FIRST_TERM 4  /* a_0 .. a_{N-1} */

/*
 * QED_TYPE: OpticStudio's Q-type asphere, the base conic (CURV, CONI) plus
 * Forbes' Qbfs or Qcon terms. Terms past the count are OpticStudio's to
 * ignore; a count past the 31 terms a prescription holds is read when the
 * terms past a_30 are 0.
 */
static int zmx_qtype(struct asph_lens_import *im, const struct zsurf *z,
		     struct asph_prescription *p)
{
	double fam = z->xdat[QED_FAMILY].v, n = z->xdat[QED_COUNT].v;
	int line, col;

	if (fam != 0 && fam != 1) {
		xdat_where(z, QED_FAMILY, &line, &col);
		return fail(im, line, col, "XDAT 1",
			    "surface %d: Q type %g (0 is Qbfs, 1 is Qcon)", z->number, fam);
	}
	p->type = fam == 0 ? ASPH_SURFACE_QBFS : ASPH_SURFACE_QCON;
	p->norm_radius = z->xdat[QED_NORM].v;
	if (n != floor(n) || n < 0 || n > ZMX_MAX_XDAT - QED_FIRST_TERM + 1) {
		xdat_where(z, QED_COUNT, &line, &col);
		return fail(im, line, col, "XDAT 2",
			    "surface %d: %g Q terms: a whole number from 0 to %d", z->number, n,
			    ZMX_MAX_XDAT - QED_FIRST_TERM + 1);
	}
	for (int m = 0; m < (int)n; m++) {
		const struct zmx_value *a = &z->xdat[QED_FIRST_TERM + m];
		if (m <= ASPH_SURFACE_MAX_Q) {
			p->Q[m] = a->v;
			continue;
		}
		if (a->v != 0)
			return fail(im, a->line, a->col, "XDAT",
				    "surface %d: term a%d is %g: a prescription holds a0 .. a%d",
				    z->number, m, a->v, ASPH_SURFACE_MAX_Q);
	}
	return 0;
}

static const char *const aperture_keywords[] = {
	[ZMX_APERTURE_CIRCULAR] = "CLAP", [ZMX_APERTURE_RECTANGULAR] = "SQAP",
	[ZMX_APERTURE_ELLIPTICAL] = "ELAP", [ZMX_APERTURE_USER] = "UDAD",
};

/* A circular clear aperture CLAP r_min r_max: r_min > 0 is a hole. Centred
 * on the axis it is aperture_diameter, else a circle about OBDC. */
static int zmx_clap(struct asph_lens_import *im, const struct zsurf *z,
		    struct asph_prescription *p)
{
	const struct zmx_value *lo = &z->aperture_size[0], *hi = &z->aperture_size[1];

	if (lo->v != 0)
		return fail(im, lo->line, lo->col, "CLAP",
			    "surface %d: the clear aperture has a hole (minimum radius %g mm), "
			    "which a prescription cannot hold", z->number, lo->v);
	if (!(hi->v > 0))
		return fail(im, hi->line, hi->col, "CLAP",
			    "surface %d: the clear aperture's radius must be positive", z->number);
	if (z->decenter[0].v == 0 && z->decenter[1].v == 0) {
		p->aperture_diameter = 2.0 * hi->v;
		return 0;
	}
	p->aperture = (struct asph_aperture){ ASPH_APERTURE_CIRCULAR, 2.0 * hi->v, 2.0 * hi->v,
					      { z->decenter[0].v, z->decenter[1].v } };
	return 0;
}

/*
 * The clear aperture: SQAP and ELAP (half widths) for a rectangle or an
 * ellipse, CLAP for a circle, each centred at OBDC (an off-axis segment of
 * the surface); without one, the semi-diameter DIAM.
 */
static int zmx_aperture(struct asph_lens_import *im, const struct zsurf *z,
			struct asph_prescription *p)
{
	const struct zmx_value *w = &z->aperture_size[0], *h = &z->aperture_size[1];
	const char *kw = aperture_keywords[z->aperture];

	if (z->aperture_lines > 1)
		return fail(im, w->line, 1, kw, "surface %d has %d aperture lines (SQAP, ELAP, "
			    "CLAP, UDAD): one aperture is read", z->number, z->aperture_lines);
	switch (z->aperture) {
	case ZMX_APERTURE_NONE:
		if (!(z->diam.v > 0))
			return fail(im, z->diam.line ? z->diam.line : z->line,
				    z->diam.line ? z->diam.col : 1, "DIAM",
				    "surface %d has no positive semi-diameter (DIAM)", z->number);
		p->aperture_diameter = 2.0 * z->diam.v;
		return 0;
	case ZMX_APERTURE_USER:
		return fail(im, w->line, 1, kw, "surface %d: a user-defined aperture is not "
			    "imported; give the part's aperture in the prescription", z->number);
	case ZMX_APERTURE_CIRCULAR:
		return zmx_clap(im, z, p);
	case ZMX_APERTURE_RECTANGULAR:
	case ZMX_APERTURE_ELLIPTICAL:
		break;
	}
	if (!(w->v > 0) || !(h->v > 0))
		return fail(im, !(w->v > 0) ? w->line : h->line, !(w->v > 0) ? w->col : h->col, kw,
			    "surface %d: the aperture's half widths must be positive", z->number);
	p->aperture = (struct asph_aperture){
		z->aperture == ZMX_APERTURE_RECTANGULAR ? ASPH_APERTURE_RECTANGULAR
							: ASPH_APERTURE_ELLIPTICAL,
		2.0 * w->v, 2.0 * h->v, { z->decenter[0].v, z->decenter[1].v } };
	return 0;
}

/* The shape of a rotationally symmetric type: the base (CURV 0 is a
 * plane), the conic, and the type's terms. */
static int zmx_rotational(struct asph_lens_import *im, const struct zsurf *z,
			  const struct zmx_type *t, struct asph_prescription *p)
{
	int r = zmx_check_unknown_data(z, t, im->name, im->err);

	if (r < 0)
		return r;
	p->type = t->type;
	p->R = z->curv.v == 0 ? INFINITY : 1.0 / z->curv.v;
	p->k = z->coni.v;
	/* EVENASPH: PARM i multiplies r^(2i); ODDASPHE: r^i; i = 1..8. */
	for (int i = 1; i <= 8 && (t->kind == ZMX_EVENASPH || t->kind == ZMX_ODDASPH); i++)
		p->A[t->kind == ZMX_EVENASPH ? 2 * i : i] = z->parm[i].v;
	return t->kind == ZMX_QTYPE ? zmx_qtype(im, z, p) : 0;
}

/* Lens units to mm: every length by f, a coefficient of r^i (mm^(1-i))
 * by f^(1-i); curvatures follow their radii. */
static void scale_lengths(struct asph_prescription *p, double f)
{
	double *lengths[] = {
		&p->R, &p->Rx, &p->Ry, &p->R_rotation, &p->aperture_diameter, &p->norm_radius,
		&p->aperture.width, &p->aperture.height, &p->aperture.offset[0],
		&p->aperture.offset[1], &p->zernike_decenter[0], &p->zernike_decenter[1],
	};

	for (size_t i = 0; i < ARRAY_SIZE(lengths); i++)
		*lengths[i] *= f;
	for (int i = 0; i <= ASPH_SURFACE_MAX_POWER; i++)
		p->A[i] *= pow(f, 1 - i);
	for (int m = 0; m <= ASPH_SURFACE_MAX_Q; m++)
		p->Q[m] *= f;
	for (int i = 0; i < ASPH_SURFACE_XY_TERMS; i++)
		p->C[i] *= f;
	for (int j = 0; j < ASPH_SURFACE_MAX_ZERNIKE; j++)
		p->Zernike[j] *= f;
	for (int m = 0; m < ASPH_SURFACE_Q2D_MAX_M; m++)
		for (int n = 0; n <= ASPH_SURFACE_Q2D_MAX_N; n++) {
			p->q2d_a[m][n] *= f;
			p->q2d_b[m][n] *= f;
		}
}

static int zmx_convert(struct asph_lens_import *im, const struct zsurf *z,
		       struct asph_prescription *p)
{
	const struct zmx_type *t = zmx_type_of(z->type);
	char names[256];
	int r;

	if (!t) {
		zmx_type_names(names, sizeof(names));
		return fail(im, z->type_line, z->type_col, "TYPE",
			    "surface %d has type %s, which is not imported (%s are)", z->number,
			    z->type, names);
	}
	if ((r = zmx_aperture(im, z, p)) < 0)
		return r;
	r = t->kind == ZMX_FREEFORM ? zmx_freeform(z, im->name, p, im->err)
				    : zmx_rotational(im, z, t, p);
	if (r < 0 || im->unit->mm == 1.0)
		return r;
	scale_lengths(p, im->unit->mm);
	snprintf(p->note, sizeof(p->note), "lens units %s (UNIT %s) converted to mm (x %g)",
		 im->unit->words, im->unit->name, im->unit->mm);
	return 0;
}

/* ---- CSV ---------------------------------------------------------------- */

enum { COL_R = -1, COL_K = -2, COL_D = -3, COL_NONE = -4 };

static int csv_header(struct asph_lens_import *im, char *l, int *cols, int *n_cols)
{
	char *p = l;
	int n = 0, have_r = 0, have_d = 0;

	while (p) {
		char *f = p, *comma = strchr(p, ',');
		int col = (int)(f - l) + 1;
		if (comma)
			*comma = '\0';
		p = comma ? comma + 1 : NULL;
		while (isspace((unsigned char)*f))
			f++;
		for (char *e = f + strlen(f); e > f && isspace((unsigned char)e[-1]); )
			*--e = '\0';
		if (n == 64)
			return fail(im, 1, col, NULL, "more than 64 columns");
		char *end;
		long pw;
		if (!strcmp(f, "R"))
			cols[n] = COL_R, have_r = 1;
		else if (!strcmp(f, "k"))
			cols[n] = COL_K;
		else if (!strcmp(f, "aperture_diameter"))
			cols[n] = COL_D, have_d = 1;
		else if (f[0] == 'A' && (pw = strtol(f + 1, &end, 10), !*end && f[1]) &&
			 pw >= 1 && pw <= ASPH_SURFACE_MAX_POWER)
			cols[n] = (int)pw;
		else
			return fail(im, 1, col, f,
				    "unknown column '%s' (R, k, A1..A20, aperture_diameter)", f);
		n++;
	}
	if (!have_r || !have_d)
		return fail(im, 1, 1, have_r ? "aperture_diameter" : "R",
			    "the header needs the columns R and aperture_diameter");
	*n_cols = n;
	return 0;
}

static int csv_row(struct asph_lens_import *im, char *l, int line, const int *cols, int n_cols,
		   struct asph_prescription *p)
{
	char *pos = l;
	int odd = 0;

	memset(p, 0, sizeof(*p));
	for (int c = 0; c < n_cols; c++) {
		if (!pos)
			return fail(im, line, (int)strlen(l) + 1, NULL,
				    "%d fields, the header has %d", c, n_cols);
		char *f = pos, *comma = strchr(pos, ',');
		int col = (int)(f - l) + 1;
		if (comma)
			*comma = '\0';
		pos = comma ? comma + 1 : NULL;
		double v = 0;
		while (isspace((unsigned char)*f))
			f++;
		for (char *e = f + strlen(f); e > f && isspace((unsigned char)e[-1]); )
			*--e = '\0';
		if (*f && parse_double(f, &v) < 0)
			return fail(im, line, col, NULL, "'%s' is not a finite number", f);
		if (cols[c] == COL_R)
			p->R = v;
		else if (cols[c] == COL_K)
			p->k = v;
		else if (cols[c] == COL_D)
			p->aperture_diameter = v;
		else
			p->A[cols[c]] = v, odd |= (cols[c] % 2) && v != 0;
	}
	if (pos)
		return fail(im, line, (int)(pos - l) + 1, NULL, "more fields than the header's %d", n_cols);
	p->type = odd ? ASPH_SURFACE_ODD_ASPHERE : ASPH_SURFACE_EVEN_ASPHERE;
	return 0;
}

static int csv_import(struct asph_lens_import *im)
{
	struct csv_rows *rows = &im->rows;
	char *rest = im->text, *l;
	int line = 0, nl, cols[64], n_cols = 0, cap = 0;

	while ((l = next_line(&rest, &nl))) {
		line++;
		if (line == 1) {
			int r = csv_header(im, l, cols, &n_cols);
			if (r < 0)
				return r;
			continue;
		}
		if (!*l)
			continue;
		if (rows->n == cap) {
			cap = cap ? 2 * cap : 16;
			void *a = realloc(rows->p, (size_t)cap * sizeof(*rows->p));
			if (a)
				rows->p = a;
			void *b = realloc(rows->line, (size_t)cap * sizeof(int));
			if (b)
				rows->line = b;
			if (!a || !b)
				return asph_error_set(im->err, -ENOMEM, "out of memory");
		}
		int r = csv_row(im, l, line, cols, n_cols, &rows->p[rows->n]);
		if (r < 0)
			return r;
		rows->line[rows->n++] = line;
	}
	if (line == 0)
		return fail(im, 0, 0, NULL, "empty file");
	if (rows->n == 0)
		return fail(im, line, 0, NULL, "a header and no data row");
	return 0;
}

/* ---- the library's face ----------------------------------------------- */

void asph_lens_import_free(struct asph_lens_import *im)
{
	if (!im)
		return;
	free(im->name);
	free(im->surf);
	free(im->rows.p);
	free(im->rows.line);
	free(im->text);
	free(im);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_lens_import *, asph_lens_import_free)

static int is_csv(const struct asph_lens_import *im)
{
	const char *dot = strrchr(im->name, '.');
	return (dot && !strcasecmp(dot, ".csv")) || !strncmp(im->text, "R,", 2);
}

int asph_lens_import_parse(const void *data, size_t len, const char *name,
			   struct asph_lens_import **out, struct asph_error *err)
{
	_cleanup_(asph_lens_import_freep) struct asph_lens_import *im = calloc(1, sizeof(*im));
	int r;

	if (!im || !(im->name = strdup(name ? name : "<input>")))
		return asph_error_set(err, -ENOMEM, "out of memory");
	im->err = err;
	r = decode(im, data, len);
	if (r == 0) {
		im->format = is_csv(im) ? ASPH_LENS_CSV : ASPH_LENS_ZMX;
		r = im->format == ASPH_LENS_CSV ? csv_import(im) : zmx_parse(im);
	}
	if (r < 0)
		return r;
	/* the text was cut into lines; what was read is in surf and rows */
	free(steal_ptr(im->text));
	im->err = NULL;
	*out = steal_ptr(im);
	return 0;
}

int asph_lens_import_load(const char *path, struct asph_lens_import **out,
			  struct asph_error *err)
{
	_cleanup_free_ char *data = NULL;
	size_t len = 0;
	int r = file_read_all(path, ASPH_LENS_IMPORT_MAX_BYTES, &data, &len, err);

	if (r < 0)
		return r;
	return asph_lens_import_parse(data, len, strcmp(path, "-") ? path : "<stdin>", out, err);
}

enum asph_lens_format asph_lens_import_format(const struct asph_lens_import *im)
{
	return im->format;
}

const char *asph_lens_import_unit(const struct asph_lens_import *im)
{
	return im->format == ASPH_LENS_ZMX ? im->unit->name : "";
}

size_t asph_lens_import_count(const struct asph_lens_import *im)
{
	return im->format == ASPH_LENS_CSV ? (size_t)im->rows.n : im->n_surf;
}

void asph_lens_import_surface(const struct asph_lens_import *im, size_t i,
			      struct asph_lens_surface *out)
{
	memset(out, 0, sizeof(*out));
	if (im->format == ASPH_LENS_CSV) {
		const struct asph_prescription *p = &im->rows.p[i];
		out->number = (int)i + 1;
		out->R = p->R;
		out->k = p->k;
		out->aperture_diameter = p->aperture_diameter;
		out->line = im->rows.line[i];
		return;
	}
	const struct zsurf *z = &im->surf[i];
	double f = im->unit->mm;
	out->number = z->number;
	snprintf(out->type, sizeof(out->type), "%s", z->type);
	out->R = z->curv.v == 0 ? INFINITY : f / z->curv.v;
	out->k = z->coni.v;
	out->aperture_diameter = 2.0 * z->diam.v * f;
	out->line = z->line;
}

static void name_from(struct asph_prescription *p, const char *path, int surface)
{
	const char *base = strrchr(path, '/');

	base = base ? base + 1 : path;
	snprintf(p->name, sizeof(p->name), "%.*s-s%d", (int)strcspn(base, "."), base, surface);
}

static int check(struct asph_lens_import *im, const struct asph_prescription *p, int line)
{
	struct asph_error e;

	asph_error_clear(&e);
	if (asph_prescription_check(p, &e) == 0)
		return 0;
	return fail(im, line, 0, e.field[0] ? e.field : NULL, "%s", e.message);
}

/* The keyword and datum of the surface that give a prescription's member
 * (a field of asph_prescription_check()); NULL where none does. */
static const struct zmx_value *zmx_source(const struct zsurf *z, const char *field,
					  char kw[16])
{
	const struct zmx_type *t = zmx_type_of(z->type);
	const int qtype = t && t->kind == ZMX_QTYPE;
	int i, j, parm = -1, xdat = -1;

	if (!strcmp(field, "R") || !strcmp(field, "Ry"))
		return snprintf(kw, 16, "CURV"), &z->curv;
	if (!strcmp(field, "k") || !strcmp(field, "ky"))
		return snprintf(kw, 16, "CONI"), &z->coni;
	if (!strncmp(field, "aperture", 8) && z->aperture != ZMX_APERTURE_NONE)
		return snprintf(kw, 16, "%s", aperture_keywords[z->aperture]), &z->aperture_size[0];
	if (!strncmp(field, "aperture", 8))
		return snprintf(kw, 16, "DIAM"), &z->diam;
	if (!strcmp(field, "Rx") || !strcmp(field, "R_rotation"))
		parm = 1;
	else if (!strcmp(field, "kx"))
		parm = 2;
	else if (!strcmp(field, "norm_radius"))
		xdat = qtype ? QED_NORM : 2;
	else if (sscanf(field, "a.[%d]", &i) == 1)
		xdat = QED_FIRST_TERM + i;
	else if (sscanf(field, "A.%d", &i) == 1)
		/* r^i is PARM i (ODDASPHE), i/2 (EVENASPH, SZERNSAG), y^i i/2 + 1 (TOROIDAL) */
		parm = t && t->kind == ZMX_ODDASPH ? i : !strcmp(z->type, "TOROIDAL") ? i / 2 + 1
											: i / 2;
	else if (sscanf(field, "zernike.[%d]", &i) == 1)
		xdat = 3 + i;
	else if (sscanf(field, "c.x%dy%d", &i, &j) == 2)
		xdat = 2 + asph_xy_index(i, j);
	if (parm >= 0 && parm <= ZMX_MAX_PARM)
		return snprintf(kw, 16, "PARM %d", parm), &z->parm[parm];
	if (xdat >= 1 && xdat <= ZMX_MAX_XDAT)
		return snprintf(kw, 16, "XDAT %d", xdat), &z->xdat[xdat];
	return NULL;
}

/* The prescription's own checks, said in the file's terms: the keyword
 * and line that give the member, the member and what is wrong. */
static int zmx_check(struct asph_lens_import *im, const struct zsurf *z,
		     const struct asph_prescription *p)
{
	const struct zmx_value *v;
	struct asph_error e;
	char kw[16];

	asph_error_clear(&e);
	if (asph_prescription_check(p, &e) == 0)
		return 0;
	v = e.field[0] ? zmx_source(z, e.field, kw) : NULL;
	if (!v)
		return fail(im, z->line, 0, e.field[0] ? e.field : NULL, "surface %d: %s",
			    z->number, e.message);
	return fail(im, v->line ? v->line : z->type_line, v->line ? v->col : z->type_col, kw,
		    "surface %d: %s: %s", z->number, e.field, e.message);
}

static int zmx_prescription(struct asph_lens_import *im, int want,
			    struct asph_prescription *p)
{
	const struct zsurf *z = NULL;
	int r;

	for (size_t i = 0; i < im->n_surf; i++)
		if (im->surf[i].number == want || (want < 0 && im->n_surf == 1))
			z = &im->surf[i];
	if (!z && want < 0)
		return asph_error_set_at(im->err, -ENOENT, im->name, 0, 0, NULL,
					 "%zu surfaces: choose one", im->n_surf);
	if (!z)
		return asph_error_set_at(im->err, -ENOENT, im->name, 0, 0, NULL,
					 "no surface %d (the file has %d to %d)", want,
					 im->surf[0].number, im->surf[im->n_surf - 1].number);
	memset(p, 0, sizeof(*p));
	if ((r = zmx_convert(im, z, p)) < 0)
		return r;
	name_from(p, im->name, z->number);
	return zmx_check(im, z, p);
}

static int csv_prescription(struct asph_lens_import *im, int want,
			    struct asph_prescription *p)
{
	const struct csv_rows *rows = &im->rows;

	if (want < 0 && rows->n > 1)
		return asph_error_set_at(im->err, -ENOENT, im->name, 0, 0, NULL,
					 "%d rows: choose one", rows->n);
	if (want == 0 || want > rows->n)
		return asph_error_set_at(im->err, -ENOENT, im->name, 0, 0, NULL,
					 "no row %d (the file has %d)", want, rows->n);
	int i = want < 0 ? 0 : want - 1;
	*p = rows->p[i];
	name_from(p, im->name, i + 1);
	return check(im, p, rows->line[i]);
}

int asph_lens_import_prescription(const struct asph_lens_import *im, int number,
				  struct asph_prescription *out,
				  struct asph_error *err)
{
	/* The error sink is the caller's for this call only. */
	struct asph_lens_import call = *im;

	call.err = err;
	return im->format == ASPH_LENS_CSV ? csv_prescription(&call, number, out)
					   : zmx_prescription(&call, number, out);
}
