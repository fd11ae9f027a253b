/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Streaming (stream.c): the stage sweeps through the plan points while the
 * probe reads at each, timed (PVT) through the feed-rate planner or at the
 * stage's own pace; each reading paired with the position the stage
 * measured. Internal.
 */
#ifndef ASPH_ENGINE_STREAM_H
#define ASPH_ENGINE_STREAM_H

#include <stddef.h>

#include "asph/motion.h"
#include "run.h"

/* What stream.c keeps of a scan; only it writes it. */
struct scan_stream {
	struct asph_motion_planner *planner;
	double *theta;          /* r-theta-z: the plan's theta, unwrapped */
	size_t run_from, run_to; /* the last whole run of a timed sweep checked */
	double path[3 * RECORD_BATCH];
	struct asph_pvt knots[RECORD_BATCH + 2];
	struct asph_motion_knot mk[RECORD_BATCH + 2];
	struct asph_probe_context ctx[RECORD_BATCH];
	struct asph_reading readings[RECORD_BATCH];
	struct pending *pend;   /* queue of readings to come */
	size_t pend_head, pend_n, pend_cap;
	struct asph_position_sample *trace;    /* queue of measured positions */
	size_t trace_head, trace_n, trace_cap;
	struct asph_position_sample latch_hist[2];     /* the last two latched */
	size_t n_hist;
};

int scan_stream_init(struct asph_scan *sc, struct asph_error *err);
void scan_stream_fini(struct asph_scan *sc);
/* Measures from plan point i on while the sweeps can go on; *done gets
 * the plan points it finished. */
int scan_stream(struct asph_scan *sc, size_t i, size_t *done, struct asph_error *err);

#endif
