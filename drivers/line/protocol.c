/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Replies, command templates and reply patterns of a line dialogue. */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "protocol.h"

/* ------------------------------------------------------------ replies */

void line_reader_clear(struct line_reader *r)
{
	r->len = 0;
}

int line_reader_add(struct line_reader *r, const char *bytes, size_t n,
		    struct asph_error *err)
{
	if (n > sizeof(r->buf) - r->len)
		return asph_error_set(err, -EPROTO,
				      "the device sent %zu bytes without ending a line", r->len + n);
	memcpy(r->buf + r->len, bytes, n);
	r->len += n;
	return 0;
}

void line_printable(const char *s, char *out, size_t size)
{
	size_t o = 0;

	for (; *s && o + 5 < size; s++) {
		unsigned char c = (unsigned char)*s;
		if (c >= 0x20 && c < 0x7f)
			out[o++] = (char)c;
		else
			o += (size_t)snprintf(out + o, size - o, "\\x%02x", c);
	}
	if (size)
		out[o < size ? o : size - 1] = '\0';
}

void line_reader_pending(const struct line_reader *r, char *out, size_t size)
{
	char tmp[LINE_REPLY_MAX + 1];
	size_t n = r->len < LINE_REPLY_MAX ? r->len : LINE_REPLY_MAX;

	memcpy(tmp, r->buf, n);
	tmp[n] = '\0';
	/* a NUL inside would end the text early: show it */
	for (size_t i = 0; i < n; i++)
		if (!tmp[i])
			tmp[i] = '\x01';
	line_printable(tmp, out, size);
}

static const char *find(const char *hay, size_t n, const char *needle)
{
	size_t m = strlen(needle);

	for (size_t i = 0; m && i + m <= n; i++)
		if (!memcmp(hay + i, needle, m))
			return hay + i;
	return NULL;
}

static bool printable_text(const char *s, size_t n)
{
	for (size_t i = 0; i < n; i++) {
		unsigned char c = (unsigned char)s[i];
		/* tabs and carriage returns are layout; anything else below a
		 * space and DEL are line noise. 8-bit bytes are text of some
		 * devices (GCS #7 answers 0xB1) */
		if ((c < 0x20 && c != '\t' && c != '\r' && c != '\n') || c == 0x7f)
			return false;
	}
	return true;
}

int line_reader_take(struct line_reader *r, const char *terminator,
		     const char *continuation, char *out, size_t size,
		     struct asph_error *err)
{
	size_t tl = strlen(terminator), cl = strlen(continuation), start = 0, o = 0;

	for (;;) {
		const char *t = find(r->buf + start, r->len - start, terminator);
		if (!t)
			return 0;
		size_t n = (size_t)(t - (r->buf + start));
		bool more = cl && n >= cl && !memcmp(r->buf + start + n - cl, continuation, cl);
		size_t keep = more ? n - cl : n;
		if (o + keep + 2 > size || o + keep + 2 > LINE_REPLY_MAX) {
			line_reader_clear(r);
			return asph_error_set(err, -EPROTO, "a reply longer than %d bytes",
					      LINE_REPLY_MAX);
		}
		if (!printable_text(r->buf + start, n)) {
			char shown[160], raw[LINE_REPLY_MAX];
			size_t s = n < sizeof(raw) - 1 ? n : sizeof(raw) - 1;
			memcpy(raw, r->buf + start, s);
			raw[s] = '\0';
			for (size_t i = 0; i < s; i++)
				if (!raw[i])
					raw[i] = '\x01';
			line_printable(raw, shown, sizeof(shown));
			memmove(r->buf, t + tl, r->len - (size_t)(t + tl - r->buf));
			r->len -= (size_t)(t + tl - r->buf);
			return asph_error_set(err, -EPROTO, "garbled reply '%s' (not text)", shown);
		}
		memcpy(out + o, r->buf + start, keep);
		o += keep;
		start += n + tl;
		if (!more)
			break;
		out[o++] = '\n';
	}
	out[o] = '\0';
	memmove(r->buf, r->buf + start, r->len - start);
	r->len -= start;
	return 1;
}

