/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * SCPI over USBTMC: a command or a query as one message, then the error
 * queue read until it is empty, so a refusal ("-113,"Undefined header"")
 * becomes the reason of the command that caused it. Command strings come
 * from the device's profile; a move command's {0} {1} {2} are the target's
 * axes. Internal.
 */
#ifndef ASPH_USB_SCPI_H
#define ASPH_USB_SCPI_H

#include <stdatomic.h>
#include <stddef.h>

#include "asph/error.h"
#include "protocol.h"

#define SCPI_REPLY_MAX 512

struct scpi_call {
	struct usbtmc *t;
	const char *error_query;        /* "" or NULL: not read */
	atomic_bool *stop;
	unsigned timeout_ms;            /* the whole call */
};

/*
 * Sends cmd; when reply is not NULL reads the answer into it (without the
 * line end). Then drains the error queue: the first error refuses the
 * call, -ERANGE for -222 "Data out of range" (a limit), -EPROTO for
 * everything else, with the device's text in the reason.
 */
int scpi_call(const struct scpi_call *c, const char *cmd, char *reply, size_t size,
	      struct asph_error *err);

/* Parses an error queue entry: <code>,"<text>" (quotes optional). */
int scpi_parse_error(const char *reply, int *code, char *text, size_t size);

/* Parses n numbers separated by commas (a reply may end in a line end).
 * SCPI's 9.91E37 (not a number) and 9.9E37 (overload) come back as NaN. */
int scpi_parse_numbers(const char *reply, double *v, int n);

/* Fills a template: {K} is v[K] (K < n) printed exactly; "{{" is "{". */
int scpi_format(const char *tmpl, const double *v, int n, char *out, size_t size);

/* Checks that a template substitutes only arguments below n. */
int scpi_check_template(const char *tmpl, int n);

#endif
