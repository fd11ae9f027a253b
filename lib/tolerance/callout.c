/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The ISO 10110-5 surface form call-out, by recursive descent:
 *
 *   callout := "3" "/" head [ "(" inner ")" ] { [";"] rms } [ [";"] lambda ]
 *   head    := value | "-"
 *   inner   := (value | "-") [ "/" (value | "-") ] { ";" rms }
 *   rms     := "RMS" ("t" | "i" | "a") "<" value
 *   lambda  := ("λ" | "lambda") "=" number [ "nm" ]
 *   value   := number [ "nm" ]         (without a unit: fringes)
 *
 * with blanks allowed between the parts. Every error names the column.
 */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/tolerance.h"

struct cursor {
	const char *s;
	size_t pos;
	struct asph_error *err;
	int *column;
	/* what was read, in the call-out's units */
	double value[3];            /* A, B, C; NaN = "-" or absent */
	int value_nm[3];
	double rms[3];              /* t, i, a */
	int rms_nm[3];
	double lambda_nm;           /* NaN when absent */
};

static int fail(struct cursor *c, size_t at, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));

static int fail(struct cursor *c, size_t at, const char *fmt, ...)
{
	va_list ap;

	if (c->column)
		*c->column = (int)at + 1;
	if (!c->err)
		return -EINVAL;
	va_start(ap, fmt);
	asph_error_vset_at(c->err, -EINVAL, NULL, 0, 0, NULL, fmt, ap);
	va_end(ap);
	return -EINVAL;
}

static void skip_blanks(struct cursor *c)
{
	while (c->s[c->pos] == ' ' || c->s[c->pos] == '\t')
		c->pos++;
}

static int at_end(const struct cursor *c)
{
	return c->s[c->pos] == '\0';
}

/* "what was there" for a message: the character, or the end. */
static const char *found(const struct cursor *c, char *buf, size_t size)
{
	unsigned char ch = (unsigned char)c->s[c->pos];

	if (!ch)
		return "the end";
	if (ch < 0x80 && isprint(ch))
		snprintf(buf, size, "'%c'", ch);
	else
		snprintf(buf, size, "byte 0x%02x", ch);
	return buf;
}

static int accept(struct cursor *c, const char *word)
{
	size_t n = strlen(word);

	if (strncmp(c->s + c->pos, word, n))
		return 0;
	c->pos += n;
	return 1;
}

/* "-" or an en or em dash, as drawings print it. */
static int accept_dash(struct cursor *c)
{
	return accept(c, "-") || accept(c, "\xe2\x80\x93") || accept(c, "\xe2\x80\x94");
}

/* An unsigned decimal number > 0 (no exponent: drawings write none). */
static int number(struct cursor *c, double *out, const char *what)
{
	size_t start, digits = 0;
	char buf[64], f[24];

	skip_blanks(c);
	start = c->pos;
	while (isdigit((unsigned char)c->s[c->pos]) || c->s[c->pos] == '.') {
		digits += c->s[c->pos] != '.';
		c->pos++;
	}
	if (digits == 0 || c->pos - start >= sizeof(buf) ||
	    memchr(c->s + start, '.', c->pos - start) !=
		    memrchr(c->s + start, '.', c->pos - start)) {
		c->pos = start;
		snprintf(buf, sizeof(buf), "%s", what);
		if (c->column)
			*c->column = (int)start + 1;
		return asph_error_set(c->err, -EINVAL, "expected a number for %s, found %s", buf,
				      found(c, f, sizeof(f)));
	}
	memcpy(buf, c->s + start, c->pos - start);
	buf[c->pos - start] = '\0';
	*out = strtod(buf, NULL);
	if (!(*out > 0) || !isfinite(*out))
		return fail(c, start, "%s must be greater than 0", what);
	return 0;
}

/* number [nm] */
static int value(struct cursor *c, double *out, int *nm, const char *what)
{
	int r = number(c, out, what);

	if (r < 0)
		return r;
	skip_blanks(c);
	*nm = accept(c, "nm");
	return 0;
}

static int value_or_dash(struct cursor *c, int k, const char *what)
{
	skip_blanks(c);
	if (accept_dash(c))
		return 0;
	return value(c, &c->value[k], &c->value_nm[k], what);
}

static int rms(struct cursor *c)
{
	static const char kinds[] = "tia";
	const char *k;
	char f[24];
	size_t at;

	skip_blanks(c);
	at = c->pos;
	if (!accept(c, "RMS"))
		return fail(c, at, "expected %s", "RMSt, RMSi or RMSa");
	skip_blanks(c);
	k = c->s[c->pos] ? strchr(kinds, c->s[c->pos]) : NULL;
	if (!k)
		return fail(c, c->pos, "RMS must be followed by t, i or a, found %s",
			    found(c, f, sizeof(f)));
	if (!isnan(c->rms[k - kinds]))
		return fail(c, at, "RMS%c is given twice", *k);
	c->pos++;
	skip_blanks(c);
	if (!accept(c, "<"))
		return fail(c, c->pos, "expected '<' after RMS, found %s", found(c, f, sizeof(f)));
	return value(c, &c->rms[k - kinds], &c->rms_nm[k - kinds], "the RMS tolerance");
}

