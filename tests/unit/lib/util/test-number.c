/* SPDX-License-Identifier: GPL-3.0-or-later */
/* util-number.h against glibc's strtod(), which rounds correctly: every
 * finite double through "%.17g" and back bit for bit, random decimal texts
 * of every length and exponent, the ties of each path, what is not a
 * number, and texts without a NUL. */
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "util-number.h"

#define N_RANDOM 100000

static uint64_t next(uint64_t *s)
{
	/* xorshift64*: reproducible high-entropy bits */
	*s ^= *s >> 12;
	*s ^= *s << 25;
	*s ^= *s >> 27;
	return *s * 0x2545F4914F6CDD1Dull;
}

static uint64_t bits_of(double v)
{
	uint64_t b;

	memcpy(&b, &v, sizeof(b));
	return b;
}

/* text parses as strtod() parses it: the same bits, the same length. */
static void check_as_strtod(const char *text)
{
	size_t len = strlen(text);
	char *copy = malloc(len + 1), *end;
	double want, got;

	assert_non_null(copy);
	memcpy(copy, text, len);    /* no NUL in the bytes parse_double() sees */
	want = strtod(text, &end);
	size_t used = parse_double(copy, len, &got);
	if (used != (size_t)(end - text) || bits_of(got) != bits_of(want)) {
		fprintf(stderr, "'%s': parse_double %.17g (%zu chars), strtod %.17g (%zu chars)\n",
			text, got, used, want, (size_t)(end - text));
		fail();
	}
	free(copy);
}

static void test_round_trip(void **state)
{
	uint64_t s = 0x9e3779b97f4a7c15ull;
	char buf[64];
	int k = 0;

	/* every kind of double: random bits, so every exponent, subnormals
	 * included; and the magnitudes of coordinates in mm and nm */
	for (int i = 0; i < N_RANDOM; i++) {
		uint64_t b = next(&s);
		double v, back;
		if (i % 2)
			b = (b & 0x800fffffffffffffull) | ((uint64_t)(1023 - 40 + i % 60) << 52);
		memcpy(&v, &b, sizeof(v));
		if (!isfinite(v))
			continue;
		for (int f = 0; f < 2; f++) {
			int n = f ? snprintf(buf, sizeof(buf), "%.16e", v)
				  : snprintf(buf, sizeof(buf), "%.17g", v);
			assert_int_equal(parse_double(buf, (size_t)n, &back), (size_t)n);
			if (bits_of(back) != bits_of(v)) {
				fprintf(stderr, "%s: %.17g back as %.17g\n", buf, v, back);
				fail();
			}
			k++;
		}
	}
	assert_true(k > N_RANDOM);
}

static void test_random_texts(void **state)
{
	uint64_t s = 0x243f6a8885a308d3ull;
	char text[128];

	for (int i = 0; i < N_RANDOM; i++) {
		uint64_t r = next(&s);
		int n_digits = 1 + (int)(r % 25), point = (int)((r >> 8) % (uint64_t)(n_digits + 2));
		int exp = (int)((r >> 16) % 81) - 40;
		size_t k = 0;
		if (r & (1ull << 40))
			text[k++] = '-';
		for (int d = 0; d < n_digits; d++) {
			if (d == point)
				text[k++] = '.';
			/* runs of 0 and 9 make the halfway and carry cases */
			uint64_t q = next(&s) % 13;
			text[k++] = (char)(q >= 10 ? (q == 10 ? '0' : '9') : '0' + (int)q);
		}
		if (r & (1ull << 41))
			k += (size_t)snprintf(text + k, sizeof(text) - k, "e%d", exp);
		text[k] = '\0';
		check_as_strtod(text);
	}
}

static void test_ties(void **state)
{
	static const char *const texts[] = {
		/* 2^53 + 1 and + 3: halfway, to the even neighbour */
		"9007199254740993", "9007199254740995", "9007199254740993.0000000000001",
		/* 2^52 + 1.5 (a quotient's tie), 2^52 + 1.25 */
		"4503599627370497.5", "4503599627370497.25", "4503599627370498.5",
		/* a product's tie: 2^60 + 2^7 is 1152921504606847104 */
		"1152921504606847104", "1152921504606847105", "115292150460684710.4e1",
		"0.1", "0.2", "0.3", "1e23", "8.98846567431158e307", "1.7976931348623157e308",
		"2.2250738585072011e-308", "2.2250738585072014e-308", "4.9406564584124654e-324",
		"1e-27", "1e27", "1e28", "1e-28", "9999999999999999999e27", "1.8446744073709551615e19",
		"18446744073709551615", "18446744073709551616", "0.0000000000000000000000000001",
		"123456789012345678901234567890", "0.000123456789012345678", "7.450580596923828125e-9",
	};

	for (size_t i = 0; i < sizeof(texts) / sizeof(texts[0]); i++)
		check_as_strtod(texts[i]);
}

