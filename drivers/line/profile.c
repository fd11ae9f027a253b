/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The line profile format: a line-oriented file, one setting or step a
 * line (docs/driver-line.md). */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "profile.h"
#include "protocol.h"

#define MAGIC "asphd-line-profile"
#define MAX_WORDS 12

static const char *const op_names[LINE_OP_COUNT] = {
	[LINE_OP_CONNECT] = "connect", [LINE_OP_ENABLE] = "enable",
	[LINE_OP_VELOCITY] = "velocity", [LINE_OP_HOME] = "home", [LINE_OP_MOVE] = "move",
	[LINE_OP_POSITION] = "position", [LINE_OP_STOP] = "stop", [LINE_OP_READ] = "read",
};

const char *line_op_name(enum line_op_id id)
{
	return (unsigned)id < LINE_OP_COUNT ? op_names[id] : "?";
}

/* One line cut into words: bare words or "quoted strings" (whose
 * backslash escapes stay for the template checks, \" excepted). */
struct words {
	char buf[4 * LINE_TEXT_MAX];
	char *w[MAX_WORDS];
	int col[MAX_WORDS];     /* 1-based column of each word */
	int n;
};

struct parser {
	const char *source;
	int line;
	struct asph_error *err;
	struct line_profile *p;
	int op;                 /* the open "op" block, or -1 */
	int op_line;            /* where it opened */
	bool seen_magic;
};

/* The reason, at the file's line and column (0: none). */
__attribute__((format(printf, 3, 4)))
static int fail(struct parser *ps, int col, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	asph_error_vset_at(ps->err, -EINVAL, ps->source, ps->line, col, NULL, fmt, ap);
	va_end(ap);
	return -EINVAL;
}

static int split(struct parser *ps, const char *line, size_t len, struct words *w)
{
	size_t o = 0, i = 0;

	w->n = 0;
	while (i < len) {
		if (line[i] == ' ' || line[i] == '\t') {
			i++;
			continue;
		}
		if (line[i] == '#')
			break;
		if (w->n == MAX_WORDS)
			return fail(ps, (int)i + 1, "too many words on a line (at most %d)", MAX_WORDS);
		w->col[w->n] = (int)i + 1;
		w->w[w->n++] = w->buf + o;
		if (line[i] == '"') {
			size_t start = i++;
			for (;; i++) {
				if (i >= len)
					return fail(ps, (int)start + 1, "a string without its closing quote");
				if (line[i] == '"')
					break;
				if (line[i] == '\\' && i + 1 < len && line[i + 1] == '"')
					i++;
				else if (line[i] == '\\' && i + 1 < len)
					w->buf[o++] = line[i++];
				if (o + 2 >= sizeof(w->buf))
					return fail(ps, (int)start + 1, "a line too long");
				w->buf[o++] = line[i];
			}
			i++;
			if (i < len && line[i] != ' ' && line[i] != '\t' && line[i] != '#')
				return fail(ps, (int)i + 1, "text right after a closing quote");
		} else {
			while (i < len && line[i] != ' ' && line[i] != '\t') {
				if (line[i] == '"')
					return fail(ps, (int)i + 1, "a quote inside a word");
				if (o + 2 >= sizeof(w->buf))
					return fail(ps, (int)i + 1, "a line too long");
				w->buf[o++] = line[i++];
			}
		}
		w->buf[o++] = '\0';
	}
	return 0;
}

static int copy_text(struct parser *ps, const struct words *w, int i, char *dst, size_t size)
{
	if (strlen(w->w[i]) >= size)
		return fail(ps, w->col[i], "'%.40s...' is too long (at most 127 bytes)", w->w[i]);
	snprintf(dst, size, "%s", w->w[i]);
	return 0;
}

static int checked(struct parser *ps, const struct words *w, int i, enum line_text_kind kind,
		   char *dst, bool *per_axis)
{
	struct asph_error e;
	bool pa = false;

	if (line_text_check(w->w[i], kind, &pa, &e) < 0) {
		/* the column of the offending byte: after the opening quote */
		int col = w->col[i] + e.column;
		return fail(ps, col, "%s in \"%s\"", e.message, w->w[i]);
	}
	if (per_axis)
		*per_axis = *per_axis || pa;
	return copy_text(ps, w, i, dst, LINE_TEXT_MAX);
}

