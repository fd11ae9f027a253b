/* SPDX-License-Identifier: GPL-3.0-or-later */
/* lib/motion: profiles against closed forms, Hermite knots, the planner's
 * limits sampled along what it plans, its lookahead window, its stops. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph/motion.h"

/* ----------------------------------------------------------- profiles */

/* Time of a rest-to-rest jerk-limited move, written out from the phases
 * of an S-curve (accelerate, cruise, decelerate). */
static double closed_form_duration(double d, double v, double a, double j)
{
	double t_ramp = v * j >= a * a ? v / a + a / j : 2 * sqrt(v / j);
	if (d >= v * t_ramp)
		return t_ramp + d / v;
	/* no cruise: the speed reached solves d = v t_ramp(v) */
	double lo = 0, hi = v;
	for (int i = 0; i < 200; i++) {
		double m = (lo + hi) / 2;
		double tr = m * j >= a * a ? m / a + a / j : 2 * sqrt(m / j);
		if (m * tr > d)
			hi = m;
		else
			lo = m;
	}
	double m = (lo + hi) / 2;
	return 2 * (m * j >= a * a ? m / a + a / j : 2 * sqrt(m / j));
}

static void check_profile(double d, double v, double a, double j)
{
	struct asph_motion_profile p;
	double want = closed_form_duration(d, v, a, j);

	asph_motion_profile_plan(d, v, a, j, &p);
	if (fabs(p.duration - want) > 1e-9 * want)
		fail_msg("d %g v %g a %g j %g: %.12g s, closed form %.12g s", d, v, a, j, p.duration,
			 want);
	/* sampled: inside the limits, monotone, ends at d at rest */
	double prev_s = 0, prev_a = 0;
	int steps = 20000;
	for (int i = 0; i <= steps; i++) {
		double t = p.duration * i / steps, s, vel, acc;
		asph_motion_profile_eval(&p, t, &s, &vel, &acc);
		assert_true(s >= prev_s - 1e-12);
		assert_true(vel <= v * (1 + 1e-12) && vel >= -1e-12);
		assert_true(fabs(acc) <= a * (1 + 1e-12));
		if (i > 0) {
			double jerk = (acc - prev_a) / (p.duration / steps);
			assert_true(fabs(jerk) <= j * (1 + 1e-6));
		}
		prev_s = s;
		prev_a = acc;
	}
	assert_true(fabs(prev_s - d) <= 1e-12 * d);
}

static void test_profiles(void **state)
{
	/* cruising and reaching the acceleration limit */
	check_profile(7.3, 17.9, 731, 41300);
	/* never reaching the acceleration limit (v j < a^2) */
	check_profile(5.1, 13.7, 1981, 52700);
	/* too short to cruise, with and without reaching a */
	check_profile(0.0371, 23.1, 417, 91000);
	check_profile(0.00113, 23.1, 4170, 91000);
}

static void test_profile_limits_off(void **state)
{
	struct asph_motion_profile p;

	/* no jerk limit: the trapezoid, d / v + v / a */
	asph_motion_profile_plan(9.37, 21.3, 613, 0, &p);
	assert_true(fabs(p.duration - (9.37 / 21.3 + 21.3 / 613)) < 1e-12);
	/* nor an acceleration limit: constant speed */
	asph_motion_profile_plan(9.37, 21.3, 0, 0, &p);
	assert_true(fabs(p.duration - 9.37 / 21.3) < 1e-12);
	/* a short trapezoid: 2 sqrt(d / a) */
	asph_motion_profile_plan(0.0123, 21.3, 613, 0, &p);
	assert_true(fabs(p.duration - 2 * sqrt(0.0123 / 613)) < 1e-12);
}

