/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The primitives of a run, below the loops (executor.c, stream.c,
 * drift.c): progress and the other threads' controls, the stage's moves
 * and settling, one measurement point by point, every point recorded with
 * the position the stage measured, the scan file, the dropouts. run.h.
 */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "scan.h"
#include "util-time.h"

/* ------------------------------------------------------------ the run */

void scan_run_init(struct asph_scan *sc)
{
	atomic_init(&sc->run.paused, false);
	atomic_init(&sc->run.aborted, false);
	pthread_mutex_init(&sc->run.lock, NULL);
	pthread_cond_init(&sc->run.wake, NULL);
	sc->run.progress.total = sc->n;
	sc->run.progress.done = sc->o.start_index;
	sc->run.progress.eta_s = -1;
}

void scan_run_fini(struct asph_scan *sc)
{
	free(sc->run.dropouts.index);
	free(sc->run.dropouts.attempt);
	pthread_mutex_destroy(&sc->run.lock);
	pthread_cond_destroy(&sc->run.wake);
}

void scan_run_begin(struct asph_scan *sc, struct asph_scanfile_writer *w)
{
	sc->run.w = w;
	sc->run.n_rec = 0;
	sc->run.t0_ns = now_monotonic_ns();
	sc->run.clock0 = asph_instrument_clock(sc->inst);
	/* a new scan's times are the instrument's from here, so that a
	 * simulated one is the same to the bit each time; a resumed one's go
	 * on from the time the file has lived */
	sc->run.scan0 = sc->o.start_index == 0 && !sc->o.recovered
				? 0 : asph_scanfile_writer_elapsed_ns(w);
	sc->run.last_report_ns = 0;
	sc->run.record_from = 0;
}

void scan_run_resumed(struct asph_scan *sc, uint64_t record_from, bool instrument_time)
{
	sc->run.record_from = record_from;
	if (instrument_time)
		sc->run.scan0 = 0;
}

void scan_measure_begin(struct asph_scan *sc, size_t i)
{
	sc->run.measure_t0_ns = now_monotonic_ns();
	sc->run.measure_done0 = i;
}

/* --------------------------------------------------------- progress */

void scan_publish(struct asph_scan *sc, enum asph_scan_state state, uint64_t done, bool force)
{
	uint64_t t = now_monotonic_ns();

	if (!force && t - sc->run.last_report_ns < sc->o.progress_interval_ns)
		return;
	struct asph_scan_progress p = {
		.state = state, .done = done, .total = sc->n, .measured = sc->run.measured,
		.elapsed_s = (double)(t - sc->run.t0_ns) * 1e-9, .eta_s = -1,
	};
	uint64_t it = asph_instrument_clock(sc->inst);
	p.instrument_s = it > sc->run.clock0 ? (double)(it - sc->run.clock0) * 1e-9 : 0;
	/* the rate over the last interval long enough to say */
	double dt = (double)(t - sc->run.rate_t_ns) * 1e-9;
	p.rate = sc->run.rate;
	if (sc->run.rate_t_ns && dt > 0.05)
		p.rate = sc->run.rate = (double)(done - sc->run.rate_done) / dt;
	if (!sc->run.rate_t_ns || dt > 0.05) {
		sc->run.rate_t_ns = t;
		sc->run.rate_done = done;
	}
	double mt = (double)(t - sc->run.measure_t0_ns) * 1e-9;
	if (sc->run.measure_t0_ns && mt > 0 && done > sc->run.measure_done0)
		p.eta_s = (double)(sc->n - done) * mt / (double)(done - sc->run.measure_done0);
	sc->run.last_report_ns = t;
	pthread_mutex_lock(&sc->run.lock);
	sc->run.progress = p;
	pthread_mutex_unlock(&sc->run.lock);
	if (sc->o.progress)
		sc->o.progress(&p, sc->o.progress_data);
}

void asph_scan_get_progress(struct asph_scan *sc, struct asph_scan_progress *out)
{
	pthread_mutex_lock(&sc->run.lock);
	*out = sc->run.progress;
	pthread_mutex_unlock(&sc->run.lock);
}

void asph_scan_pause(struct asph_scan *sc)
{
	atomic_store(&sc->run.paused, true);
}