/* ---------------------------------------------------- templates, patterns */

enum ph {
	PH_AXIS, PH_TARGET, PH_SPEED, PH_A0, PH_A1, PH_A2, PH_T0, PH_T1, PH_T2,
	PH_POS, PH_P0, PH_P1, PH_P2, PH_VALUE, PH_CODE, PH_HEX, PH_INT, PH_NUM, PH_TEXT,
	PH_ANY, PH_COUNT
};

static const struct {
	const char *name;
	unsigned kinds;         /* 1: command, 2: pattern */
	bool per_axis;
} placeholders[PH_COUNT] = {
	[PH_AXIS] = { "axis", 3, true }, [PH_TARGET] = { "target", 1, true },
	[PH_SPEED] = { "speed", 1, false }, [PH_A0] = { "a0", 3, false },
	[PH_A1] = { "a1", 3, false }, [PH_A2] = { "a2", 3, false },
	[PH_T0] = { "t0", 1, false }, [PH_T1] = { "t1", 1, false }, [PH_T2] = { "t2", 1, false },
	[PH_POS] = { "pos", 2, true }, [PH_P0] = { "p0", 2, false }, [PH_P1] = { "p1", 2, false },
	[PH_P2] = { "p2", 2, false }, [PH_VALUE] = { "value", 2, false },
	[PH_CODE] = { "code", 2, false }, [PH_HEX] = { "hex", 2, false },
	[PH_INT] = { "int", 2, false }, [PH_NUM] = { "num", 2, false },
	[PH_TEXT] = { "text", 2, false }, [PH_ANY] = { "*", 2, false },
};

/* One item of a template or pattern: a literal byte or a placeholder. */
struct item {
	int ph;                 /* -1: literal c */
	char c;
	size_t len;             /* bytes of text it takes */
};

static int hexval(char c)
{
	if (c >= '0' && c <= '9')
		return c - '0';
	c = (char)tolower((unsigned char)c);
	return c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
}

/* The item at s; -1 with *why for a malformed one. */
static int next_item(const char *s, struct item *it, const char **why)
{
	it->ph = -1;
	if (*s == '\\') {
		static const char from[] = "nrt\\{}", to[] = "\n\r\t\\{}";
		const char *k = s[1] ? strchr(from, s[1]) : NULL;
		if (k) {
			it->c = to[k - from];
			it->len = 2;
			return 0;
		}
		if (s[1] == 'x' && hexval(s[2]) >= 0 && hexval(s[3]) >= 0 &&
		    (hexval(s[2]) << 4 | hexval(s[3])) != 0) {
			it->c = (char)(hexval(s[2]) << 4 | hexval(s[3]));
			it->len = 4;
			return 0;
		}
		*why = "unknown escape (\\n \\r \\t \\\\ \\{ \\} \\xHH)";
		return -1;
	}
	if (*s == '{') {
		const char *end = strchr(s, '}');
		if (!end) {
			*why = "'{' without '}' (write \\{ for a brace)";
			return -1;
		}
		for (int p = 0; p < PH_COUNT; p++) {
			size_t n = strlen(placeholders[p].name);
			if (n == (size_t)(end - s - 1) && !strncmp(s + 1, placeholders[p].name, n)) {
				it->ph = p;
				it->len = n + 2;
				return 0;
			}
		}
		*why = "unknown placeholder";
		return -1;
	}
	if (*s == '}') {
		*why = "'}' without '{' (write \\} for a brace)";
		return -1;
	}
	it->c = *s;
	it->len = 1;
	return 0;
}

int line_text_check(const char *text, enum line_text_kind kind, bool *per_axis,
		    struct asph_error *err)
{
	unsigned mask = kind == LINE_TEXT_COMMAND ? 1 : 2;
	const char *why = NULL;
	bool prev_wild = false;

