/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The wire codec asphd and asphctl share: JSON-RPC 2.0, one JSON text per
 * line. Line framing with a length limit, message checks and builders, the
 * numbered error codes of proto/README.md, and typed parameter access.
 * Internal to the tree.
 */
#ifndef ASPH_PROTO_H
#define ASPH_PROTO_H

#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

/* Protocol version reported by `hello`; the minor part grows with
 * compatible additions. */
#define PROTO_VERSION_MAJOR 1
#define PROTO_VERSION_MINOR 7

#define PROTO_DEFAULT_SOCKET "/run/asphd/asphd.sock"
#define PROTO_DEFAULT_MAX_LINE (1u << 20)
/* Requests in one batch: each answer costs far more memory than the
 * two bytes "1," it may come from. */
#define PROTO_MAX_BATCH 1000

/* Error codes, with the messages of proto_error_message(). */
enum proto_error_code {
	/* JSON-RPC 2.0 */
	PROTO_PARSE_ERROR = -32700,
	PROTO_INVALID_REQUEST = -32600,
	PROTO_METHOD_NOT_FOUND = -32601,
	PROTO_INVALID_PARAMS = -32602,
	PROTO_INTERNAL_ERROR = -32603,
	/* server errors (transport level) */
	PROTO_REQUEST_TOO_LARGE = -32000,
	PROTO_SHUTTING_DOWN = -32001,
	PROTO_TOO_MANY_CLIENTS = -32002,
	PROTO_REQUEST_TIMEOUT = -32003,
	PROTO_RESPONSE_TOO_LARGE = -32004,
	/* application errors */
	PROTO_PERMISSION_DENIED = 100,
	PROTO_NO_SUCH_JOB = 101,
	PROTO_NO_SUCH_INSTRUMENT = 102,
	PROTO_INVALID_STATE = 103,
	PROTO_LIMIT_REACHED = 104,
	PROTO_INVALID_LENS = 105,
	PROTO_INVALID_PLAN = 106,
	PROTO_NO_RESULT = 107,
	PROTO_STORAGE_ERROR = 108,
	PROTO_INVALID_PATH = 109,
	PROTO_INSTRUMENT_LOCKED = 110,
};

/* The short message of a code ("Parse error", "No such job", ...). */
const char *proto_error_message(int code);

/* ------------------------------------------------------------ framing */

/*
 * Input side of a connection: bytes in, complete lines out. A line longer
 * than max bytes is dropped up to its newline and reported once.
 */
struct proto_lines {
	char *buf;
	size_t start, len, cap;   /* pending bytes are buf[start, start+len) */
	size_t max;
	size_t scanned;           /* bytes of the pending data without '\n' */
	bool discarding;          /* inside an oversized line */
};

void proto_lines_init(struct proto_lines *l, size_t max_line);
void proto_lines_release(struct proto_lines *l);

/* Space for at least want bytes at *dst; -ENOMEM. */
int proto_lines_reserve(struct proto_lines *l, size_t want, char **dst);
/* n bytes were written at the reserved place. */
void proto_lines_commit(struct proto_lines *l, size_t n);

/*
 * The next complete line, NUL-terminated in place, without its "\n" (and
 * "\r\n"); valid until the next call of any proto_lines_* function.
 * Returns 1 with a line, 0 when none is complete, -EMSGSIZE once for every
 * line over the limit (its bytes are dropped).
 */
int proto_lines_next(struct proto_lines *l, char **line, size_t *len);

/* Bytes of an incomplete line still pending (for end of input). */
size_t proto_lines_pending(const struct proto_lines *l);

/* ------------------------------------------------------------ messages */

enum proto_kind {
	PROTO_KIND_REQUEST,       /* method and id */
	PROTO_KIND_NOTIFICATION,  /* method, no id */
	PROTO_KIND_RESPONSE,      /* result or error, and id */
};

struct proto_message {
	enum proto_kind kind;
	json_t *id;               /* borrowed; NULL for notifications */
	const char *method;
	json_t *params;           /* borrowed; NULL when absent */
	json_t *result;
	json_t *error;
	int error_code;           /* of a response with error */
	const char *error_message;
	const char *unknown;      /* the member that made a request invalid */
};