static int number(struct parser *ps, const struct words *w, int i, double lo, double hi,
		  double *out)
{
	char *end;
	double x = strtod(w->w[i], &end);

	if (!*w->w[i] || *end || !isfinite(x))
		return fail(ps, w->col[i], "'%s' is not a number", w->w[i]);
	if (x < lo || x > hi) {
		char range[64];
		snprintf(range, sizeof(range), "%g .. %g", lo, hi);
		return fail(ps, w->col[i], "%s is outside %s", w->w[i], range);
	}
	*out = x;
	return 0;
}

static int integer(struct parser *ps, const struct words *w, int i, double lo, double hi,
		   int *out)
{
	double x;
	int r = number(ps, w, i, lo, hi, &x);

	/* x is only set, and only fits an int, when number() took it */
	if (r < 0)
		return r;
	if (x != floor(x))
		return fail(ps, w->col[i], "'%s' is not a whole number", w->w[i]);
	*out = (int)x;
	return 0;
}

static int want(struct parser *ps, const struct words *w, int lo, int hi)
{
	if (w->n - 1 >= lo && w->n - 1 <= hi)
		return 0;
	if (lo == hi)
		return fail(ps, w->col[0], "'%s' takes %d value%s, not %d", w->w[0], lo,
			    lo == 1 ? "" : "s", w->n - 1);
	return fail(ps, w->col[0], "'%s' takes %d to %d values, not %d", w->w[0], lo, hi, w->n - 1);
}

static int terminator(struct parser *ps, const struct words *w, char *dst, size_t size,
		      bool may_be_empty)
{
	int r = want(ps, w, 1, 1);

	if (r < 0)
		return r;
	if (may_be_empty && !*w->w[1]) {
		dst[0] = '\0';
		return 0;
	}
	if (line_unescape(w->w[1], dst, size) < 0 || strlen(dst) > 4)
		return fail(ps, w->col[1], "\"%s\" is not a terminator of 1 to 4 bytes (\\r \\n \\xHH ...)",
			    w->w[1]);
	return 0;
}

/* serial BAUD DATA_BITS PARITY STOP_BITS [rtscts] */
static int serial_line(struct parser *ps, const struct words *w)
{
	struct line_profile *p = ps->p;
	int r = want(ps, w, 4, 5);

	if (r == 0)
		r = integer(ps, w, 1, 50, 4000000, &p->baud);
	if (r == 0)
		r = integer(ps, w, 2, 5, 8, &p->data_bits);
	if (r < 0)
		return r;
	if (strcmp(w->w[3], "none") && strcmp(w->w[3], "even") && strcmp(w->w[3], "odd"))
		return fail(ps, w->col[3], "parity '%s': none, even or odd", w->w[3]);
	p->parity = (char)toupper((unsigned char)w->w[3][0]);
	r = integer(ps, w, 4, 1, 2, &p->stop_bits);
	if (r < 0)
		return r;
	if (w->n == 6 && strcmp(w->w[5], "rtscts"))
		return fail(ps, w->col[5], "'%s': the only flow control is rtscts", w->w[5]);
	p->rtscts = w->n == 6;
	return 0;
}

static int unit_line(struct parser *ps, const struct words *w)
{
	static const struct { const char *name; double mm; } units[] = {
		{ "mm", 1 }, { "um", 1e-3 }, { "nm", 1e-6 }, { "inch", 25.4 }, { "m", 1e3 },
	};
	int r = want(ps, w, 1, 1);

	for (size_t i = 0; r == 0 && i < sizeof(units) / sizeof(units[0]); i++)
		if (!strcmp(w->w[1], units[i].name))
			return ps->p->unit_mm = units[i].mm, 0;
	return r < 0 ? r : fail(ps, w->col[1], "unit '%s': mm, um, nm, inch or m", w->w[1]);
}

static int error_entry(struct parser *ps, const struct words *w)
{
	struct line_profile *p = ps->p;
	char *end;
	int r = want(ps, w, 2, 2);

	if (r < 0)
		return r;
	long code = strtol(w->w[1], &end, 0);
	if (!*w->w[1] || *end)
		return fail(ps, w->col[1], "error code '%s' is not an integer", w->w[1]);
	if (p->n_errors == LINE_MAX_ERRORS)
		return fail(ps, w->col[0], "more than %d error texts", LINE_MAX_ERRORS);
	for (unsigned i = 0; i < p->n_errors; i++)
		if (p->errors[i].code == code)
			return fail(ps, w->col[1], "error code %s listed twice", w->w[1]);
	p->errors[p->n_errors].code = code;
	return copy_text(ps, w, 2, p->errors[p->n_errors++].text, LINE_TEXT_MAX);
}

