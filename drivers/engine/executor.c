/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The scan executor: a plan measured point by point (or swept and
 * streamed), every point recorded with the position the stage measured,
 * drift references measured as the instrument says, dropouts measured
 * again, faults ending the file with a reason. This file is a scan's
 * life, above the parts it uses (scan.h). */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scan.h"
#include "util-mem.h"

#define DEFAULT_READ_TIMEOUT_MS 2000

const char *asph_scan_state_name(enum asph_scan_state s)
{
	static const char *const names[] = {
		"ready", "checking", "homing", "measuring", "paused",
		"completed", "aborted", "failed",
	};
	return (unsigned)s < ARRAY_SIZE(names) ? names[s] : "unknown";
}

/* The longest wait for one reading: the probe driver's option named
 * read_timeout (int, ms) when it gives one above 0, for a probe that
 * needs longer than the host's default (a reading the operator triggers
 * by hand). */
static unsigned probe_read_timeout(const struct asph_instrument *inst)
{
	const struct asph_instrument_config *c = inst->config;
	int i = c ? asph_option_index(c->probe_driver, "read_timeout") : -1;

	if (i < 0 || c->probe_driver->options[i].type != ASPH_OPTION_INT)
		return DEFAULT_READ_TIMEOUT_MS;
	int64_t ms = asph_options_values(c->probe_options)[i].i;
	return ms > 0 && ms <= UINT_MAX ? (unsigned)ms : DEFAULT_READ_TIMEOUT_MS;
}

int asph_scan_new(struct asph_instrument *inst, const struct asph_surface *s,
		  const double *xyz, size_t n, const struct asph_scan_options *opts,
		  struct asph_scan **out, struct asph_error *err)
{
	struct asph_scan *sc = calloc(1, sizeof(*sc));

	if (!sc)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (opts)
		sc->o = *opts;
	if (sc->o.clearance == 0)
		sc->o.clearance = 0.5;
	if (!sc->o.move_timeout_ms)
		sc->o.move_timeout_ms = 60000;
	if (!sc->o.read_timeout_ms)
		sc->o.read_timeout_ms = probe_read_timeout(inst);
	if (!sc->o.home_timeout_ms)
		sc->o.home_timeout_ms = 120000;
	if (!sc->o.stream_batch || sc->o.stream_batch > RECORD_BATCH)
		sc->o.stream_batch = RECORD_BATCH;
	if (!sc->o.progress_interval_ns)
		sc->o.progress_interval_ns = 100000000u;
	if (!(sc->o.clearance > 0) || !isfinite(sc->o.clearance) ||
	    sc->o.start_index > n) {
		int r = asph_error_set(err, -EINVAL,
				       "scan options not valid (clearance %g mm, start %llu of %zu points)",
				       sc->o.clearance, (unsigned long long)sc->o.start_index, n);
		free(sc);
		return r;
	}
	sc->inst = inst;
	sc->surface = s;
	sc->xyz = xyz;
	sc->n = n;
	sc->acq = inst->config->acquisition;
	asph_acquisition_advised(&sc->acq, &inst->stage_info);
	/* the default reference, the vertex, on a part that does not hold it
	 * (an off-axis segment): the centre of its aperture instead */
	if (sc->acq.n_references == 1 && sc->acq.references[0][0] == 0 &&
	    sc->acq.references[0][1] == 0 && !asph_surface_contains(s, 0, 0, 0)) {
		double r;
		asph_surface_aperture_disk(s, sc->acq.references[0], &r);
	}
	sc->tactile = inst->probe_info.type == ASPH_PROBE_TACTILE;
	sc->tip = sc->tactile ? inst->probe_info.tip_radius : 0;
	sc->latency = inst->probe_info.latency > 0 ? inst->probe_info.latency : 0;
	sc->streamed = (sc->o.flags & ASPH_SCAN_STREAM) && !sc->tactile &&
		       inst->probe_info.can_stream && inst->probe_driver->probe->stream &&
		       (inst->stage_driver->stage->sweep || inst->stage_ops.sweep_pvt);
	sc->pvt = sc->streamed && inst->stage_ops.sweep_pvt;
	scan_motion_limits(&inst->stage_info, &inst->probe_info, &sc->lim);
	scan_geometry_init(sc);
	scan_run_init(sc);
	*out = sc;
	return 0;
}

void asph_scan_free(struct asph_scan *sc)
{
	if (!sc)
		return;
	scan_stream_fini(sc);
	scan_run_fini(sc);
	free(sc);
}

int asph_scan_check(struct asph_scan *sc, struct asph_error *err)
{
	/* a scan going on with the interrupted one's motion checks what that
	 * one did: the same travel height */
	return scan_check(sc, sc->resume.replay_below ? 0 : sc->o.start_index, err);
}

/* ------------------------------------------------------ the loop */

static int measure_point(struct asph_scan *sc, size_t i, bool *recorded, struct asph_error *err)
{
	struct target t;
	struct pending m = { .index = i, .kind = ASPH_MEASURE_PLAN };

	scan_target(sc, i, false, &t);
	return scan_measure_at(sc, &t, &m, 0, NULL, recorded, err);
}