static void test_move(void **state)
{
	struct asph_motion_limits lim = { { 20, 15, 7 }, { 900, 700, 300 }, { 5e4, 4e4, 2e4 }, 0 };
	const double from[3] = { -3.1, 2.2, 0.5 }, to[3] = { 4.7, -1.9, 1.3 };
	struct asph_motion_move m;
	double pos[3], vel[3], acc[3];

	asph_motion_move_plan(from, to, &lim, &m);
	/* along the move each axis runs at its share: the tightest axis sets
	 * the limit, written out here */
	double d[3], len = 0, v = INFINITY, a = INFINITY, j = INFINITY;
	for (int k = 0; k < 3; k++) {
		d[k] = to[k] - from[k];
		len += d[k] * d[k];
	}
	len = sqrt(len);
	for (int k = 0; k < 3; k++) {
		double u = fabs(d[k]) / len;
		v = fmin(v, lim.speed[k] / u);
		a = fmin(a, lim.accel[k] / u);
		j = fmin(j, lim.jerk[k] / u);
	}
	assert_true(fabs(m.profile.duration - closed_form_duration(len, v, a, j)) < 1e-9);
	asph_motion_move_eval(&m, m.profile.duration, pos, vel, acc);
	assert_memory_equal(pos, to, sizeof(pos));
	asph_motion_move_eval(&m, m.profile.duration / 3, pos, vel, acc);
	for (int k = 0; k < 3; k++) {
		assert_true(fabs(vel[k]) <= lim.speed[k] * (1 + 1e-12));
		assert_true(fabs(acc[k]) <= lim.accel[k] * (1 + 1e-12));
	}
}

static void test_knot_cubic(void **state)
{
	/* a cubic through two knots is reproduced exactly */
	const double c[4] = { 0.37, -1.21, 2.93, -0.71 }, t0 = 0.113, t1 = 0.429;
	struct asph_motion_knot a = { .t = t0 }, b = { .t = t1 };
	for (int k = 0; k < 3; k++) {
		double s = k + 1.0;
		a.position[k] = s * (c[0] + t0 * (c[1] + t0 * (c[2] + t0 * c[3])));
		a.velocity[k] = s * (c[1] + t0 * (2 * c[2] + 3 * t0 * c[3]));
		b.position[k] = s * (c[0] + t1 * (c[1] + t1 * (c[2] + t1 * c[3])));
		b.velocity[k] = s * (c[1] + t1 * (2 * c[2] + 3 * t1 * c[3]));
	}
	double t = 0.2917, pos[3], vel[3], acc[3], jerk[3];
	asph_motion_knot_eval(&a, &b, t, pos, vel, acc, jerk);
	for (int k = 0; k < 3; k++) {
		double s = k + 1.0;
		assert_true(fabs(pos[k] - s * (c[0] + t * (c[1] + t * (c[2] + t * c[3])))) < 1e-13);
		assert_true(fabs(vel[k] - s * (c[1] + t * (2 * c[2] + 3 * t * c[3]))) < 1e-12);
		assert_true(fabs(acc[k] - s * (2 * c[2] + 6 * t * c[3])) < 1e-10);
		assert_true(fabs(jerk[k] - s * 6 * c[3]) < 1e-8);
	}
}

/* ------------------------------------------------------------ planner */

static struct asph_motion_knot *plan_all(const double *pts, size_t n,
					 const struct asph_motion_limits *lim, size_t window,
					 size_t *n_knots)
{
	struct asph_motion_planner *p;
	struct asph_motion_knot *k = malloc((n + 1) * sizeof(*k));
	size_t got, total = 0;

	assert_non_null(k);
	assert_int_equal(asph_motion_planner_alloc(window, &p), 0);
	assert_int_equal(asph_motion_planner_start(p, pts, n, lim, NULL), 0);
	do {
		assert_int_equal(asph_motion_planner_next(p, k + total, n + 1 - total, &got), 0);
		total += got;
	} while (got);
	asph_motion_planner_free(p);
	*n_knots = total;
	return k;
}