	*per_axis = false;
	for (const char *s = text; *s;) {
		struct item it;
		if (next_item(s, &it, &why) < 0 ||
		    (it.ph >= 0 && !(placeholders[it.ph].kinds & mask) &&
		     (why = kind == LINE_TEXT_COMMAND ? "a reply placeholder in a command"
						      : "a command placeholder in a pattern")) ||
		    (it.ph == PH_ANY || it.ph == PH_TEXT ?
		     (prev_wild && (why = "two wildcards ({*}, {text}) in a row")) : false)) {
			asph_error_set(err, -EINVAL, "%s at '%.24s'", why, s);
			if (err)
				err->column = (int)(s - text) + 1;
			return -EINVAL;
		}
		prev_wild = it.ph == PH_ANY || it.ph == PH_TEXT;
		if (it.ph >= 0 && placeholders[it.ph].per_axis)
			*per_axis = true;
		s += it.len;
	}
	return 0;
}

static int put(char *out, size_t size, size_t *o, const char *s, size_t n)
{
	if (*o + n >= size)
		return -ENOSPC;
	memcpy(out + *o, s, n);
	*o += n;
	out[*o] = '\0';
	return 0;
}

static int put_number(char *out, size_t size, size_t *o, double x, int decimals)
{
	char num[64];

	if (!isfinite(x) || fabs(x) > 1e15)
		return -EINVAL;
	int n = snprintf(num, sizeof(num), "%.*f", decimals, x);
	/* no "-0.000": some controllers refuse a signed zero */
	if (strspn(num, "-0.") == (size_t)n && num[0] == '-')
		return put(out, size, o, num + 1, (size_t)n - 1);
	return put(out, size, o, num, (size_t)n);
}

int line_expand(const char *tmpl, const struct line_vars *v, char *out, size_t size,
		struct asph_error *err)
{
	size_t o = 0;
	const char *why = NULL;
	int r = 0;

	if (size)
		out[0] = '\0';
	for (const char *s = tmpl; *s && r == 0;) {
		struct item it;
		if (next_item(s, &it, &why) < 0)
			return asph_error_set(err, -EINVAL, "command template: %s", why);
		int k = v->axis < 0 ? 0 : v->axis;
		switch (it.ph) {
		case -1: r = put(out, size, &o, &it.c, 1); break;
		case PH_AXIS: r = put(out, size, &o, v->axis_ids[k], strlen(v->axis_ids[k])); break;
		case PH_A0: case PH_A1: case PH_A2:
			r = put(out, size, &o, v->axis_ids[it.ph - PH_A0], strlen(v->axis_ids[it.ph - PH_A0]));
			break;
		case PH_TARGET: r = put_number(out, size, &o, v->target[k], v->decimals); break;
		case PH_T0: case PH_T1: case PH_T2:
			r = put_number(out, size, &o, v->target[it.ph - PH_T0], v->decimals);
			break;
		case PH_SPEED: r = put_number(out, size, &o, v->speed, v->decimals); break;
		default:
			return asph_error_set(err, -EINVAL, "command template: a reply placeholder");
		}
		s += it.len;
	}
	if (r == -ENOSPC)
		return asph_error_set(err, r, "the command '%.40s...' is longer than %zu bytes", out,
				      size - 1);
	if (r < 0)
		return asph_error_set(err, r, "a number of the command is not finite");
	return 0;
}

/* A decimal number at s: its length, 0 when there is none. */
static size_t scan_number(const char *s, double *x)
{
	size_t i = 0, digits = 0;

	if (s[i] == '+' || s[i] == '-')
		i++;
	while (isdigit((unsigned char)s[i]))
		i++, digits++;
	if (s[i] == '.') {
		i++;
		while (isdigit((unsigned char)s[i]))
			i++, digits++;
	}
	if (!digits)
		return 0;
	if ((s[i] == 'e' || s[i] == 'E') && (isdigit((unsigned char)s[i + 1]) ||
					     ((s[i + 1] == '+' || s[i + 1] == '-') &&
					      isdigit((unsigned char)s[i + 2])))) {
		i += 2;
		while (isdigit((unsigned char)s[i]))
			i++;
	}
	char buf[64];
	if (i >= sizeof(buf))
		return 0;
	memcpy(buf, s, i);
	buf[i] = '\0';
	*x = strtod(buf, NULL);
	return isfinite(*x) ? i : 0;
}

