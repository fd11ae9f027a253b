/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The scan executor: a plan measured point by point (or swept and
 * streamed), every point recorded with the position the stage measured,
 * drift references measured as the instrument says, dropouts measured
 * again, faults ending the file with a reason. */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "executor-internal.h"
#include "util-mem.h"
#include "util-time.h"

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
	sc->stream = (sc->o.flags & ASPH_SCAN_STREAM) && !sc->tactile &&
		     inst->probe_info.can_stream && inst->probe_driver->probe->stream &&
		     (inst->stage_driver->stage->sweep || inst->stage_ops.sweep_pvt);
	sc->pvt = sc->stream && inst->stage_ops.sweep_pvt;
	atomic_init(&sc->paused, false);
	atomic_init(&sc->aborted, false);
	pthread_mutex_init(&sc->lock, NULL);
	pthread_cond_init(&sc->wake, NULL);
	sc->curvature = scan_curvature_bound(s);
	sc->progress.total = n;
	sc->progress.done = sc->o.start_index;
	sc->progress.eta_s = -1;
	*out = sc;
	return 0;
}

void asph_scan_free(struct asph_scan *sc)
{
	if (!sc)
		return;
	scan_stream_fini(sc);
	free(sc->invalid);
	free(sc->invalid_attempts);
	pthread_mutex_destroy(&sc->lock);
	pthread_cond_destroy(&sc->wake);
	free(sc);
}

/* --------------------------------------------------------- progress */

void scan_publish(struct asph_scan *sc, enum asph_scan_state state, uint64_t done, bool force)
{
	uint64_t t = now_monotonic_ns();

	if (!force && t - sc->last_report_ns < sc->o.progress_interval_ns)
		return;
	struct asph_scan_progress p = {
		.state = state, .done = done, .total = sc->n, .measured = sc->measured,
		.elapsed_s = (double)(t - sc->t0_ns) * 1e-9, .eta_s = -1,
	};
	uint64_t it = asph_instrument_clock(sc->inst);
	p.instrument_s = it > sc->clock0 ? (double)(it - sc->clock0) * 1e-9 : 0;
	/* the rate over the last interval long enough to say */
	double dt = (double)(t - sc->rate_t_ns) * 1e-9;
	p.rate = sc->rate;
	if (sc->rate_t_ns && dt > 0.05)
		p.rate = sc->rate = (double)(done - sc->rate_done) / dt;
	if (!sc->rate_t_ns || dt > 0.05) {
		sc->rate_t_ns = t;
		sc->rate_done = done;
	}
	double mt = (double)(t - sc->measure_t0_ns) * 1e-9;
	if (sc->measure_t0_ns && mt > 0 && done > sc->measure_done0)
		p.eta_s = (double)(sc->n - done) * mt / (double)(done - sc->measure_done0);
	sc->last_report_ns = t;
	pthread_mutex_lock(&sc->lock);
	sc->progress = p;
	pthread_mutex_unlock(&sc->lock);
	if (sc->o.progress)
		sc->o.progress(&p, sc->o.progress_data);
}

void asph_scan_get_progress(struct asph_scan *sc, struct asph_scan_progress *out)
{
	pthread_mutex_lock(&sc->lock);
	*out = sc->progress;
	pthread_mutex_unlock(&sc->lock);
}

void asph_scan_pause(struct asph_scan *sc)
{
	atomic_store(&sc->paused, true);
}

void asph_scan_resume(struct asph_scan *sc)
{
	pthread_mutex_lock(&sc->lock);
	atomic_store(&sc->paused, false);
	pthread_cond_broadcast(&sc->wake);
	pthread_mutex_unlock(&sc->lock);
}

void asph_scan_abort(struct asph_scan *sc)
{
	struct asph_instrument *in = sc->inst;

	pthread_mutex_lock(&sc->lock);
	atomic_store(&sc->aborted, true);
	pthread_cond_broadcast(&sc->wake);
	pthread_mutex_unlock(&sc->lock);
	/* the drivers' stop() is safe from any thread by contract */
	in->stage_driver->stage->stop(in->stage, NULL);
	in->probe_driver->probe->stop(in->probe, NULL);
}

/* ---------------------------------------------------------- records */

int scan_flush(struct asph_scan *sc, struct asph_error *err)
{
	int r = 0;

	if (sc->n_rec)
		r = asph_scanfile_writer_append(sc->w, sc->rec, sc->n_rec, err);
	sc->n_rec = 0;
	return r;
}