/* ------------------------------------------------------------- steps */

static int step_options(struct parser *ps, const struct words *w, int first,
			struct line_step *st)
{
	for (int i = first; i < w->n; i += 2) {
		const char *key = w->w[i];
		if (!strcmp(key, "check") && st->kind == LINE_STEP_SEND) {
			if (!ps->p->error_query[0])
				return fail(ps, w->col[i], "'check' needs an error_query before it");
			st->check = true;
			i--;
			continue;
		}
		if (i + 1 >= w->n)
			return fail(ps, w->col[i], "'%s' needs a pattern after it", key);
		int r;
		if (!strcmp(key, "ack") && st->kind == LINE_STEP_SEND) {
			r = checked(ps, w, i + 1, LINE_TEXT_PATTERN, st->ack, NULL);
		} else if (!strcmp(key, "range") &&
			   (st->kind == LINE_STEP_QUERY || st->kind == LINE_STEP_READ)) {
			r = checked(ps, w, i + 1, LINE_TEXT_PATTERN, st->range, NULL);
		} else if (!strcmp(key, "mask") && st->kind == LINE_STEP_WAIT) {
			char *end1, *end2;
			if (i + 2 >= w->n)
				return fail(ps, w->col[i], "'mask' takes a mask and the value the masked "
					    "{code} has when done");
			st->mask = strtol(w->w[i + 1], &end1, 0);
			st->value = strtol(w->w[i + 2], &end2, 0);
			if (!*w->w[i + 1] || *end1 || !*w->w[i + 2] || *end2)
				return fail(ps, w->col[i + 1], "'mask' takes two integers (0x.. allowed)");
			if (!strstr(st->reply, "{code}") && !strstr(st->reply, "{hex}"))
				return fail(ps, w->col[i], "'mask' needs {code} or {hex} in the done pattern");
			st->has_mask = true;
			i++;
			r = 0;
		} else if (!strcmp(key, "busy") && st->kind == LINE_STEP_WAIT) {
			if (st->n_busy == LINE_MAX_PATTERNS)
				return fail(ps, w->col[i], "more than %d busy patterns", LINE_MAX_PATTERNS);
			r = checked(ps, w, i + 1, LINE_TEXT_PATTERN, st->busy[st->n_busy++], NULL);
		} else {
			return fail(ps, w->col[i], "'%s' is not an option of this step", key);
		}
		if (r < 0)
			return r;
	}
	return 0;
}

/* A step of one text, a command or a pattern, and its options. */
static int text_step(struct parser *ps, const struct words *w, struct line_step *st,
		     enum line_text_kind kind, char *dst)
{
	if (w->n < 2)
		return want(ps, w, 1, 1);
	int r = checked(ps, w, 1, kind, dst, &st->per_axis);
	return r < 0 ? r : step_options(ps, w, 2, st);
}

static int step_line(struct parser *ps, const struct words *w)
{
	struct line_op *op = &ps->p->ops[ps->op];
	const char *k = w->w[0];
	int r = 0;

	if (op->n == LINE_MAX_STEPS)
		return fail(ps, w->col[0], "an operation has at most %d steps", LINE_MAX_STEPS);
	struct line_step *st = &op->steps[op->n];
	memset(st, 0, sizeof(*st));
	st->line = ps->line;
	if (!strcmp(k, "send")) {
		st->kind = LINE_STEP_SEND;
		r = text_step(ps, w, st, LINE_TEXT_COMMAND, st->command);
	} else if (!strcmp(k, "query") || !strcmp(k, "wait")) {
		st->kind = k[0] == 'q' ? LINE_STEP_QUERY : LINE_STEP_WAIT;
		if (w->n < 3)
			return fail(ps, w->col[0], "'%s' takes a command and a reply pattern", k);
		r = checked(ps, w, 1, LINE_TEXT_COMMAND, st->command, &st->per_axis);
		if (r == 0)
			r = checked(ps, w, 2, LINE_TEXT_PATTERN, st->reply, &st->per_axis);
		if (r == 0)
			r = step_options(ps, w, 3, st);
	} else if (!strcmp(k, "read")) {
		st->kind = LINE_STEP_READ;
		r = text_step(ps, w, st, LINE_TEXT_PATTERN, st->reply);
	} else if (!strcmp(k, "check")) {
		st->kind = LINE_STEP_CHECK;
		r = want(ps, w, 0, 0);
		if (r == 0 && !ps->p->error_query[0])
			return fail(ps, w->col[0], "'check' needs an error_query before it");
	} else if (!strcmp(k, "delay") || !strcmp(k, "dtr")) {
		int ms = 0;
		st->kind = k[0] == 'd' && k[1] == 'e' ? LINE_STEP_DELAY : LINE_STEP_DTR;
		r = want(ps, w, 1, 1);
		if (r == 0)
			r = integer(ps, w, 1, 1, 10000, &ms);
		st->ms = (unsigned)ms;
	} else {
		return fail(ps, w->col[0], "'%s' is not a step (send, query, wait, read, check, "
			    "delay, dtr) or 'end'", k);
	}
	if (r == 0)
		op->n++;
	return r;
}

