/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <string.h>

#include <cmocka.h>

#include "asph/error.h"

static void test_format(void **state)
{
	struct asph_error e;
	char buf[256];

	asph_error_clear(&e);
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)), "unknown error");
	assert_int_equal(asph_error_set(&e, -EINVAL, "bad %s at %d", "value", 7), -EINVAL);
	assert_int_equal(e.code, -EINVAL);
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)), "bad value at 7");
	asph_error_locate(&e, "lens.json", 3, 14, "A.6");
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)), "lens.json:3:14: A.6: bad value at 7");
	asph_error_clear(&e);
	asph_error_set(&e, -ENOENT, "gone");
	asph_error_locate(&e, "f.csv", 0, 0, NULL);
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)), "f.csv: gone");
	/* truncation never overruns */
	char tiny[8];
	asph_error_format(&e, tiny, sizeof(tiny));
	assert_int_equal(strlen(tiny), 7);
}

static void test_set_at(void **state)
{
	struct asph_error e;
	char buf[256];

	asph_error_clear(&e);
	assert_int_equal(asph_error_set_at(&e, -EINVAL, "lens.zmx", 12, 3, "SURF 2",
					   "bad %s", "CURV"), -EINVAL);
	assert_int_equal(e.code, -EINVAL);
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)),
			    "lens.zmx:12:3: SURF 2: bad CURV");
	/* absent parts stay as they were */
	asph_error_set_at(&e, -ERANGE, NULL, 0, 0, NULL, "too large");
	assert_int_equal(e.code, -ERANGE);
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)),
			    "lens.zmx:12:3: SURF 2: too large");
	/* re-wording a message with its own text and parts */
	asph_error_set_at(&e, -EINVAL, e.source, 0, 0, e.field, "in %s: %s", e.field, e.message);
	assert_string_equal(e.message, "in SURF 2: too large");
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)),
			    "lens.zmx:12:3: SURF 2: in SURF 2: too large");
	asph_error_set(&e, -EIO, "%s, again", e.message);
	assert_string_equal(e.message, "in SURF 2: too large, again");
	/* jansson's -1 for "no place" is no place: never "-1:-1" */
	asph_error_clear(&e);
	asph_error_set_at(&e, -ENOENT, "tol.json", -1, -1, NULL, "unable to open");
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)), "tol.json: unable to open");
	asph_error_set_at(&e, -EINVAL, NULL, 2, -1, NULL, "bad");
	assert_string_equal(asph_error_format(&e, buf, sizeof(buf)), "tol.json:2: bad");
}

static void test_null_error(void **state)
{
	assert_int_equal(asph_error_set(NULL, -EIO, "x"), -EIO);
	assert_int_equal(asph_error_set_at(NULL, -EIO, "a", 1, 1, "b", "x"), -EIO);
	asph_error_locate(NULL, "a", 1, 1, "b");
	asph_error_clear(NULL);
	char buf[4];
	assert_string_equal(asph_error_format(NULL, buf, sizeof(buf)), "");
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_format),
		cmocka_unit_test(test_set_at),
		cmocka_unit_test(test_null_error),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