void asph_scan_resume(struct asph_scan *sc)
{
	pthread_mutex_lock(&sc->run.lock);
	atomic_store(&sc->run.paused, false);
	pthread_cond_broadcast(&sc->run.wake);
	pthread_mutex_unlock(&sc->run.lock);
}

void asph_scan_abort(struct asph_scan *sc)
{
	struct asph_instrument *in = sc->inst;

	pthread_mutex_lock(&sc->run.lock);
	atomic_store(&sc->run.aborted, true);
	pthread_cond_broadcast(&sc->run.wake);
	pthread_mutex_unlock(&sc->run.lock);
	/* the drivers' stop() is safe from any thread by contract */
	in->stage_driver->stage->stop(in->stage, NULL);
	in->probe_driver->probe->stop(in->probe, NULL);
}

int scan_aborted(struct asph_scan *sc, struct asph_error *err)
{
	if (!atomic_load_explicit(&sc->run.aborted, memory_order_relaxed))
		return 0;
	return asph_error_set(err, -ECANCELED, "aborted");
}

bool scan_stop_asked(struct asph_scan *sc)
{
	return atomic_load_explicit(&sc->run.paused, memory_order_relaxed) ||
	       atomic_load_explicit(&sc->run.aborted, memory_order_relaxed);
}

int scan_wait_paused(struct asph_scan *sc, uint64_t done, struct asph_error *err)
{
	if (!atomic_load_explicit(&sc->run.paused, memory_order_relaxed))
		return 0;
	int r = scan_flush(sc, err);
	if (r == 0)
		r = asph_scanfile_writer_flush(sc->run.w, err);
	scan_publish(sc, ASPH_SCAN_PAUSED, done, true);
	pthread_mutex_lock(&sc->run.lock);
	while (r == 0 && atomic_load(&sc->run.paused) && !atomic_load(&sc->run.aborted)) {
		/* the condition variable's clock is CLOCK_REALTIME */
		struct timespec ts = timespec_from_ns(now_realtime_ns() + 200 * NS_PER_MS);
		pthread_cond_timedwait(&sc->run.wake, &sc->run.lock, &ts);
		pthread_mutex_unlock(&sc->run.lock);
		r = asph_scanfile_writer_tick(sc->run.w, err);
		pthread_mutex_lock(&sc->run.lock);
	}
	pthread_mutex_unlock(&sc->run.lock);
	sc->run.last_report_ns = 0;
	scan_publish(sc, ASPH_SCAN_MEASURING, done, true);
	return r;
}

/* ----------------------------------------------------------- motion */

int scan_prefixed(int r, const char *who, size_t i, struct asph_error *err)
{
	if (r >= 0 || !err)
		return r;
	char msg[sizeof(err->message)];
	snprintf(msg, sizeof(msg), "%s", err->message);
	return asph_error_set(err, r, "plan point %zu: %s: %s", i, who, msg);
}

/* Seconds the stage needs from a to b: its motion profile at its limits. */
static double motion_s(const struct asph_scan *sc, const double *a, const double *b)
{
	struct asph_motion_move mv;

	if (!(sc->lim.speed[0] > 0))
		return 0;
	asph_motion_move_plan(a, b, &sc->lim, &mv);
	return mv.profile.duration;
}

unsigned scan_timeout(unsigned base_ms, double expected_s)
{
	double ms = base_ms + 2000.0 * expected_s;
	return ms >= (double)UINT_MAX ? UINT_MAX : (unsigned)ms;
}

int scan_read_position(struct asph_scan *sc, size_t i, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;

	return scan_prefixed(in->stage_driver->stage->position(in->stage, sc->run.pos,
							       sc->o.move_timeout_ms, err),
			     "stage", i, err);
}

void scan_moved_to(struct asph_scan *sc, const double m[3])
{
	memcpy(sc->run.pos, m, sizeof(sc->run.pos));
}

int scan_stage_move(struct asph_scan *sc, const double *m, size_t i, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	unsigned timeout = scan_timeout(sc->o.move_timeout_ms, motion_s(sc, sc->run.pos, m));
	int r = in->stage_driver->stage->move_to(in->stage, m, timeout, err);

	if (r == 0)
		memcpy(sc->run.pos, m, sizeof(sc->run.pos));
	return scan_prefixed(r, "stage", i, err);
}

