/* SPDX-License-Identifier: GPL-3.0-or-later */
/* SCPI commands, queries and the error queue over USBTMC. */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scpi.h"
#include "transport.h"

/* Entries of the error queue read after one call at most. */
#define MAX_ERRORS 16

int scpi_parse_error(const char *reply, int *code, char *text, size_t size)
{
	char *end;
	long c = strtol(reply, &end, 10);

	if (end == reply || c < -9999 || c > 9999)
		return -EINVAL;
	while (isspace((unsigned char)*end))
		end++;
	if (*end && *end != ',')
		return -EINVAL;
	*code = (int)c;
	const char *s = *end ? end + 1 : end;
	while (isspace((unsigned char)*s))
		s++;
	size_t n = strcspn(s, "\r\n");
	if (n && *s == '"') {
		s++;
		n--;
		if (n && s[n - 1] == '"')
			n--;
	}
	snprintf(text, size, "%.*s", (int)n, s);
	return 0;
}

int scpi_parse_numbers(const char *reply, double *v, int n)
{
	const char *c = reply;

	for (int k = 0; k < n; k++) {
		char *end;
		v[k] = strtod(c, &end);
		if (end == c)
			return -EINVAL;
		if (fabs(v[k]) >= 9.9e37)
			v[k] = NAN;
		while (isspace((unsigned char)*end) && *end != '\n' && *end != '\r')
			end++;
		if (k + 1 < n && *end != ',')
			return -EINVAL;
		c = end + (k + 1 < n);
	}
	return c[strspn(c, "\r\n")] ? -EINVAL : 0;
}

int scpi_check_template(const char *tmpl, int n)
{
	for (const char *c = tmpl; *c; c++) {
		if (c[0] == '{' && c[1] == '{') {
			c++;
			continue;
		}
		if (*c != '{')
			continue;
		if (!isdigit((unsigned char)c[1]) || c[2] != '}' || c[1] - '0' >= n)
			return -EINVAL;
		c += 2;
	}
	return 0;
}

int scpi_format(const char *tmpl, const double *v, int n, char *out, size_t size)
{
	size_t len = 0;

	if (scpi_check_template(tmpl, n) < 0)
		return -EINVAL;
	for (const char *c = tmpl; *c; c++) {
		int w;
		if (c[0] == '{' && c[1] == '{') {
			w = snprintf(out + len, size - len, "{");
			c++;
		} else if (*c == '{') {
			/* %.17g reads back as the same double */
			w = snprintf(out + len, size - len, "%.17g", v[c[1] - '0']);
			c += 2;
		} else {
			w = snprintf(out + len, size - len, "%c", *c);
		}
		if (w < 0 || (size_t)w >= size - len)
			return -ENOSPC;
		len += (size_t)w;
	}
	return 0;
}

static void chomp(char *s, size_t *len)
{
	while (*len && (s[*len - 1] == '\n' || s[*len - 1] == '\r'))
		s[--*len] = '\0';
}

static int send(const struct scpi_call *c, const char *cmd, uint64_t deadline,
		struct asph_error *err)
{
	char line[SCPI_REPLY_MAX];
	int n = snprintf(line, sizeof(line), "%s\n", cmd);

	if (n < 0 || (size_t)n >= sizeof(line))
		return asph_error_set(err, -EINVAL, "SCPI command too long: %s", cmd);
	return usbtmc_write(c->t, line, (size_t)n, c->stop, transport_ms_left(deadline), err);
}

static int query(const struct scpi_call *c, const char *cmd, char *reply, size_t size,
		 uint64_t deadline, struct asph_error *err)
{
	size_t len;
	int r = send(c, cmd, deadline, err);

	if (r == 0)
		r = usbtmc_read(c->t, reply, size, &len, c->stop, transport_ms_left(deadline), err);
	if (r == 0)
		chomp(reply, &len);
	return r;
}

/* Reads the error queue until it says 0; the first error is the reason. */
static int drain_errors(const struct scpi_call *c, const char *cmd, uint64_t deadline,
			struct asph_error *err)
{
	int first = 0;

	for (int i = 0; i < MAX_ERRORS; i++) {
		char reply[SCPI_REPLY_MAX], text[SCPI_REPLY_MAX];
		int code;
		int r = query(c, c->error_query, reply, sizeof(reply), deadline, err);
		if (r < 0)
			return r;
		if (scpi_parse_error(reply, &code, text, sizeof(text)) < 0)
			return asph_error_set(err, -EPROTO, "%s: '%s' answered '%s', not an error "
					      "queue entry (code,\"text\")", usbtmc_name(c->t),
					      c->error_query, reply);
		if (code == 0)
			return first;
		if (!first)
			first = asph_error_set(err, code == -222 ? -ERANGE : -EPROTO,
					       "%s: '%s' refused: %d,\"%s\"", usbtmc_name(c->t),
					       cmd, code, text);
	}
	return asph_error_set(err, -EPROTO, "%s: the error queue does not empty after '%s'",
			      usbtmc_name(c->t), cmd);
}

int scpi_call(const struct scpi_call *c, const char *cmd, char *reply, size_t size,
	      struct asph_error *err)
{
	bool check = c->error_query && *c->error_query;
	uint64_t deadline = transport_deadline(c->timeout_ms);
	/* A device that refuses a query sends no reply: the reply gets three
	 * quarters of the time, so that the rest can ask the error queue why
	 * and report the refusal rather than a bare timeout. */
	uint64_t reply_deadline = transport_deadline(check ? c->timeout_ms - c->timeout_ms / 4
							   : c->timeout_ms);
	int r = reply ? query(c, cmd, reply, size, reply_deadline, err)
		      : send(c, cmd, deadline, err);

	if (r == -ETIMEDOUT && check) {
		struct asph_error why;
		asph_error_clear(&why);
		if (drain_errors(c, cmd, deadline, &why) < 0 &&
		    (why.code == -EPROTO || why.code == -ERANGE) && strstr(why.message, "refused"))
			*err = why;
		return err ? err->code : r;
	}
	if (r < 0 || !check)
		return r;
	return drain_errors(c, cmd, deadline, err);
}
