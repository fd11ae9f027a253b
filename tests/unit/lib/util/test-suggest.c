/* SPDX-License-Identifier: GPL-3.0-or-later */
/* util-suggest.h: the edit distance against hand-counted edits, the
 * suggestions the tools make, and the messages for options getopt_long()
 * refuses, read from getopt_long() itself. */
#include <getopt.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "util-suggest.h"

static void test_distance(void **state)
{
	assert_int_equal(suggest_distance("", ""), 0);
	assert_int_equal(suggest_distance("cvt", "cvt"), 0);
	assert_int_equal(suggest_distance("", "abc"), 3);
	assert_int_equal(suggest_distance("cvtt", "cvt"), 1);           /* insertion */
	assert_int_equal(suggest_distance("strog", "strong"), 1);       /* deletion */
	assert_int_equal(suggest_distance("tolerence", "tolerance"), 1); /* substitution */
	assert_int_equal(suggest_distance("stauts", "status"), 1);      /* swap */
	assert_int_equal(suggest_distance("sumbit", "submit"), 1);
	assert_int_equal(suggest_distance("STRONG", "strong"), 0);      /* case */
	assert_int_equal(suggest_distance("kitten", "sitting"), 3);
	assert_int_equal(suggest_distance("ca", "abc"), 3);             /* OSA, not Damerau */
	/* symmetric */
	assert_int_equal(suggest_distance("fermat", "format"), suggest_distance("format", "fermat"));
	char long_name[SUGGEST_MAX_LEN + 2];
	memset(long_name, 'a', sizeof(long_name) - 1);
	long_name[sizeof(long_name) - 1] = '\0';
	assert_true(suggest_distance(long_name, "a") == SIZE_MAX);
}

static void test_suggest(void **state)
{
	static const char *const methods[] = { "op", "ot", "lb", "ci", "raster", "concentric",
						"spiral", "fermat", "cvt", NULL };
	static const char *const presets[] = { "weak", "strong", "turning-point", NULL };
	struct suggest s;
	char hint[64];

	assert_string_equal(suggest_from_list("cvtt", methods), "cvt");
	assert_string_equal(suggest_from_list("fermta", methods), "fermat");
	assert_string_equal(suggest_from_list("Raster", methods), "raster");
	assert_null(suggest_from_list("hexagon", methods));
	assert_null(suggest_from_list("x", methods));
	assert_string_equal(suggest_from_list("strog", presets), "strong");
	assert_string_equal(suggest_from_list("turning", presets), "turning-point");  /* prefix */
	assert_null(suggest_from_list("tu", presets));          /* too short a prefix */
	assert_null(suggest_from_list("weak", presets));        /* the name itself */
	assert_null(suggest_from_list("", presets));
	/* the closest wins, the first of equals */
	suggest_init(&s, "lot");
	suggest_offer(&s, "list");
	suggest_offer(&s, "lock");
	suggest_offer(&s, "lots");
	assert_string_equal(suggest_best(&s), "lots");
	suggest_init(&s, "ab");
	suggest_offer(&s, "ax");
	suggest_offer(&s, "ay");
	assert_string_equal(suggest_best(&s), "ax");
	assert_string_equal(suggest_hint(&s, hint, sizeof(hint)), " (did you mean 'ax'?)");
	suggest_init(&s, "zzz");
	suggest_offer(&s, NULL);
	suggest_offer(&s, "abc");
	assert_string_equal(suggest_hint(&s, hint, sizeof(hint)), "");
}

static const struct option longopts[] = {
	{ "tolerance", required_argument, NULL, 't' },
	{ "robust", no_argument, NULL, 'R' },
	{ "correction", required_argument, NULL, 0x100 },
	{ "correction-kind", required_argument, NULL, 0x101 },
	{ "json", no_argument, NULL, 'j' },
	{ NULL, 0, NULL, 0 },
};

/* Runs getopt_long() over args until it refuses one and returns the
 * message for it. */
static const char *refused(char *buf, size_t size, int argc, ...)
{
	char *argv[8] = { (char *)"fit" };
	va_list ap;
	int c;

	va_start(ap, argc);
	for (int i = 1; i < argc; i++)
		argv[i] = va_arg(ap, char *);
	va_end(ap);
	argv[argc] = NULL;
	optind = 0;
	opterr = 0;
	while ((c = getopt_long(argc, argv, "ho:", longopts, NULL)) != -1)
		if (c == '?' || c == ':')
			return suggest_getopt_error(argv, "ho:", longopts, buf, size);
	return "accepted";
}

static void test_getopt_error(void **state)
{
	char buf[256];

	assert_string_equal(refused(buf, sizeof(buf), 3, "--tolerence", "x"),
			    "unknown option '--tolerence' (did you mean '--tolerance'?)");
	assert_string_equal(refused(buf, sizeof(buf), 2, "--tolerence=x"),
			    "unknown option '--tolerence' (did you mean '--tolerance'?)");
	assert_string_equal(refused(buf, sizeof(buf), 2, "--frobnicate"),
			    "unknown option '--frobnicate'");
	assert_string_equal(refused(buf, sizeof(buf), 3, "a", "--tolerance"),
			    "option '--tolerance' needs a value");
	assert_string_equal(refused(buf, sizeof(buf), 2, "--tol"),
			    "option '--tolerance' needs a value");
	assert_string_equal(refused(buf, sizeof(buf), 2, "--robust=yes"),
			    "option '--robust' takes no value");
	assert_string_equal(refused(buf, sizeof(buf), 2, "--corr"),
			    "option '--corr' is ambiguous: --correction --correction-kind");
	assert_string_equal(refused(buf, sizeof(buf), 3, "--json", "-x"), "unknown option '-x'");
	assert_string_equal(refused(buf, sizeof(buf), 3, "--json", "-hx"), "unknown option '-x'");
	assert_string_equal(refused(buf, sizeof(buf), 2, "-o"), "option '-o' needs a value");
	assert_string_equal(refused(buf, sizeof(buf), 3, "--json", "--robust"), "accepted");
}

/* A table's names joined for a message: NULL ones left out, the last
 * separator as asked, the whole length returned however small buf is. */
static void test_join(void **state)
{
	const char *names[] = { "conformal", NULL, "vertex-plane", "plan-mesh" };
	char buf[64], small[8];

	assert_int_equal(suggest_join(buf, sizeof(buf), names, 4, " or "), 36);
	assert_string_equal(buf, "conformal, vertex-plane or plan-mesh");
	assert_int_equal(suggest_join(buf, sizeof(buf), names, 4, ", "), 34);
	assert_string_equal(buf, "conformal, vertex-plane, plan-mesh");
	assert_int_equal(suggest_join(small, sizeof(small), names, 4, " or "), 36);
	assert_string_equal(small, "conform");
	assert_int_equal(suggest_join(buf, sizeof(buf), names + 1, 2, " or "), 12);
	assert_string_equal(buf, "vertex-plane");
	assert_int_equal(suggest_join(buf, sizeof(buf), names, 0, " or "), 0);
	assert_string_equal(buf, "");
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_distance),
		cmocka_unit_test(test_suggest),
		cmocka_unit_test(test_getopt_error),
		cmocka_unit_test(test_join),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