int scan_move_clear(struct asph_scan *sc, const double *m, double min_gap, size_t i,
		    struct asph_error *err)
{
	double way[3][3];
	size_t n = scan_clear_path(sc, sc->run.pos, m, min_gap, way);
	int r = 0;

	for (size_t k = 0; k < n && r == 0; k++)
		r = scan_stage_move(sc, way[k], i, err);
	return r;
}

/* How far a read-back position is from the target, in mm. */
static double off_target(const struct asph_scan *sc, const double a[3], const double b[3])
{
	double ca[3], cb[3];

	scan_to_cartesian(sc, a, ca);
	scan_to_cartesian(sc, b, cb);
	return sqrt((ca[0] - cb[0]) * (ca[0] - cb[0]) + (ca[1] - cb[1]) * (ca[1] - cb[1]) +
		    (ca[2] - cb[2]) * (ca[2] - cb[2]));
}

int scan_settle(struct asph_scan *sc, const double target[3], size_t i, double out[3],
		struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	uint64_t deadline = now_monotonic_ns() + (uint64_t)sc->o.move_timeout_ms * NS_PER_MS;
	uint64_t inside_since = 0;
	bool inside = false;

	for (;;) {
		int r = scan_prefixed(in->stage_driver->stage->position(in->stage, out,
									sc->o.move_timeout_ms, err),
				      "stage", i, err);
		if (r < 0)
			return r;
		double off = off_target(sc, out, target);
		if (!(sc->acq.settle_window > 0))
			return 0;
		uint64_t t = asph_instrument_clock(in);
		if (off <= sc->acq.settle_window) {
			if (!inside)
				inside_since = t;
			inside = true;
			if ((double)(t - inside_since) * 1e-9 >= sc->acq.settle_dwell)
				return 0;
		} else {
			inside = false;
		}
		if (now_monotonic_ns() > deadline)
			return asph_error_set(err, -ETIMEDOUT,
					      "plan point %zu: stage: not settled within %.3g um of its target for %.3g s in %u ms (%.3g um off at the last reading)",
					      i, sc->acq.settle_window * 1e3, sc->acq.settle_dwell,
					      sc->o.move_timeout_ms, off * 1e3);
		if ((r = scan_aborted(sc, err)) < 0)
			return r;
	}
}

/* ---------------------------------------------------------- records */

int scan_flush(struct asph_scan *sc, struct asph_error *err)
{
	int r = 0;

	if (sc->run.n_rec)
		r = asph_scanfile_writer_append(sc->run.w, sc->run.rec, sc->run.n_rec, err);
	sc->run.n_rec = 0;
	return r;
}

uint64_t scan_time(const struct asph_scan *sc, uint64_t instrument_ns)
{
	return instrument_ns > sc->run.clock0 ? sc->run.scan0 + (instrument_ns - sc->run.clock0) : sc->run.scan0;
}

/* The instant the probe sampled, on the instrument's clock. */
static uint64_t sample_instant(const struct asph_scan *sc, const struct asph_reading *rd)
{
	if (rd->t_ns && sc->inst->shared_timebase)
		return rd->t_ns + (uint64_t)llround(sc->latency * 1e9);
	return asph_instrument_clock(sc->inst);
}

/*
 * The point of a reading: the stage's position (cartesian) plus the
 * reading along +z, then a tactile probe's tip radius back along the
 * normal; or the point a recording gives whole.
 */