static void test_straight_line(void **state)
{
	/* a straight line: the trapezoid at the tangential share of the
	 * acceleration (0.6 a), delayed by the moving average's width
	 * T = 2 a_t / (0.75 j), the tangential share of the jerk */
	const size_t n = 1201;
	const double h = 0.0211, v = 17.3, a = 811, j = 37900;
	double *pts = malloc(3 * n * sizeof(double));
	struct asph_motion_limits lim = { { v, v, v }, { a, a, a }, { j, j, j }, 0 };
	size_t nk;

	assert_non_null(pts);
	for (size_t i = 0; i < n; i++) {
		pts[3 * i] = h * (double)i;
		pts[3 * i + 1] = 0;
		pts[3 * i + 2] = 0;
	}
	struct asph_motion_knot *k = plan_all(pts, n, &lim, 0, &nk);
	double at = 0.6 * a, T = 2 * at / (0.75 * j), len = h * (double)(n - 1);
	double want = len / v + v / at + T;
	assert_int_equal(nk, n);
	if (fabs(k[n - 1].t - want) > 1e-9 * want)
		fail_msg("%.12g s, closed form %.12g s", k[n - 1].t, want);
	for (size_t i = 0; i < n; i++) {
		assert_int_equal(k[i].point, i);
		assert_true(k[i].flags & ASPH_MOTION_KNOT_POINT);
		assert_true(fabs(k[i].velocity[0]) <= v * (1 + 1e-9));
	}
	free(k);
	free(pts);
}

static void test_corner_direction(void **state)
{
	/* a right-angle corner between a segment of 0.2 and one of 0.03: the
	 * stage passes the corner along the bisector of the two directions,
	 * (1, 1) / sqrt 2, whatever the segments' lengths; elsewhere on the
	 * straight parts along the lines */
	const double xs[] = { 0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.0, 1.0, 1.0, 1.0 };
	const double ys[] = { 0, 0, 0, 0, 0, 0, 0.03, 0.23, 0.43, 0.63 };
	const size_t n = sizeof(xs) / sizeof(xs[0]), corner = 5;
	struct asph_motion_limits lim = { { 20, 20, 20 }, { 1000, 1000, 1000 },
					  { 5e4, 5e4, 5e4 }, 0 };
	double pts[3 * 10];
	size_t nk;

	for (size_t i = 0; i < n; i++) {
		pts[3 * i] = xs[i];
		pts[3 * i + 1] = ys[i];
		pts[3 * i + 2] = 0;
	}
	struct asph_motion_knot *k = plan_all(pts, n, &lim, 0, &nk);
	assert_int_equal(nk, n);
	const double *v = k[corner].velocity;
	assert_true(v[0] > 0);
	if (fabs(v[0] - v[1]) > 1e-12 * v[0] || v[2] != 0)
		fail_msg("corner velocity (%.15g, %.15g, %.15g): not along (1, 1, 0)", v[0], v[1], v[2]);
	for (size_t i = 1; i < corner; i++)
		assert_true(fabs(k[i].velocity[1]) <= 1e-12 * fabs(k[i].velocity[0]));
	for (size_t i = corner + 2; i + 1 < n; i++)
		assert_true(fabs(k[i].velocity[0]) <= 1e-12 * fabs(k[i].velocity[1]));
	free(k);
}

/* Samples the Hermite command between the knots: speed, acceleration and
 * jerk of every axis, and the time between points for the probe. */
struct worst {
	double v, a, j, dt;     /* ratios to the limits; dt: min time * rate */
};

