/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Newton's method kept inside a bracket, for the inverse maps of the
 * surface and the plans (monotone increasing functions). Internal to lib. */
#ifndef ASPH_NUMERIC_NEWTON_H
#define ASPH_NUMERIC_NEWTON_H

/*
 * One step at r, where the function is f (its value minus the target) with
 * derivative df: the bracket [*lo, *hi] shrinks to the side of r that the
 * sign of f leaves the root on, and the Newton step r - f / df is taken when
 * it stays inside, else the midpoint. f = 0 is the caller's to test first.
 */
static inline double newton_bracketed_step(double r, double f, double df, double *lo,
					   double *hi)
{
	if (f > 0)
		*hi = r;
	else
		*lo = r;
	double next = r - f / df;
	return next > *lo && next < *hi ? next : 0.5 * (*lo + *hi);
}

#endif
