/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Decimal text to the nearest double. A number of at most 19 significant
 * digits is an integer w < 2^64 times 10^e; within |e| <= 27 its value is
 * found exactly in 128-bit integers and rounded once:
 *
 *	w 10^e = w 5^e 2^e              (e >= 0: a product below 2^127)
 *	w 10^e = (w 2^s / 5^-e) 2^(e-s)  (e < 0: a quotient of more than 64
 *	                                  bits and whether a remainder is left)
 *
 * which with Clinger's fast path (w < 2^53 and |e| <= 22: one correctly
 * rounded multiplication or division of exact doubles) covers what
 * instruments and programs write ("%.17g" of millimetres and nanometres).
 * Anything else (more digits, a far exponent, hexadecimal, inf, nan) is
 * strtod()'s.
 */
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "util-number.h"

#define MAX_DIGITS 19           /* every 19-digit integer is below 2^64 */
#define MAX_EXACT_EXP 27        /* 5^27 < 2^63 */
#define MAX_FAST_EXP 22         /* 10^22 is the largest exact power of ten */

static const uint64_t pow5[MAX_EXACT_EXP + 1] = {
	1ull, 5ull, 25ull, 125ull, 625ull, 3125ull, 15625ull, 78125ull, 390625ull,
	1953125ull, 9765625ull, 48828125ull, 244140625ull, 1220703125ull, 6103515625ull,
	30517578125ull, 152587890625ull, 762939453125ull, 3814697265625ull,
	19073486328125ull, 95367431640625ull, 476837158203125ull, 2384185791015625ull,
	11920928955078125ull, 59604644775390625ull, 298023223876953125ull,
	1490116119384765625ull, 7450580596923828125ull,
};

static const double exact_pow10[MAX_FAST_EXP + 1] = {
	1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11,
	1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
};

__extension__ typedef unsigned __int128 u128;

static inline bool is_digit(char c)
{
	return c >= '0' && c <= '9';
}

/* m 2^e for m of exactly 53 bits, a normal double. */
static double from_bits(uint64_t m, int e)
{
	uint64_t b = ((uint64_t)(e + 52 + 1023) << 52) | (m & (((uint64_t)1 << 52) - 1));
	double v;

	memcpy(&v, &b, sizeof(v));
	return v;
}

/* (q + f) 2^bin to the nearest double, ties to even, where 0 <= f < 1 is
 * known only as whether it is 0 (!sticky). q > 0; the result is a normal
 * number (its exponent stays far from the limits here). */
static double round_to_double(u128 q, bool sticky, int bin)
{
	uint64_t hi = (uint64_t)(q >> 64);
	int bits = hi ? 128 - __builtin_clzll(hi) : 64 - __builtin_clzll((uint64_t)q);

	if (bits <= 53)         /* exact: only a product is this short */
		return from_bits((uint64_t)q << (53 - bits), bin - (53 - bits));
	int shift = bits - 53;
	uint64_t m = (uint64_t)(q >> shift);
	u128 rest = q & (((u128)1 << shift) - 1), half = (u128)1 << (shift - 1);
	if ((rest > half || (rest == half && (sticky || (m & 1)))) && ++m == (uint64_t)1 << 53) {
		m >>= 1;
		shift++;
	}
	return from_bits(m, bin + shift);
}

/* w 10^e10 exactly rounded, or false when it is beyond this method. */
static bool convert(uint64_t w, long e10, double *out)
{
	if (w < (uint64_t)1 << 53 && e10 >= -MAX_FAST_EXP && e10 <= MAX_FAST_EXP) {
		*out = e10 < 0 ? (double)w / exact_pow10[-e10] : (double)w * exact_pow10[e10];
		return true;
	}
	if (e10 < -MAX_EXACT_EXP || e10 > MAX_EXACT_EXP)
		return false;
	if (e10 >= 0) {
		*out = round_to_double((u128)w * pow5[e10], false, (int)e10);
		return true;
	}
	/* w normalized to 64 bits, then 64 more below it: the quotient by
	 * 5^-e10 < 2^63 keeps more than 64 bits */
	int lz = __builtin_clzll(w);
	u128 num = (u128)(w << lz) << 64;
	uint64_t d = pow5[-e10];
	*out = round_to_double(num / d, num % d != 0, (int)e10 - 64 - lz);
	return true;
}