static struct worst sample_knots(const struct asph_motion_knot *k, size_t n,
				 const struct asph_motion_limits *lim)
{
	struct worst w = { 0, 0, 0, INFINITY };

	for (size_t i = 1; i < n; i++) {
		for (int s = 0; s <= 8; s++) {
			double t = k[i - 1].t + (k[i].t - k[i - 1].t) * s / 8, pos[3], vel[3], acc[3],
			       jerk[3];
			asph_motion_knot_eval(&k[i - 1], &k[i], t, pos, vel, acc, jerk);
			for (int a = 0; a < 3; a++) {
				w.v = fmax(w.v, fabs(vel[a]) / lim->speed[a]);
				w.a = fmax(w.a, fabs(acc[a]) / lim->accel[a]);
				if (s == 4)
					w.j = fmax(w.j, fabs(jerk[a]) / lim->jerk[a]);
			}
		}
		if (lim->rate > 0)
			w.dt = fmin(w.dt, (k[i].t - k[i - 1].t) * lim->rate);
	}
	return w;
}

/* The command between knots is a Hermite curve, not the planner's own
 * profile: a few per cent over on acceleration and jerk. */
static void assert_within_limits(const struct asph_motion_knot *k, size_t n,
				 const struct asph_motion_limits *lim)
{
	struct worst w = sample_knots(k, n, lim);

	if (w.v > 1.005 || w.a > 1.05 || w.j > 1.3 || w.dt < 1 - 1e-9)
		fail_msg("worst ratios: speed %.4f accel %.4f jerk %.4f, point spacing in time * rate %.4f",
			 w.v, w.a, w.j, w.dt);
}

/* An Archimedean spiral in x, y with z following a sag, as a circle
 * involute plan and a streamed scan have it. */
static double *spiral(size_t n, double pitch, double step)
{
	double *p = malloc(3 * n * sizeof(double)), phi = 0;

	assert_non_null(p);
	for (size_t i = 0; i < n; i++) {
		double r = pitch * phi / (2 * M_PI);
		p[3 * i] = r * cos(phi);
		p[3 * i + 1] = r * sin(phi);
		p[3 * i + 2] = -r * r / (2 * 20.1);
		/* the next point a step further along the arc */
		phi += step / sqrt(r * r + (pitch / (2 * M_PI)) * (pitch / (2 * M_PI)));
	}
	return p;
}

static void test_spiral_limits(void **state)
{
	const size_t n = 6000;
	double *pts = spiral(n, 0.2, 0.2);
	struct asph_motion_limits lim = { { 20, 20, 20 }, { 1000, 1000, 1000 },
					  { 5e4, 5e4, 5e4 }, 1000 };
	size_t nk;
	struct asph_motion_knot *k = plan_all(pts, n, &lim, 0, &nk);

	assert_int_equal(nk, n);
	assert_within_limits(k, n, &lim);
	/* it moves at the speed limit on most of the way: at least 20 mm/s
	 * along x or y somewhere */
	double vmax = 0;
	for (size_t i = 0; i < n; i++)
		vmax = fmax(vmax, fmax(fabs(k[i].velocity[0]), fabs(k[i].velocity[1])));
	assert_true(vmax > 19.9);
	free(k);
	free(pts);
}

static void test_window_independent(void **state)
{
	/* the lookahead window only bounds memory: the plan is the same */
	const size_t n = 3000;
	double *pts = spiral(n, 0.3, 0.07);
	struct asph_motion_limits lim = { { 25, 25, 9 }, { 1200, 1200, 500 },
					  { 6e4, 6e4, 3e4 }, 700 };
	size_t n1, n2;
	struct asph_motion_knot *a = plan_all(pts, n, &lim, 256, &n1);
	struct asph_motion_knot *b = plan_all(pts, n, &lim, 100000, &n2);

	assert_int_equal(n1, n);
	assert_int_equal(n2, n);
	for (size_t i = 0; i < n; i++) {
		if (fabs(a[i].t - b[i].t) > 1e-9 * (1 + b[i].t))
			fail_msg("knot %zu: %.15g s with a small window, %.15g s with a large one", i,
				 a[i].t, b[i].t);
	}
	free(a);
	free(b);
	free(pts);
}

