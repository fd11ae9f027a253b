/* SPDX-License-Identifier: GPL-3.0-or-later */
/* bench-motion's kinematic lower bound (tests/bench/motion-bound.c): its
 * building blocks and whole paths against the closed forms of time-optimal
 * jerk-limited motions, written out here from their phases. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include <cmocka.h>

#include "motion-bound.h"

#define CLOSE(got, want, tol)                                                            \
	do {                                                                             \
		double g_ = (got), w_ = (want);                                          \
		if (!(fabs(g_ - w_) <= (tol) * (1 + fabs(w_))))                          \
			fail_msg("%s = %.15g, closed form %.15g", #got, g_, w_);          \
	} while (0)

/* Rest to rest over d reaching the speed v (d long enough to cruise): the
 * 7-phase S-curve, d / v + v / a + a / j when a is reached (v j >= a^2),
 * d / v + 2 sqrt(v / j) when not, d / v + v / a without a jerk limit. */
static double rest_to_rest(double d, double v, double a, double j)
{
	if (j <= 0)
		return a > 0 ? d / v + v / a : d / v;
	if (a <= 0 || v * j < a * a)
		return d / v + 2 * sqrt(v / j);
	return d / v + v / a + a / j;
}

static void test_rest_to_rest(void **state)
{
	/* a rest-to-rest move is at rest at both ends: the bound's reach from
	 * rest on both sides meets in the middle, T >= 2 P^-1(d / 2), which
	 * is the S-curve's time when the move cruises */
	static const struct mb_axis axes[] = {
		{ 20, 1000, 5e4 },      /* the realistic bench: v j >= a^2 */
		{ 17.3, 811, 37900 },
		{ 13.7, 1981, 52700 },  /* v j < a^2: a never reached */
		{ 21.3, 613, 0 },       /* no jerk limit */
		{ 9.1, 0, 7e4 },        /* no acceleration limit */
		{ 9.1, 0, 0 },          /* neither */
	};
	for (size_t i = 0; i < sizeof(axes) / sizeof(axes[0]); i++) {
		const struct mb_axis *ax = &axes[i];
		double d = 7.3, t = 2 * mb_reach_time(ax, 0, d / 2);
		CLOSE(t, rest_to_rest(d, ax->v, ax->a, ax->j), 1e-12);
		/* and the reach is its inverse */
		CLOSE(mb_reach(ax, 0, t / 2), d / 2, 1e-12);
	}
	/* too short to cruise: no more than the S-curve's time (jerk phases
	 * only: 4 (d / (2 j))^(1/3)), and not far below it */
	struct mb_axis ax = { 20, 1000, 5e4 };
	double d = 0.17, want = 4 * cbrt(d / (2 * 5e4)), t = 2 * mb_reach_time(&ax, 0, d / 2);
	assert_true(t <= want * (1 + 1e-12));
	assert_true(t >= 0.7 * want);
}

static void test_reversal(void **state)
{
	/* an axis reversing from +v to -v at its acceleration and jerk limits
	 * (2 v j >= a^2): jerk -j for a / j, -a for 2 v / a - a / j, jerk +j
	 * for a / j, 2 v / a + a / j in all. Its turning point is the middle,
	 * where the acceleration is -a: from there the reach with a free start
	 * acceleration is this half, a constant a for t1 = v / a - a / (2 j)
	 * and a jerk ramp of a / j, covering a t1^2 / 2 + a^2 t1 / j +
	 * a^3 / (3 j^2). */
	const double v = 20, a = 1000, j = 5e4;
	struct mb_axis ax = { v, a, j };
	double t1 = v / a - a / (2 * j);
	double half = v / a + a / (2 * j), dist = a * t1 * t1 / 2 + a * a * t1 / j + a * a * a / (3 * j * j);
	double d_ramp, t_ramp = mb_reach_ramp(&ax, INFINITY, &d_ramp);

	CLOSE(t_ramp, half, 1e-14);
	CLOSE(d_ramp, dist, 1e-13);
	CLOSE(mb_reach(&ax, INFINITY, t1), a * t1 * t1 / 2, 1e-13);
	/* past the ramp at the full speed */
	CLOSE(mb_reach_time(&ax, INFINITY, dist + 1.3), half + 1.3 / v, 1e-13);
	/* within the constant acceleration: sqrt(2 d / a) */
	CLOSE(mb_reach_time(&ax, INFINITY, 0.01), sqrt(2 * 0.01 / a), 1e-12);
	/* a start acceleration above sqrt(2 j v) would overshoot v: the reach
	 * is the triangle's, a = sqrt(2 j v) falling to 0 in a / j */
	struct mb_axis slow = { 1, 1000, 5e4 };
	double ap = sqrt(2 * 5e4 * 1), tr = ap / 5e4;
	CLOSE(mb_reach_ramp(&slow, INFINITY, &d_ramp), tr, 1e-14);
	CLOSE(d_ramp, ap * tr * tr / 2 - 5e4 * tr * tr * tr / 6, 1e-13);
}

