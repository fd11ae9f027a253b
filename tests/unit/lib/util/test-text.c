/* SPDX-License-Identifier: GPL-3.0-or-later */
/* util-text.h: the escapes of other people's text, as asphctl prints them
 * and asphd logs them. Expected texts written out by hand. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "util-text.h"

static void check(const char *in, bool json, const char *want)
{
	char *out = text_escape_controls(in, json);

	assert_non_null(out);
	assert_string_equal(out, want);
	free(out);
}

static void test_escapes(void **state)
{
	/* a forged log line: newline, ESC, OSC title with BEL */
	check("lock\nasphd: API token \"admin\" revoked\x1b[2J\x1b]0;t\x07", false,
	      "lock\\nasphd: API token \"admin\" revoked\\x1b[2J\\x1b]0;t\\x07");
	check("a\tb\rc\x7f", false, "a\\tb\\x0dc\\x7f");
	/* C1 CSI (U+009B) and the bidi override U+202E, isolate U+2066 */
	check("x\xc2\x9b" "31m\xe2\x80\xae" "y\xe2\x81\xa6" "z", false,
	      "x\\u009b31m\\u202ey\\u2066z");
	/* other UTF-8 is text: é, €, U+00A0 (0xc2 0xa0) */
	check("\xc3\xa9\xe2\x82\xac\xc2\xa0", false, "\xc3\xa9\xe2\x82\xac\xc2\xa0");
	/* in JSON text the C0 characters are layout, the others escaped */
	check("{\n\"a\": \"\xc2\x9b\"}", true, "{\n\"a\": \"\\u009b\"}");
	check("", false, "");
}

static void test_detect(void **state)
{
	unsigned cp = 0;

	assert_false(text_has_controls("plain text, é"));
	assert_true(text_has_controls("tab\there"));
	assert_true(text_has_controls("\xe2\x80\xabx"));
	assert_int_equal(text_control_at("\xe2\x81\xa9", &cp), 3);
	assert_int_equal(cp, 0x2069);
	assert_int_equal(text_control_at("\xe2\x81\xaa", &cp), 0);     /* U+206A: not one */
	assert_int_equal(text_control_at("\xc2\x9f", &cp), 2);
	assert_int_equal(cp, 0x9f);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_escapes),
		cmocka_unit_test(test_detect),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
