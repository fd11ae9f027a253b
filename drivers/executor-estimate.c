/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The measuring time a scan will take, predicted before anything is opened
 * from what the instrument's options say of its stage and probe: streamed,
 * the feed-rate planner's time along the plan's path (the same planner the
 * executor drives the stage with); point by point, each point's moves at
 * the axes' limits, the settling dwell and the reading; either way the
 * approach from home and the rounds of drift references. Homing and the
 * stage's own settling (its ringing) are not predicted.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "executor-internal.h"

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

static double move_time(const double from[3], const double to[3],
			const struct asph_motion_limits *lim)
{
	struct asph_motion_move mv;

	asph_motion_move_plan(from, to, lim, &mv);
	return mv.profile.duration;
}

/* Up by the clearance, across, down: how the executor reaches a point. */
static double approach_time(const double from[3], const double to[3], double clearance,
			    const struct asph_motion_limits *lim)
{
	double up[3] = { from[0], from[1], fmax(from[2], to[2]) + clearance };
	double above[3] = { to[0], to[1], up[2] };

	return move_time(from, up, lim) + move_time(up, above, lim) + move_time(above, to, lim);
}

/* A round of the drift references from the plan point at and back. */
static double round_time(const struct asph_stage_info *si, const struct asph_probe_info *pi,
			 const struct asph_surface *s, const struct asph_acquisition *a,
			 const double at[3], double clearance, double read,
			 const struct asph_motion_limits *lim)
{
	double from[3], ref[3], t = 0;

	memcpy(from, at, sizeof(from));
	for (size_t k = 0; k < a->n_references; k++) {
		double p[3] = { a->references[k][0], a->references[k][1], 0 }, th = from[1];
		p[2] = asph_surface_sag_xy(s, p[0], p[1]);
		machine_of(si, pi, p, &th, ref);
		t += approach_time(from, ref, clearance / 2, lim) + a->settle_dwell + read;
		memcpy(from, ref, sizeof(from));
	}
	return t + approach_time(from, at, clearance / 2, lim);
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
	bool stream = (flags & ASPH_SCAN_STREAM) && pi.type == ASPH_PROBE_OPTICAL && pi.can_stream &&
		      asph_driver_abi_minor(c->stage_driver) >= 1 && ops->sweep_pvt;
	double read = (pi.rate > 0 ? 1 / pi.rate : 0) + (pi.latency > 0 ? pi.latency : 0);
	double home[3] = { 0, 0, 0 }, t = approach_time(home, m, clearance, &lim) + a->settle_dwell;

	if (stream) {
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
		for (size_t i = 0; i < n; i++) {
			if (i)
				t += approach_time(m + 3 * (i - 1), m + 3 * i, clearance / 2, &lim) +
				     a->settle_dwell;
			t += read;
		}
	}

	/* the rounds of drift references: at the start, every interval, at
	 * the end; each one from where the scan is then to the references
	 * and back (a streamed path stops for it and starts again) */
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
			t += round_time(&si, &pi, s, a, m + 3 * i, clearance, read, &lim);
		}
	}
	free(m);
	if (r < 0)
		return r;
	*seconds = t;
	return 0;
}
