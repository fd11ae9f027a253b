/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The time of the driver's moves and sweeps, step by step as api.c makes
 * them: each SDO exchange costs sdo_s, each poll of a statusword that
 * finds the axis still under way poll_s more, and each axis runs its own
 * profile (CiA 402 profile position mode: trapezoidal at the profile
 * velocity and acceleration, through a buffered set point without
 * stopping where the next one goes on in the same direction).
 */
#include <math.h>

#include "timing.h"

/* 11-bit identifier, 8 data bytes: SOF, identifier, RTR, control field,
 * data, CRC and its delimiter, ACK slot and delimiter, EOF, intermission. */
#define FRAME_BITS (1 + 11 + 1 + 6 + 64 + 16 + 2 + 7 + 3)

double can_sdo_exchange_s(double bitrate)
{
	return 2.0 * FRAME_BITS / bitrate;
}

/* One axis' run over d (mm, >= 0) entering at v0 and leaving at most at
 * v1 (mm/s): the time, and in *out the speed it leaves with. */
static double run_time(const struct can_timing *t, double d, double v0, double v1, double *out)
{
	double v = t->speed, a = t->acceleration;
	double up = (v * v - v0 * v0) / (2 * a), down = (v * v - v1 * v1) / (2 * a);

	if (up + down <= d) {
		*out = v1;
		return (v - v0) / a + (v - v1) / a + (d - up - down) / v;
	}
	/* no cruise: the peak speed where the two ramps meet */
	double peak = sqrt((2 * a * d + v0 * v0 + v1 * v1) / 2);
	if (peak >= v0 && peak >= v1) {
		*out = v1;
		return (peak - v0) / a + (peak - v1) / a;
	}
	if (peak < v1) {        /* too short to reach v1: speeding up all along */
		*out = sqrt(v0 * v0 + 2 * a * d);
		return (*out - v0) / a;
	}
	/* too short to slow down to v1: it leaves faster */
	*out = sqrt(fmax(0, v0 * v0 - 2 * a * d));
	return (v0 - *out) / a;
}

/* The distance of an axis' move as the drive makes it, in whole counts. */
static double span(const struct can_timing *t, int k, double from, double to)
{
	double c = t->counts_per_mm[k];
	return (nearbyint(to * c) - nearbyint(from * c)) / c;
}

/* Polls a statusword (one exchange each, poll_s between two) until it
 * shows the state the axis reaches at when. */
static double poll_until(const struct can_timing *t, double now, double when)
{
	if (!(t->sdo_s + t->poll_s > 0))
		return fmax(now, when);
	for (;;) {
		now += t->sdo_s;
		if (now >= when)
			return now;
		now += t->poll_s;
	}
}

double can_move_time(const struct can_timing *t, const double from[3], const double to[3])
{
	double now = 0, arrive[3] = { 0 }, v;
	bool moving[3] = { false };

	/* send_set_point(): target, controlword, statusword, controlword; the
	 * axis sets off with the second */
	for (int k = 0; k < 3; k++) {
		double d = t->axis[k] ? fabs(span(t, k, from[k], to[k])) : 0;
		if (d == 0)
			continue;
		moving[k] = true;
		arrive[k] = now + 2 * t->sdo_s + run_time(t, d, 0, 0, &v);
		now += 4 * t->sdo_s;
	}
	/* every moving axis polled in turn until all have arrived */
	if (!(t->sdo_s + t->poll_s > 0))
		return fmax(fmax(now, arrive[0]), fmax(arrive[1], arrive[2]));
	for (;;) {
		bool all = true;
		for (int k = 0; k < 3; k++) {
			if (!moving[k])
				continue;
			now += t->sdo_s;
			moving[k] = now < arrive[k];
			all = all && !moving[k];
		}
		if (all)
			return now;
		now += t->poll_s;
	}
}

/* The exchanges of one trigger: the output up and down, the positions. */
static double fire_time(const struct can_timing *t, int axes)
{
	static const int reads[] = { [CAN_LATCH_NONE] = 1, [CAN_LATCH_CONTINUOUS] = 2,
				     [CAN_LATCH_SINGLE] = 4 };

	return ((t->trigger ? 2 : 0) + axes * reads[t->latch]) * t->sdo_s;
}

/* An axis along a sweep: where its current run started, how, and when it
 * passes (or reaches) the point it runs to. */
struct run {
	double start, d, v0, v1, pass;
};

/* The run to point k of an axis whose set point was taken at accept,
 * after the run before (prev). */
static void next_run(const struct can_timing *t, const struct run *prev, bool first, double accept,
		     double d, double d_next, bool last, struct run *out)
{
	double v1 = last || d * d_next < 0 ? 0 : t->speed;

	out->d = d;
	if (first || accept > prev->pass) {
		/* the axis was at rest at the point before (or stopped there:
		 * its set point came late) */
		double rest = prev->pass;
		if (!first && prev->v1 > 0)
			rest = prev->start + run_time(t, fabs(prev->d), prev->v0, 0, &(double){ 0 });
		out->start = fmax(accept, first ? accept : rest);
		out->v0 = 0;
	} else {
		out->start = prev->pass;
		out->v0 = prev->v1;
	}
	out->pass = out->start + run_time(t, fabs(d), out->v0, v1, &out->v1);
}

double can_sweep_time(const struct can_timing *t, const double from[3], const double *p, size_t n)
{
	static const int arm[] = { [CAN_LATCH_NONE] = 0, [CAN_LATCH_CONTINUOUS] = 4,
				   [CAN_LATCH_SINGLE] = 3 };
	struct run run[3] = { 0 };
	int axes = t->axis[0] + t->axis[1] + t->axis[2];
	double now;

	if (n == 0)
		return 0;
	/* sweep_prepare(): the touch probes armed, the outputs read (the
	 * trigger output's enable, written once after the open, left out) */
	now = (axes * arm[t->latch] + (t->trigger ? 2 : 0)) * t->sdo_s;
	for (size_t k = 0; k < n; k++) {
		for (int a = 0; a < 3; a++) {
			if (!t->axis[a])
				continue;
			const double *prev = k ? p + 3 * (k - 1) : from;
			double d = span(t, a, prev[a], p[3 * k + a]);
			double d_next = k + 1 < n ? span(t, a, p[3 * k + a], p[3 * (k + 1) + a]) : 0;
			if (k == 0)
				now += t->sdo_s;        /* the buffer is free: at rest */
			/* queue_set_point(): target, controlword (taken), the
			 * acknowledge, controlword */
			struct run r;
			next_run(t, &run[a], k == 0, now + 2 * t->sdo_s, d, d_next, k + 1 == n, &r);
			run[a] = r;
			now += 4 * t->sdo_s;
		}
		if (k == 0)
			continue;
		/* every axis took point k, that is, passed point k - 1; then
		 * its trigger */
		for (int a = 0; a < 3; a++)
			if (t->axis[a])
				now = poll_until(t, now, run[a].start);
		now += fire_time(t, axes);
	}
	/* the last point reached by every axis, its trigger at rest, the
	 * touch probes switched off */
	for (int a = 0; a < 3; a++)
		if (t->axis[a])
			now = poll_until(t, now, run[a].pass);
	now += fire_time(t, axes);
	if (t->latch != CAN_LATCH_NONE)
		now += axes * t->sdo_s;
	return now;
}
