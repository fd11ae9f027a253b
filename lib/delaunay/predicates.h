/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Robust geometric predicates for the plane. Internal header.
 *
 * Each predicate first evaluates its determinant in plain double arithmetic
 * and accepts the result when its magnitude exceeds a proven bound on the
 * rounding error; otherwise it recomputes the determinant exactly with
 * floating-point expansion arithmetic. The sign of the result is therefore
 * always the sign of the exact determinant of the given doubles, as long as
 * no intermediate product overflows or underflows (true for coordinates of
 * magnitude between about 1e-60 and 1e60, or zero).
 *
 * Points are `const double[2]` (x, y).
 */
#ifndef ASPH_PREDICATES_H
#define ASPH_PREDICATES_H

/*
 * Positive when a, b, c are in counter-clockwise order, negative when
 * clockwise, zero when collinear. The magnitude approximates twice the
 * signed area of the triangle.
 */
double orient2d(const double *a, const double *b, const double *c);

/*
 * Positive when d lies strictly inside the circle through a, b, c (taken in
 * counter-clockwise order), negative when strictly outside, zero when the
 * four points are cocircular. The sign flips when a, b, c are clockwise.
 */
double incircle(const double *a, const double *b, const double *c,
		const double *d);

/* The same, always by the exact path (for tests and for callers that must
 * not depend on the filter). Only the sign of the result is meaningful. */
double orient2d_exact(const double *a, const double *b, const double *c);
double incircle_exact(const double *a, const double *b, const double *c,
		      const double *d);

#endif