/* ---------------------------------------------------------- settings */

static int setting(struct parser *ps, const struct words *w)
{
	struct line_profile *p = ps->p;
	const char *k = w->w[0];
	double x;
	int r;

	if (!strcmp(k, "op")) {
		if ((r = want(ps, w, 1, 1)) < 0)
			return r;
		for (int i = 0; i < LINE_OP_COUNT; i++)
			if (!strcmp(w->w[1], op_names[i])) {
				if (p->ops[i].defined)
					return fail(ps, w->col[1], "operation '%s' defined twice", w->w[1]);
				p->ops[i].defined = true;
				ps->op = i;
				ps->op_line = ps->line;
				p->ops[i].line = ps->line;
				return 0;
			}
		return fail(ps, w->col[1], "'%s' is not an operation (connect, enable, velocity, "
			    "home, move, position, stop, read)", w->w[1]);
	}
	if (!strcmp(k, "name")) {
		if ((r = want(ps, w, 1, 1)) < 0)
			return r;
		for (const char *c = w->w[1]; *c; c++)
			if (!islower((unsigned char)*c) && !isdigit((unsigned char)*c) && *c != '-' && *c != '_')
				return fail(ps, w->col[1], "name '%s': lower-case letters, digits, - and _",
					    w->w[1]);
		if (strlen(w->w[1]) >= sizeof(p->name) || !*w->w[1])
			return fail(ps, w->col[1], "name '%s' is empty or too long", w->w[1]);
		snprintf(p->name, sizeof(p->name), "%s", w->w[1]);
		return 0;
	}
	if (!strcmp(k, "description") || !strcmp(k, "reference"))
		return (r = want(ps, w, 1, 1)) < 0 ? r
		       : copy_text(ps, w, 1, k[0] == 'd' ? p->description : p->reference, LINE_TEXT_MAX);
	if (!strcmp(k, "role")) {
		if ((r = want(ps, w, 1, 1)) < 0)
			return r;
		if (strcmp(w->w[1], "stage") && strcmp(w->w[1], "probe"))
			return fail(ps, w->col[1], "role '%s': stage or probe", w->w[1]);
		p->roles = w->w[1][0] == 's' ? LINE_ROLE_STAGE : LINE_ROLE_PROBE;
		return 0;
	}
	if (!strcmp(k, "tcp_port"))
		return (r = want(ps, w, 1, 1)) < 0 ? r : integer(ps, w, 1, 1, 65535, &p->tcp_port);
	if (!strcmp(k, "serial"))
		return serial_line(ps, w);
	if (!strcmp(k, "send_terminator"))
		return terminator(ps, w, p->send_terminator, sizeof(p->send_terminator), false);
	if (!strcmp(k, "reply_terminator"))
		return terminator(ps, w, p->reply_terminator, sizeof(p->reply_terminator), false);
	if (!strcmp(k, "continuation"))
		return terminator(ps, w, p->continuation, sizeof(p->continuation), true);
	if (!strcmp(k, "axes")) {
		if ((r = want(ps, w, 3, 3)) < 0)
			return r;
		for (int i = 0; i < 3; i++) {
			if (strlen(w->w[i + 1]) >= sizeof(p->axes[i]) || strpbrk(w->w[i + 1], "{}\\"))
				return fail(ps, w->col[i + 1], "axis id '%s' is too long or has braces",
					    w->w[i + 1]);
			snprintf(p->axes[i], sizeof(p->axes[i]), "%s", w->w[i + 1]);
		}
		return 0;
	}
	if (!strcmp(k, "decimals"))
		return (r = want(ps, w, 1, 1)) < 0 ? r : integer(ps, w, 1, 0, 12, &p->decimals);
	if (!strcmp(k, "unit"))
		return unit_line(ps, w);
	if (!strcmp(k, "poll_ms")) {
		if ((r = want(ps, w, 1, 1)) == 0)
			r = number(ps, w, 1, 0, 10000, &x);
		p->poll_ms = (unsigned)x;
		return r;
	}
	if (!strcmp(k, "ack"))
		return (r = want(ps, w, 1, 1)) < 0 ? r
		       : checked(ps, w, 1, LINE_TEXT_PATTERN, p->ack, NULL);
	if (!strcmp(k, "error_query")) {
		bool pa = false;
		if ((r = want(ps, w, 2, 2)) == 0)
			r = checked(ps, w, 1, LINE_TEXT_COMMAND, p->error_query, &pa);
		if (r == 0)
			r = checked(ps, w, 2, LINE_TEXT_PATTERN, p->error_reply_pattern, &pa);
		if (r == 0 && !strstr(p->error_reply_pattern, "{code}") &&
		    !strstr(p->error_reply_pattern, "{hex}") && !strstr(p->error_reply_pattern, "{text}"))
			return fail(ps, w->col[2], "the error query's reply needs {code}, {hex} or {text}");
		return r;
	}
	if (!strcmp(k, "error_none")) {
		if ((r = want(ps, w, 1, 1)) == 0)
			r = number(ps, w, 1, -1e9, 1e9, &x);
		p->error_none = (long)x;
		return r;
	}
	if (!strcmp(k, "error_none_text"))
		return (r = want(ps, w, 1, 1)) < 0 ? r
		       : copy_text(ps, w, 1, p->error_none_text, LINE_TEXT_MAX);
	if (!strcmp(k, "error_bits"))
		return (r = want(ps, w, 0, 0)) < 0 ? r : (p->error_bits = true, 0);
	if (!strcmp(k, "error_format")) {
		if ((r = want(ps, w, 1, 1)) < 0)
			return r;
		for (const char *c = strchr(w->w[1], '{'); c; c = strchr(c + 1, '{'))
			if (strncmp(c, "{code}", 6) && strncmp(c, "{text}", 6))
				return fail(ps, w->col[1], "error_format knows {code} and {text} only");
		return copy_text(ps, w, 1, p->error_format, LINE_TEXT_MAX);
	}
	if (!strcmp(k, "error"))
		return error_entry(ps, w);
	if (!strcmp(k, "error_reply")) {
		if ((r = want(ps, w, 1, 2)) < 0)
			return r;
		if (p->n_error_replies == LINE_MAX_PATTERNS)
			return fail(ps, w->col[0], "more than %d error replies", LINE_MAX_PATTERNS);
		struct line_error_reply *er = &p->error_replies[p->n_error_replies];
		r = checked(ps, w, 1, LINE_TEXT_PATTERN, er->pattern, NULL);
		if (r == 0 && w->n == 3)
			r = copy_text(ps, w, 2, er->text, LINE_TEXT_MAX);
		if (r == 0)
			p->n_error_replies++;
		return r;
	}
	return fail(ps, w->col[0], "unknown keyword '%s'", k);
}

