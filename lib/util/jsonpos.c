/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "jsonpos.h"

/* The analyzers' view of it (jsonpos.h) is not the function. */
#undef json_error_set_at

struct cursor {
	const char *text;
	size_t len, pos;
	int line, col;
	int depth;
};

#define MAX_NESTING 512

static int peek(const struct cursor *c)
{
	return c->pos < c->len ? (unsigned char)c->text[c->pos] : -1;
}

static void advance(struct cursor *c)
{
	if (c->pos >= c->len)
		return;
	if (c->text[c->pos] == '\n') {
		c->line++;
		c->col = 1;
	} else {
		c->col++;
	}
	c->pos++;
}

static void skip_space(struct cursor *c)
{
	int ch;
	while ((ch = peek(c)) == ' ' || ch == '\t' || ch == '\n' || ch == '\r')
		advance(c);
}

/* Skips a string starting at '"'; copies up to cap-1 raw bytes to buf. */
static int scan_string(struct cursor *c, char *buf, size_t cap)
{
	size_t n = 0;
	if (peek(c) != '"')
		return -EINVAL;
	advance(c);
	for (;;) {
		int ch = peek(c);
		if (ch < 0)
			return -EINVAL;
		advance(c);
		if (ch == '"')
			break;
		if (ch == '\\') {
			if (peek(c) < 0)
				return -EINVAL;
			ch = peek(c);
			advance(c);
		}
		if (buf && n + 1 < cap)
			buf[n++] = (char)ch;
	}
	if (buf && cap)
		buf[n] = '\0';
	return 0;
}

static int skip_value(struct cursor *c);

static int skip_container(struct cursor *c, int open, int close)
{
	if (++c->depth > MAX_NESTING)
		return -ELOOP;
	advance(c); /* open */
	skip_space(c);
	if (peek(c) == close) {
		advance(c);
		c->depth--;
		return 0;
	}
	for (;;) {
		skip_space(c);
		if (open == '{') {
			if (scan_string(c, NULL, 0) < 0)
				return -EINVAL;
			skip_space(c);
			if (peek(c) != ':')
				return -EINVAL;
			advance(c);
		}
		if (skip_value(c) < 0)
			return -EINVAL;
		skip_space(c);
		int ch = peek(c);
		if (ch == ',') {
			advance(c);
			continue;
		}
		if (ch == close) {
			advance(c);
			c->depth--;
			return 0;
		}
		return -EINVAL;
	}
}

static int skip_value(struct cursor *c)
{
	skip_space(c);
	int ch = peek(c);
	if (ch == '"')
		return scan_string(c, NULL, 0);
	if (ch == '{')
		return skip_container(c, '{', '}');
	if (ch == '[')
		return skip_container(c, '[', ']');
	if (ch < 0)
		return -EINVAL;
	/* number, true, false, null */
	while ((ch = peek(c)) >= 0 && ch != ',' && ch != '}' && ch != ']' &&
	       ch != ' ' && ch != '\n' && ch != '\t' && ch != '\r')
		advance(c);
	return 0;
}

/* Skips the value at the cursor and the comma after it: -ENOENT when the
 * object or array ends there (or the text is malformed). */
static int skip_item(struct cursor *c)
{
	if (skip_value(c) < 0)
		return -ENOENT;
	skip_space(c);
	if (peek(c) != ',')
		return -ENOENT;
	advance(c);
	return 0;
}

/* Moves the cursor to the value of member `name` of the object at the
 * cursor, leaving the key position in line and col. */
static int find_member(struct cursor *c, const char *name, int *line, int *col)
{
	char key[256];

	skip_space(c);
	if (peek(c) != '{')
		return -ENOENT;
	advance(c);
	for (;;) {
		skip_space(c);
		if (peek(c) == '}')
			return -ENOENT;
		int kl = c->line, kc = c->col;
		if (scan_string(c, key, sizeof(key)) < 0)
			return -ENOENT;
		skip_space(c);
		if (peek(c) != ':')
			return -ENOENT;
		advance(c);
		if (!strcmp(key, name)) {
			skip_space(c);
			*line = kl;
			*col = kc;
			return 0;
		}
		if (skip_item(c) < 0)
			return -ENOENT;
	}
}

static int find_element(struct cursor *c, long index, int *line, int *col)
{
	skip_space(c);
	if (peek(c) != '[')
		return -ENOENT;
	advance(c);
	for (long i = 0;; i++) {
		skip_space(c);
		if (peek(c) == ']' || peek(c) < 0)
			return -ENOENT;
		if (i == index) {
			*line = c->line;
			*col = c->col;
			return 0;
		}
		if (skip_item(c) < 0)
			return -ENOENT;
	}
}

int json_locate(const char *text, size_t len, const char *const *path,
		size_t depth, int *line, int *column)
{
	struct cursor c = { .text = text, .len = len, .line = 1, .col = 1 };
	int l = 1, col = 1;

	skip_space(&c);
	l = c.line;
	col = c.col;
	for (size_t i = 0; i < depth; i++) {
		const char *p = path[i];
		int r;
		if (p[0] == '[') {
			char *end;
			long idx = strtol(p + 1, &end, 10);
			if (*end != ']' || idx < 0)
				return -ENOENT;
			r = find_element(&c, idx, &l, &col);
		} else {
			r = find_member(&c, p, &l, &col);
		}
		if (r < 0)
			return r;
	}
	*line = l;
	*column = col;
	return 0;
}

int json_locate_dotted(const char *text, size_t len, const char *dotted,
		       int *line, int *column)
{
	char buf[512];
	const char *parts[32] = { NULL };
	size_t n = 0;

	if (strlen(dotted) >= sizeof(buf))
		return -ENOENT;
	strcpy(buf, dotted);
	if (buf[0] == '\0')
		return json_locate(text, len, parts, 0, line, column);
	char *save = NULL;
	for (char *tok = strtok_r(buf, ".", &save); tok && n < 32;
	     tok = strtok_r(NULL, ".", &save))
		parts[n++] = tok;
	return json_locate(text, len, parts, n, line, column);
}

int json_error_locate(struct asph_error *err, int code,
		      const struct json_source *src, const char *dotted)
{
	int line = 0, column = 0;

	if (err && dotted && src->text)
		json_locate_dotted(src->text, src->len, dotted, &line, &column);
	asph_error_locate(err, src->name, line, column, dotted);
	return code;
}

int json_error_set_at(struct asph_error *err, int code,
		      const struct json_source *src, const char *dotted,
		      const char *fmt, ...)
{
	va_list ap;

	if (!err)
		return code;
	va_start(ap, fmt);
	asph_error_vset_at(err, code, NULL, 0, 0, NULL, fmt, ap);
	va_end(ap);
	return json_error_locate(err, code, src, dotted);
}
