/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Line-protocol device profiles: what a device's ASCII dialogue looks like
 * (terminators, command templates per operation, reply patterns, errors),
 * read from a profile file (docs/driver-line.md has the format). The
 * parser is pure: text in, a profile or an error with file, line and
 * reason out. Internal to drivers/line/.
 */
#ifndef ASPH_LINE_PROFILE_H
#define ASPH_LINE_PROFILE_H

#include <stdbool.h>
#include <stddef.h>

#include "asph/error.h"

#define LINE_TEXT_MAX 128       /* a template, a pattern, a terminator */
#define LINE_MAX_STEPS 12       /* steps of one operation */
#define LINE_MAX_ERRORS 96      /* entries of the error table */
#define LINE_MAX_PATTERNS 4     /* busy patterns of a wait, error replies */

enum line_role {
	LINE_ROLE_STAGE = 1,
	LINE_ROLE_PROBE = 2,
};

enum line_step_kind {
	LINE_STEP_SEND = 1,     /* a command; reads an acknowledgement when one is set */
	LINE_STEP_QUERY,        /* a command and the reply that must match */
	LINE_STEP_WAIT,         /* a query repeated until its done pattern matches */
	LINE_STEP_CHECK,        /* the error query: a device error ends the operation */
	LINE_STEP_DELAY,        /* a pause, ms */
	LINE_STEP_DTR,          /* a DTR pulse, ms (a gauge's data request) */
	LINE_STEP_READ,         /* a line the device sends by itself (foot switch) */
};

struct line_step {
	enum line_step_kind kind;
	char command[LINE_TEXT_MAX];    /* template */
	char reply[LINE_TEXT_MAX];      /* QUERY, READ: the pattern; WAIT: done */
	char ack[LINE_TEXT_MAX];        /* SEND: its acknowledgement ("" none) */
	char range[LINE_TEXT_MAX];      /* QUERY, READ: an out-of-range reading */
	char busy[LINE_MAX_PATTERNS][LINE_TEXT_MAX]; /* WAIT: not done yet */
	unsigned n_busy;
	unsigned ms;                    /* DELAY, DTR */
	bool has_mask;                  /* WAIT: done when ({code} & mask) == value */
	long mask, value;
	bool per_axis;                  /* the command names one axis */
	bool check;                     /* SEND: the error query after it (for
					 * each axis: the error names it) */
	int line;                       /* where in the profile */
};

struct line_op {
	struct line_step steps[LINE_MAX_STEPS];
	unsigned n;
	bool defined;
	int line;                       /* where it opens in the profile */
};

enum line_op_id {
	LINE_OP_CONNECT = 0,    /* once after each connection */
	LINE_OP_ENABLE,         /* servo / motor on, once after connect */
	LINE_OP_VELOCITY,       /* sets {speed} */
	LINE_OP_HOME,
	LINE_OP_MOVE,
	LINE_OP_POSITION,
	LINE_OP_STOP,
	LINE_OP_READ,           /* a probe reading */
	LINE_OP_COUNT
};

struct line_error_entry {
	long code;
	char text[LINE_TEXT_MAX];
};

/* An error reply: a pattern that, matched by any reply, ends the
 * operation with text (or, empty, with the error query's answer). */
struct line_error_reply {
	char pattern[LINE_TEXT_MAX];
	char text[LINE_TEXT_MAX];
};

struct line_profile {
	char name[64];
	char description[LINE_TEXT_MAX];
	char reference[LINE_TEXT_MAX];  /* the vendor document it follows */
	unsigned roles;                 /* enum line_role */
	int tcp_port;                   /* 0: no default */
	int baud, data_bits, stop_bits;
	char parity;                    /* 'N', 'E', 'O' */
	bool rtscts;
	char send_terminator[8];
	char reply_terminator[8];
	char continuation[8];           /* "" or what ends a continued line */
	char axes[3][16];               /* default axis ids */
	int decimals;                   /* of {target} and {speed} */
	double unit_mm;                 /* mm per device length unit */
	unsigned poll_ms;
	char ack[LINE_TEXT_MAX];        /* acknowledgement of every send */
	/* the error query and its table */
	char error_query[LINE_TEXT_MAX];
	char error_reply_pattern[LINE_TEXT_MAX]; /* with {code} and/or {text} */
	long error_none;
	char error_none_text[LINE_TEXT_MAX]; /* a {text} error query: "no error" */
	bool error_bits;                /* codes are bit masks of the table */
	char error_format[LINE_TEXT_MAX]; /* "PI error {code}: {text}" */
	struct line_error_entry errors[LINE_MAX_ERRORS];
	unsigned n_errors;
	struct line_error_reply error_replies[LINE_MAX_PATTERNS];
	unsigned n_error_replies;
	struct line_op ops[LINE_OP_COUNT];
};

const char *line_op_name(enum line_op_id id);

/*
 * Parses profile text (len bytes, need not end in NUL). source names it
 * in errors. -EINVAL with err's file, line and reason for any malformed
 * line, an unknown keyword, a template or pattern with an unknown or
 * misplaced placeholder, or a profile that lacks what its role needs.
 */
int line_profile_parse(const char *text, size_t len, const char *source,
		       struct line_profile *out, struct asph_error *err);

/* The text of an error code ("" when the table has none); with
 * error_bits, the texts of every set bit joined with ", ". */
void line_profile_error_text(const struct line_profile *p, long code, char *buf,
			     size_t size);

#endif
