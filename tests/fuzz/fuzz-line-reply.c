/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The line driver's reply decoder (drivers/line/protocol.c): the input's
 * first line is a reply pattern, the rest the bytes a device sends, in
 * chunks. Replies are split at the terminator (continued lines joined),
 * garbled ones refused with a reason, and each matched against the
 * pattern: a match yields finite numbers only.
 */
#include <math.h>
#include <string.h>

#include "fuzz.h"
#include "line/protocol.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	static struct line_reader r;
	char pattern[256], out[LINE_REPLY_MAX];
	const char *nl = memchr(data, '\n', size < 255 ? size : 255);
	struct line_vars v = { .axis_ids = { "1", "X", "AB" }, .axis = 1, .decimals = 6 };
	struct asph_error err;
	bool per_axis;

	if (!nl)
		return 0;
	size_t plen = (size_t)(nl - (const char *)data);
	memcpy(pattern, data, plen);
	pattern[plen] = '\0';
	if (strlen(pattern) != plen)
		return 0;
	asph_error_clear(&err);
	if (line_text_check(pattern, LINE_TEXT_PATTERN, &per_axis, &err) < 0) {
		fuzz_check_error(&err);
		return 0;
	}
	line_reader_clear(&r);
	const char *p = nl + 1, *end = (const char *)data + size;
	while (p < end) {
		size_t chunk = (size_t)(end - p) < 7 ? (size_t)(end - p) : 7;
		asph_error_clear(&err);
		if (line_reader_add(&r, p, chunk, &err) < 0) {
			fuzz_check_error(&err);
			return 0;
		}
		p += chunk;
		for (;;) {
			asph_error_clear(&err);
			int n = line_reader_take(&r, "\r\n", " ", out, sizeof(out), &err);
			if (n < 0) {
				fuzz_check_error(&err);
				continue;
			}
			if (n == 0)
				break;
			struct line_match m;
			memset(&m, 0, sizeof(m));
			if (!line_match(pattern, out, &v, &m))
				continue;
			for (int k = 0; k < 3; k++)
				if (m.has_pos[k] && !isfinite(m.pos[k]))
					fuzz_die("a position that is not finite");
			if (m.has_value && !isfinite(m.value))
				fuzz_die("a value that is not finite");
		}
	}
	line_reader_pending(&r, out, sizeof(out));
	return 0;
}
