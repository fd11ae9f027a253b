/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdint.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nettle/base64.h>

#include "asph-proto.h"
#include "util-mem.h"
#include "util-time.h"

static const struct {
	int code;
	const char *message;
} error_messages[] = {
	{ PROTO_PARSE_ERROR, "Parse error" },
	{ PROTO_INVALID_REQUEST, "Invalid Request" },
	{ PROTO_METHOD_NOT_FOUND, "Method not found" },
	{ PROTO_INVALID_PARAMS, "Invalid params" },
	{ PROTO_INTERNAL_ERROR, "Internal error" },
	{ PROTO_REQUEST_TOO_LARGE, "Request too large" },
	{ PROTO_SHUTTING_DOWN, "Server shutting down" },
	{ PROTO_TOO_MANY_CLIENTS, "Too many clients" },
	{ PROTO_REQUEST_TIMEOUT, "Request timed out" },
	{ PROTO_RESPONSE_TOO_LARGE, "Response too large" },
	{ PROTO_PERMISSION_DENIED, "Permission denied" },
	{ PROTO_NO_SUCH_JOB, "No such job" },
	{ PROTO_NO_SUCH_INSTRUMENT, "No such instrument" },
	{ PROTO_INVALID_STATE, "Invalid job state" },
	{ PROTO_LIMIT_REACHED, "Limit reached" },
	{ PROTO_INVALID_LENS, "Invalid lens" },
	{ PROTO_INVALID_PLAN, "Invalid plan" },
	{ PROTO_NO_RESULT, "No result" },
	{ PROTO_STORAGE_ERROR, "Storage error" },
	{ PROTO_INVALID_PATH, "Invalid path" },
	{ PROTO_INSTRUMENT_LOCKED, "Instrument locked" },
};

const char *proto_error_message(int code)
{
	for (size_t i = 0; i < ARRAY_SIZE(error_messages); i++)
		if (error_messages[i].code == code)
			return error_messages[i].message;
	return "Error";
}

/* ------------------------------------------------------------ framing */

void proto_lines_init(struct proto_lines *l, size_t max_line)
{
	memset(l, 0, sizeof(*l));
	l->max = max_line ? max_line : PROTO_DEFAULT_MAX_LINE;
}

void proto_lines_release(struct proto_lines *l)
{
	free(l->buf);
	memset(l, 0, sizeof(*l));
}

int proto_lines_reserve(struct proto_lines *l, size_t want, char **dst)
{
	if (l->start > 0 && l->start + l->len + want > l->cap) {
		memmove(l->buf, l->buf + l->start, l->len);
		l->start = 0;
	}
	if (l->len + want + 1 > l->cap) {
		size_t cap = l->cap ? l->cap : 4096;
		while (cap < l->len + want + 1)
			cap *= 2;
		char *b = realloc(l->buf, cap);
		if (!b)
			return -ENOMEM;
		l->buf = b;
		l->cap = cap;
	}
	*dst = l->buf + l->start + l->len;
	return 0;
}

void proto_lines_commit(struct proto_lines *l, size_t n)
{
	l->len += n;
}

static void lines_drop(struct proto_lines *l, size_t n)
{
	l->start += n;
	l->len -= n;
	l->scanned = 0;
	if (l->len == 0)
		l->start = 0;
}

int proto_lines_next(struct proto_lines *l, char **line, size_t *len)
{
	for (;;) {
		char *p = l->buf + l->start;
		char *nl = l->len > l->scanned
			? memchr(p + l->scanned, '\n', l->len - l->scanned)
			: NULL;

		if (!nl) {
			l->scanned = l->len;
			if (!l->discarding && l->len <= l->max)
				return 0;
			/* Over the limit: forget what came so far, keep
			 * dropping until the newline. */
			bool first = !l->discarding;
			l->discarding = true;
			lines_drop(l, l->len);
			return first ? -EMSGSIZE : 0;
		}
		size_t n = (size_t)(nl - p);
		if (l->discarding) {
			l->discarding = false;
			lines_drop(l, n + 1);
			continue;
		}
		if (n > l->max) {
			lines_drop(l, n + 1);
			return -EMSGSIZE;
		}
		*nl = '\0';
		if (n > 0 && p[n - 1] == '\r')
			p[--n] = '\0';
		*line = p;
		*len = n;
		lines_drop(l, (size_t)(nl - p) + 1);
		return 1;
	}
}