/* strtod() on a NUL-terminated copy of what may be a number. */
static size_t parse_with_strtod(const char *text, size_t len, double *out)
{
	char buf[PARSE_DOUBLE_MAX + 2], *end;
	size_t n = len < PARSE_DOUBLE_MAX + 1 ? len : PARSE_DOUBLE_MAX + 1;

	memcpy(buf, text, n);
	buf[n] = '\0';
	*out = strtod(buf, &end);
	n = (size_t)(end - buf);
	if (n == 0 || n > PARSE_DOUBLE_MAX) {
		*out = 0;
		return 0;
	}
	return n;
}

/* The decimal digits of a number: the first MAX_DIGITS significant ones
 * as w, what they are scaled by as e10, whether any non-zero digit was
 * left out. */
struct decimal {
	uint64_t w;
	long e10;
	int digits;
	bool any, dropped;
};

/* The digits from i on (of the fraction when fraction is set) into d;
 * returns where they end. */
static size_t digits(const char *text, size_t i, size_t len, bool fraction, struct decimal *d)
{
	size_t start = i;

	if (d->w == 0)          /* leading zeros: only the scale of a fraction's */
		for (; i < len && text[i] == '0'; i++)
			d->e10 -= fraction;
	size_t first = i;
	for (; i < len && is_digit(text[i]); i++)
		;
	size_t take = i - first, room = (size_t)(MAX_DIGITS - d->digits);
	if (take > room) {
		for (size_t k = first + room; k < i; k++)
			d->dropped |= text[k] != '0';
		if (!fraction)
			d->e10 += (long)(take - room);
		take = room;
	}
	for (size_t k = first; k < first + take; k++)
		d->w = 10 * d->w + (uint64_t)(text[k] - '0');
	d->digits += (int)take;
	if (fraction)
		d->e10 -= (long)take;
	d->any |= i > start;
	return i;
}

/* An exponent ("e-7") at i, added to e10; i itself when there is none. */
static size_t exponent(const char *text, size_t i, size_t len, long *e10)
{
	size_t j = i + 1;
	long e = 0;
	bool neg = false;

	if (i >= len || (text[i] != 'e' && text[i] != 'E'))
		return i;
	if (j < len && (text[j] == '+' || text[j] == '-'))
		neg = text[j++] == '-';
	if (j >= len || !is_digit(text[j]))
		return i;
	for (; j < len && is_digit(text[j]); j++)
		if (e < 100000)         /* far beyond any double: saturate */
			e = 10 * e + (text[j] - '0');
	*e10 += neg ? -e : e;
	return j;
}

size_t parse_double(const char *text, size_t len, double *out)
{
	struct decimal d = { 0 };
	size_t i = 0;
	bool neg = false;
	double v;

	*out = 0;
	if (i < len && (text[i] == '+' || text[i] == '-'))
		neg = text[i++] == '-';
	/* inf, nan, hexadecimal: strtod's */
	if (i < len && (text[i] == 'i' || text[i] == 'I' || text[i] == 'n' || text[i] == 'N' ||
			(text[i] == '0' && i + 1 < len && (text[i + 1] == 'x' || text[i + 1] == 'X'))))
		return parse_with_strtod(text, len, out);
	i = digits(text, i, len, false, &d);
	if (i < len && text[i] == '.')
		i = digits(text, i + 1, len, true, &d);
	if (!d.any)
		return 0;
	i = exponent(text, i, len, &d.e10);
	if (i > PARSE_DOUBLE_MAX)
		return 0;
	if (d.w == 0) {
		*out = neg ? -0.0 : 0.0;
		return i;
	}
	if (d.dropped || !convert(d.w, d.e10, &v))
		return parse_with_strtod(text, i, out);
	*out = neg ? -v : v;
	return i;
}

/* ------------------------------------------------------------ writing */

#define G17_DIGITS 17
#define TEN_16 10000000000000000ull
#define TEN_17 100000000000000000ull