static size_t scan_int(const char *s, long *x, int base)
{
	size_t i = (base == 10 && (s[0] == '+' || s[0] == '-')) ? 1 : 0, start = i;

	while (base == 10 ? isdigit((unsigned char)s[i]) : hexval(s[i]) >= 0)
		i++;
	if (i == start || i - start > 15)
		return 0;
	*x = strtol(s, NULL, base);
	return i;
}

/* Matches pattern p against the reply at s to its end; depth bounds the
 * backtracking of wildcards. */
static bool match_at(const char *p, const char *s, const struct line_vars *v,
		     struct line_match *m, int depth)
{
	const char *why;

	if (depth > 8)
		return false;
	while (*p) {
		struct item it;
		double x;
		long c;
		size_t n;
		if (next_item(p, &it, &why) < 0)
			return false;
		p += it.len;
		int k = v->axis < 0 ? 0 : v->axis;
		switch (it.ph) {
		case -1:
			if (*s++ != it.c)
				return false;
			break;
		case PH_AXIS: case PH_A0: case PH_A1: case PH_A2: {
			const char *id = v->axis_ids[it.ph == PH_AXIS ? k : it.ph - PH_A0];
			n = strlen(id);
			if (strncmp(s, id, n))
				return false;
			s += n;
			break;
		}
		case PH_POS: case PH_P0: case PH_P1: case PH_P2: case PH_VALUE: case PH_NUM:
			if (!(n = scan_number(s, &x)))
				return false;
			s += n;
			if (it.ph == PH_VALUE)
				m->value = x, m->has_value = true;
			else if (it.ph != PH_NUM) {
				int a = it.ph == PH_POS ? k : it.ph - PH_P0;
				m->pos[a] = x;
				m->has_pos[a] = true;
			}
			break;
		case PH_CODE: case PH_INT: case PH_HEX:
			if (!(n = scan_int(s, &c, it.ph == PH_HEX ? 16 : 10)))
				return false;
			s += n;
			if (it.ph != PH_INT)
				m->code = c, m->has_code = true;
			break;
		case PH_TEXT: case PH_ANY:
			/* the shortest run after which the rest matches */
			for (const char *e = s;; e++) {
				struct line_match t = *m;
				if (match_at(p, e, v, &t, depth + 1)) {
					*m = t;
					if (it.ph == PH_TEXT) {
						size_t len = (size_t)(e - s) < sizeof(m->text) - 1
							     ? (size_t)(e - s) : sizeof(m->text) - 1;
						memcpy(m->text, s, len);
						m->text[len] = '\0';
						m->has_text = true;
					}
					return true;
				}
				if (!*e)
					return false;
			}
		default:
			return false;
		}
	}
	return *s == '\0';
}

bool line_match(const char *pattern, const char *reply, const struct line_vars *v,
		struct line_match *m)
{
	struct line_match t;

	memset(&t, 0, sizeof(t));
	if (!match_at(pattern, reply, v, &t, 0))
		return false;
	/* keep what earlier matches of the same operation found */
	for (int k = 0; k < 3; k++)
		if (t.has_pos[k])
			m->pos[k] = t.pos[k], m->has_pos[k] = true;
	if (t.has_value)
		m->value = t.value, m->has_value = true;
	if (t.has_code)
		m->code = t.code, m->has_code = true;
	if (t.has_text) {
		memcpy(m->text, t.text, sizeof(m->text));
		m->has_text = true;
	}
	return true;
}

int line_unescape(const char *text, char *out, size_t size)
{
	size_t o = 0;
	const char *why;

	for (const char *s = text; *s;) {
		struct item it;
		if (next_item(s, &it, &why) < 0 || it.ph >= 0 || o + 1 >= size)
			return -EINVAL;
		out[o++] = it.c;
		s += it.len;
	}
	out[o] = '\0';
	return o ? 0 : -EINVAL;
}