static int fill_point(struct asph_scan *sc, struct asph_scanfile_point *pt,
		      const struct pending *m, const struct placed *pl, const double normal[3],
		      const struct asph_reading *rd, struct asph_error *err)
{
	double cart[3];

	pt->plan_index = m->index;
	pt->raw = rd->raw;
	pt->t_ns = scan_time(sc, sample_instant(sc, rd));
	if (rd->flags & ASPH_READING_ABSOLUTE) {
		/* a point given whole, with its own account of the position */
		pt->position_source = rd->position_source;
		if (rd->position_source != ASPH_POSITION_NONE)
			memcpy(pt->stage, rd->position, sizeof(pt->stage));
		else
			pt->stage[0] = pt->stage[1] = pt->stage[2] = NAN;
	} else {
		pt->position_source = pl->source;
		memcpy(pt->stage, pl->machine, sizeof(pt->stage));
	}
	if (rd->flags & ASPH_READING_LOW_SIGNAL)
		pt->flags |= ASPH_SCANFILE_POINT_LOW_SIGNAL;
	if (rd->flags & ASPH_READING_OUT_OF_RANGE) {
		pt->flags |= ASPH_SCANFILE_POINT_OUT_OF_RANGE;
		pt->x = pt->y = pt->z = NAN;
		return 0;
	}
	if (rd->flags & ASPH_READING_INVALID) {
		pt->flags |= ASPH_SCANFILE_POINT_INVALID;
		pt->x = pt->y = pt->z = NAN;
		return 0;
	}
	if (rd->flags & ASPH_READING_ABSOLUTE) {
		pt->x = rd->xyz[0];
		pt->y = rd->xyz[1];
		pt->z = rd->xyz[2];
		if (rd->flags & ASPH_READING_TIP_COMPENSATED)
			pt->flags |= ASPH_SCANFILE_POINT_TIP_COMPENSATED;
		if (rd->flags & ASPH_READING_COMMANDED)
			pt->flags |= ASPH_SCANFILE_POINT_COMMANDED;
		return 0;
	}
	scan_to_cartesian(sc, pl->machine, cart);
	pt->x = cart[0];
	pt->y = cart[1];
	pt->z = cart[2] + rd->value;
	if (sc->tip > 0 && normal) {
		pt->x += sc->tip * normal[0];
		pt->y += sc->tip * normal[1];
		pt->z += sc->tip * normal[2];
		pt->flags |= ASPH_SCANFILE_POINT_TIP_COMPENSATED;
	}
	if (!isfinite(pt->x) || !isfinite(pt->y) || !isfinite(pt->z))
		return asph_error_set(err, -EPROTO, "plan point %llu: the probe's reading is not a number",
				      (unsigned long long)m->index);
	return 0;
}

/* Notes a plan point's reading as invalid or valid again. */
static int note_reading(struct asph_scan *sc, uint64_t index, uint32_t attempt, bool invalid)
{
	/* the second pass keeps its own account */
	if (attempt > 0 || !invalid)
		return 0;
	return scan_dropout_add(sc, index, attempt);
}

int scan_record(struct asph_scan *sc, const struct pending *m, const struct placed *pl,
		const double normal[3], const struct asph_reading *rd, uint32_t extra_flags,
		struct asph_scanfile_point *keep, struct asph_error *err)
{
	struct asph_scanfile_point pt = { .flags = extra_flags };

	if (pl->source == ASPH_POSITION_COMMANDED && !(rd->flags & ASPH_READING_ABSOLUTE))
		pt.flags |= ASPH_SCANFILE_POINT_COMMANDED;
	int r = fill_point(sc, &pt, m, pl, normal, rd, err);
	if (r < 0)
		return r;
	sc->run.last_flags = pt.flags;
	if (keep) {
		*keep = pt;
		return 0;
	}
	if (m->attempt == 0 && m->index < sc->run.record_from) {
		/* in the file already: measured again for the motion's sake */
		sc->run.readings++;
		return 0;
	}
	sc->run.rec[sc->run.n_rec++] = pt;
	sc->run.measured++;
	sc->run.readings++;
	r = note_reading(sc, m->index, m->attempt, pt.flags & ASPH_SCANFILE_POINT_INVALID);
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	return sc->run.n_rec == RECORD_BATCH ? scan_flush(sc, err) : 0;
}

int scan_check_reading(struct asph_scan *sc, size_t i, const struct asph_reading *rd,
		       struct asph_error *err)
{
	if (!(rd->flags & ASPH_READING_OUT_OF_RANGE) || (sc->o.flags & ASPH_SCAN_SKIP_OUT_OF_RANGE))
		return 0;
	return asph_error_set(err, -ERANGE,
			      "plan point %zu: probe reading out of range (the surface is not where the plan expects it); the scan stopped before the next move",
			      i);
}

