/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A scan: what it measures and with what, set by asph_scan_new() and
 * read-only after; and the state of each part of the engine, each written
 * by its own file only and read by the files above it:
 *
 *   executor.c      a scan's life: new, run, the loop over the plan, the
 *                   second pass of dropouts, the end of the file
 *   stream.c        sweeps                             struct scan_stream
 *   drift.c         rounds of drift references         struct scan_drift
 *   resume.c        what a recovered scan says         struct scan_resume
 *   run.c           the primitives: progress, pause
 *                   and abort, moves, settling, one
 *                   measurement, records, dropouts     struct scan_run
 *   geometry.c      kinematics, targets, clearance,
 *                   the checks                         struct scan_geometry
 *
 * A file calls only the files below it in this list (scripts/check-circles
 * checks there is no circle): the loops are above the primitives. drift.c
 * reads what resume.c found (the replayed round), never calls it.
 * estimate.c and simulate.c use the executor from outside. Internal.
 */
#ifndef ASPH_ENGINE_SCAN_H
#define ASPH_ENGINE_SCAN_H

#include <stdbool.h>

#include "asph-engine/executor.h"
#include "asph/motion.h"
#include "drift.h"
#include "geometry.h"
#include "resume.h"
#include "run.h"
#include "stream.h"

struct asph_scan {
	struct asph_instrument *inst;
	const struct asph_surface *surface;
	const double *xyz;
	size_t n;
	struct asph_scan_options o;
	struct asph_acquisition acq;
	struct asph_motion_limits lim;  /* the stage's and the probe's */
	bool tactile;
	bool streamed;                  /* the probe streams along the stage's sweeps */
	bool pvt;                       /* ... timed sweeps */
	double tip, latency;

	struct scan_geometry geo;
	struct scan_run run;
	struct scan_resume resume;
	struct scan_drift drift;
	struct scan_stream stream;
};

#endif