size_t proto_lines_pending(const struct proto_lines *l)
{
	return l->discarding ? 0 : l->len;
}

/* ------------------------------------------------------------ messages */

/* Length of the valid UTF-8 sequence at s (RFC 3629: no overlong forms, no
 * surrogates, nothing past U+10FFFF), or 0. */
static size_t utf8_sequence(const unsigned char *s)
{
	unsigned n, min, cp;

	if (s[0] < 0x80)
		return 1;
	if (s[0] >= 0xc2 && s[0] <= 0xdf) {
		n = 2;
		min = 0x80;
	} else if (s[0] >= 0xe0 && s[0] <= 0xef) {
		n = 3;
		min = 0x800;
	} else if (s[0] >= 0xf0 && s[0] <= 0xf4) {
		n = 4;
		min = 0x10000;
	} else {
		return 0;
	}
	cp = s[0] & (0x7fu >> n);
	for (unsigned i = 1; i < n; i++) {
		if ((s[i] & 0xc0) != 0x80)
			return 0;
		cp = cp << 6 | (s[i] & 0x3fu);
	}
	if (cp < min || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff))
		return 0;
	return n;
}

size_t proto_utf8_clean(char *text)
{
	unsigned char *s = (unsigned char *)text, *out = s;

	while (*s) {
		size_t n = utf8_sequence(s);
		if (n == 0) {
			s++;
			continue;
		}
		memmove(out, s, n);
		out += n;
		s += n;
	}
	*out = '\0';
	return (size_t)(out - (unsigned char *)text);
}

int proto_why_vset(struct proto_why *why, const char *fmt, va_list ap)
{
	if (why) {
		vsnprintf(why->text, sizeof(why->text), fmt, ap);
		/* a cut, or jansson quoting the text near an error, may end
		 * in the middle of a character */
		proto_utf8_clean(why->text);
	}
	return -EINVAL;
}

int proto_why_set(struct proto_why *why, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	proto_why_vset(why, fmt, ap);
	va_end(ap);
	return -EINVAL;
}

json_t *proto_parse(const char *text, size_t len, struct proto_why *why)
{
	static const char bom[] = "\xef\xbb\xbf";
	int skipped = 0;
	json_error_t e;
	json_t *j;

	/* RFC 8259 lets a parser ignore a byte-order mark before a text, and
	 * some tools (.NET's UTF8Encoding, Windows editors) write one. */
	if (len >= 3 && !memcmp(text, bom, 3)) {
		text += 3;
		len -= 3;
		skipped = 1;
	}
	j = json_loadb(text, len, JSON_REJECT_DUPLICATES | JSON_ALLOW_NUL | JSON_DECODE_ANY, &e);
	/* The column counts the mark too: it is a character of the line as
	 * sent (0: at the start). jansson has none (-1) for an error that is
	 * not at a place: then none is said. */
	if (!j && e.column >= 0)
		proto_why_set(why, "column %d: %s", e.column > 0 ? e.column + skipped : 0, e.text);
	else if (!j)
		proto_why_set(why, "%s", e.text);
	return j;
}

static bool valid_id(const json_t *id)
{
	return json_is_string(id) || json_is_integer(id) || json_is_null(id) ||
	       (json_is_real(id) && isfinite(json_real_value(id)));
}

int proto_check_request(json_t *msg, struct proto_message *out,
			struct proto_why *why)
{
	json_t *v, *id, *method, *params;
	const char *key;

