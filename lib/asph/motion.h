/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_MOTION_H
#define ASPH_MOTION_H

#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Motion of a three-axis stage: jerk-limited point-to-point moves, the
 * PVT trajectories (position, velocity, time) a stage follows through a
 * path, and the feed-rate planner that times a path of measuring points
 * close to the kinematic limit. docs/scanning.md ("Motion") states the
 * model; in short:
 *
 * - Limits are per axis, in the axes' own units (mm or rad): speed,
 *   acceleration and jerk, and the probe's reading rate (one reading per
 *   path point, so two points are at least 1 / rate apart in time).
 * - A move is a straight line in the axes, its parameter following a
 *   7-phase jerk-limited profile from rest to rest.
 * - A path is followed through PVT knots: between two knots the stage's
 *   command is the cubic Hermite curve that has the knots' positions and
 *   velocities at their times.
 * - The planner sets the speed along the path by a lookahead over the
 *   points to come (a backward pass from where the motion must be slow,
 *   a forward pass from where it is). The speed at a point is limited by
 *   the axes' speeds along the path, the probe's rate for the spacing, and
 *   the turn: the Hermite curve the stage follows there (with the path's
 *   direction at a point the bisector of its two segments' directions),
 *   whose acceleration and jerk grow as v^2 and v^3, may take 0.4 of each
 *   axis' acceleration and 0.25 of its jerk; the motion along the path
 *   takes the other 0.6 and 0.75. The accelerations a are then made
 *   jerk-limited by a moving average of the path parameter over
 *   T = 2 a / j, which bounds its jerk by j; a point's speed limit is
 *   the lowest within the average's reach, where a point at a distance d
 *   limits it to no less than d / (0.6 T) (at that speed the average
 *   reads back just to it), and a point that the average
 *   still passes over a hard limit (the whole acceleration or jerk of an
 *   axis, the speed, the rate) is planned slower until none is.
 */

#define ASPH_MOTION_AXES 3

struct asph_motion_limits {
	double speed[ASPH_MOTION_AXES];  /* > 0, unit/s */
	double accel[ASPH_MOTION_AXES];  /* unit/s^2; 0 = no limit */
	double jerk[ASPH_MOTION_AXES];   /* unit/s^3; 0 = no limit */
	double rate;                     /* points per second; 0 = no limit */
};

/* -EINVAL with err naming the limit when one is not finite, a speed is not
 * positive, or anything is negative. */
int asph_motion_limits_check(const struct asph_motion_limits *lim,
			     struct asph_error *err);

/* -------------------------------------------------------------- moves */

/*
 * A rest-to-rest profile of a path parameter over a length d: jerk +j,
 * constant acceleration a, jerk -j, cruise at v, and the mirror image
 * (phase durations t[0 .. 6]). v, a, j are the peaks it reaches, which the
 * limits bound (a or j 0: not limited; an unlimited acceleration makes the
 * speed jump, an unlimited jerk the acceleration).
 */
struct asph_motion_profile {
	double t[7];
	double d;                       /* the length */
	double v, a, j;
	double duration;
};

void asph_motion_profile_plan(double d, double v_max, double a_max, double j_max,
			      struct asph_motion_profile *p);

/* s, ds/dt and d2s/dt2 at time t (clamped to 0 .. duration); v, acc may be
 * NULL. */
void asph_motion_profile_eval(const struct asph_motion_profile *p, double t, double *s,
			      double *v, double *acc);

/* Phase k of the profile (0 .. 6): its start s, speed, acceleration (just
 * after the start, where they jump without limits) and its jerk; over the
 * phase s = s0 + v0 t + a0 t^2 / 2 + j t^3 / 6. */
void asph_motion_profile_phase(const struct asph_motion_profile *p, int k, double *s0,
			       double *v0, double *a0, double *j);

/*
 * A straight move from rest to rest: the path parameter follows a profile
 * whose speed, acceleration and jerk are the largest that keep every axis
 * inside its limits along the move's direction.
 */
struct asph_motion_move {
	double from[ASPH_MOTION_AXES], to[ASPH_MOTION_AXES];
	double dir[ASPH_MOTION_AXES];   /* unit direction in the axes */
	double length;                  /* in the axes' units */
	struct asph_motion_profile profile;
};

void asph_motion_move_plan(const double from[ASPH_MOTION_AXES],
			   const double to[ASPH_MOTION_AXES],
			   const struct asph_motion_limits *lim,
			   struct asph_motion_move *m);

/* Where the move is at t (clamped to 0 .. its duration); vel, acc may be
 * NULL. */
void asph_motion_move_eval(const struct asph_motion_move *m, double t,
			   double pos[ASPH_MOTION_AXES], double vel[ASPH_MOTION_AXES],
			   double acc[ASPH_MOTION_AXES]);

/* ---------------------------------------------------------------- PVT */

enum asph_motion_knot_flags {
	/* The knot is a path point: the probe reads there. */
	ASPH_MOTION_KNOT_POINT = 1u << 0,
};

struct asph_motion_knot {
	double t;                               /* s from the start of the path */
	double position[ASPH_MOTION_AXES];
	double velocity[ASPH_MOTION_AXES];
	uint32_t flags;
	uint32_t point;                         /* index of the path point */
};

/* The cubic Hermite command between knots a and b at time t (a->t <= t <=
 * b->t); vel, acc, jerk may be NULL. */
void asph_motion_knot_eval(const struct asph_motion_knot *a, const struct asph_motion_knot *b,
			   double t, double pos[ASPH_MOTION_AXES], double vel[ASPH_MOTION_AXES],
			   double acc[ASPH_MOTION_AXES], double jerk[ASPH_MOTION_AXES]);

/* ------------------------------------------------------------ planner */

struct asph_motion_planner;

/*
 * A planner that looks ahead over at most window points at a time (0 =
 * 8192); its memory does not grow with the path. The caller owns it and
 * may plan any number of paths with it, one at a time.
 */
int asph_motion_planner_alloc(size_t window, struct asph_motion_planner **out);
void asph_motion_planner_free(struct asph_motion_planner *p);

/*
 * Starts timing the path points[0 .. n-1] (3 n, the axes' units), from
 * rest at points[0] to rest at points[n-1]. points must stay valid until
 * the path is done. -EINVAL for bad limits or a non-finite point.
 */
int asph_motion_planner_start(struct asph_motion_planner *p, const double *points,
			      size_t n, const struct asph_motion_limits *lim,
			      struct asph_error *err);

/* Path point i into out (the axes' units): a path read as it is needed. */
typedef void (*asph_motion_point_fn)(const void *data, size_t i, double out[ASPH_MOTION_AXES]);

/* The same for the n points point() gives; the planner reads each point as
 * its window reaches it (finite points are the caller's to give). */
int asph_motion_planner_start_path(struct asph_motion_planner *p, asph_motion_point_fn point,
				   const void *data, size_t n, const struct asph_motion_limits *lim,
				   struct asph_error *err);

/*
 * The next knots of the path, in order: at most max into out. *n_out is 0
 * when the path is done. The first knot is points[0] at t = 0, at rest;
 * every point of the path is a knot (ASPH_MOTION_KNOT_POINT); after a stop
 * the path goes on from rest at the stop's last knot.
 */
int asph_motion_planner_next(struct asph_motion_planner *p, struct asph_motion_knot *out,
			     size_t max, size_t *n_out);

/*
 * Stops as soon as the limits allow after the last knot handed out: the
 * knots that bring the stage to rest (the path points it still passes,
 * then a knot at rest that is no path point, unless it stops exactly on
 * one), at most max (-ENOBUFS when more are needed: the points within a
 * braking distance and the average's reach). The next knots then start
 * from rest there.
 */
int asph_motion_planner_stop(struct asph_motion_planner *p, struct asph_motion_knot *out,
			     size_t max, size_t *n_out);

/* Points of the path so far where no slower plan kept the hard limits
 * (a turn too sharp for the jerk at any speed the average can pass at). */
unsigned asph_motion_planner_unkept(const struct asph_motion_planner *p);

/* Times a whole path: the duration in s (0 for one point), or a negative
 * errno. */
int asph_motion_path_duration(struct asph_motion_planner *p, const double *points,
			      size_t n, const struct asph_motion_limits *lim,
			      double *seconds, struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
