/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The measuring time a scan will take, predicted before anything is opened
 * from what the instrument's options say of its stage and probe: streamed
 * through timed sweeps, the feed-rate planner's time along the plan's path
 * (the same planner the executor drives the stage with); through untimed
 * sweeps, the plan cut into sweeps as the executor cuts it, each timed by
 * the stage's own prediction (motion_time), else at the axes' speeds;
 * point by point, each point's moves (the stage's prediction, else at the
 * axes' limits), the settling dwell and the reading; either way the
 * approach from home and the rounds of drift references. Homing and the
 * stage's own settling (its ringing) are not predicted.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scan.h"

/* Plan point p where the stage puts the probe's reference point: a
 * standoff above an optical probe's point, the tip's centre on a tactile
 * one's (the nominal normal's tilt neglected), in the stage's axes. */
static void machine_of(const struct asph_stage_info *si, const struct asph_probe_info *pi,
		       const double p[3], double *theta, double m[3])
{
	double z = pi->type == ASPH_PROBE_OPTICAL ? p[2] - pi->standoff : p[2] + pi->tip_radius;

	if (si->kinematics == ASPH_KINEMATICS_RTZ) {
		if (hypot(p[0], p[1]) > 1e-12)
			*theta += remainder(atan2(p[1], p[0]) - *theta, 2 * M_PI);
		m[0] = hypot(p[0], p[1]);
		m[1] = *theta;
	} else {
		m[0] = p[0];
		m[1] = p[1];
	}
	m[2] = z;
}

/* What the moves' times are predicted from. */
struct motion {
	const struct asph_motion_limits *lim;
	const struct asph_instrument_config *c;
	int (*motion_time)(const struct asph_driver *drv, const struct asph_option_value *options,
			   const double *from, const double *positions, size_t n, bool sweep,
			   double *seconds, struct asph_error *err);
};

/* A move of the stage from rest to rest: the stage's prediction, else the
 * planner's move at the axes' limits. */
static double move_time(const double from[3], const double to[3], const struct motion *mo)
{
	struct asph_motion_move mv;
	double t;

	if (mo->motion_time &&
	    mo->motion_time(mo->c->stage_driver, asph_options_values(mo->c->stage_options), from,
			    to, 1, false, &t, NULL) == 0)
		return t;
	asph_motion_move_plan(from, to, mo->lim, &mv);
	return mv.profile.duration;
}

/* The untimed sweeps of the n points m (stage axes) as the executor cuts
 * them (at most batch points each), the stage at rest at m[0] before. */
static double sweeps_time(const double *m, size_t n, size_t batch, double rate,
			  const struct motion *mo)
{
	double t = 0;

	for (size_t i = 0; i < n;) {
		const double *from = m + 3 * (i ? i - 1 : 0);
		struct sweep_cut cut = { 0 };
		while (i + cut.n < n && cut.n < batch && sweep_cut_open(&cut))
			sweep_cut_add(&cut, cut.n ? m + 3 * (i + cut.n - 1) : from, m + 3 * (i + cut.n),
				      mo->lim, rate);
		double s;
		if (mo->motion_time &&
		    mo->motion_time(mo->c->stage_driver, asph_options_values(mo->c->stage_options),
				    from, m + 3 * i, cut.n, true, &s, NULL) == 0)
			t += s;
		else
			t += cut.motion;
		i += cut.n;
	}
	return t;
}

/* Up by the clearance, across, down: how the executor reaches a point. */
static double approach_time(const double from[3], const double to[3], double clearance,
			    const struct motion *mo)
{
	double up[3] = { from[0], from[1], fmax(from[2], to[2]) + clearance };
	double above[3] = { to[0], to[1], up[2] };

	return move_time(from, up, mo) + move_time(up, above, mo) + move_time(above, to, mo);
}

/* A round of the drift references from the plan point at, and back to it
 * unless it is the last (the scan ends at the references). */
static double round_time(const struct asph_stage_info *si, const struct asph_probe_info *pi,
			 const struct asph_surface *s, const struct asph_acquisition *a,
			 const double at[3], double clearance, double read, bool back,
			 const struct motion *mo)
{
	double from[3], ref[3], t = 0;

	memcpy(from, at, sizeof(from));
	for (size_t k = 0; k < a->n_references; k++) {
		double p[3] = { a->references[k][0], a->references[k][1], 0 }, th = from[1];
		p[2] = asph_surface_sag_xy(s, p[0], p[1]);
		machine_of(si, pi, p, &th, ref);
		t += approach_time(from, ref, clearance / 2, mo) + a->settle_dwell + read;
		memcpy(from, ref, sizeof(from));
	}
	return back ? t + approach_time(from, at, clearance / 2, mo) : t;
}

/* Point by point, the moves the executor makes (scan_measure_at): to
 * above each point by the clearance (over the part at the travel height
 * where the straight way comes too close), down, the reading, up again;
 * from home. Its own geometry, on an instrument that is only described. */