	memset(out, 0, sizeof(*out));
	if (!json_is_object(msg)) {
		proto_why_set(why, "a request must be an object");
		return PROTO_INVALID_REQUEST;
	}
	id = json_object_get(msg, "id");
	if (id && valid_id(id))
		out->id = id;
	v = json_object_get(msg, "jsonrpc");
	if (!json_is_string(v) || json_string_length(v) != 3 ||
	    strcmp(json_string_value(v), "2.0")) {
		proto_why_set(why, "\"jsonrpc\" must be \"2.0\"");
		return PROTO_INVALID_REQUEST;
	}
	if (id && !valid_id(id)) {
		proto_why_set(why, "\"id\" must be a string, a number or null");
		return PROTO_INVALID_REQUEST;
	}
	method = json_object_get(msg, "method");
	if (!json_is_string(method)) {
		proto_why_set(why, "\"method\" must be a string");
		return PROTO_INVALID_REQUEST;
	}
	/* Lines may hold \u0000 (JSON_ALLOW_NUL): "hello\u0000x" must not
	 * dispatch as "hello". */
	if (strlen(json_string_value(method)) != json_string_length(method)) {
		proto_why_set(why, "\"method\" contains a NUL character");
		return PROTO_INVALID_REQUEST;
	}
	params = json_object_get(msg, "params");
	if (params && !json_is_object(params) && !json_is_array(params)) {
		proto_why_set(why, "\"params\" must be an object or an array");
		return PROTO_INVALID_REQUEST;
	}
	json_object_foreach(msg, key, v) {
		if (strcmp(key, "jsonrpc") && strcmp(key, "id") &&
		    strcmp(key, "method") && strcmp(key, "params")) {
			proto_why_set(why, "unknown member in request");
			out->unknown = key;
			return PROTO_INVALID_REQUEST;
		}
	}
	out->kind = id ? PROTO_KIND_REQUEST : PROTO_KIND_NOTIFICATION;
	out->method = json_string_value(method);
	out->params = params;
	return 0;
}

int proto_check_incoming(json_t *msg, struct proto_message *out,
			 struct proto_why *why)
{
	json_t *v, *method;

	memset(out, 0, sizeof(*out));
	if (!json_is_object(msg)) {
		proto_why_set(why, "a message must be an object");
		return PROTO_INVALID_REQUEST;
	}
	v = json_object_get(msg, "jsonrpc");
	if (!json_is_string(v) || strcmp(json_string_value(v), "2.0")) {
		proto_why_set(why, "\"jsonrpc\" must be \"2.0\"");
		return PROTO_INVALID_REQUEST;
	}
	method = json_object_get(msg, "method");
	if (method) {
		if (!json_is_string(method)) {
			proto_why_set(why, "\"method\" must be a string");
			return PROTO_INVALID_REQUEST;
		}
		out->kind = PROTO_KIND_NOTIFICATION;
		out->method = json_string_value(method);
		out->params = json_object_get(msg, "params");
		return 0;
	}
	out->kind = PROTO_KIND_RESPONSE;
	out->id = json_object_get(msg, "id");
	out->result = json_object_get(msg, "result");
	out->error = json_object_get(msg, "error");
	if (!out->id || !!out->result == !!out->error) {
		proto_why_set(why, "a response needs an id and exactly one of result and error");
		return PROTO_INVALID_REQUEST;
	}
	if (out->error) {
		json_t *c = json_object_get(out->error, "code");
		json_t *m = json_object_get(out->error, "message");
		if (!json_is_integer(c) || !json_is_string(m)) {
			proto_why_set(why, "an error needs an integer code and a message");
			return PROTO_INVALID_REQUEST;
		}
		out->error_code = (int)json_integer_value(c);
		out->error_message = json_string_value(m);
	}
	return 0;
}

json_t *proto_make_request(json_int_t id, const char *method, json_t *params)
{
	json_t *m = json_pack("{s:s, s:I, s:s}", "jsonrpc", "2.0", "id", id,
			      "method", method);
	if (m && params)
		json_object_set_new(m, "params", params);
	else
		json_decref(params);
	return m;
}

json_t *proto_make_notification(const char *method, json_t *params)
{
	json_t *m = json_pack("{s:s, s:s}", "jsonrpc", "2.0", "method", method);
	if (m && params)
		json_object_set_new(m, "params", params);
	else
		json_decref(params);
	return m;
}

