/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A kinematic lower bound on the time of any motion through a path of
 * points, derived here from first principles and independent of
 * lib/motion (docs/scanning.md, "Measuring time per plan"). The motion
 * passes the points in order; each axis k keeps |v| <= V_k, |a| <= A_k,
 * |j| <= J_k; the probe reads once per point, two readings at least
 * 1 / rate apart; the motion starts and ends at rest.
 */
#ifndef ASPH_BENCH_MOTION_BOUND_H
#define ASPH_BENCH_MOTION_BOUND_H

#include <stddef.h>

/* One axis' limits: v > 0; a, j 0 for none. */
struct mb_axis {
	double v, a, j;
};

/*
 * The farthest an axis can be, t after an instant at which it was at rest
 * with an acceleration of at most alpha0 in its direction of travel
 * (INFINITY: any the limits allow), from where it was then. The same
 * holds backwards in time towards an instant of rest.
 */
double mb_reach(const struct mb_axis *ax, double alpha0, double t);

/* The least t with mb_reach(ax, alpha0, t) >= d (d >= 0). */
double mb_reach_time(const struct mb_axis *ax, double alpha0, double d);

/* The time after which the reach grows at the full speed v: the reach's
 * distance then in *d (may be NULL). */
double mb_reach_ramp(const struct mb_axis *ax, double alpha0, double *d);

struct mb_stats {
	double length;          /* of the polyline, in the axes' units */
	double segments;        /* the bound from the segments alone (s) */
	size_t windows;         /* reversal and rest windows that raised it */
};

/*
 * The lower bound (s) for the n points m (3 n: x, y, z) under the three
 * axes' limits ax and the probe's rate (0: none); st may be NULL. -1 when
 * out of memory.
 */
double mb_path_bound(const double *m, size_t n, const struct mb_axis ax[3], double rate,
		     struct mb_stats *st);

#endif
