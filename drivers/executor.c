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

#include "asph/executor.h"
#include "util-mem.h"

#define RECORD_BATCH 4096
/* A sweep lasts at most this long (s), so that pause, abort and progress
 * stay prompt at any speed. */
#define SWEEP_SECONDS 0.25

struct asph_scan {
	struct asph_instrument *inst;
	const struct asph_surface *surface;
	const double *xyz;
	size_t n;
	struct asph_scan_options o;
	bool tactile, stream;
	double tip;

	atomic_bool paused, aborted;
	pthread_mutex_t lock;           /* progress, pause condition */
	pthread_cond_t wake;
	struct asph_scan_progress progress;

	/* run state, run thread only */
	uint64_t t0_ns, last_report_ns, rate_t_ns, rate_done, measure_t0_ns;
	double rate;
	uint64_t measure_done0;
	double theta_prev;
	double pos[3];          /* where the last motion ended, stage axes */
	double z_safe;          /* travel height over the whole part (machine z) */
	double curvature;       /* bound of the surface's curvature, 1/mm */
	struct asph_scanfile_writer *w;
	struct asph_scanfile_point rec[RECORD_BATCH];
	size_t n_rec;
	double path[3 * RECORD_BATCH];
	double cart[3 * RECORD_BATCH];
	double normal[3 * RECORD_BATCH];
	struct asph_probe_context ctx[RECORD_BATCH];
	struct asph_reading readings[RECORD_BATCH];
};

/* Where the stage goes for one plan point. */
struct target {
	double cart[3];         /* probe reference point, cartesian, mm */
	double machine[3];      /* the same in the stage's axes */
	double approach[3];     /* clearance above, stage's axes */
	double normal[3];       /* nominal surface normal at the point */
};

