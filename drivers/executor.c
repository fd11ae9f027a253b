/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The scan executor: a plan measured point by point (or swept and
 * streamed), every point recorded, faults ending the file with a reason. */
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
#include "options-internal.h"
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
	int i = c ? option_index(c->probe_driver, "read_timeout") : -1;

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
	sc->tactile = inst->probe_info.type == ASPH_PROBE_TACTILE;
	sc->tip = sc->tactile ? inst->probe_info.tip_radius : 0;
	sc->stream = (sc->o.flags & ASPH_SCAN_STREAM) && !sc->tactile &&
		     inst->probe_info.can_stream && inst->probe_driver->probe->stream &&
		     inst->stage_driver->stage->sweep;
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
	pthread_mutex_destroy(&sc->lock);
	pthread_cond_destroy(&sc->wake);
	free(sc);
}

/* --------------------------------------------------------- progress */

static void publish(struct asph_scan *sc, enum asph_scan_state state, uint64_t done,
		    uint64_t measured, bool force)
{
	uint64_t t = now_monotonic_ns();

	if (!force && t - sc->last_report_ns < sc->o.progress_interval_ns)
		return;
	struct asph_scan_progress p = {
		.state = state, .done = done, .total = sc->n, .measured = measured,
		.elapsed_s = (double)(t - sc->t0_ns) * 1e-9, .eta_s = -1,
	};
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

static int flush_records(struct asph_scan *sc, struct asph_error *err)
{
	int r = 0;

	if (sc->n_rec)
		r = asph_scanfile_writer_append(sc->w, sc->rec, sc->n_rec, err);
	sc->n_rec = 0;
	return r;
}

/* The scan's clock now, and CLOCK_MONOTONIC now: a reading's timestamp
 * becomes the scan time it was taken at. */
struct stamp {
	uint64_t scan_ns, mono_ns;
};

static struct stamp stamp_now(const struct asph_scan *sc)
{
	return (struct stamp){ asph_scanfile_writer_elapsed_ns(sc->w), now_monotonic_ns() };
}

static uint64_t reading_time(const struct stamp *st, uint64_t t_ns)
{
	if (t_ns && t_ns <= st->mono_ns && st->mono_ns - t_ns <= st->scan_ns)
		return st->scan_ns - (st->mono_ns - t_ns);
	return st->scan_ns;
}

/* The measured point of a reading: the stage's cartesian position plus
 * the reading along +z, then the tip radius back along the normal. A
 * sweep has no normals (NULL): streaming is for optical probes only
 * (asph_scan_alloc), which have no tip. */
static int record(struct asph_scan *sc, size_t i, const double cart[3],
		  const double normal[3], const struct asph_reading *rd,
		  const struct stamp *st, struct asph_error *err)
{
	struct asph_scanfile_point *pt = &sc->rec[sc->n_rec++];

	pt->plan_index = i;
	pt->raw = rd->raw;
	pt->t_ns = reading_time(st, rd->t_ns);
	pt->flags = 0;
	if (rd->flags & ASPH_READING_LOW_SIGNAL)
		pt->flags |= ASPH_SCANFILE_POINT_LOW_SIGNAL;
	if (rd->flags & ASPH_READING_OUT_OF_RANGE) {
		pt->flags |= ASPH_SCANFILE_POINT_OUT_OF_RANGE;
		pt->x = pt->y = pt->z = NAN;
		return 0;
	}
	if (rd->flags & ASPH_READING_ABSOLUTE) {
		pt->x = rd->xyz[0];
		pt->y = rd->xyz[1];
		pt->z = rd->xyz[2];
		if (rd->flags & ASPH_READING_TIP_COMPENSATED)
			pt->flags |= ASPH_SCANFILE_POINT_TIP_COMPENSATED;
		return 0;
	}
	pt->x = cart[0];
	pt->y = cart[1];
	pt->z = cart[2] + rd->value;
	if (sc->tip > 0 && normal) {
		pt->x += sc->tip * normal[0];
		pt->y += sc->tip * normal[1];
		pt->z += sc->tip * normal[2];
		pt->flags |= ASPH_SCANFILE_POINT_TIP_COMPENSATED;
	}
	if (!isfinite(pt->x) || !isfinite(pt->y) || !isfinite(pt->z)) {
		sc->n_rec--;
		return asph_error_set(err, -EPROTO, "plan point %zu: the probe's reading is not a number", i);
	}
	return 0;
}

/* An out-of-range reading fails the scan unless told to go on. */
static int check_reading(struct asph_scan *sc, size_t i, const struct asph_reading *rd,
			 struct asph_error *err)
{
	if (!(rd->flags & ASPH_READING_OUT_OF_RANGE) || (sc->o.flags & ASPH_SCAN_SKIP_OUT_OF_RANGE))
		return 0;
	return asph_error_set(err, -ERANGE,
			      "plan point %zu: probe reading out of range (the surface is not where the plan expects it); the scan stopped before the next move",
			      i);
}

/* ----------------------------------------------------------- motion */

static int prefixed(int r, const char *who, size_t i, struct asph_error *err)
{
	if (r >= 0 || !err)
		return r;
	char msg[sizeof(err->message)];
	snprintf(msg, sizeof(msg), "%s", err->message);
	return asph_error_set(err, r, "plan point %zu: %s: %s", i, who, msg);
}

/* Seconds the stage needs from a to b at its axes' speeds (0: unknown). */
static double motion_s(const struct asph_scan *sc, const double *a, const double *b)
{
	double t = 0;

	for (unsigned k = 0; k < 3; k++) {
		double v = sc->inst->stage_info.axes[k].max_speed;
		if (v > 0)
			t = fmax(t, fabs(b[k] - a[k]) / v);
	}
	return t;
}

/* The base timeout plus twice what the operation should take. */
static unsigned scaled_timeout(unsigned base_ms, double expected_s)
{
	double ms = base_ms + 2000.0 * expected_s;
	return ms >= (double)UINT_MAX ? UINT_MAX : (unsigned)ms;
}

static int stage_move(struct asph_scan *sc, const double *m, size_t i, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	unsigned timeout = scaled_timeout(sc->o.move_timeout_ms, motion_s(sc, sc->pos, m));
	int r = in->stage_driver->stage->move_to(in->stage, m, timeout, err);

	if (r == 0)
		memcpy(sc->pos, m, sizeof(sc->pos));
	return prefixed(r, "stage", i, err);
}

/* Moves to m straight when that keeps min_gap all the way, else up to the
 * travel height, across, and down. Moving up (-z) is always away from the
 * part. */
static int move_clear(struct asph_scan *sc, const double *m, double min_gap, size_t i,
		      struct asph_error *err)
{
	if (scan_path_clear(sc, sc->pos, m, min_gap))
		return stage_move(sc, m, i, err);
	double up[3] = { sc->pos[0], sc->pos[1], fmin(sc->z_safe, sc->pos[2]) };
	double over[3] = { m[0], m[1], up[2] };
	int r = stage_move(sc, up, i, err);
	if (r == 0)
		r = stage_move(sc, over, i, err);
	if (r == 0)
		r = stage_move(sc, m, i, err);
	return r;
}

/* Waits while paused, keeping the file's flush policy. */
static int wait_paused(struct asph_scan *sc, uint64_t done, uint64_t measured,
		       struct asph_error *err)
{
	if (!atomic_load_explicit(&sc->paused, memory_order_relaxed))
		return 0;
	int r = flush_records(sc, err);
	if (r == 0)
		r = asph_scanfile_writer_flush(sc->w, err);
	publish(sc, ASPH_SCAN_PAUSED, done, measured, true);
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
	publish(sc, ASPH_SCAN_MEASURING, done, measured, true);
	return r;
}

static int aborted(struct asph_scan *sc, struct asph_error *err)
{
	if (!atomic_load_explicit(&sc->aborted, memory_order_relaxed))
		return 0;
	return asph_error_set(err, -ECANCELED, "aborted");
}

/* *recorded: the point is in the file, even when the move away after it
 * failed. */
static int measure_point(struct asph_scan *sc, size_t i, bool *recorded, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	struct asph_probe_context ctx = { .plan_index = i };
	struct asph_reading rd;
	struct target t;
	double cart[3];

	scan_target(sc, i, false, &t);
	int r = move_clear(sc, t.approach, sc->o.clearance / 2, i, err);
	if (r == 0)
		r = stage_move(sc, t.machine, i, err);
	if (r == 0)
		r = prefixed(in->stage_driver->stage->position(in->stage, ctx.machine,
							       sc->o.move_timeout_ms, err),
			     "stage", i, err);
	if (r < 0)
		return r;
	scan_to_cartesian(sc, ctx.machine, ctx.xyz);
	memcpy(cart, ctx.xyz, sizeof(cart));
	double rate = in->probe_info.rate;
	r = prefixed(in->probe_driver->probe->read(in->probe, &ctx, &rd,
						   scaled_timeout(sc->o.read_timeout_ms,
								  rate > 0 ? 1 / rate : 0), err),
		     "probe", i, err);
	struct stamp st = stamp_now(sc);
	if (r == 0)
		r = record(sc, i, cart, t.normal, &rd, &st, err);
	if (r == 0)
		r = flush_records(sc, err);
	*recorded = r == 0;
	if (r == 0)
		r = check_reading(sc, i, &rd, err);
	if (r == 0)
		r = stage_move(sc, t.approach, i, err);
	return r;
}

/* One sweep of up to stream_batch points from i; *done gets how many were
 * measured and recorded. */
static int measure_sweep(struct asph_scan *sc, size_t i, size_t *done, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	size_t max = sc->n - i < sc->o.stream_batch ? sc->n - i : sc->o.stream_batch, n = 0, got = 0;
	double rate = in->probe_info.rate, motion = 0, reading = 0;
	const double *prev = sc->pos;
	struct target t;

	/* along a sweep the probe may come closer than on the measuring
	 * positions by half its standoff or half the clearance */
	double sweep_gap = -fmax(in->probe_info.standoff, sc->o.clearance) / 2;
	int r;

	*done = 0;
	scan_target(sc, i, false, &t);
	if (!scan_path_clear(sc, sc->pos, t.machine, sweep_gap)) {
		r = move_clear(sc, t.approach, sc->o.clearance / 2, i, err);
		if (r == 0)
			r = stage_move(sc, t.machine, i, err);
		if (r < 0)
			return r;
	}
	double g_prev = NAN;
	while (n < max && (n == 0 || fmax(motion, reading) < SWEEP_SECONDS)) {
		if (n > 0) {
			scan_target(sc, i + n, false, &t);
			/* a segment too close to the part ends the sweep; the next
			 * one starts over the part */
			double g = scan_gap(sc, t.cart);
			if (!scan_path_clear_g(sc, prev, g_prev, t.machine, g, sweep_gap))
				break;
			g_prev = g;
		}
		motion += motion_s(sc, prev, t.machine);
		reading += rate > 0 ? 1 / rate : 0;
		memcpy(sc->path + 3 * n, t.machine, sizeof(t.machine));
		memcpy(sc->ctx[n].machine, t.machine, sizeof(t.machine));
		memcpy(sc->ctx[n].xyz, t.cart, sizeof(t.cart));
		sc->ctx[n].plan_index = i + n;
		prev = sc->path + 3 * n++;
	}
	r = in->stage_driver->stage->sweep(in->stage, sc->path, n,
					       scaled_timeout(sc->o.move_timeout_ms, motion), err);
	if (r < 0)
		return prefixed(r, "stage", i, err);
	memcpy(sc->pos, sc->path + 3 * (n - 1), sizeof(sc->pos));
	r = in->probe_driver->probe->stream(in->probe, sc->ctx, n, sc->readings, &got,
					    scaled_timeout(sc->o.read_timeout_ms, reading), err);
	if (r < 0)
		r = prefixed(r, "probe", i + got, err);
	struct stamp st = stamp_now(sc);
	int rr = 0;
	for (size_t k = 0; k < got && rr == 0; k++) {
		rr = record(sc, i + k, sc->ctx[k].xyz, NULL, &sc->readings[k], &st, err);
		if (rr == 0)
			rr = check_reading(sc, i + k, &sc->readings[k], err);
		if (rr == 0 || rr == -ERANGE)
			*done = k + 1;
	}
	int fr = flush_records(sc, rr < 0 ? NULL : err);
	if (rr < 0)
		return rr;
	return r < 0 ? r : fr;
}

static int scan_loop(struct asph_scan *sc, struct asph_error *err)
{
	uint64_t measured = 0;
	size_t i = sc->o.start_index;
	int r = 0;

	sc->measure_t0_ns = now_monotonic_ns();
	sc->measure_done0 = i;
	while (r == 0 && i < sc->n) {
		r = wait_paused(sc, i, measured, err);
		if (r == 0)
			r = aborted(sc, err);
		if (r < 0)
			break;
		if (sc->stream) {
			size_t done = 0;
			r = measure_sweep(sc, i, &done, err);
			i += done;
			measured += done;
		} else {
			bool recorded = false;
			r = measure_point(sc, i, &recorded, err);
			if (recorded)
				i++, measured++;
		}
		publish(sc, ASPH_SCAN_MEASURING, i, measured, false);
	}
	if (r == 0)
		r = aborted(sc, err);
	publish(sc, ASPH_SCAN_MEASURING, i, measured, true);
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
	int rf = flush_records(sc, &ferr);
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
	publish(sc, state, sc->progress.done, sc->progress.measured, true);
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
	sc->last_report_ns = 0;
	publish(sc, ASPH_SCAN_CHECKING, sc->o.start_index, 0, true);
	r = asph_scan_check(sc, err);
	if (r == 0 && !(sc->o.flags & ASPH_SCAN_NO_HOME)) {
		publish(sc, ASPH_SCAN_HOMING, sc->o.start_index, 0, true);
		r = in->stage_driver->stage->home(in->stage, sc->o.home_timeout_ms, err);
		r = prefixed(r, "stage", sc->o.start_index, err);
	}
	if (r == 0)
		r = prefixed(in->stage_driver->stage->position(in->stage, sc->pos,
							       sc->o.move_timeout_ms, err),
			     "stage", sc->o.start_index, err);
	if (r == 0)
		r = aborted(sc, err);
	if (r == 0)
		r = scan_loop(sc, err);
	if (r < 0)
		stop_all(sc);
	return finish(sc, r, err);
}