static void test_forms(void **state)
{
	static const char *const texts[] = {
		"0", "-0", "+0", "0.0", ".5", "-.5", "5.", "+5", "00012.5000", "1e5", "1E+05",
		"1e-5", "2.5e", "2.5e+", "2.5e-x", "1e999999999999", "-1e999999999999",
		"1e-999999999999", "inf", "-Infinity", "nan", "NaN", "0x1.8p1", "-0X10", "0x",
		"12,5", "3.25 mm", "7-2",
	};
	double v;

	for (size_t i = 0; i < sizeof(texts) / sizeof(texts[0]); i++)
		check_as_strtod(texts[i]);
	/* not numbers: nothing read, 0 */
	static const char *const none[] = { "", "+", "-", ".", "-.", "e5", "abc", " 1", "\t1",
					     "+-1", ".e1" };
	for (size_t i = 0; i < sizeof(none) / sizeof(none[0]); i++) {
		v = 1;
		assert_int_equal(parse_double(none[i], strlen(none[i]), &v), 0);
		assert_true(v == 0);
	}
	/* only len characters are read */
	assert_int_equal(parse_double("1.5", 2, &v), 2);
	assert_true(v == 1.0);
	assert_int_equal(parse_double("-2.5e3", 4, &v), 4);
	assert_true(v == -2.5);
	assert_int_equal(parse_double("1e-7", 2, &v), 1);
	assert_true(v == 1.0);
	/* a number longer than the limit is not read, one at it is */
	char *big = malloc(PARSE_DOUBLE_MAX + 2);
	assert_non_null(big);
	memset(big, '0', PARSE_DOUBLE_MAX + 1);
	big[PARSE_DOUBLE_MAX - 1] = '7';
	assert_int_equal(parse_double(big, PARSE_DOUBLE_MAX, &v), PARSE_DOUBLE_MAX);
	assert_true(v == 7.0);
	assert_int_equal(parse_double(big, PARSE_DOUBLE_MAX + 1, &v), 0);
	free(big);
}

/* v written as snprintf("%.17g") writes it, byte for byte. */
static void check_as_snprintf(double v)
{
	char want[64], got[FORMAT_G17_MAX];
	int n = snprintf(want, sizeof(want), "%.17g", v);
	size_t len = format_double_g17(got, v);

	if (len != (size_t)n || strcmp(got, want) != 0) {
		fprintf(stderr, "%a: format_double_g17 '%s', snprintf '%s'\n", v, got, want);
		fail();
	}
}

static void test_format_g17(void **state)
{
	uint64_t s = 0x243f6a8885a308d3ull;

	/* every kind of double (random bits), and the magnitudes of the exact
	 * path, 1e-12 to 1e17, both signs */
	for (int i = 0; i < N_RANDOM / 2; i++) {
		uint64_t b = next(&s);
		double v;
		if (i % 4)
			b = (b & 0x800fffffffffffffull) | ((uint64_t)(1023 - 40 + i % 97) << 52);
		memcpy(&v, &b, sizeof(v));
		check_as_snprintf(v);
	}
	/* ties at the 18th digit (u / 2^k with k fraction bits has an
	 * expansion of k digits: 17 + 1 significant ones for the right k),
	 * rounded to even; and the neighbours of powers of ten, where the
	 * rounding carries into a new digit */
	for (int i = 0; i < N_RANDOM / 8; i++) {
		uint64_t u = (next(&s) >> (11 + i % 40)) | 1;
		check_as_snprintf(ldexp((double)u, -(i % 64)));
	}
	for (int e = -14; e <= 18; e++) {
		double p = pow(10, e), v = p;
		for (int k = 0; k < 40; k++, v = nextafter(v, 0))
			check_as_snprintf(v);
		v = p;
		for (int k = 0; k < 40; k++, v = nextafter(v, INFINITY))
			check_as_snprintf(-v);
		check_as_snprintf(9.9999999999999995 * p);
		check_as_snprintf(9.99999999999999995 * p);
	}
	/* what the exact path leaves to snprintf */
	double others[] = { 0.0, -0.0, INFINITY, -INFINITY, NAN, -NAN, 5e-324, 1e300,
			    -1e-300, 1e16, 1e17, 123456789012345678.0, 1e-11, 1e-12, 0.1, 1.5,
			    1 + 0x1p-17, 1 + 3 * 0x1p-17 /* ties */ };
	for (size_t i = 0; i < sizeof(others) / sizeof(others[0]); i++)
		check_as_snprintf(others[i]);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_round_trip),
		cmocka_unit_test(test_random_texts),
		cmocka_unit_test(test_ties),
		cmocka_unit_test(test_forms),
		cmocka_unit_test(test_format_g17),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