static void test_corners(void **state)
{
	/* back and forth rows 0.2 mm apart: corners of 90 degrees */
	const size_t per_row = 60, rows = 12, n = per_row * rows;
	double *pts = malloc(3 * n * sizeof(double));
	struct asph_motion_limits lim = { { 20, 20, 20 }, { 1000, 1000, 1000 },
					  { 5e4, 5e4, 5e4 }, 0 };
	size_t nk;

	assert_non_null(pts);
	for (size_t r = 0; r < rows; r++)
		for (size_t i = 0; i < per_row; i++) {
			size_t q = r * per_row + i;
			pts[3 * q] = 0.2 * (double)(r % 2 ? per_row - 1 - i : i);
			pts[3 * q + 1] = 0.2 * (double)r;
			pts[3 * q + 2] = 0;
		}
	struct asph_motion_knot *k = plan_all(pts, n, &lim, 0, &nk);
	assert_int_equal(nk, n);
	/* at each corner the speed stays under what the turn allows, v^2 kappa
	 * <= a, kappa = (pi / 2) / 0.2 */
	double v_turn = sqrt(1000 / ((M_PI / 2) / 0.2));
	for (size_t r = 0; r + 1 < rows; r++) {
		size_t q = r * per_row + per_row - 1;
		for (size_t c = q; c <= q + 1; c++) {
			double s = hypot(k[c].velocity[0], k[c].velocity[1]);
			if (s > v_turn * (1 + 1e-6))
				fail_msg("corner at point %zu: %.6f mm/s > %.6f", c, s, v_turn);
		}
	}
	struct worst w = sample_knots(k, n, &lim);
	if (w.v > 1.005 || w.a > 1.05)
		fail_msg("worst ratios: speed %.4f accel %.4f jerk %.4f", w.v, w.a, w.j);
	free(k);
	free(pts);
}

static void test_raster_turnarounds(void **state)
{
	/* a serpentine raster over a sloped part, as a raster plan has it:
	 * rows 0.17 mm apart ending on a rim point closer than the pitch, z
	 * following the slope; the stage turns back at every row end */
	const size_t per_row = 40, rows = 10, n = per_row * rows;
	const double pitch = 0.17, v = 20, a = 1000, j = 5e4;
	double *pts = malloc(3 * n * sizeof(double));
	struct asph_motion_limits lim = { { v, v, v }, { a, a, a }, { j, j, j }, 1000 };
	size_t nk;

	assert_non_null(pts);
	for (size_t r = 0; r < rows; r++)
		for (size_t i = 0; i < per_row; i++) {
			size_t q = r * per_row + i, c = r % 2 ? per_row - 1 - i : i;
			double x = c + 1 == per_row ? pitch * (double)(per_row - 2) + 0.12
						    : pitch * (double)c;
			pts[3 * q] = x;
			pts[3 * q + 1] = pitch * (double)r;
			pts[3 * q + 2] = 0.45 * x;
		}
	struct asph_motion_knot *k = plan_all(pts, n, &lim, 0, &nk);
	assert_int_equal(nk, n);
	assert_within_limits(k, n, &lim);
	/* each turnaround reverses the x velocity: between the knots two
	 * points before the row's end and two after the next row's start no
	 * faster than the S-curve that takes the x axis from +vx to -vx
	 * (closed form: 2 vx / a + a / j, or 2 sqrt(2 vx / j) when a is not
	 * reached), vx the slower of the two */
	for (size_t r = 0; r + 1 < rows; r++) {
		size_t in = r * per_row + per_row - 3, out = in + 5;
		double vx = fmin(fabs(k[in].velocity[0]), fabs(k[out].velocity[0]));
		double dv = 2 * vx, t_rev = dv * j >= a * a ? dv / a + a / j : 2 * sqrt(dv / j);
		double dt = k[out].t - k[in].t;
		/* cruising mid-row */
		assert_true(fabs(k[in - per_row / 2].velocity[0]) > 0.9 * v / sqrt(1 + 0.45 * 0.45));
		assert_true(vx > 0);
		if (dt < t_rev)
			fail_msg("turnaround %zu: %.6f s, the x axis needs %.6f s", r, dt, t_rev);
	}
	free(k);
	free(pts);
}