uint64_t scan_time(const struct asph_scan *sc, uint64_t instrument_ns)
{
	return instrument_ns > sc->clock0 ? sc->scan0 + (instrument_ns - sc->clock0) : sc->scan0;
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

int scan_record(struct asph_scan *sc, const struct pending *m, const struct placed *pl,
		const double normal[3], const struct asph_reading *rd, uint32_t extra_flags,
		struct asph_error *err)
{
	struct asph_scanfile_point pt = { .flags = extra_flags };

	if (pl->source == ASPH_POSITION_COMMANDED && !(rd->flags & ASPH_READING_ABSOLUTE))
		pt.flags |= ASPH_SCANFILE_POINT_COMMANDED;
	int r = fill_point(sc, &pt, m, pl, normal, rd, err);
	if (r < 0)
		return r;
	sc->rec_last_flags = pt.flags;
	if (m->kind == ASPH_MEASURE_REFERENCE) {
		sc->refs[m->index] = pt;
		return 0;
	}
	if (m->attempt == 0 && m->index < sc->replay_below) {
		/* in the file already: measured again for the motion's sake */
		sc->points_since_round++;
		return 0;
	}
	if (pt.flags & ASPH_SCANFILE_POINT_COMMANDED)
		sc->commanded++;
	sc->rec[sc->n_rec++] = pt;
	sc->measured++;
	sc->points_since_round++;
	r = scan_note_reading(sc, m->index, m->attempt, pt.flags & ASPH_SCANFILE_POINT_INVALID);
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	return sc->n_rec == RECORD_BATCH ? scan_flush(sc, err) : 0;
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

int scan_stage_move(struct asph_scan *sc, const double *m, size_t i, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	unsigned timeout = scan_timeout(sc->o.move_timeout_ms, motion_s(sc, sc->pos, m));
	int r = in->stage_driver->stage->move_to(in->stage, m, timeout, err);

	if (r == 0)
		memcpy(sc->pos, m, sizeof(sc->pos));
	return scan_prefixed(r, "stage", i, err);
}

/* Moves to m straight when that keeps min_gap all the way, else up to the
 * travel height, across, and down. Moving up (-z) is always away from the
 * part. */
size_t scan_clear_path(const struct asph_scan *sc, const double from[3], const double *m,
		       double min_gap, double way[3][3])
{
	if (scan_path_clear(sc, from, m, min_gap)) {
		memcpy(way[0], m, sizeof(way[0]));
		return 1;
	}
	double up[3] = { from[0], from[1], fmin(sc->z_safe, from[2]) };
	memcpy(way[0], up, sizeof(way[0]));
	memcpy(way[1], (double[3]){ m[0], m[1], up[2] }, sizeof(way[1]));
	memcpy(way[2], m, sizeof(way[2]));
	return 3;
}

int scan_move_clear(struct asph_scan *sc, const double *m, double min_gap, size_t i,
		    struct asph_error *err)
{
	double way[3][3];
	size_t n = scan_clear_path(sc, sc->pos, m, min_gap, way);
	int r = 0;

	for (size_t k = 0; k < n && r == 0; k++)
		r = scan_stage_move(sc, way[k], i, err);
	return r;
}

int scan_aborted(struct asph_scan *sc, struct asph_error *err)
{
	if (!atomic_load_explicit(&sc->aborted, memory_order_relaxed))
		return 0;
	return asph_error_set(err, -ECANCELED, "aborted");
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

/* ------------------------------------------------ step and measure */

int scan_measure_at(struct asph_scan *sc, const struct target *t, const struct pending *m,
		    uint32_t extra_flags, bool *recorded, struct asph_error *err)
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
		r = scan_record(sc, m, &pl, t->normal, &rd, extra_flags, err);
	if (r == 0 && m->kind == ASPH_MEASURE_PLAN)
		r = scan_flush(sc, err);
	*recorded = r == 0;
	if (r == 0)
		r = scan_check_reading(sc, i, &rd, err);
	if (r == 0)
		r = scan_stage_move(sc, t->approach, i, err);
	return r;
}

static int measure_point(struct asph_scan *sc, size_t i, bool *recorded, struct asph_error *err)
{
	struct target t;
	struct pending m = { .index = i, .kind = ASPH_MEASURE_PLAN };

	scan_target(sc, i, false, &t);
	return scan_measure_at(sc, &t, &m, 0, recorded, err);
}

/* Waits while paused, keeping the file's flush policy. */
static int wait_paused(struct asph_scan *sc, uint64_t done, struct asph_error *err)
{
	if (!atomic_load_explicit(&sc->paused, memory_order_relaxed))
		return 0;
	int r = scan_flush(sc, err);
	if (r == 0)
		r = asph_scanfile_writer_flush(sc->w, err);
	scan_publish(sc, ASPH_SCAN_PAUSED, done, true);
	pthread_mutex_lock(&sc->lock);
	while (r == 0 && atomic_load(&sc->paused) && !atomic_load(&sc->aborted)) {
		/* the condition variable's clock is CLOCK_REALTIME */
		struct timespec ts = timespec_from_ns(now_realtime_ns() + 200 * NS_PER_MS);
		pthread_cond_timedwait(&sc->wake, &sc->lock, &ts);
		pthread_mutex_unlock(&sc->lock);
		r = asph_scanfile_writer_tick(sc->w, err);
		pthread_mutex_lock(&sc->lock);
	}
	pthread_mutex_unlock(&sc->lock);
	sc->last_report_ns = 0;
	scan_publish(sc, ASPH_SCAN_MEASURING, done, true);
	return r;
}

static int scan_loop(struct asph_scan *sc, struct asph_error *err)
{
	size_t i = sc->loop_from;
	int r = 0;

	sc->measure_t0_ns = now_monotonic_ns();
	sc->measure_done0 = i;
	while (r == 0 && i < sc->n) {
		r = wait_paused(sc, i, err);
		if (r == 0)
			r = scan_aborted(sc, err);
		if (r == 0 && scan_round_due(sc))
			r = scan_reference_round(sc, err);
		if (r < 0)
			break;
		if (sc->stream) {
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
		r = scan_second_pass(sc, err);
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
				     : r == -ECANCELED && atomic_load(&sc->aborted) ? ASPH_SCAN_ABORTED
										    : ASPH_SCAN_FAILED;
	char reason[sizeof(err->message) + 64] = "";
	struct asph_error ferr;
	int fr;

	if (r < 0 && err)
		asph_error_format(err, reason, sizeof(reason));
	else if (r < 0)
		snprintf(reason, sizeof(reason), "%s", strerror(-r));
	asph_error_clear(&ferr);
	int rf = scan_flush(sc, &ferr);
	if (state == ASPH_SCAN_ABORTED && (sc->o.flags & ASPH_SCAN_ABORT_RESUMABLE))
		fr = asph_scanfile_writer_close(sc->w, &ferr);
	else
		fr = asph_scanfile_writer_finish(sc->w,
						 state == ASPH_SCAN_COMPLETED ? ASPH_SCANFILE_COMPLETED
						 : state == ASPH_SCAN_ABORTED ? ASPH_SCANFILE_ABORTED
									      : ASPH_SCANFILE_FAILED,
						 r < 0 ? reason : NULL, &ferr);
	sc->w = NULL;
	if (rf < 0)
		fr = rf;
	pthread_mutex_lock(&sc->lock);
	sc->progress.state = state;
	pthread_mutex_unlock(&sc->lock);
	scan_publish(sc, state, sc->progress.done, true);
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
	sc->w = w;
	sc->n_rec = 0;
	sc->t0_ns = now_monotonic_ns();
	sc->clock0 = asph_instrument_clock(in);
	/* a new scan's times are the instrument's from here, so that a
	 * simulated one is the same to the bit each time; a resumed one's go
	 * on from the time the file has lived */
	sc->scan0 = sc->o.start_index == 0 && !sc->o.recovered ? 0
								: asph_scanfile_writer_elapsed_ns(w);
	sc->last_report_ns = 0;
	sc->loop_from = sc->o.start_index;
	sc->replay_below = 0;
	sc->replay_round = false;
	scan_publish(sc, ASPH_SCAN_CHECKING, sc->o.start_index, true);
	r = scan_stream_init(sc, err);
	if (r == 0)
		r = scan_resume_state(sc, err);
	if (r == 0)
		r = asph_scan_check(sc, err);
	if (r == 0 && !(sc->o.flags & ASPH_SCAN_NO_HOME)) {
		scan_publish(sc, ASPH_SCAN_HOMING, sc->o.start_index, true);
		r = in->stage_driver->stage->home(in->stage, sc->o.home_timeout_ms, err);
		r = scan_prefixed(r, "stage", sc->o.start_index, err);
	}
	if (r == 0)
		r = scan_prefixed(in->stage_driver->stage->position(in->stage, sc->pos,
								    sc->o.move_timeout_ms, err),
				  "stage", sc->o.start_index, err);
	if (r == 0)
		r = scan_aborted(sc, err);
	if (r == 0)
		r = scan_loop(sc, err);
	if (r < 0)
		stop_all(sc);
	return finish(sc, r, err);
}
