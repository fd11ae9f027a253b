/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Quintic Hermite pieces: the polynomial through a function's value, first
 * and second derivative at both ends of an interval. Internal. */
#ifndef ASPH_HERMITE_H
#define ASPH_HERMITE_H

/*
 * y0, y1: value, first and second derivative at x0 and x0 + h. c receives
 * p(s) = sum c[k] s^k in s = (x - x0) / h. The error is O(h^6 y^(6)),
 * largest near the middle of the interval.
 */
static inline void hermite5(const double y0[3], const double y1[3], double h,
			    double c[6])
{
	double d0 = h * y0[1], s0 = h * h * y0[2];
	double d1 = h * y1[1], s1 = h * h * y1[2];
	double D = y1[0] - y0[0] - d0 - 0.5 * s0, E = d1 - d0 - s0, G = s1 - s0;

	c[0] = y0[0];
	c[1] = d0;
	c[2] = 0.5 * s0;
	c[3] = 10.0 * D - 4.0 * E + 0.5 * G;
	c[4] = -15.0 * D + 7.0 * E - G;
	c[5] = 6.0 * D - 3.0 * E + 0.5 * G;
}

static inline double poly5(const double c[6], double s)
{
	return c[0] + s * (c[1] + s * (c[2] + s * (c[3] + s * (c[4] + s * c[5]))));
}

/* dp/ds (divide by h for d/dx). */
static inline double poly5_deriv(const double c[6], double s)
{
	return c[1] + s * (2.0 * c[2] + s * (3.0 * c[3] + s * (4.0 * c[4] +
		s * 5.0 * c[5])));
}

#endif