/* Why a message or a parameter was refused, for the "detail" of the error
 * response: valid UTF-8, cut to fit. Every function here that refuses
 * takes one (or NULL, not to be told). */
struct proto_why {
	char text[256];
};

/* Sets why (which may be NULL) and returns -EINVAL. */
int proto_why_set(struct proto_why *why, const char *fmt, ...)
	__attribute__((format(printf, 2, 3)));
int proto_why_vset(struct proto_why *why, const char *fmt, va_list ap)
	__attribute__((format(printf, 2, 0)));

/* Parses one line; NULL with a message in why on a syntax error. Duplicate
 * object keys are refused. A UTF-8 byte-order mark at the start of the
 * line is skipped (columns still count it). */
json_t *proto_parse(const char *text, size_t len, struct proto_why *why);

/*
 * Server side: checks one element (a request or a notification). Returns 0,
 * or PROTO_INVALID_REQUEST with why set. out->id is the id when it could be
 * read (so the error response can carry it), else NULL.
 */
int proto_check_request(json_t *msg, struct proto_message *out,
			struct proto_why *why);

/* Client side: checks a response or a notification from the server. */
int proto_check_incoming(json_t *msg, struct proto_message *out,
			 struct proto_why *why);

/* Builders; every json_t argument is stolen except id, which is copied. */
json_t *proto_make_request(json_int_t id, const char *method, json_t *params);
json_t *proto_make_notification(const char *method, json_t *params);
json_t *proto_make_result(json_t *id, json_t *result);
json_t *proto_make_error(json_t *id, int code, const char *message,
			 json_t *data);

/* Compact text with "\n" appended (malloc'd, caller frees), or NULL. */
char *proto_dump(const json_t *msg, size_t *len);

/* Drops the bytes of text that are not valid UTF-8 (a message cut with
 * "%.64s" may end inside a character, and JSON strings must be valid);
 * returns the new length. */
size_t proto_utf8_clean(char *text);

/* ------------------------------------------------------------------ time */

/* A time as every message carries it: ISO 8601 UTC to the millisecond
 * ("2026-12-07T16:55:01.123Z"), or null when not known (ns <= 0: not yet
 * started, never expires). NULL when out of memory. */
json_t *proto_time_json(int64_t ns);

/* ---------------------------------------------------------------- base64 */

/* RFC 4648 base64 with padding, as job.file sends bytes: the text
 * (malloc'd, NUL-terminated) or NULL. */
char *proto_base64_encode(const void *data, size_t n);
/* Back to bytes (malloc'd, *n of them): 0, -EINVAL for anything but
 * padded base64 of the standard alphabet, -ENOMEM. */
int proto_base64_decode(const char *text, size_t len, void **out, size_t *n);

/* RFC 4648 base64url without padding (§5): tokens and cookie values,
 * which then need no quoting. NULL when out of memory. */
char *proto_base64url_encode(const void *data, size_t n);

/* ---------------------------------------------------------- parameters */

/*
 * Typed access to a params object. Each returns 0, -ENOENT when an
 * optional member is absent (out untouched), or -EINVAL with why (a
 * message naming the member) for a wrong type or value. A NULL params
 * counts as an empty object.
 */
int proto_params_only(json_t *params, const char *const *names,
		      struct proto_why *why);
int proto_param_int(json_t *params, const char *name, bool required,
		    int64_t min, int64_t max, int64_t *out,
		    struct proto_why *why);
int proto_param_number(json_t *params, const char *name, bool required,
		       double min, double max, double *out,
		       struct proto_why *why);
int proto_param_bool(json_t *params, const char *name, bool required,
		     bool *out, struct proto_why *why);
/* out is borrowed from params. max_len counts bytes. */
int proto_param_string(json_t *params, const char *name, bool required,
		       size_t max_len, const char **out,
		       struct proto_why *why);
int proto_param_object(json_t *params, const char *name, bool required,
		       json_t **out, struct proto_why *why);
/* An array of strings, each one of allowed (NULL-terminated); sets bit i
 * of *mask for allowed[i]. */
int proto_param_flags(json_t *params, const char *name, bool required,
		      const char *const *allowed, unsigned *mask,
		      struct proto_why *why);

#endif
