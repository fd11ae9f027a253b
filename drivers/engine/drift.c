/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Drift control and dropouts. Every drift_interval the executor measures
 * the instrument's reference points again (the vertex unless the
 * instrument names others) and records them in blocks of their own;
 * characterization fits the drift model to them (lib/drift). Readings that
 * came back invalid are measured again at the end, point by point, up to
 * the instrument's retries; a point still invalid then stays so.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "executor-internal.h"
#include "util-time.h"

bool scan_round_due(const struct asph_scan *sc)
{
	const struct asph_acquisition *a = &sc->acq;

	if (!asph_acquisition_drift(a))
		return false;
	if (sc->last_round_ns == 0)
		return true;    /* the first of the run */
	if (a->drift_interval_points && sc->points_since_round >= a->drift_interval_points)
		return true;
	if (a->drift_interval_s > 0) {
		uint64_t t = asph_instrument_clock(sc->inst);
		return t - sc->last_round_ns >= (uint64_t)llround(a->drift_interval_s * 1e9);
	}
	return false;
}

int scan_reference_round(struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_acquisition *a = &sc->acq;
	int r = scan_flush(sc, err);

	for (size_t k = 0; k < a->n_references && r == 0; k++) {
		struct target t;
		/* the file's last round again: its number */
		struct pending m = { .index = k, .kind = ASPH_MEASURE_REFERENCE,
				     .attempt = (uint32_t)(sc->round - (sc->replay_round && sc->round)) };
		bool recorded;
		double p[3] = { a->references[k][0], a->references[k][1], 0 };
		p[2] = asph_surface_sag_xy(sc->surface, p[0], p[1]);
		scan_target_at(sc, p, false, &t);
		r = scan_measure_at(sc, &t, &m, 0, &recorded, err);
		if (r < 0 && err) {
			char msg[sizeof(err->message)];
			snprintf(msg, sizeof(msg), "%s", err->message);
			/* a reference is no plan point: say which it is */
			const char *tail = strncmp(msg, "plan point ", 11) ? msg : strchr(msg, ':');
			asph_error_set(err, r, "drift reference %zu (%g, %g): %s", k, p[0], p[1],
				       tail && tail != msg ? tail + 2 : msg);
		}
	}
	if (r == 0 && !sc->replay_round)
		r = asph_scanfile_writer_append_references(sc->w, sc->refs, a->n_references, err);
	if (r == 0)
		r = scan_align_clock(sc, err);
	if (r < 0)
		return r;
	if (!sc->replay_round)
		sc->round++;
	sc->replay_round = false;
	sc->last_round_ns = asph_instrument_clock(sc->inst);
	sc->points_since_round = 0;
	return 0;
}

/* -------------------------------------------------------- dropouts */

static int add_invalid(struct asph_scan *sc, uint64_t index, uint32_t attempt)
{
	if (sc->n_invalid == sc->cap_invalid) {
		size_t cap = sc->cap_invalid ? 2 * sc->cap_invalid : 64;
		uint64_t *a = realloc(sc->invalid, cap * sizeof(*a));
		if (!a)
			return -ENOMEM;
		sc->invalid = a;
		uint32_t *b = realloc(sc->invalid_attempts, cap * sizeof(*b));
		if (!b)
			return -ENOMEM;
		sc->invalid_attempts = b;
		sc->cap_invalid = cap;
	}
	sc->invalid[sc->n_invalid] = index;
	sc->invalid_attempts[sc->n_invalid++] = attempt;
	return 0;
}

int scan_note_reading(struct asph_scan *sc, uint64_t index, uint32_t attempt, bool invalid)
{
	/* the second pass keeps its own account */
	if (attempt > 0 || !invalid)
		return 0;
	return add_invalid(sc, index, attempt);
}

int scan_second_pass(struct asph_scan *sc, struct asph_error *err)
{
	int r = 0;

	for (size_t k = 0; k < sc->n_invalid && r == 0; k++) {
		uint64_t i = sc->invalid[k];
		for (uint32_t a = sc->invalid_attempts[k] + 1; a <= sc->acq.retries && r == 0; a++) {
			struct target t;
			struct pending m = { .index = i, .kind = ASPH_MEASURE_PLAN, .attempt = a };
			bool recorded;
			r = scan_aborted(sc, err);
			if (r == 0 && scan_round_due(sc))
				r = scan_reference_round(sc, err);
			if (r < 0)
				break;
			scan_target(sc, (size_t)i, false, &t);
			r = scan_measure_at(sc, &t, &m, ASPH_SCANFILE_POINT_RETRIED, &recorded, err);
			if (r == 0 && !(sc->rec_last_flags & ASPH_SCANFILE_POINT_INVALID))
				break;
		}
	}
	sc->n_invalid = 0;
	return r;
}

