/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Jerk-limited rest-to-rest profiles, straight moves, PVT knots. */
#include <errno.h>
#include <math.h>
#include <string.h>

#include "asph/motion.h"

int asph_motion_limits_check(const struct asph_motion_limits *lim, struct asph_error *err)
{
	static const char *const axis[] = { "0", "1", "2" };

	for (int k = 0; k < ASPH_MOTION_AXES; k++) {
		if (!(lim->speed[k] > 0) || !isfinite(lim->speed[k]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "speed",
						 "axis %s: speed %g is not a positive number", axis[k],
						 lim->speed[k]);
		if (!(lim->accel[k] >= 0) || !isfinite(lim->accel[k]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "accel",
						 "axis %s: acceleration %g is not a number >= 0", axis[k],
						 lim->accel[k]);
		if (!(lim->jerk[k] >= 0) || !isfinite(lim->jerk[k]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "jerk",
						 "axis %s: jerk %g is not a number >= 0", axis[k],
						 lim->jerk[k]);
	}
	if (!(lim->rate >= 0) || !isfinite(lim->rate))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "rate",
					 "rate %g is not a number >= 0", lim->rate);
	return 0;
}

/* ----------------------------------------------------------- profile */

/* The ramp from rest to v: its jerk phases, its constant-acceleration
 * phase and the peak acceleration. */
static void ramp(double v, double a_max, double j_max, double *tj, double *tc, double *a_peak)
{
	if (j_max <= 0) {
		*tj = 0;
		*tc = a_max > 0 ? v / a_max : 0;
		*a_peak = a_max;
	} else if (a_max <= 0 || v * j_max <= a_max * a_max) {
		*tj = sqrt(v / j_max);
		*tc = 0;
		*a_peak = j_max * *tj;
	} else {
		*tj = a_max / j_max;
		*tc = v / a_max - *tj;
		*a_peak = a_max;
	}
}

/* The highest speed whose ramp up and ramp down fit in d together. */
static double peak_speed(double d, double a, double j)
{
	if (j <= 0)
		return sqrt(a * d);
	double tri = cbrt(d * d * j / 4);   /* accelerations that never reach a */
	if (a <= 0 || tri * j <= a * a)
		return tri;
	return (-a * a / j + sqrt(a * a * a * a / (j * j) + 4 * a * d)) / 2;
}

void asph_motion_profile_plan(double d, double v_max, double a_max, double j_max,
			      struct asph_motion_profile *p)
{
	double tj, tc, ap;

	memset(p, 0, sizeof(*p));
	if (!(d > 0))
		return;
	p->d = d;
	double v = v_max;
	ramp(v, a_max, j_max, &tj, &tc, &ap);
	double d_ramp = v * (2 * tj + tc) / 2;
	if (2 * d_ramp > d && (a_max > 0 || j_max > 0)) {
		v = fmin(v_max, peak_speed(d, a_max, j_max));
		ramp(v, a_max, j_max, &tj, &tc, &ap);
		d_ramp = v * (2 * tj + tc) / 2;
	}
	double cruise = fmax(0, d - 2 * d_ramp) / v;
	p->t[0] = p->t[2] = p->t[4] = p->t[6] = tj;
	p->t[1] = p->t[5] = tc;
	p->t[3] = cruise;
	p->v = v;
	p->a = ap;
	p->j = j_max > 0 ? j_max : 0;
	p->duration = 4 * tj + 2 * tc + cruise;
}

void asph_motion_profile_eval(const struct asph_motion_profile *p, double t, double *s,
			      double *v, double *acc)
{
	/* jerk and the acceleration at the start of each phase */
	const double jk[7] = { p->j, 0, -p->j, 0, -p->j, 0, p->j };
	const double a0[7] = { 0, p->a, p->a, 0, 0, -p->a, -p->a };
	double ss = 0, vv = 0, aa = 0;

	if (t >= p->duration) {
		/* at rest at the end: exactly, without the phases' round-off */
		ss = p->d;
	} else if (t > 0) {
		for (int k = 0; k < 7; k++) {
			double d = p->t[k] < t ? p->t[k] : t;
			if (k == 3)
				vv = p->v;      /* exact at the cruise */
			aa = a0[k];
			ss += vv * d + aa * d * d / 2 + jk[k] * d * d * d / 6;
			vv += aa * d + jk[k] * d * d / 2;
			aa += jk[k] * d;
			t -= d;
			if (t <= 0)
				break;
		}
	}
	if (s)
		*s = ss;
	if (v)
		*v = vv;
	if (acc)
		*acc = aa;
}

void asph_motion_profile_phase(const struct asph_motion_profile *p, int k, double *s0,
			       double *v0, double *a0, double *j)
{
	const double jk[7] = { p->j, 0, -p->j, 0, -p->j, 0, p->j };
	const double ak[7] = { 0, p->a, p->a, 0, 0, -p->a, -p->a };
	double ss = 0, vv = 0;

	for (int i = 0; i < k; i++) {
		double d = p->t[i];
		if (i == 3)
			vv = p->v;
		ss += vv * d + ak[i] * d * d / 2 + jk[i] * d * d * d / 6;
		vv += ak[i] * d + jk[i] * d * d / 2;
	}
	if (k == 3)
		vv = p->v;
	*s0 = ss;
	*v0 = vv;
	*a0 = ak[k];
	*j = jk[k];
}

/* -------------------------------------------------------------- move */

/* The tightest of per-axis limits along the unit direction u (0 = none). */
static double along(const double *lim, const double *u)
{
	double best = 0;

	for (int k = 0; k < ASPH_MOTION_AXES; k++) {
		if (!(lim[k] > 0) || fabs(u[k]) < 1e-15)
			continue;
		double l = lim[k] / fabs(u[k]);
		if (best == 0 || l < best)
			best = l;
	}
	return best;
}

void asph_motion_move_plan(const double from[ASPH_MOTION_AXES], const double to[ASPH_MOTION_AXES],
			   const struct asph_motion_limits *lim, struct asph_motion_move *m)
{
	double len = 0;

	memset(m, 0, sizeof(*m));
	memcpy(m->from, from, sizeof(m->from));
	memcpy(m->to, to, sizeof(m->to));
	for (int k = 0; k < ASPH_MOTION_AXES; k++)
		len += (to[k] - from[k]) * (to[k] - from[k]);
	len = sqrt(len);
	m->length = len;
	if (!(len > 0))
		return;
	for (int k = 0; k < ASPH_MOTION_AXES; k++)
		m->dir[k] = (to[k] - from[k]) / len;
	asph_motion_profile_plan(len, along(lim->speed, m->dir), along(lim->accel, m->dir),
				 along(lim->jerk, m->dir), &m->profile);
}

void asph_motion_move_eval(const struct asph_motion_move *m, double t,
			   double pos[ASPH_MOTION_AXES], double vel[ASPH_MOTION_AXES],
			   double acc[ASPH_MOTION_AXES])
{
	double s, v, a;

	asph_motion_profile_eval(&m->profile, t, &s, &v, &a);
	for (int k = 0; k < ASPH_MOTION_AXES; k++) {
		/* exactly at the target at the end */
		pos[k] = t >= m->profile.duration ? m->to[k] : m->from[k] + m->dir[k] * s;
		if (vel)
			vel[k] = m->dir[k] * v;
		if (acc)
			acc[k] = m->dir[k] * a;
	}
}

/* ------------------------------------------------------------- knots */

void asph_motion_knot_eval(const struct asph_motion_knot *a, const struct asph_motion_knot *b,
			   double t, double pos[ASPH_MOTION_AXES], double vel[ASPH_MOTION_AXES],
			   double acc[ASPH_MOTION_AXES], double jerk[ASPH_MOTION_AXES])
{
	double dt = b->t - a->t;

	if (!(dt > 0)) {
		for (int k = 0; k < ASPH_MOTION_AXES; k++) {
			pos[k] = b->position[k];
			if (vel)
				vel[k] = b->velocity[k];
			if (acc)
				acc[k] = 0;
			if (jerk)
				jerk[k] = 0;
		}
		return;
	}
	double u = (t - a->t) / dt;
	u = u < 0 ? 0 : u > 1 ? 1 : u;
	for (int k = 0; k < ASPH_MOTION_AXES; k++) {
		double p0 = a->position[k], p1 = b->position[k];
		double c1 = dt * a->velocity[k];
		double c2 = 3 * (p1 - p0) - dt * (2 * a->velocity[k] + b->velocity[k]);
		double c3 = 2 * (p0 - p1) + dt * (a->velocity[k] + b->velocity[k]);
		pos[k] = p0 + u * (c1 + u * (c2 + u * c3));
		if (vel)
			vel[k] = (c1 + u * (2 * c2 + 3 * u * c3)) / dt;
		if (acc)
			acc[k] = (2 * c2 + 6 * u * c3) / (dt * dt);
		if (jerk)
			jerk[k] = 6 * c3 / (dt * dt * dt);
	}
}