json_t *proto_make_result(json_t *id, json_t *result)
{
	return json_pack("{s:s, s:O?, s:o}", "jsonrpc", "2.0", "id", id,
			 "result", result ? result : json_null());
}

json_t *proto_make_error(json_t *id, int code, const char *message,
			 json_t *data)
{
	json_t *e = json_pack("{s:i, s:s}", "code", code, "message",
			      message ? message : proto_error_message(code));
	if (e && data)
		json_object_set_new(e, "data", data);
	else
		json_decref(data);
	return json_pack("{s:s, s:O?, s:o}", "jsonrpc", "2.0", "id", id,
			 "error", e);
}

char *proto_dump(const json_t *msg, size_t *len)
{
	size_t n = json_dumpb(msg, NULL, 0, JSON_COMPACT);
	char *s;

	if (n == 0)
		return NULL;
	s = malloc(n + 2);
	if (!s)
		return NULL;
	json_dumpb(msg, s, n, JSON_COMPACT);
	s[n] = '\n';
	s[n + 1] = '\0';
	if (len)
		*len = n + 1;
	return s;
}

/* ---------------------------------------------------------- parameters */

static int param_get(json_t *params, const char *name, bool required,
		     json_t **v, struct proto_why *why)
{
	/* null is a value of the wrong type, not an absent member. */
	*v = json_is_object(params) ? json_object_get(params, name) : NULL;
	if (!*v)
		return required ? proto_why_set(why, "missing parameter \"%s\"", name)
				: -ENOENT;
	return 0;
}

#define TYPE(t) (1u << (t))

/* param_get(), and the member is one of the JSON types in the mask types
 * (TYPE(JSON_STRING), ...), else the error that it must be must_be. */
static int param_typed(json_t *params, const char *name, bool required, unsigned types,
		       const char *must_be, json_t **v, struct proto_why *why)
{
	int r = param_get(params, name, required, v, why);

	if (r < 0)
		return r;
	if (!(types & TYPE(json_typeof(*v))))
		return proto_why_set(why, "\"%s\" must be %s", name, must_be);
	return 0;
}

int proto_params_only(json_t *params, const char *const *names,
		      struct proto_why *why)
{
	const char *key;
	json_t *v;

	if (!params)
		return 0;
	if (!json_is_object(params))
		return proto_why_set(why, "params must be an object");
	json_object_foreach(params, key, v) {
		size_t i;
		for (i = 0; names[i]; i++)
			if (!strcmp(names[i], key))
				break;
		if (!names[i])
			return proto_why_set(why, "unknown parameter \"%.64s\"", key);
	}
	return 0;
}

int proto_param_int(json_t *params, const char *name, bool required,
		    int64_t min, int64_t max, int64_t *out,
		    struct proto_why *why)
{
	json_t *v;
	int r = param_typed(params, name, required, TYPE(JSON_INTEGER), "an integer", &v, why);

	if (r < 0)
		return r;
	json_int_t x = json_integer_value(v);
	if (x < min || x > max)
		return proto_why_set(why, "\"%s\" must be in [%lld, %lld]", name,
			       (long long)min, (long long)max);
	*out = x;
	return 0;
}

int proto_param_number(json_t *params, const char *name, bool required,
		       double min, double max, double *out,
		       struct proto_why *why)
{
	json_t *v;
	int r = param_typed(params, name, required, TYPE(JSON_INTEGER) | TYPE(JSON_REAL),
			    "a number", &v, why);

	if (r < 0)
		return r;
	double x = json_number_value(v);
	if (!isfinite(x) || x < min || x > max)
		return proto_why_set(why, "\"%s\" must be in [%g, %g]", name, min, max);
	*out = x;
	return 0;
}

int proto_param_bool(json_t *params, const char *name, bool required,
		     bool *out, struct proto_why *why)
{
	json_t *v;
	int r = param_typed(params, name, required, TYPE(JSON_TRUE) | TYPE(JSON_FALSE),
			    "true or false", &v, why);

	if (r < 0)
		return r;
	*out = json_is_true(v);
	return 0;
}

