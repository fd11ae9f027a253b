/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Numbers in text, read the one way the tree reads them: exactly as strtod()
 * in the C locale, correctly rounded, without strtod()'s locale and
 * arbitrary-precision machinery for the numbers files hold (up to 19
 * significant digits, a decimal exponent within +-27 of them), which is
 * what makes reading millions of them slow. Shared by the readers of points
 * (delimited text, PLY) and anything else that reads numbers. Internal
 * header.
 */
#ifndef ASPH_UTIL_NUMBER_H
#define ASPH_UTIL_NUMBER_H

#include <stddef.h>

/* The longest number parse_double() reads; a longer one is not read. */
#define PARSE_DOUBLE_MAX 400

/*
 * Reads the number at the start of text[0 .. len) (no NUL needed, no blank
 * skipped) as strtod() does in the C locale: an optional sign, then decimal
 * digits with an optional point and exponent, "inf", "infinity", "nan" (any
 * case) or a hexadecimal number ("0x1.8p3"). *out is the double nearest to
 * it (ties to even; +-HUGE_VAL beyond the range, as strtod). Returns the
 * characters read, 0 when text does not start with a number (or with one
 * longer than PARSE_DOUBLE_MAX characters); *out is then 0.
 */
size_t parse_double(const char *text, size_t len, double *out);

/* The longest text format_double_g17() writes, its NUL included. */
#define FORMAT_G17_MAX 32

/*
 * Writes v as snprintf("%.17g") does in the C locale, byte for byte, and
 * returns its length (the NUL is written after it). Seventeen significant
 * digits give every double back through parse_double() or strtod(). The
 * digits of a number between 1e-11 and 1e16 in magnitude are found exactly
 * in 128-bit integers, without snprintf()'s arbitrary-precision machinery,
 * which is what makes writing millions of them slow; the rest is
 * snprintf()'s.
 */
size_t format_double_g17(char buf[FORMAT_G17_MAX], double v);

#endif