/* A line of points 0, h, .., L along axis k, and back when back is set. */
static double *line(size_t k, double h, size_t steps, int back, size_t *n)
{
	*n = back ? 2 * steps + 1 : steps + 1;
	double *m = calloc(3 * *n, sizeof(double));
	assert_non_null(m);
	for (size_t i = 0; i < *n; i++)
		m[3 * i + k] = h * (double)(i <= steps ? i : 2 * steps - i);
	return m;
}

static void test_paths(void **state)
{
	const double v = 20, a = 1000, j = 5e4, h = 0.05;
	struct mb_axis ax[3] = { { v, a, j }, { v, a, j }, { v, a, j } };
	struct mb_stats st;
	size_t n;

	/* out along y and back, rest to rest: the time-optimal motion
	 * accelerates, cruises, reverses at the far end (the half reversal's
	 * closed form of test_reversal, twice), cruises and stops */
	double L = 6.35;
	double *m = line(1, h, 127, 1, &n);
	double t1 = v / a - a / (2 * j);
	double rev = 2 * v / a + a / j;
	double rev_d = 2 * (a * t1 * t1 / 2 + a * a * t1 / j + a * a * a / (3 * j * j));
	double want = (2 * L - rev_d) / v + rev + (v / a + a / j);
	CLOSE(mb_path_bound(m, n, ax, 0, &st), want, 1e-12);
	CLOSE(st.length, 2 * L, 1e-12);
	CLOSE(st.segments, 2 * L / v, 1e-12);
	assert_int_equal(st.windows, 3);
	free(m);

	/* one way along x: the S-curve, d / v + v / a + a / j */
	m = line(0, h, 127, 0, &n);
	CLOSE(mb_path_bound(m, n, ax, 0, &st), rest_to_rest(L, v, a, j), 1e-12);
	/* the probe's rate binds when h / v < 1 / rate: (n - 1) / rate at
	 * least, with the ramps' share where they are slower still */
	double slow = mb_path_bound(m, n, ax, 100, &st);
	assert_true(slow >= 127 / 100.0 * (1 - 1e-12));
	CLOSE(st.segments, 127 / 100.0, 1e-12);
	free(m);

	/* a single point, two points */
	double one[3] = { 1, 2, 3 }, two[6] = { 0, 0, 0, 0.001, 0, 0 };
	assert_true(mb_path_bound(one, 1, ax, 0, NULL) == 0);
	double t2 = mb_path_bound(two, 2, ax, 0, NULL);
	assert_true(t2 > 0.001 / v && t2 <= 4 * cbrt(0.001 / (2 * j)) * (1 + 1e-12));
}

static void test_circle(void **state)
{
	/* three turns of a circle of radius r: a motion that ramps up to u
	 * along it with a_t and j_t, goes round at u and ramps down is feasible
	 * (each axis' acceleration at most a_t + u^2 / r and its jerk at most
	 * j_t + u^3 / r^2 + 3 u a_t / r), so the bound is no more than its
	 * time, 2 pi r turns / u + u / a_t + a_t / j_t */
	const double r = 0.2, u = 8, a_t = 200, j_t = 10000;
	const size_t per_turn = 200, turns = 3, n = per_turn * turns + 1;
	struct mb_axis ax[3] = { { 20, 1000, 5e4 }, { 20, 1000, 5e4 }, { 20, 1000, 5e4 } };
	double *m = calloc(3 * n, sizeof(double));
	struct mb_stats st;

	assert_non_null(m);
	assert_true(a_t + u * u / r <= 1000);
	assert_true(j_t + u * u * u / (r * r) + 3 * u * a_t / r <= 5e4);
	for (size_t i = 0; i < n; i++) {
		double phi = 2 * M_PI * (double)i / per_turn;
		m[3 * i] = r * cos(phi);
		m[3 * i + 1] = r * sin(phi);
	}
	double b = mb_path_bound(m, n, ax, 0, &st);
	assert_true(b <= 2 * M_PI * r * turns / u + u / a_t + a_t / j_t);
	/* the reversals of x and y at the circle's sides (at most sqrt(a r)
	 * there) raise it above the segments' speed alone */
	assert_true(b > st.segments * 1.05);
	assert_true(st.windows > 0);
	free(m);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_rest_to_rest),
		cmocka_unit_test(test_reversal),
		cmocka_unit_test(test_paths),
		cmocka_unit_test(test_circle),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
