/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The request side of the wire codec as asphd runs it: bytes in arbitrary
 * chunks through the line framer (with a small limit, so oversized lines
 * are common), each line parsed and checked as a request, its params read
 * through the typed accessors, and an answer built and encoded. The client
 * side check runs on the same messages.
 */
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "asph-proto.h"
#include "fuzz.h"

#define MAX_LINE 512

static void read_params(json_t *params)
{
	static const char *const names[] = { "id", "lens", "plan", "label", "priority",
					     "events", "instrument", NULL };
	static const char *const classes[] = { "job", "progress", "instrument", "queue", NULL };
	struct proto_why why;
	int64_t i;
	double d;
	bool b;
	const char *s;
	json_t *o;
	unsigned mask;

	proto_params_only(params, names, &why);
	proto_param_int(params, "id", false, 1, INT64_MAX, &i, &why);
	proto_param_int(params, "priority", true, -100, 100, &i, &why);
	proto_param_number(params, "density", false, 1e-6, 1e6, &d, &why);
	proto_param_bool(params, "restart", false, &b, &why);
	proto_param_string(params, "label", false, 128, &s, &why);
	proto_param_object(params, "lens", false, &o, &why);
	proto_param_flags(params, "events", false, classes, &mask, &why);
}

static void answer(json_t *msg)
{
	struct proto_message m;
	struct proto_why why = { "" };
	json_t *reply;

	int code = proto_check_request(msg, &m, &why);
	if (code) {
		if (!why.text[0])
			fuzz_die("request refused without a reason");
		reply = proto_make_error(m.id, code, why.text, NULL);
	} else {
		read_params(m.params);
		reply = proto_make_result(m.id, json_string(m.method));
	}
	size_t len = 0;
	char *text = proto_dump(reply, &len);
	if (!text || len == 0 || text[len - 1] != '\n' || memchr(text, '\n', len - 1))
		fuzz_die("the answer is not one line");
	/* What the server sends, its client reads back. */
	json_t *back = proto_parse(text, len - 1, NULL);
	if (!back || proto_check_incoming(back, &m, &why) != 0)
		fuzz_die("the client refuses the server's answer: %s", text);
	json_decref(back);
	free(text);
	json_decref(reply);
	proto_check_incoming(msg, &m, &why);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct proto_lines lines;
	size_t off = 0;

	proto_lines_init(&lines, MAX_LINE);
	while (off < size) {
		/* Chunk sizes come from the data, as reads of a socket would. */
		size_t chunk = 1 + (data[off] % 97);
		if (chunk > size - off)
			chunk = size - off;
		char *dst;
		if (proto_lines_reserve(&lines, chunk, &dst) < 0)
			fuzz_die("out of memory in the framer");
		memcpy(dst, data + off, chunk);
		proto_lines_commit(&lines, chunk);
		off += chunk;

		char *line;
		size_t len;
		int r;
		while ((r = proto_lines_next(&lines, &line, &len)) != 0) {
			if (r < 0)
				continue;
			if (len > MAX_LINE || strlen(line) > len)
				fuzz_die("the framer returned a line of %zu bytes", len);
			struct proto_why why;
			json_t *msg = proto_parse(line, len, &why);
			if (!msg)
				continue;
			answer(msg);
			json_decref(msg);
		}
	}
	if (proto_lines_pending(&lines) > MAX_LINE)
		fuzz_die("the framer holds %zu bytes", proto_lines_pending(&lines));
	proto_lines_release(&lines);
	return 0;
}