int scan_append_references(struct asph_scan *sc, const struct asph_scanfile_point *refs,
			   size_t n, struct asph_error *err)
{
	return asph_scanfile_writer_append_references(sc->run.w, refs, n, err);
}

/* ------------------------------------------------ step and measure */

int scan_measure_at(struct asph_scan *sc, const struct target *t, const struct pending *m,
		    uint32_t extra_flags, struct asph_scanfile_point *keep, bool *recorded,
		    struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	size_t i = (size_t)m->index;
	struct asph_probe_context ctx = { .plan_index = m->index, .kind = m->kind,
					  .attempt = m->attempt };
	struct asph_reading rd;
	struct placed pl = { .source = ASPH_POSITION_READ_BACK };

	*recorded = false;
	int r = scan_move_clear(sc, t->approach, sc->o.clearance / 2, i, err);
	if (r == 0)
		r = scan_stage_move(sc, t->machine, i, err);
	if (r == 0)
		r = scan_settle(sc, t->machine, i, pl.machine, err);
	if (r < 0)
		return r;
	if (sc->o.flags & ASPH_SCAN_COMMANDED) {
		memcpy(pl.machine, t->machine, sizeof(pl.machine));
		pl.source = ASPH_POSITION_COMMANDED;
	}
	memcpy(ctx.machine, pl.machine, sizeof(ctx.machine));
	scan_to_cartesian(sc, ctx.machine, ctx.xyz);
	double rate = in->probe_info.rate;
	r = scan_prefixed(asph_instrument_read(in, &ctx, &rd,
					       scan_timeout(sc->o.read_timeout_ms,
							    (rate > 0 ? 1 / rate : 0) + sc->latency),
					       err),
			  "probe", i, err);
	if (r == 0 && rd.position_source != ASPH_POSITION_NONE &&
	    !(sc->o.flags & ASPH_SCAN_COMMANDED)) {
		/* the probe knows where it was */
		memcpy(pl.machine, rd.position, sizeof(pl.machine));
		pl.source = rd.position_source;
	}
	if (r == 0)
		r = scan_record(sc, m, &pl, t->normal, &rd, extra_flags, keep, err);
	if (r == 0 && m->kind == ASPH_MEASURE_PLAN)
		r = scan_flush(sc, err);
	*recorded = r == 0;
	if (r == 0)
		r = scan_check_reading(sc, i, &rd, err);
	if (r == 0)
		r = scan_stage_move(sc, t->approach, i, err);
	return r;
}

/* --------------------------------------------------------- dropouts */

int scan_dropout_add(struct asph_scan *sc, uint64_t index, uint32_t attempt)
{
	struct scan_dropouts *d = &sc->run.dropouts;

	if (d->n == d->cap) {
		size_t cap = d->cap ? 2 * d->cap : 64;
		uint64_t *a = realloc(d->index, cap * sizeof(*a));
		if (!a)
			return -ENOMEM;
		d->index = a;
		uint32_t *b = realloc(d->attempt, cap * sizeof(*b));
		if (!b)
			return -ENOMEM;
		d->attempt = b;
		d->cap = cap;
	}
	d->index[d->n] = index;
	d->attempt[d->n++] = attempt;
	return 0;
}

void scan_dropouts_clear(struct asph_scan *sc)
{
	sc->run.dropouts.n = 0;
}

/* ---------------------------------------------------------- the end */

int scan_run_end(struct asph_scan *sc, enum asph_scan_state state, const char *reason,
		 bool resumable, struct asph_error *err)
{
	int rf = scan_flush(sc, err), fr;

	if (resumable)
		fr = asph_scanfile_writer_close(sc->run.w, err);
	else
		fr = asph_scanfile_writer_finish(sc->run.w,
						 state == ASPH_SCAN_COMPLETED ? ASPH_SCANFILE_COMPLETED
						 : state == ASPH_SCAN_ABORTED ? ASPH_SCANFILE_ABORTED
									      : ASPH_SCANFILE_FAILED,
						 reason, err);
	sc->run.w = NULL;
	pthread_mutex_lock(&sc->run.lock);
	sc->run.progress.state = state;
	pthread_mutex_unlock(&sc->run.lock);
	scan_publish(sc, state, sc->run.progress.done, true);
	return rf < 0 ? rf : fr;
}