int proto_param_string(json_t *params, const char *name, bool required,
		       size_t max_len, const char **out,
		       struct proto_why *why)
{
	json_t *v;
	int r = param_typed(params, name, required, TYPE(JSON_STRING), "a string", &v, why);

	if (r < 0)
		return r;
	if (json_string_length(v) > max_len)
		return proto_why_set(why, "\"%s\" is longer than %zu bytes", name, max_len);
	if (strlen(json_string_value(v)) != json_string_length(v))
		return proto_why_set(why, "\"%s\" contains a NUL character", name);
	*out = json_string_value(v);
	return 0;
}

int proto_param_object(json_t *params, const char *name, bool required,
		       json_t **out, struct proto_why *why)
{
	json_t *v;
	int r = param_typed(params, name, required, TYPE(JSON_OBJECT), "an object", &v, why);

	if (r < 0)
		return r;
	*out = v;
	return 0;
}

int proto_param_flags(json_t *params, const char *name, bool required,
		      const char *const *allowed, unsigned *mask,
		      struct proto_why *why)
{
	json_t *v, *e;
	size_t i;
	int r = param_typed(params, name, required, TYPE(JSON_ARRAY), "an array of strings",
			    &v, why);

	if (r < 0)
		return r;
	*mask = 0;
	json_array_foreach(v, i, e) {
		size_t k;
		if (!json_is_string(e))
			return proto_why_set(why, "\"%s\"[%zu] must be a string", name, i);
		if (strlen(json_string_value(e)) != json_string_length(e))
			return proto_why_set(why, "\"%s\"[%zu] contains a NUL character", name, i);
		for (k = 0; allowed[k]; k++)
			if (!strcmp(allowed[k], json_string_value(e)))
				break;
		if (!allowed[k])
			return proto_why_set(why, "\"%s\"[%zu]: unknown value \"%.64s\"",
				       name, i, json_string_value(e));
		*mask |= 1u << k;
	}
	return 0;
}

/* ------------------------------------------------------------- base64 */

json_t *proto_time_json(int64_t ns)
{
	char buf[ISO8601_SIZE];

	if (ns <= 0)
		return json_null();
	iso8601_utc(ns, 3, buf, sizeof(buf));
	return json_string(buf);
}

char *proto_base64_encode(const void *data, size_t n)
{
	char *out = n <= (SIZE_MAX - 1) / 2 ? malloc(BASE64_ENCODE_RAW_LENGTH(n) + 1) : NULL;

	if (!out)
		return NULL;
	base64_encode_raw(out, n, data);
	out[BASE64_ENCODE_RAW_LENGTH(n)] = '\0';
	return out;
}

char *proto_base64url_encode(const void *data, size_t n)
{
	struct base64_encode_ctx ctx;
	char *out = n <= (SIZE_MAX - 1) / 2 ? malloc(BASE64_ENCODE_LENGTH(n) + BASE64_ENCODE_FINAL_LENGTH + 1) : NULL;
	size_t len;

	if (!out)
		return NULL;
	base64url_encode_init(&ctx);
	len = base64_encode_update(&ctx, out, n, data);
	len += base64_encode_final(&ctx, out + len);
	out[len] = '\0';
	out[strcspn(out, "=")] = '\0';
	return out;
}

int proto_base64_decode(const char *text, size_t len, void **out, size_t *n)
{
	struct base64_decode_ctx ctx;
	unsigned char *buf;
	size_t got;

	/* nettle skips white space; the protocol's base64 has none, and is padded */
	if (len % 4)
		return -EINVAL;
	for (size_t i = 0; i < len; i++)
		if (text[i] == ' ' || text[i] == '\t' || text[i] == '\r' || text[i] == '\n')
			return -EINVAL;
	buf = malloc(BASE64_DECODE_LENGTH(len) + 1);
	if (!buf)
		return -ENOMEM;
	got = BASE64_DECODE_LENGTH(len) + 1;
	base64_decode_init(&ctx);
	if (!base64_decode_update(&ctx, &got, buf, len, text) || !base64_decode_final(&ctx)) {
		free(buf);
		return -EINVAL;
	}
	*out = buf;
	*n = got;
	return 0;
}