static uint64_t now_ns(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

const char *asph_scan_state_name(enum asph_scan_state s)
{
	static const char *const names[] = {
		"ready", "checking", "homing", "measuring", "paused",
		"completed", "aborted", "failed",
	};
	return (unsigned)s < ARRAY_SIZE(names) ? names[s] : "unknown";
}

/* max over the aperture of the surface's principal curvatures' bound,
 * max(|Z''|, |Z'/r|), with a margin for the sampling. */
static double curvature_bound(const struct asph_surface *s)
{
	double a = asph_surface_aperture_radius(s), k = 0, d[3];

	for (int j = 0; j <= 2000; j++) {
		double r = a * j / 2000.0;
		asph_surface_sag_derivs(s, r, d);
		k = fmax(k, fabs(d[2]));
		if (r > 0)
			k = fmax(k, fabs(d[1] / r));
	}
	return 1.25 * k;
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
		sc->o.read_timeout_ms = 2000;
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
	sc->curvature = curvature_bound(s);
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

/* ------------------------------------------------------ kinematics */

static void to_machine(struct asph_scan *sc, const double c[3], double m[3])
{
	if (sc->inst->stage_info.kinematics != ASPH_KINEMATICS_RTZ) {
		memcpy(m, c, 3 * sizeof(double));
		return;
	}
	double r = hypot(c[0], c[1]), th = sc->theta_prev;
	if (r > 1e-12) {
		/* the rotary axis takes the short way from where it is */
		double d = remainder(atan2(c[1], c[0]) - sc->theta_prev, 2 * M_PI);
		th = sc->theta_prev + d;
	}
	sc->theta_prev = th;
	m[0] = r;
	m[1] = th;
	m[2] = c[2];
}

static void to_cartesian(const struct asph_scan *sc, const double m[3], double c[3])
{
	if (sc->inst->stage_info.kinematics != ASPH_KINEMATICS_RTZ) {
		memcpy(c, m, 3 * sizeof(double));
		return;
	}
	c[0] = m[0] * cos(m[1]);
	c[1] = m[0] * sin(m[1]);
	c[2] = m[2];
}

/* The stage position measuring plan point i: the tip centre (tactile) on
 * the point's normal, the probe reference a standoff before it. The probe
 * looks along +z, so "before" and "above" are -z. */
static void target_of(struct asph_scan *sc, size_t i, bool need_normal, struct target *t)
{
	const double *p = sc->xyz + 3 * i;

	/* the normal costs as much as the rest: only when it is used */
	if (need_normal || sc->tip > 0)
		asph_surface_normal(sc->surface, p[0], p[1], t->normal);
	else
		t->normal[0] = t->normal[1] = 0, t->normal[2] = 1;
	for (int k = 0; k < 3; k++)
		t->cart[k] = p[k] - sc->tip * t->normal[k];
	t->cart[2] -= sc->inst->probe_info.standoff;
	to_machine(sc, t->cart, t->machine);
	t->approach[0] = t->machine[0];
	t->approach[1] = t->machine[1];
	t->approach[2] = t->machine[2] - sc->o.clearance;
}

/* ------------------------------------------------------- clearance */

/* How far the probe at cartesian c is from where it measures: the gap
 * along the probe axis between its reference point and the nominal
 * surface, less the standoff and the tip (0 on a measuring position,
 * clearance above it). Nothing below: +infinity. */
static double gap_at(const struct asph_scan *sc, const double c[3])
{
	double d[3];

	asph_surface_sag_derivs(sc->surface, sqrt(c[0] * c[0] + c[1] * c[1]), d);
	if (!isfinite(d[0]))
		return INFINITY;
	return d[0] - c[2] - sc->inst->probe_info.standoff - sc->tip * sqrt(1 + d[1] * d[1]);
}

/* Whether the stage's straight move (in its axes) from a to b keeps the
 * gap at least min_gap all along; ga, gb are the gaps at the ends when
 * known, else NAN. */
static bool path_clear_g(const struct asph_scan *sc, const double *a, double ga,
			 const double *b, double gb, double min_gap)
{
	double ca[3], cb[3], c[3], m[3];

	to_cartesian(sc, a, ca);
	to_cartesian(sc, b, cb);
	double g = fmin(isnan(ga) ? gap_at(sc, ca) : ga, isnan(gb) ? gap_at(sc, cb) : gb);
	if (g < min_gap)
		return false;
	double dx = cb[0] - ca[0], dy = cb[1] - ca[1], len = sqrt(dx * dx + dy * dy);
	bool rtz = sc->inst->stage_info.kinematics == ASPH_KINEMATICS_RTZ;
	/* a straight line dips below its chord by at most curvature len^2 / 8 */
	if (!rtz && sc->tip == 0 && g - sc->curvature * len * len / 8 >= min_gap)
		return true;
	if (rtz)
		len = fabs(b[0] - a[0]) + fmax(a[0], b[0]) * fabs(b[1] - a[1]);
	int steps = 4 + (int)fmin(len / 0.1, 4000);
	for (int k = 1; k < steps; k++) {
		double t = (double)k / steps;
		for (int j = 0; j < 3; j++)
			m[j] = a[j] + t * (b[j] - a[j]);
		to_cartesian(sc, m, c);
		if (gap_at(sc, c) < min_gap)
			return false;
	}
	return true;
}

static bool path_clear(const struct asph_scan *sc, const double *a, const double *b,
		       double min_gap)
{
	return path_clear_g(sc, a, NAN, b, NAN, min_gap);
}

/* The travel height: clearance above the whole part and every approach. */
static double safe_height(struct asph_scan *sc, double min_approach_z)
{
	const struct asph_surface *s = sc->surface;
	double a = asph_surface_aperture_radius(s), z = min_approach_z, d[3];

	for (int j = 0; j <= 2000; j++) {
		asph_surface_sag_derivs(s, a * j / 2000.0, d);
		z = fmin(z, d[0] - sc->inst->probe_info.standoff -
			       sc->tip * sqrt(1 + d[1] * d[1]) - sc->o.clearance);
	}
	return z;
}

/* ------------------------------------------------------------ check */

static int refuse_axis(const struct asph_scan *sc, size_t i, const double *m,
		       const char *what, struct asph_error *err)
{
	const struct asph_stage_info *si = &sc->inst->stage_info;

	for (unsigned k = 0; k < si->n_axes; k++) {
		const struct asph_axis_info *a = &si->axes[k];
		if (m[k] >= a->min && m[k] <= a->max)
			continue;
		asph_error_set(err, -ERANGE,
			       "plan point %zu (%.6f, %.6f, %.6f): the %s needs axis %s at %.6f %s, outside its travel %.6g .. %.6g",
			       i, sc->xyz[3 * i], sc->xyz[3 * i + 1], sc->xyz[3 * i + 2], what,
			       a->name, m[k], a->unit, a->min, a->max);
		asph_error_locate(err, NULL, 0, 0, a->name);
		return -ERANGE;
	}
	return 0;
}

static inline bool inside(const double *m, const double *lo, const double *hi)
{
	return m[0] >= lo[0] && m[0] <= hi[0] && m[1] >= lo[1] && m[1] <= hi[1] &&
	       m[2] >= lo[2] && m[2] <= hi[2];
}

static int check_point(struct asph_scan *sc, size_t i, const double *lo, const double *hi,
		       double *min_z, struct asph_error *err)
{
	const struct asph_probe_info *pi = &sc->inst->probe_info;
	const double *p = sc->xyz + 3 * i;
	struct target t;

	if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
		return asph_error_set(err, -EINVAL, "plan point %zu is not finite", i);
	target_of(sc, i, pi->max_slope > 0, &t);
	if (pi->max_slope > 0 && acos(fmin(1.0, t.normal[2])) > pi->max_slope)
		return asph_error_set(err, -ERANGE,
				      "plan point %zu (%.6f, %.6f, %.6f): surface slope %.3f deg is steeper than the probe reads (%.3f deg)",
				      i, p[0], p[1], p[2], acos(fmin(1.0, t.normal[2])) * 180 / M_PI,
				      pi->max_slope * 180 / M_PI);
	if (!inside(t.machine, lo, hi))
		return refuse_axis(sc, i, t.machine, "measuring position", err);
	if (!inside(t.approach, lo, hi))
		return refuse_axis(sc, i, t.approach, "approach", err);
	*min_z = fmin(*min_z, t.approach[2]);
	return 0;
}

static int check_probe(const struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_probe_info *pi = &sc->inst->probe_info;

	if (!(pi->standoff >= pi->range_min && pi->standoff <= pi->range_max))
		return asph_error_set(err, -ERANGE,
				      "the probe's standoff %.6g mm is outside its range %.6g .. %.6g mm",
				      pi->standoff, pi->range_min, pi->range_max);
	if (sc->tactile && !(pi->tip_radius > 0))
		return asph_error_set(err, -ERANGE, "tactile probe without a tip radius");
	return 0;
}

int asph_scan_check(struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_stage_info *si = &sc->inst->stage_info;
	double lo[3], hi[3];
	int r = check_probe(sc, err);

	if (r < 0)
		return r;
	for (int k = 0; k < 3; k++) {
		lo[k] = si->axes[k].min;
		hi[k] = si->axes[k].max;
	}
	double min_z = INFINITY;
	sc->theta_prev = 0;
	for (size_t i = sc->o.start_index; r == 0 && i < sc->n; i++)
		r = check_point(sc, i, lo, hi, &min_z, err);
	sc->theta_prev = 0;
	if (r < 0)
		return r;
	sc->z_safe = safe_height(sc, min_z);
	if (!(sc->z_safe >= lo[2]))
		return asph_error_set(err, -ERANGE,
				      "the travel height over the part, %.6f mm, is outside the z travel %.6g .. %.6g",
				      sc->z_safe, lo[2], hi[2]);
	return 0;
}

/* --------------------------------------------------------- progress */

static void publish(struct asph_scan *sc, enum asph_scan_state state, uint64_t done,
		    uint64_t measured, bool force)
{
	uint64_t t = now_ns();

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
	return (struct stamp){ asph_scanfile_writer_elapsed_ns(sc->w), now_ns() };
}

static uint64_t reading_time(const struct stamp *st, uint64_t t_ns)
{
	if (t_ns && t_ns <= st->mono_ns && st->mono_ns - t_ns <= st->scan_ns)
		return st->scan_ns - (st->mono_ns - t_ns);
	return st->scan_ns;
}

/* The measured point of a reading: the stage's cartesian position plus
 * the reading along +z, then the tip radius back along the normal. */
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
	if (sc->tip > 0) {
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
	if (path_clear(sc, sc->pos, m, min_gap))
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
		struct timespec ts;
		clock_gettime(CLOCK_REALTIME, &ts);
		ts.tv_nsec += 200000000;
		if (ts.tv_nsec >= 1000000000) {
			ts.tv_sec++;
			ts.tv_nsec -= 1000000000;
		}
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

static int measure_point(struct asph_scan *sc, size_t i, struct asph_error *err)
{
	struct asph_instrument *in = sc->inst;
	struct asph_probe_context ctx = { .plan_index = i };
	struct asph_reading rd;
	struct target t;
	double cart[3];

	target_of(sc, i, false, &t);
	int r = move_clear(sc, t.approach, sc->o.clearance / 2, i, err);
	if (r == 0)
		r = stage_move(sc, t.machine, i, err);
	if (r == 0)
		r = prefixed(in->stage_driver->stage->position(in->stage, ctx.machine,
							       sc->o.move_timeout_ms, err),
			     "stage", i, err);
	if (r < 0)
		return r;
	to_cartesian(sc, ctx.machine, ctx.xyz);
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
	target_of(sc, i, false, &t);
	if (!path_clear(sc, sc->pos, t.machine, sweep_gap)) {
		r = move_clear(sc, t.approach, sc->o.clearance / 2, i, err);
		if (r == 0)
			r = stage_move(sc, t.machine, i, err);
		if (r < 0)
			return r;
	}
	double g_prev = NAN;
	while (n < max && (n == 0 || fmax(motion, reading) < SWEEP_SECONDS)) {
		if (n > 0) {
			target_of(sc, i + n, false, &t);
			/* a segment too close to the part ends the sweep; the next
			 * one starts over the part */
			double g = gap_at(sc, t.cart);
			if (!path_clear_g(sc, prev, g_prev, t.machine, g, sweep_gap))
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

	sc->measure_t0_ns = now_ns();
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
			r = measure_point(sc, i, err);
			if (r == 0 || r == -ERANGE)
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
	sc->t0_ns = now_ns();
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