static void test_stop(void **state)
{
	const size_t n = 800;
	double *pts = spiral(n, 0.4, 0.15);
	struct asph_motion_limits lim = { { 20, 20, 20 }, { 1000, 1000, 1000 },
					  { 5e4, 5e4, 5e4 }, 0 };
	struct asph_motion_planner *p;
	struct asph_motion_knot k[1024], st[1024];
	size_t got, nst, seen = 0;
	double last_t = -1;

	assert_int_equal(asph_motion_planner_alloc(128, &p), 0);
	assert_int_equal(asph_motion_planner_start(p, pts, n, &lim, NULL), 0);
	assert_int_equal(asph_motion_planner_next(p, k, 300, &got), 0);
	assert_int_equal(got, 300);
	seen = 300;
	last_t = k[299].t;
	assert_int_equal(asph_motion_planner_stop(p, st, 1024, &nst), 0);
	assert_true(nst >= 1);
	/* in order, through the next points, to rest */
	for (size_t i = 0; i < nst; i++) {
		assert_true(st[i].t > last_t);
		last_t = st[i].t;
		if (st[i].flags & ASPH_MOTION_KNOT_POINT)
			assert_int_equal(st[i].point, seen++);
	}
	for (int a = 0; a < 3; a++)
		assert_true(st[nst - 1].velocity[a] == 0);
	/* it stopped within the braking distance plus the average's reach */
	double v0 = hypot(k[299].velocity[0], k[299].velocity[1]);
	double dx = hypot(st[nst - 1].position[0] - k[299].position[0],
			  st[nst - 1].position[1] - k[299].position[1]);
	double at = 600, T = 2 * at / (0.6 * 5e4);
	assert_true(dx <= v0 * v0 / (2 * at) + 2 * v0 * T + 1e-9);
	/* and goes on from there to the end, every point once */
	do {
		assert_int_equal(asph_motion_planner_next(p, k, 1024, &got), 0);
		for (size_t i = 0; i < got; i++) {
			assert_true(k[i].t > last_t);
			last_t = k[i].t;
			assert_true(k[i].flags & ASPH_MOTION_KNOT_POINT);
			assert_int_equal(k[i].point, seen++);
		}
	} while (got);
	assert_int_equal(seen, n);
	asph_motion_planner_free(p);
	free(pts);
}

static void test_bad_limits(void **state)
{
	struct asph_motion_planner *p;
	struct asph_motion_limits lim = { { 20, 0, 20 }, { 0 }, { 0 }, 0 };
	double pts[6] = { 0, 0, 0, 1, 1, 1 };
	struct asph_error err;

	assert_int_equal(asph_motion_planner_alloc(0, &p), 0);
	assert_int_equal(asph_motion_planner_start(p, pts, 2, &lim, &err), -EINVAL);
	assert_string_equal(err.field, "speed");
	lim.speed[1] = 20;
	lim.jerk[2] = -1;
	assert_int_equal(asph_motion_planner_start(p, pts, 2, &lim, &err), -EINVAL);
	assert_string_equal(err.field, "jerk");
	lim.jerk[2] = 0;
	pts[4] = NAN;
	assert_int_equal(asph_motion_planner_start(p, pts, 2, &lim, &err), -EINVAL);
	asph_motion_planner_free(p);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_profiles),
		cmocka_unit_test(test_profile_limits_off),
		cmocka_unit_test(test_move),
		cmocka_unit_test(test_knot_cubic),
		cmocka_unit_test(test_straight_line),
		cmocka_unit_test(test_corner_direction),
		cmocka_unit_test(test_spiral_limits),
		cmocka_unit_test(test_window_independent),
		cmocka_unit_test(test_corners),
		cmocka_unit_test(test_raster_turnarounds),
		cmocka_unit_test(test_stop),
		cmocka_unit_test(test_bad_limits),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