/* ---------------------------------------------------------- resume */

/*
 * A simulated stage goes on with the interrupted scan's time: the
 * measuring starts again after the file's last round of references (or
 * from the first plan point without one), that round measured again to
 * put the stage where it was and then the clock set to the file's time.
 * From there the motion, the clock and so every reading are those of the
 * uninterrupted scan; the plan points the file has are measured again but
 * not recorded.
 */
static void replay_from_round(struct asph_scan *sc, const struct asph_scanfile *s, size_t per)
{
	uint64_t t_round = 0;   /* none: nothing comes before it */
	size_t from = 0;

	if (asph_acquisition_drift(&sc->acq) && s->n_references >= per) {
		t_round = s->references[s->n_references - per].t_ns;
		sc->replay_ref_ns = s->references[s->n_references - 1].t_ns;
		sc->replay_round = true;
	}
	for (size_t k = 0; k < s->n; k++) {
		const struct asph_scanfile_point *p = &s->points[k];
		if (!(p->flags & ASPH_SCANFILE_POINT_RETRIED) && p->t_ns < t_round &&
		    p->plan_index + 1 > from)
			from = (size_t)p->plan_index + 1;
	}
	sc->loop_from = from < sc->o.start_index ? from : sc->o.start_index;
	sc->replay_below = sc->o.start_index;
	/* the scan's time is the instrument's, as when it began */
	sc->scan0 = 0;
}

int scan_align_clock(struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_stage_ops *ops = &sc->inst->stage_ops;

	if (!ops->clock_align)
		return 0;
	int64_t t = (int64_t)scan_time(sc, asph_instrument_clock(sc->inst));
	if (sc->replay_round) {
		/* where the file's round ended: as long after its last
		 * reference as this one after the same */
		t += (int64_t)sc->replay_ref_ns -
		     (int64_t)sc->refs[sc->acq.n_references - 1].t_ns;
	}
	/* the next whole millisecond: a few nanoseconds of rounding in the
	 * file's times do not move it */
	int64_t ms = (int64_t)NS_PER_MS, e = (t + ms - 1) / ms * ms;
	if (e < 0)
		e = 0;
	uint64_t instr = (uint64_t)e - sc->scan0 + sc->clock0;
	return scan_prefixed(ops->clock_align(sc->inst->stage, instr, err), "stage",
			     sc->loop_from, err);
}

int scan_resume_state(struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_scanfile *s = sc->o.recovered;
	size_t per = sc->acq.n_references ? sc->acq.n_references : 1;
	bool any = false;

	if (!s)
		return 0;
	/* the reference rounds so far: the next one is numbered after them */
	sc->round = (s->n_references + per - 1) / per;
	if (sc->o.start_index > 0 && sc->inst->stage_ops.clock_align)
		replay_from_round(sc, s, per);
	for (size_t k = 0; k < s->n && !any; k++)
		any = s->points[k].flags & ASPH_SCANFILE_POINT_INVALID;
	if (!any)
		return 0;
	/* the points whose last measurement was invalid, with its attempt */
	uint16_t *count = calloc(sc->n ? sc->n : 1, sizeof(*count));
	uint8_t *last_invalid = calloc(sc->n ? sc->n : 1, 1);
	if (!count || !last_invalid) {
		free(count);
		free(last_invalid);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	for (size_t k = 0; k < s->n; k++) {
		uint64_t i = s->points[k].plan_index;
		if (i >= sc->n)
			continue;
		if (count[i] < UINT16_MAX)
			count[i]++;
		last_invalid[i] = (s->points[k].flags & ASPH_SCANFILE_POINT_INVALID) != 0;
	}
	int r = 0;
	for (size_t i = 0; i < sc->n && r == 0; i++)
		if (count[i] && last_invalid[i])
			r = add_invalid(sc, i, (uint32_t)count[i] - 1);
	free(count);
	free(last_invalid);
	return r < 0 ? asph_error_set(err, r, "out of memory") : 0;
}