static int one_line(struct parser *ps, const char *line, size_t len)
{
	struct words w;
	int r = split(ps, line, len, &w);

	if (r < 0 || w.n == 0)
		return r;
	if (!ps->seen_magic) {
		if (strcmp(w.w[0], MAGIC) || w.n != 2 || strcmp(w.w[1], "1"))
			return fail(ps, w.col[0], "the first line must be '" MAGIC " 1'");
		ps->seen_magic = true;
		return 0;
	}
	if (ps->op >= 0) {
		if (!strcmp(w.w[0], "end")) {
			ps->op = -1;
			return want(ps, &w, 0, 0);
		}
		return step_line(ps, &w);
	}
	return setting(ps, &w);
}

/* What a role needs, and placeholders that must appear. */
static int complete(struct parser *ps)
{
	struct line_profile *p = ps->p;
	static const int stage_ops[] = { LINE_OP_HOME, LINE_OP_MOVE, LINE_OP_POSITION, LINE_OP_STOP };

	/* what is missing belongs to the whole file, not its last line */
	ps->line = 0;

	if (!p->name[0])
		return fail(ps, 0, "the profile has no 'name'");
	if (!p->roles)
		return fail(ps, 0, "the profile has no 'role' (stage or probe)");
	if (!p->reply_terminator[0] || !p->send_terminator[0])
		return fail(ps, 0, "the profile needs send_terminator and reply_terminator");
	for (size_t i = 0; p->roles == LINE_ROLE_STAGE && i < 4; i++)
		if (!p->ops[stage_ops[i]].defined || !p->ops[stage_ops[i]].n)
			return fail(ps, 0, "a stage profile needs the operation '%s'",
				    op_names[stage_ops[i]]);
	if (p->roles == LINE_ROLE_PROBE && (!p->ops[LINE_OP_READ].defined || !p->ops[LINE_OP_READ].n))
		return fail(ps, 0, "a probe profile needs the operation 'read'");
	bool pos = false, value = false;
	const struct line_op *op = &p->ops[LINE_OP_POSITION];
	for (unsigned i = 0; i < op->n; i++)
		pos = pos || strstr(op->steps[i].reply, "{pos}") || strstr(op->steps[i].reply, "{p0}");
	op = &p->ops[LINE_OP_READ];
	for (unsigned i = 0; i < op->n; i++)
		value = value || strstr(op->steps[i].reply, "{value}");
	ps->line = p->ops[LINE_OP_POSITION].line;
	if (p->roles == LINE_ROLE_STAGE && !pos)
		return fail(ps, 1, "the 'position' operation's replies need {pos} or {p0} {p1} {p2}");
	ps->line = p->ops[LINE_OP_READ].line;
	if (p->roles == LINE_ROLE_PROBE && !value)
		return fail(ps, 1, "the 'read' operation's replies need {value}");
	return 0;
}