/* The dropouts measured again, point by point, each up to the retries; a
 * point still invalid then stays so. */
static int second_pass(struct asph_scan *sc, struct asph_error *err)
{
	const struct scan_dropouts *d = &sc->run.dropouts;
	int r = 0;

	for (size_t k = 0; k < d->n && r == 0; k++) {
		uint64_t i = d->index[k];
		for (uint32_t a = d->attempt[k] + 1; a <= sc->acq.retries && r == 0; a++) {
			struct target t;
			struct pending m = { .index = i, .kind = ASPH_MEASURE_PLAN, .attempt = a };
			bool recorded;
			r = scan_aborted(sc, err);
			if (r == 0 && scan_round_due(sc))
				r = scan_reference_round(sc, err);
			if (r < 0)
				break;
			scan_target(sc, (size_t)i, false, &t);
			r = scan_measure_at(sc, &t, &m, ASPH_SCANFILE_POINT_RETRIED, NULL, &recorded,
					    err);
			if (r == 0 && !(sc->run.last_flags & ASPH_SCANFILE_POINT_INVALID))
				break;
		}
	}
	scan_dropouts_clear(sc);
	return r;
}

static int scan_loop(struct asph_scan *sc, struct asph_error *err)
{
	size_t i = sc->resume.loop_from;
	int r = 0;

	scan_measure_begin(sc, i);
	while (r == 0 && i < sc->n) {
		r = scan_wait_paused(sc, i, err);
		if (r == 0)
			r = scan_aborted(sc, err);
		if (r == 0 && scan_round_due(sc))
			r = scan_reference_round(sc, err);
		if (r < 0)
			break;
		if (sc->streamed) {
			size_t done = 0;
			r = scan_stream(sc, i, &done, err);
			i += done;
		} else {
			bool recorded = false;
			r = measure_point(sc, i, &recorded, err);
			if (recorded)
				i++;
		}
		scan_publish(sc, ASPH_SCAN_MEASURING, i, false);
	}
	if (r == 0)
		r = second_pass(sc, err);
	/* the last round closes the drift model */
	if (r == 0 && asph_acquisition_drift(&sc->acq))
		r = scan_reference_round(sc, err);
	if (r == 0)
		r = scan_aborted(sc, err);
	scan_publish(sc, ASPH_SCAN_MEASURING, i, true);
	return r;
}

static void stop_all(struct asph_scan *sc)
{
	struct asph_instrument *in = sc->inst;

	in->stage_driver->stage->stop(in->stage, NULL);
	in->probe_driver->probe->stop(in->probe, NULL);
}

static int finish(struct asph_scan *sc, int r, struct asph_error *err)
{
	enum asph_scan_state state = r == 0 ? ASPH_SCAN_COMPLETED
				     : r == -ECANCELED && atomic_load(&sc->run.aborted) ? ASPH_SCAN_ABORTED
										    : ASPH_SCAN_FAILED;
	char reason[sizeof(err->message) + 64] = "";
	struct asph_error ferr;
	int fr;

	if (r < 0 && err)
		asph_error_format(err, reason, sizeof(reason));
	else if (r < 0)
		snprintf(reason, sizeof(reason), "%s", strerror(-r));
	asph_error_clear(&ferr);
	fr = scan_run_end(sc, state, r < 0 ? reason : NULL,
			  state == ASPH_SCAN_ABORTED && (sc->o.flags & ASPH_SCAN_ABORT_RESUMABLE),
			  &ferr);
	if (r == 0 && fr < 0) {
		if (err)
			*err = ferr;
		return fr;
	}
	return r;
}

int asph_scan_run(struct asph_scan *sc, struct asph_scanfile_writer *w,
		  struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	int r;

	asph_error_clear(err);
	scan_run_begin(sc, w);
	scan_publish(sc, ASPH_SCAN_CHECKING, sc->o.start_index, true);
	r = scan_stream_init(sc, err);
	if (r == 0)
		r = scan_resume_state(sc, err);
	if (r == 0) {
		/* taking up the interrupted scan's motion, its time is the
		 * instrument's as when it began */
		scan_run_resumed(sc, sc->resume.replay_below, sc->resume.replay);
		scan_drift_begin(sc);
		r = asph_scan_check(sc, err);
	}
	if (r == 0 && !(sc->o.flags & ASPH_SCAN_NO_HOME)) {
		scan_publish(sc, ASPH_SCAN_HOMING, sc->o.start_index, true);
		r = in->stage_driver->stage->home(in->stage, sc->o.home_timeout_ms, err);
		r = scan_prefixed(r, "stage", sc->o.start_index, err);
	}
	if (r == 0)
		r = scan_read_position(sc, sc->o.start_index, err);
	if (r == 0)
		r = scan_aborted(sc, err);
	if (r == 0)
		r = scan_loop(sc, err);
	if (r < 0)
		stop_all(sc);
	return finish(sc, r, err);
}
