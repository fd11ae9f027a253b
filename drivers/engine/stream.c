/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Streaming: the stage sweeps through the plan points while the probe
 * reads at each. With timed (PVT) sweeps the feed-rate planner of
 * lib/motion drives the path close to the kinematic limit; otherwise the
 * stage sweeps at its own pace. Each reading is paired with the position
 * the stage measured at its trigger (latched), or with positions it
 * sampled in time (interpolated), the probe's latency compensated; with
 * nothing better, with the commanded position, flagged.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scan.h"
#include "util-mem.h"
#include "util-time.h"

/* ------------------------------------------------------------ set up */

int scan_stream_init(struct asph_scan *sc, struct asph_error *err)
{
	struct scan_stream *st = &sc->stream;

	st->run_from = st->run_to = 0;
	if (!sc->streamed)
		return 0;
	if (sc->pvt && !st->planner && asph_motion_planner_alloc(0, &st->planner) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (sc->pvt && sc->inst->stage_info.kinematics == ASPH_KINEMATICS_RTZ && !st->theta) {
		/* theta of every plan point, the short way from the one before, as
		 * the motion will take it */
		st->theta = malloc((sc->n ? sc->n : 1) * sizeof(double));
		if (!st->theta)
			return asph_error_set(err, -ENOMEM, "out of memory");
		double prev = 0;
		for (size_t i = 0; i < sc->n; i++) {
			const double *p = sc->xyz + 3 * i;
			if (hypot(p[0], p[1]) > 1e-12)
				prev += remainder(atan2(p[1], p[0]) - prev, 2 * M_PI);
			st->theta[i] = prev;
		}
	}
	return 0;
}

void scan_stream_fini(struct asph_scan *sc)
{
	struct scan_stream *st = &sc->stream;

	asph_motion_planner_free(st->planner);
	st->planner = NULL;
	free(st->theta);
	free(st->pend);
	free(st->trace);
	st->theta = NULL;
	st->pend = NULL;
	st->trace = NULL;
}

/* ------------------------------------------------------------ queues */

static struct pending *push_pending(struct asph_scan *sc)
{
	struct scan_stream *st = &sc->stream;

	if (st->pend_head + st->pend_n == st->pend_cap && st->pend_head) {
		memmove(st->pend, st->pend + st->pend_head, st->pend_n * sizeof(*st->pend));
		st->pend_head = 0;
	}
	if (array_grow((void **)&st->pend, &st->pend_cap, st->pend_head + st->pend_n + 1,
		       sizeof(*st->pend), 256) < 0)
		return NULL;
	return &st->pend[st->pend_head + st->pend_n++];
}

/* The positions the stage measured since its last report. */
static int pull_trace(struct asph_scan *sc, size_t i, struct asph_error *err)
{
	struct scan_stream *st = &sc->stream;
	const struct asph_stage_ops *ops = &sc->inst->stage_ops;

	if (!ops->sweep_trace || (sc->o.flags & ASPH_SCAN_COMMANDED))
		return 0;
	for (;;) {
		size_t got = 0;
		if (st->trace_head + st->trace_n + 256 > st->trace_cap && st->trace_head) {
			memmove(st->trace, st->trace + st->trace_head,
				st->trace_n * sizeof(*st->trace));
			st->trace_head = 0;
		}
		if (array_grow((void **)&st->trace, &st->trace_cap, st->trace_head + st->trace_n + 256,
			       sizeof(*st->trace), 256) < 0)
			return asph_error_set(err, -ENOMEM, "out of memory");
		int r = ops->sweep_trace(sc->inst->stage, st->trace + st->trace_head + st->trace_n,
					 256, &got, sc->o.read_timeout_ms, err);
		if (r < 0)
			return scan_prefixed(r, "stage", i, err);
		st->trace_n += got;
		if (got < 256)
			return 0;
	}
}

/* ----------------------------------------------------------- pairing */

/* The quadratic through up to three (t, p) samples, at t. */
static void lagrange(const struct asph_position_sample *s[], size_t n, double t, double out[3])
{
	for (int k = 0; k < 3; k++)
		out[k] = 0;
	for (size_t a = 0; a < n; a++) {
		double w = 1, ta = (double)s[a]->t_ns * 1e-9;
		for (size_t b = 0; b < n; b++)
			if (b != a)
				w *= (t - (double)s[b]->t_ns * 1e-9) /
				     (ta - (double)s[b]->t_ns * 1e-9);
		for (int k = 0; k < 3; k++)
			out[k] += w * s[a]->position[k];
	}
}

/* Where a reading latched at c was sampled: the latency later. On a timed
 * sweep, c moved on as the command did over the latency (the axes follow
 * their command with a lag that hardly changes within it; the neighbouring
 * latches, a plan spacing away, cannot tell the motion of a fraction of a
 * millisecond as well); else on the parabola of c and its neighbours (the
 * ones before when the next is not there yet). */
static void compensate(struct asph_scan *sc, const struct pending *pd,
		       const struct asph_position_sample *c,
		       const struct asph_position_sample *next, double out[3])
{
	struct scan_stream *st = &sc->stream;
	const struct asph_position_sample *s[3];
	size_t n = 0;

	if (!(sc->latency > 0)) {
		memcpy(out, c->position, 3 * sizeof(double));
		return;
	}
	if (pd->timed) {
		for (int k = 0; k < 3; k++)
			out[k] = c->position[k] + pd->dcmd[k];
		return;
	}
	if (next) {
		if (st->n_hist)
			s[n++] = &st->latch_hist[st->n_hist - 1];
		s[n++] = c;
		s[n++] = next;
	} else {
		for (size_t k = 0; k < st->n_hist; k++)
			s[n++] = &st->latch_hist[k];
		s[n++] = c;
	}
	/* relative times keep the nanoseconds */
	struct asph_position_sample rel[3];
	const struct asph_position_sample *r[3];
	for (size_t k = 0; k < n; k++) {
		rel[k] = *s[k];
		rel[k].t_ns = s[k]->t_ns - c->t_ns + (uint64_t)1e12;
		r[k] = &rel[k];
	}
	lagrange(r, n, 1e3 + sc->latency, out);
}

static void remember_latch(struct asph_scan *sc, const struct asph_position_sample *c)
{
	struct scan_stream *st = &sc->stream;

	if (st->n_hist == 2) {
		st->latch_hist[0] = st->latch_hist[1];
		st->n_hist = 1;
	}
	st->latch_hist[st->n_hist++] = *c;
}

/* Positions sampled in time around t (ns): the cubic through the four
 * nearest. false when there are none around it. */
static bool interpolate(struct asph_scan *sc, uint64_t t, double out[3])
{
	struct scan_stream *st = &sc->stream;
	const struct asph_position_sample *q = st->trace + st->trace_head;
	size_t n = st->trace_n, k = 0;

	if (n < 2 || t < q[0].t_ns || t > q[n - 1].t_ns + 2 * NS_PER_MS)
		return false;
	while (k + 1 < n && q[k + 1].t_ns <= t)
		k++;
	size_t lo = k >= 1 ? k - 1 : 0;
	if (lo + 4 > n)
		lo = n >= 4 ? n - 4 : 0;
	size_t m = n - lo < 4 ? n - lo : 4;
	const struct asph_position_sample *s[4];
	struct asph_position_sample rel[4];
	for (size_t a = 0; a < m; a++) {
		rel[a] = q[lo + a];
		rel[a].t_ns = q[lo + a].t_ns - q[lo].t_ns;
		s[a] = &rel[a];
	}
	/* lagrange() takes three; four: the same weights written out */
	double tt = (double)(t - q[lo].t_ns) * 1e-9;
	for (int c = 0; c < 3; c++)
		out[c] = 0;
	for (size_t a = 0; a < m; a++) {
		double w = 1, ta = (double)s[a]->t_ns * 1e-9;
		for (size_t b = 0; b < m; b++)
			if (b != a)
				w *= (tt - (double)s[b]->t_ns * 1e-9) / (ta - (double)s[b]->t_ns * 1e-9);
		for (int c = 0; c < 3; c++)
			out[c] += w * s[a]->position[c];
	}
	/* the samples before the one just before t are spent */
	if (k >= 2) {
		st->trace_head += k - 2;
		st->trace_n -= k - 2;
	}
	return true;
}

/* The position a reading is paired with. */
static void place(struct asph_scan *sc, const struct pending *pd, const struct asph_reading *rd,
		  struct placed *pl)
{
	struct scan_stream *st = &sc->stream;

	if (!(sc->o.flags & ASPH_SCAN_COMMANDED)) {
		if (rd->position_source != ASPH_POSITION_NONE) {
			memcpy(pl->machine, rd->position, sizeof(pl->machine));
			pl->source = rd->position_source;
			return;
		}
		if (st->trace_n && st->trace[st->trace_head].source == ASPH_POSITION_LATCHED) {
			struct asph_position_sample c = st->trace[st->trace_head];
			st->trace_head++;
			st->trace_n--;
			const struct asph_position_sample *next =
				st->trace_n && st->trace[st->trace_head].source == ASPH_POSITION_LATCHED
					? &st->trace[st->trace_head] : NULL;
			compensate(sc, pd, &c, next, pl->machine);
			remember_latch(sc, &c);
			pl->source = ASPH_POSITION_LATCHED;
			return;
		}
		if (st->trace_n && sc->inst->shared_timebase && rd->t_ns &&
		    interpolate(sc, rd->t_ns + (uint64_t)llround(sc->latency * 1e9), pl->machine)) {
			pl->source = ASPH_POSITION_INTERPOLATED;
			return;
		}
	}
	memcpy(pl->machine, pd->cmd, sizeof(pl->machine));
	pl->source = ASPH_POSITION_COMMANDED;
}

/* Takes the readings of the oldest n pending triggers, pairs and records
 * them; *done: how many were recorded. */
static int collect(struct asph_scan *sc, size_t n, size_t *done, struct asph_error *err)
{
	struct scan_stream *st = &sc->stream;
	struct asph_instrument *in = sc->inst;
	const struct pending *pd = st->pend + st->pend_head;
	size_t got = 0;
	double rate = in->probe_info.rate;

	*done = 0;
	if (n == 0)
		return 0;
	for (size_t k = 0; k < n; k++) {
		struct asph_probe_context *c = &st->ctx[k];
		memset(c, 0, sizeof(*c));
		c->plan_index = pd[k].index;
		c->kind = pd[k].kind;
		c->attempt = pd[k].attempt;
		memcpy(c->machine, pd[k].cmd, sizeof(c->machine));
		scan_to_cartesian(sc, c->machine, c->xyz);
	}
	int r = asph_instrument_stream(in, st->ctx, n, st->readings, &got,
				       scan_timeout(sc->o.read_timeout_ms,
						    (rate > 0 ? (double)n / rate : 0) + sc->latency),
				       err);
	if (r < 0)
		r = scan_prefixed(r, "probe", (size_t)pd[got < n ? got : n - 1].index, err);
	int rr = 0;
	for (size_t k = 0; k < got && rr == 0; k++) {
		struct placed pl;
		place(sc, &pd[k], &st->readings[k], &pl);
		rr = scan_record(sc, &pd[k], &pl, NULL, &st->readings[k], 0, NULL, err);
		if (rr == 0)
			rr = scan_check_reading(sc, (size_t)pd[k].index, &st->readings[k], err);
		if (rr == 0 || rr == -ERANGE)
			*done = k + 1;
	}
	st->pend_head += *done;
	st->pend_n -= *done;
	if (st->pend_n == 0)
		st->pend_head = 0;
	int fr = scan_flush(sc, rr < 0 ? NULL : err);
	if (rr < 0)
		return rr;
	return r < 0 ? r : fr;
}

/* ------------------------------------------------------------- runs */

/* Along a sweep the probe may come closer than on the measuring positions
 * by half its standoff or half the clearance. */
static double sweep_gap(const struct asph_scan *sc)
{
	return -fmax(sc->inst->probe_info.standoff, sc->o.clearance) / 2;
}

/*
 * How far a timed sweep's Hermite command may leave the straight segment
 * from a to b (machine axes), with the path's directions ta, tb there:
 * the curve minus the chord is h10 (m0 ta - D) + h11 (m1 tb - D), each
 * weight at most 4/27, m the directions' lengths (the speed times the
 * segment's time: about its length, which speed changes move by at most
 * half of it along the chord).
 */
static double bulge(const double *a, const double *b, const double *ta, const double *tb)
{
	double d[3], l = 0, ea = 0, eb = 0;

	for (int k = 0; k < 3; k++) {
		d[k] = b[k] - a[k];
		l += d[k] * d[k];
	}
	l = sqrt(l);
	for (int k = 0; k < 3; k++) {
		ea += (l * ta[k] - d[k]) * (l * ta[k] - d[k]);
		eb += (l * tb[k] - d[k]) * (l * tb[k] - d[k]);
	}
	return 4.0 / 27.0 * (sqrt(ea) + sqrt(eb) + l);
}

/* The unit direction of the path through b from a to c (central). */
static void direction(const double *a, const double *c, double u[3])
{
	double n = 0;

	for (int k = 0; k < 3; k++) {
		u[k] = c[k] - a[k];
		n += u[k] * u[k];
	}
	n = sqrt(n);
	for (int k = 0; k < 3; k++)
		u[k] = n > 0 ? u[k] / n : 0;
}

/* The end of the run of plan points from i that a sweep may join: a
 * segment too close to the part ends it (the next run starts over the
 * part); for timed sweeps the curve's bulge off the segment counts too.
 * Timed sweeps take the whole run at once; else at most a batch. */
static size_t run_end_from(struct asph_scan *sc, size_t i, size_t max)
{
	struct target t0, t1, t2;
	double g_prev = NAN, ta[3], tb[3];
	size_t e = i + 1;

	scan_target(sc, i, false, &t0);
	if (e < sc->n)
		scan_target(sc, e, false, &t1);
	memcpy(ta, (double[3]){ 0, 0, 0 }, sizeof(ta));
	for (; e < sc->n && e - i < max; e++) {
		double g = scan_gap(sc, t1.cart), margin = 0;
		if (sc->pvt) {
			/* directions as the planner takes them: from the neighbours */
			if (e + 1 < sc->n)
				scan_target(sc, e + 1, false, &t2);
			else
				t2 = t1;
			direction(t0.machine, t2.machine, tb);
			if (e == i + 1)
				direction(t0.machine, t1.machine, ta);
			margin = bulge(t0.machine, t1.machine, ta, tb);
			memcpy(ta, tb, sizeof(ta));
		}
		if (!scan_path_clear_g(sc, t0.machine, g_prev, t1.machine, g, sweep_gap(sc) + margin))
			break;
		g_prev = g;
		t0 = t1;
		if (sc->pvt && e + 1 < sc->n)
			t1 = t2;
		else if (e + 1 < sc->n)
			scan_target(sc, e + 1, false, &t1);
	}
	return e;
}

/* The same, remembering a whole run: a timed sweep that stopped inside it
 * (for drift references, a pause) goes on with the pairs already checked,
 * but for its first one, where the planner now starts from rest. */
static size_t run_end(struct asph_scan *sc, size_t i, size_t max)
{
	struct scan_stream *st = &sc->stream;

	if (max != SIZE_MAX)
		return run_end_from(sc, i, max);
	if (st->run_from <= i && i + 1 < st->run_to && run_end_from(sc, i, 2) > i + 1)
		return st->run_to;
	st->run_from = i;
	st->run_to = run_end_from(sc, i, max);
	return st->run_to;
}

/* To plan point i, at rest there. */
static int approach(struct asph_scan *sc, size_t i, bool clear_move, struct asph_error *err)
{
	struct target t;
	double at[3];

	/* the rotary axis takes the short way from where the stage is (the
	 * checks and the path's look-ups have turned the angle on meanwhile) */
	if (sc->inst->stage_info.kinematics == ASPH_KINEMATICS_RTZ)
		scan_turn_from(sc, sc->run.pos[1]);
	scan_target(sc, i, false, &t);
	int r = 0;
	if (!clear_move || !scan_path_clear(sc, sc->run.pos, t.machine, sweep_gap(sc)))
		r = scan_move_clear(sc, t.approach, sc->o.clearance / 2, i, err);
	if (r == 0)
		r = scan_stage_move(sc, t.machine, i, err);
	if (r == 0)
		r = scan_settle(sc, t.machine, i, at, err);
	return r;
}

/* -------------------------------------------------- untimed sweeps */

/* A sweep at the stage's own pace through at most a batch of points. */
static int stream_plain(struct asph_scan *sc, size_t i, size_t *done, struct asph_error *err)
{
	struct scan_stream *st = &sc->stream;
	struct asph_instrument *in = sc->inst;
	size_t e = run_end(sc, i, sc->o.stream_batch), n = 0;
	struct sweep_cut cut = { 0 };
	const double *prev = sc->run.pos;
	struct target t;
	int r;

	*done = 0;
	scan_target(sc, i, false, &t);
	if (!scan_path_clear(sc, sc->run.pos, t.machine, sweep_gap(sc))) {
		r = approach(sc, i, false, err);
		if (r < 0)
			return r;
	}
	st->n_hist = 0;
	while (i + n < e && sweep_cut_open(&cut)) {
		scan_target(sc, i + n, false, &t);
		sweep_cut_add(&cut, prev, t.machine, &sc->lim, in->probe_info.rate);
		memcpy(st->path + 3 * n, t.machine, sizeof(t.machine));
		struct pending *pd = push_pending(sc);
		if (!pd)
			return asph_error_set(err, -ENOMEM, "out of memory");
		*pd = (struct pending){ .index = i + n, .kind = ASPH_MEASURE_PLAN };
		memcpy(pd->cmd, t.machine, sizeof(pd->cmd));
		prev = st->path + 3 * n++;
	}
	r = in->stage_driver->stage->sweep(in->stage, st->path, n,
					       scan_timeout(sc->o.move_timeout_ms, cut.motion), err);
	if (r < 0) {
		st->pend_n = st->pend_head = 0;
		return scan_prefixed(r, "stage", i, err);
	}
	scan_moved_to(sc, st->path + 3 * (n - 1));
	r = pull_trace(sc, i, err);
	if (r == 0)
		r = collect(sc, st->pend_n, done, err);
	st->pend_n = st->pend_head = 0;
	st->trace_n = st->trace_head = 0;
	return r;
}

/* ---------------------------------------------------- timed sweeps */

struct run {
	struct asph_scan *sc;
	size_t first;
};

/* Plan point first + i in the stage's axes, as the planner reads it. */
static void run_point(const void *data, size_t i, double out[3])
{
	const struct run *rn = data;
	const struct asph_scan *sc = rn->sc;
	const struct scan_stream *st = &sc->stream;
	size_t k = rn->first + i;
	const double *p = sc->xyz + 3 * k;

	if (st->theta) {
		out[0] = hypot(p[0], p[1]);
		out[1] = st->theta[k];
	} else {
		out[0] = p[0];
		out[1] = p[1];
	}
	/* optical: the probe's reference point a standoff before the point */
	out[2] = p[2] - sc->inst->probe_info.standoff;
}

/* The command at t between the knots of a batch (extrapolated past the
 * last at its velocity). */
static void command_at(const struct asph_motion_knot *k, size_t n, size_t j, double t,
		       double out[3])
{
	if (j + 1 < n && t <= k[j + 1].t) {
		asph_motion_knot_eval(&k[j], &k[j + 1], t, out, NULL, NULL, NULL);
		return;
	}
	for (int a = 0; a < 3; a++)
		out[a] = k[j].position[a] + k[j].velocity[a] * (t - k[j].t);
}

static bool stop_wanted(struct asph_scan *sc)
{
	return scan_stop_asked(sc) || scan_round_due(sc);
}

/* The next batch of knots: up to a sweep's time or a batch of points, or
 * the knots of a stop. */
static int next_knots(struct asph_scan *sc, bool stop, size_t *n)
{
	struct scan_stream *st = &sc->stream;
	size_t got = 0, max = sc->o.stream_batch;
	int r;

	*n = 0;
	if (stop)
		return asph_motion_planner_stop(st->planner, st->mk, RECORD_BATCH, n);
	do {
		size_t want = max - *n < 64 ? max - *n : 64;
		r = asph_motion_planner_next(st->planner, st->mk + *n, want, &got);
		if (r < 0)
			return r;
		*n += got;
	} while (got && *n < max && st->mk[*n - 1].t - st->mk[0].t < SWEEP_SECONDS);
	return 0;
}

/* The rotary axis's angles of the run from i to e as the stage takes them
 * from where the approach left it: whole turns on, and the first point's
 * exactly where the stage is (at r = 0 any angle is that point). */
static void align_theta(struct asph_scan *sc, size_t i, size_t e)
{
	struct scan_stream *st = &sc->stream;
	double shift = 2 * M_PI * round((sc->run.pos[1] - st->theta[i]) / (2 * M_PI));

	for (size_t k = i; k < e; k++)
		st->theta[k] += shift;
	st->theta[i] = sc->run.pos[1];
}

static int stream_pvt(struct asph_scan *sc, size_t i, size_t *done, struct asph_error *err)
{
	struct scan_stream *st = &sc->stream;
	struct asph_instrument *in = sc->inst;
	size_t e = run_end(sc, i, SIZE_MAX);
	struct run rn = { sc, i };
	double t_prev = 0, lat = sc->latency;
	uint64_t base;
	bool stopped = false;
	int r;

	*done = 0;
	r = approach(sc, i, true, err);
	if (r == 0 && st->theta)
		align_theta(sc, i, e);
	if (r == 0)
		r = asph_motion_planner_start_path(st->planner, run_point, &rn, e - i, &sc->lim, err);
	if (r < 0)
		return r;
	base = asph_instrument_clock(in);
	st->n_hist = 0;
	st->trace_n = st->trace_head = 0;
	while (!stopped) {
		size_t n, got;
		bool stop = stop_wanted(sc);
		r = next_knots(sc, stop, &n);
		if (r < 0)
			return asph_error_set(err, r, "plan point %zu: the path could not be planned", i);
		if (n == 0)
			break;
		stopped = stop;
		for (size_t k = 0; k < n; k++) {
			struct asph_pvt *p = &st->knots[k];
			const struct asph_motion_knot *m = &st->mk[k];
			p->t = m->t - t_prev;
			memcpy(p->position, m->position, sizeof(p->position));
			memcpy(p->velocity, m->velocity, sizeof(p->velocity));
			p->trigger = (m->flags & ASPH_MOTION_KNOT_POINT) != 0;
			p->reserved = 0;
			if (!p->trigger)
				continue;
			struct pending *pd = push_pending(sc);
			if (!pd)
				return asph_error_set(err, -ENOMEM, "out of memory");
			*pd = (struct pending){ .index = i + m->point, .kind = ASPH_MEASURE_PLAN,
						.t_ns = base + (uint64_t)llround(m->t * 1e9),
						.timed = true };
			command_at(st->mk, n, k, m->t + lat, pd->cmd);
			for (int a = 0; a < 3; a++)
				pd->dcmd[a] = pd->cmd[a] - m->position[a];
		}
		double dur = st->mk[n - 1].t - t_prev;
		t_prev = st->mk[n - 1].t;
		r = in->stage_ops.sweep_pvt(in->stage, st->knots, n,
					    scan_timeout(sc->o.move_timeout_ms, dur), err);
		if (r < 0)
			return scan_prefixed(r, "stage", i + *done, err);
		scan_moved_to(sc, st->mk[n - 1].position);
		const double *v = st->mk[n - 1].velocity;
		bool rest = v[0] == 0 && v[1] == 0 && v[2] == 0;
		r = pull_trace(sc, i + *done, err);
		if (r < 0)
			return r;
		/* the readings whose sample the motion has passed (all, at rest) */
		uint64_t end = base + (uint64_t)llround(t_prev * 1e9);
		size_t ready = 0;
		while (ready < st->pend_n &&
		       (rest || st->pend[st->pend_head + ready].t_ns +
					(uint64_t)llround(lat * 1e9) <= end))
			ready++;
		r = collect(sc, ready, &got, err);
		*done += got;
		if (r < 0)
			return r;
		scan_publish(sc, ASPH_SCAN_MEASURING, i + *done, false);
	}
	st->pend_n = st->pend_head = 0;
	return 0;
}

int scan_stream(struct asph_scan *sc, size_t i, size_t *done, struct asph_error *err)
{
	return sc->pvt ? stream_pvt(sc, i, done, err) : stream_plain(sc, i, done, err);
}