/* m 2^q 10^k rounded to an integer, ties to even, for 0 <= k <= 27 (the
 * product m 5^k of a 53-bit m is below 2^116); false when it would not fit
 * in 64 bits. */
static bool scaled_round(uint64_t m, int q, int k, uint64_t *out)
{
	u128 p = (u128)m * pow5[k], n;
	int s = -(q + k);

	if (s <= 0) {
		if (-s >= 64 || (p >> (64 + s)) != 0)
			return false;
		*out = (uint64_t)(p << -s);
		return true;
	}
	if (s >= 127) {
		*out = 0;       /* below 2^-10: no power of ten here needs it */
		return true;
	}
	n = p >> s;
	u128 rem = p - (n << s), half = (u128)1 << (s - 1);
	if (rem > half || (rem == half && (n & 1)))
		n++;
	if (n >> 64)
		return false;
	*out = (uint64_t)n;
	return true;
}

/* The 17 significant digits of |v| (a normal double) as an integer in
 * [10^16, 10^17) and the decimal exponent of the first; false where the
 * power of ten needed is not exact in 128 bits. */
static bool g17_digits(double v, uint64_t *digits, int *exp10)
{
	uint64_t b;
	int be, e;

	memcpy(&b, &v, sizeof(b));
	be = (int)((b >> 52) & 0x7ff);
	if (be == 0 || be == 0x7ff)
		return false;           /* zero, subnormal, inf, nan */
	uint64_t m = (b & ((1ull << 52) - 1)) | (1ull << 52);
	int q = be - 1075;
	/* 2^(q + 52) <= |v| < 2^(q + 53): e is the exponent or one below */
	e = (int)floor((q + 52) * 0.30102999566398119521);
	for (int tries = 0; tries < 3; tries++) {
		int k = G17_DIGITS - 1 - e;
		uint64_t n;
		if (k < 0 || k > MAX_EXACT_EXP || !scaled_round(m, q, k, &n))
			return false;
		if (n >= TEN_17)
			e++;
		else if (n < TEN_16)
			e--;
		else {
			*digits = n;
			*exp10 = e;
			return true;
		}
	}
	return false;
}

/* %g's layout of the digits d[0 .. nd) (trailing zeros gone) of a number
 * d.ddd 10^e: fixed when -4 <= e < 17, else with an exponent. */
static size_t g17_layout(char *buf, size_t i, const char *d, int nd, int e)
{
	if (e < -4 || e >= G17_DIGITS) {
		buf[i++] = d[0];
		if (nd > 1) {
			buf[i++] = '.';
			memcpy(buf + i, d + 1, (size_t)nd - 1);
			i += (size_t)nd - 1;
		}
		return i + (size_t)sprintf(buf + i, "e%c%02d", e < 0 ? '-' : '+', abs(e));
	}
	if (e < 0) {
		buf[i++] = '0';
		buf[i++] = '.';
		for (int z = 0; z < -e - 1; z++)
			buf[i++] = '0';
		memcpy(buf + i, d, (size_t)nd);
		return i + (size_t)nd;
	}
	memcpy(buf + i, d, (size_t)e + 1);
	i += (size_t)e + 1;
	if (nd > e + 1) {
		buf[i++] = '.';
		memcpy(buf + i, d + e + 1, (size_t)(nd - e - 1));
		i += (size_t)(nd - e - 1);
	}
	return i;
}

size_t format_double_g17(char buf[FORMAT_G17_MAX], double v)
{
	char d[G17_DIGITS];
	uint64_t n;
	int e, nd = G17_DIGITS;
	size_t i = 0;

	if (!g17_digits(v, &n, &e))
		return (size_t)snprintf(buf, FORMAT_G17_MAX, "%.17g", v);
	for (int k = G17_DIGITS - 1; k >= 0; k--) {
		d[k] = (char)('0' + n % 10);
		n /= 10;
	}
	while (nd > 1 && d[nd - 1] == '0')
		nd--;
	if (signbit(v))
		buf[i++] = '-';
	i = g17_layout(buf, i, d, nd, e);
	buf[i] = '\0';
	return i;
}