int line_profile_parse(const char *text, size_t len, const char *source,
		       struct line_profile *out, struct asph_error *err)
{
	struct parser ps = { source, 0, err, out, -1, 0, false };
	size_t i = 0;

	memset(out, 0, sizeof(*out));
	out->baud = 9600;
	out->data_bits = 8;
	out->stop_bits = 1;
	out->parity = 'N';
	out->decimals = 6;
	out->unit_mm = 1;
	out->poll_ms = 5;
	snprintf(out->axes[0], sizeof(out->axes[0]), "X");
	snprintf(out->axes[1], sizeof(out->axes[1]), "Y");
	snprintf(out->axes[2], sizeof(out->axes[2]), "Z");
	while (i < len) {
		size_t e = i;
		while (e < len && text[e] != '\n')
			e++;
		ps.line++;
		size_t n = e - i;
		if (n && text[i + n - 1] == '\r')
			n--;
		for (size_t k = i; k < i + n; k++)
			if (!text[k] || (unsigned char)text[k] >= 0x80 ||
			    ((unsigned char)text[k] < 0x20 && text[k] != '\t'))
				return fail(&ps, (int)(k - i) + 1, "a byte that is not ASCII text");
		int r = one_line(&ps, text + i, n);
		if (r < 0)
			return r;
		i = e + 1;
	}
	ps.line = ps.line ? ps.line : 1;
	if (!ps.seen_magic)
		return fail(&ps, 1, "empty profile: the first line must be '" MAGIC " 1'");
	if (ps.op >= 0) {
		ps.line = ps.op_line;
		return fail(&ps, 1, "the operation '%s' has no 'end'", op_names[ps.op]);
	}
	return complete(&ps);
}

void line_profile_error_text(const struct line_profile *p, long code, char *buf, size_t size)
{
	size_t o = 0;

	buf[0] = '\0';
	for (unsigned i = 0; i < p->n_errors; i++) {
		const struct line_error_entry *e = &p->errors[i];
		bool hit = p->error_bits ? (e->code > 0 && (code & e->code) == e->code) : e->code == code;
		if (!hit)
			continue;
		int n = snprintf(buf + o, size - o, "%s%s", o ? ", " : "", e->text);
		if (n < 0 || (size_t)n >= size - o)
			break;
		o += (size_t)n;
		if (!p->error_bits)
			break;
	}
}
