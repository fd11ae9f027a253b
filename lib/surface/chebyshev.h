/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Piecewise Chebyshev interpolants built adaptively from an accurate but
 * slow function, evaluated in O(log panels + degree). Internal. */
#ifndef ASPH_CHEBYSHEV_H
#define ASPH_CHEBYSHEV_H

#include <stddef.h>

#define CHEB_DEGREE 24

struct cheb_panel {
	double lo, hi;
	double c[CHEB_DEGREE];
};

struct cheb_table {
	size_t n_panels;
	struct cheb_panel *panels;   /* sorted, contiguous over [lo, hi] */
};

/*
 * Builds an interpolant of f over [lo, hi], splitting panels until the
 * interpolant matches f at the panel's check points within rel_tol
 * (relative to max |f| over the panel) or max_panels is reached.
 * Returns 0, -ENOMEM, or -ERANGE when the tolerance was not met (the table
 * is still usable, at lower accuracy).
 */
int cheb_table_build(struct cheb_table *t, double lo, double hi,
		     double (*f)(double x, void *ctx), void *ctx,
		     double rel_tol, size_t max_panels);
void cheb_table_clear(struct cheb_table *t);

/* x is clamped to [lo, hi] of the table. */
double cheb_table_eval(const struct cheb_table *t, double x);

#endif
