/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Drift control. Every drift_interval the executor measures the
 * instrument's reference points again (the vertex unless the instrument
 * names others) and records them in blocks of their own; characterization
 * fits the drift model to them (lib/drift). drift.h.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scan.h"
#include "util-time.h"

void scan_drift_begin(struct asph_scan *sc)
{
	sc->drift.round = sc->resume.rounds;
	sc->drift.run_rounds = 0;
}

bool scan_round_due(const struct asph_scan *sc)
{
	const struct asph_acquisition *a = &sc->acq;

	if (!asph_acquisition_drift(a))
		return false;
	if (sc->drift.last_round_ns == 0)
		return true;    /* the first of the run */
	if (a->drift_interval_points &&
	    sc->run.readings - sc->drift.readings_at_round >= a->drift_interval_points)
		return true;
	if (a->drift_interval_s > 0) {
		uint64_t t = asph_instrument_clock(sc->inst);
		return t - sc->drift.last_round_ns >= (uint64_t)llround(a->drift_interval_s * 1e9);
	}
	return false;
}

/* A simulated stage's clock set to the next whole millisecond of the
 * scan's time after a round of references, of the file's time when the
 * round was the file's last measured again (replay). */
static int align_clock(struct asph_scan *sc, bool replay, struct asph_error *err)
{
	const struct asph_stage_ops *ops = &sc->inst->stage_ops;

	if (!ops->clock_align)
		return 0;
	int64_t t = (int64_t)scan_time(sc, asph_instrument_clock(sc->inst));
	if (replay) {
		/* where the file's round ended: as long after its last
		 * reference as this one after the same */
		t += (int64_t)sc->resume.replay_ref_ns -
		     (int64_t)sc->drift.refs[sc->acq.n_references - 1].t_ns;
	}
	/* the next whole millisecond: a few nanoseconds of rounding in the
	 * file's times do not move it */
	int64_t ms = (int64_t)NS_PER_MS, e = (t + ms - 1) / ms * ms;
	if (e < 0)
		e = 0;
	uint64_t instr = (uint64_t)e - sc->run.scan0 + sc->run.clock0;
	return scan_prefixed(ops->clock_align(sc->inst->stage, instr, err), "stage",
			     sc->resume.loop_from, err);
}

int scan_reference_round(struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_acquisition *a = &sc->acq;
	struct scan_drift *d = &sc->drift;
	bool replay = sc->resume.replay_round && d->run_rounds == 0;
	int r = scan_flush(sc, err);

	for (size_t k = 0; k < a->n_references && r == 0; k++) {
		struct target t;
		/* the file's last round again: its number */
		struct pending m = { .index = k, .kind = ASPH_MEASURE_REFERENCE,
				     .attempt = (uint32_t)(d->round - (replay && d->round)) };
		bool recorded;
		double p[3] = { a->references[k][0], a->references[k][1], 0 };
		p[2] = asph_surface_sag_xy(sc->surface, p[0], p[1]);
		scan_target_at(sc, p, false, &t);
		r = scan_measure_at(sc, &t, &m, 0, &d->refs[k], &recorded, err);
		if (r < 0 && err) {
			char msg[sizeof(err->message)];
			snprintf(msg, sizeof(msg), "%s", err->message);
			/* a reference is no plan point: say which it is */
			const char *tail = strncmp(msg, "plan point ", 11) ? msg : strchr(msg, ':');
			asph_error_set(err, r, "drift reference %zu (%g, %g): %s", k, p[0], p[1],
				       tail && tail != msg ? tail + 2 : msg);
		}
	}
	if (r == 0 && !replay)
		r = scan_append_references(sc, d->refs, a->n_references, err);
	if (r == 0)
		r = align_clock(sc, replay, err);
	if (r < 0)
		return r;
	if (!replay)
		d->round++;
	d->run_rounds++;
	d->last_round_ns = asph_instrument_clock(sc->inst);
	d->readings_at_round = sc->run.readings;
	return 0;
}