static int lambda(struct cursor *c)
{
	char f[24];
	int r;

	skip_blanks(c);
	if (!accept(c, "="))
		return fail(c, c->pos, "expected '=' after lambda, found %s", found(c, f, sizeof(f)));
	r = number(c, &c->lambda_nm, "the wavelength");
	if (r < 0)
		return r;
	skip_blanks(c);
	accept(c, "nm");
	return 0;
}

static int starts_lambda(struct cursor *c)
{
	return accept(c, "\xce\xbb") || accept(c, "lambda");
}

static int inner(struct cursor *c)
{
	char f[24];
	int r = value_or_dash(c, 1, "B (irregularity)");

	if (r < 0)
		return r;
	skip_blanks(c);
	if (accept(c, "/")) {
		r = value_or_dash(c, 2, "C (rotationally symmetric irregularity)");
		if (r < 0)
			return r;
	}
	skip_blanks(c);
	while (accept(c, ";")) {
		r = rms(c);
		if (r < 0)
			return r;
		skip_blanks(c);
	}
	if (!accept(c, ")"))
		return at_end(c) ? fail(c, c->pos, "missing '%s'", ")")
				 : fail(c, c->pos, "expected '/', ';' or ')', found %s",
					found(c, f, sizeof(f)));
	return 0;
}

/* The parts after the head and its parentheses. */
static int tail(struct cursor *c)
{
	char f[24];
	int r;

	for (;;) {
		/* A part is set off by ';' or by blanks (which the caller may
		 * have skipped already). */
		int blank = c->pos > 0 && (c->s[c->pos - 1] == ' ' || c->s[c->pos - 1] == '\t');
		size_t before = c->pos;
		skip_blanks(c);
		int sep = accept(c, ";");
		skip_blanks(c);
		if (at_end(c))
			return sep ? fail(c, c->pos, "nothing follows '%s'", ";") : 0;
		if (!sep && !blank && c->pos == before)
			return fail(c, c->pos, "expected ';' or a blank before %s",
				    found(c, f, sizeof(f)));
		if (starts_lambda(c))
			r = lambda(c);
		else if (!strncmp(c->s + c->pos, "RMS", 3))
			r = rms(c);
		else
			return fail(c, c->pos, "expected RMSt, RMSi, RMSa or lambda, found %s",
				    found(c, f, sizeof(f)));
		if (r < 0)
			return r;
	}
}

static int parse(struct cursor *c)
{
	char f[24];
	int r;

	skip_blanks(c);
	if (!accept(c, "3"))
		return fail(c, c->pos, "a surface form call-out starts with '3/', found %s",
			    found(c, f, sizeof(f)));
	skip_blanks(c);
	if (!accept(c, "/"))
		return fail(c, c->pos, "expected '/' after the code number 3, found %s",
			    found(c, f, sizeof(f)));
	r = value_or_dash(c, 0, "A (sagitta deviation)");
	if (r < 0)
		return r;
	skip_blanks(c);
	if (accept(c, "(")) {
		r = inner(c);
		if (r < 0)
			return r;
	}
	return tail(c);
}

/* A call-out value in nm. */
static double to_nm(double v, int nm, double wavelength_nm)
{
	return isnan(v) ? NAN : nm ? v : v * 0.5 * wavelength_nm;
}

int asph_tolerance_parse_callout(const char *callout, double wavelength_nm,
				 struct asph_tolerance *t, int *column,
				 struct asph_error *err)
{
	struct cursor c = { .s = callout, .err = err, .column = column, .lambda_nm = NAN };
	double w;
	int r;

	for (int k = 0; k < 3; k++)
		c.value[k] = c.rms[k] = NAN;
	if (column)
		*column = 0;
	if (strlen(callout) >= sizeof(t->callout))
		return fail(&c, sizeof(t->callout) - 1, "the call-out is longer than %zu bytes",
			    sizeof(t->callout) - 1);
	r = parse(&c);
	if (r < 0)
		return r;
	w = isnan(c.lambda_nm) ? wavelength_nm : c.lambda_nm;
	if (!(w > 0))
		return fail(&c, 0, "no wavelength for the fringes");
	if (isnan(c.value[0]) && isnan(c.value[1]) && isnan(c.value[2]) && isnan(c.rms[0]) &&
	    isnan(c.rms[1]) && isnan(c.rms[2]))
		return fail(&c, 0, "the call-out tolerances nothing");
	if (!isnan(c.lambda_nm))
		t->wavelength_nm = c.lambda_nm;
	snprintf(t->callout, sizeof(t->callout), "%s", callout);
	t->A.v = to_nm(c.value[0], c.value_nm[0], w);
	t->B.v = to_nm(c.value[1], c.value_nm[1], w);
	t->C.v = to_nm(c.value[2], c.value_nm[2], w);
	t->rms_t.v = to_nm(c.rms[0], c.rms_nm[0], w);
	t->rms_i.v = to_nm(c.rms[1], c.rms_nm[1], w);
	t->rms_a.v = to_nm(c.rms[2], c.rms_nm[2], w);
	return 0;
}