static int steps_time(const struct asph_instrument_config *c, const struct asph_stage_info *si,
		      const struct asph_probe_info *pi, const struct asph_surface *s,
		      const double *xyz, size_t n, const struct asph_scan_options *so, double read,
		      double settle, const struct motion *mo, double *out, struct asph_error *err)
{
	struct asph_instrument inst = { .config = c, .stage_driver = c->stage_driver,
					.probe_driver = c->probe_driver, .stage_info = *si,
					.probe_info = *pi };
	struct asph_scan *sc;
	double pos[3] = { 0, 0, 0 }, way[3][3], t = 0;
	int r = asph_scan_new(&inst, s, xyz, n, so, &sc, err);

	if (r < 0)
		return r;
	r = asph_scan_check(sc, err);
	for (size_t i = 0; i < n && r == 0; i++) {
		struct target tg;
		scan_target(sc, i, false, &tg);
		size_t nw = scan_clear_path(sc, pos, tg.approach, sc->o.clearance / 2, way);
		for (size_t k = 0; k < nw; k++) {
			t += move_time(pos, way[k], mo);
			memcpy(pos, way[k], sizeof(pos));
		}
		t += move_time(pos, tg.machine, mo) + settle + read +
		     move_time(tg.machine, tg.approach, mo);
		memcpy(pos, tg.approach, sizeof(pos));
	}
	asph_scan_free(sc);
	*out = t;
	return r;
}

int asph_scan_estimate(const struct asph_instrument_config *c, const struct asph_surface *s,
		       const double *xyz, size_t n, const struct asph_scan_options *so,
		       double *seconds, struct asph_error *err)
{
	struct asph_stage_info si;
	struct asph_probe_info pi;
	struct asph_motion_limits lim;
	struct asph_acquisition acq = c->acquisition;
	const struct asph_acquisition *a = &acq;
	unsigned flags = so ? so->flags : 0;
	double clearance = so && so->clearance > 0 ? so->clearance : 0.5, theta = 0;
	int r = asph_instrument_describe(c, &si, &pi, err);

	*seconds = 0;
	if (r < 0)
		return r;
	if (n == 0)
		return 0;
	asph_acquisition_advised(&acq, &si);
	scan_motion_limits(&si, &pi, &lim);
	double *m = malloc(3 * n * sizeof(double));
	if (!m)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < n; i++)
		machine_of(&si, &pi, xyz + 3 * i, &theta, m + 3 * i);

	const struct asph_stage_ops *ops = c->stage_driver->stage;
	unsigned minor = asph_driver_abi_minor(c->stage_driver);
	bool pvt = minor >= 1 && ops->sweep_pvt;
	/* as the executor decides (asph_scan_new) */
	bool stream = (flags & ASPH_SCAN_STREAM) && pi.type == ASPH_PROBE_OPTICAL && pi.can_stream &&
		      c->probe_driver->probe->stream && (ops->sweep || pvt);
	struct motion mo = { &lim, c, minor >= 3 ? ops->motion_time : NULL };
	double read = (pi.rate > 0 ? 1 / pi.rate : 0) + (pi.latency > 0 ? pi.latency : 0);
	double home[3] = { 0, 0, 0 }, t = approach_time(home, m, clearance, &mo) + a->settle_dwell;

	if (stream && !pvt) {
		size_t batch = so && so->stream_batch && so->stream_batch < RECORD_BATCH ? so->stream_batch
										   : RECORD_BATCH;
		t += sweeps_time(m, n, batch, pi.rate, &mo) + (pi.latency > 0 ? pi.latency : 0);
	} else if (stream) {
		struct asph_motion_planner *pl;
		double path;
		r = asph_motion_planner_alloc(0, &pl);
		if (r < 0) {
			free(m);
			return asph_error_set(err, r, "out of memory");
		}
		r = asph_motion_path_duration(pl, m, n, &lim, &path, err);
		asph_motion_planner_free(pl);
		t += path + (pi.latency > 0 ? pi.latency : 0);
	} else {
		r = steps_time(c, &si, &pi, s, xyz, n, so, read, a->settle_dwell, &mo, &t, err);
	}

	/* the rounds of drift references: at the start, every interval, at
	 * the end; each one from where the scan is then to the references
	 * and back (a streamed path stops for it and starts again), the last
	 * one without the way back */
	if (r == 0 && asph_acquisition_drift(a)) {
		double measuring = t;
		size_t rounds = 2;
		if (a->drift_interval_s > 0)
			rounds += (size_t)floor(measuring / a->drift_interval_s);
		else
			rounds += (n - 1) / a->drift_interval_points;
		for (size_t j = 0; j < rounds; j++) {
			/* the plan point the round interrupts, by its share of the scan */
			size_t i = j + 1 == rounds ? n - 1 : (size_t)((double)j / (double)(rounds - 1) * (double)(n - 1));
			t += round_time(&si, &pi, s, a, m + 3 * i, clearance, read, j + 1 < rounds, &mo);
		}
	}
	free(m);
	if (r < 0)
		return r;
	*seconds = t;
	return 0;
}

int asph_scan_plan_time(void *timing, const struct asph_plan *plan, double *seconds,
			struct asph_error *err)
{
	const struct asph_scan_timing *t = timing;

	return asph_scan_estimate(t->instrument, t->surface, plan->xyz, plan->n, &t->options,
				  seconds, err);
}
