/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The mock instrument's physics on a simulated clock (see bench.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bench.h"
#include "util-mem.h"

/* Encoders are logged this often when the capture is by time. */
#define SERVO_PERIOD 0.001
/* After a move the stage rings with this amplitude per mm/s of the move's
 * peak speed (1 um at 20 mm/s), decaying to RING_END at settle_time. */
#define RING_PER_SPEED 5e-5
#define RING_END 1e-6
/* The ringing's period, in settle times. */
#define RING_PERIOD 0.25
/* The settling window the stage advises when it rings (mm): 10 nm, ten
 * steps of a 1 nm encoder, a hundredth of the ringing after a move at
 * 20 mm/s. */
#define SETTLE_WINDOW 1e-5
/* Below this (mm) the ringing is no more: a millionth of a nanometre, far
 * below any encoder step, and then not worth its exp() and cos() per
 * position. */
#define RING_NONE 1e-15

/* The command over a piece of time: c(tau) = c[0] + c[1] tau + c[2] tau^2 +
 * c[3] tau^3 per axis, tau in [0, d]. */
struct piece {
	double d;
	double c[4][3];
	double end[3];          /* c(d), exactly (a knot, a target) */
	bool trigger;           /* fires the probe at its end */
};

struct ring {
	double t0, amp[3], tau, period;
	double life;            /* from t0 until below RING_NONE */
	double t_end;           /* t0 + life: from here on none */
	bool on;
};

struct mock_bench {
	struct mock_stage_params sp;
	struct mock_probe_params pp;
	bool probe;
	double omega;           /* servo bandwidth, rad/s; 0 = ideal */
	double inv_omega;       /* 1 / omega, s (a product costs less than a quotient) */
	double t;               /* simulated now */
	double x[3];            /* the axes' true positions (servo output) */
	double cmd[3], vel[3];  /* the command's end and its velocity */
	struct ring ring;
	double last_trigger;    /* time of the last trigger, -inf: none */
	double next_log;        /* next encoder log (capture by time) */
	/* triggers not yet taken by the probe; those before trig_unsampled
	 * have their sample (samples come in the order of their triggers) */
	struct mock_trigger *trig;
	size_t trig_head, trig_n, trig_cap, trig_unsampled;
	/* positions measured during sweeps, not yet handed out */
	struct asph_position_sample *trace;
	size_t trace_head, trace_n, trace_cap;
	/* pieces of the command being run */
	struct piece *pcs;
	size_t pcs_cap;
};

int mock_bench_new(const struct mock_stage_params *sp, struct mock_bench **out)
{
	struct mock_bench *b = calloc(1, sizeof(*b));

	if (!b)
		return -ENOMEM;
	b->sp = *sp;
	b->omega = sp->servo_bandwidth > 0 ? 2 * M_PI * sp->servo_bandwidth : 0;
	b->inv_omega = b->omega > 0 ? 1 / b->omega : 0;
	b->last_trigger = -INFINITY;
	*out = b;
	return 0;
}

void mock_bench_free(struct mock_bench *b)
{
	if (!b)
		return;
	free(b->trig);
	free(b->trace);
	free(b->pcs);
	free(b);
}

void mock_bench_mount_probe(struct mock_bench *b, const struct mock_probe_params *pp)
{
	b->pp = *pp;
	b->probe = true;
}

bool mock_bench_has_probe(const struct mock_bench *b)
{
	return b->probe;
}

double mock_bench_now(const struct mock_bench *b)
{
	return b->t;
}

/* An instant of the past at the same age from t as it is from now. */
static double aged(const struct mock_bench *b, double t, double then)
{
	return t - (b->t - then);
}

void mock_bench_align(struct mock_bench *b, double t)
{
	if (b->ring.on) {
		b->ring.t0 = aged(b, t, b->ring.t0);
		b->ring.t_end = b->ring.t0 + b->ring.life;
	}
	if (isfinite(b->last_trigger))
		b->last_trigger = aged(b, t, b->last_trigger);
	b->next_log = t;
	for (size_t i = 0; i < b->trig_n; i++) {
		struct mock_trigger *tr = &b->trig[b->trig_head + i];
		tr->t = aged(b, t, tr->t);
		tr->sample.t = aged(b, t, tr->sample.t);
	}
	for (size_t i = 0; i < b->trace_n; i++) {
		struct asph_position_sample *s = &b->trace[b->trace_head + i];
		s->t_ns = (uint64_t)llround(aged(b, t, (double)s->t_ns * 1e-9) * 1e9);
	}
	/* what is left of the servo's error after settling is far below any
	 * length the bench resolves; at rest it is gone, so that the stage's
	 * state is the same whatever motion came before */
	for (int k = 0; k < 3 && b->vel[0] == 0 && b->vel[1] == 0 && b->vel[2] == 0; k++)
		if (fabs(b->x[k] - b->cmd[k]) <= RING_NONE)
			b->x[k] = b->cmd[k];
	b->t = t;
}

void mock_bench_target(const struct mock_bench *b, double m[3])
{
	memcpy(m, b->cmd, 3 * sizeof(double));
}

/* ------------------------------------------------------------ physics */

void mock_stage_settling(const struct mock_stage_params *sp, double *window, double *dwell)
{
	bool rings = sp->settle_time > 0;

	*window = rings ? SETTLE_WINDOW : 0;
	/* inside the window for a whole period of the ringing: a read-back
	 * near one of its zero crossings does not pass for a settled stage */
	*dwell = rings ? sp->settle_time * RING_PERIOD : 0;
}

void mock_drift(const struct mock_probe_params *pp, double t, double d[3])
{
	/* linear, plus a slow thermal cycle of 20 minutes whose amplitude is
	 * one minute of the linear drift */
	double cycle = sin(2 * M_PI * t / 1200.0) * 60.0;
	double z = pp->drift_z * (t + cycle), xy = pp->drift_xy * (t + cycle);

	d[0] = 0.8 * xy;
	d[1] = 0.6 * xy;
	d[2] = z;
}

double mock_dropout_probability(const struct mock_probe_params *pp, double slope)
{
	if (!(pp->dropout > 0))
		return 0;
	if (!(pp->max_slope > 0))
		return pp->dropout;
	double q = fmin(1, fabs(slope) / pp->max_slope);
	return pp->dropout * q * q * q * q * q * q;
}

static uint64_t splitmix64(uint64_t *state)
{
	uint64_t z = (*state += 0x9e3779b97f4a7c15u);
	z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9u;
	z = (z ^ (z >> 27)) * 0x94d049bb133111ebu;
	return z ^ (z >> 31);
}

/* The generator's state for a measurement: a plan point's first attempt
 * keeps the state the mock always used. */
static uint64_t key(uint64_t seed, uint32_t kind, uint64_t index, uint32_t attempt)
{
	uint64_t st = seed * 0xd1342543de82ef95u + index;

	if (kind || attempt) {
		uint64_t k = ((uint64_t)kind << 32 | attempt) ^ 0xa0761d6478bd642fu;
		st ^= splitmix64(&k);
	}
	return st;
}

double mock_gaussian(uint64_t seed, uint32_t kind, uint64_t index, uint32_t attempt)
{
	uint64_t st = key(seed, kind, index, attempt);
	double u1 = ((double)(splitmix64(&st) >> 11) + 0.5) * 0x1p-53;
	double u2 = (double)(splitmix64(&st) >> 11) * 0x1p-53;

	return sqrt(-2 * log(u1)) * cos(2 * M_PI * u2);
}

double mock_uniform(uint64_t seed, uint32_t kind, uint64_t index, uint32_t attempt)
{
	uint64_t st = key(seed, kind, index, attempt) ^ 0xe7037ed1a0b428dbu;

	return (double)(splitmix64(&st) >> 11) * 0x1p-53;
}

/* ------------------------------------------------------------- servo */

/*
 * The axes through piece p from x0: each follows its command through a
 * first-order loop, dx/dt = omega (c - x), so that at a steady speed v it
 * lags by v / omega, and by v / omega - a / omega^2 + ... in general. For a
 * cubic command the error e = c - x is a quadratic plus e^(-omega t) times
 * what it started with beyond it. The quadratic and the start are the
 * piece's, worked out once for all the instants taken in it.
 */
struct servo_piece {
	const struct piece *p;
	double a[3][3];         /* per axis: the error's quadratic a0 + a1 tau + a2 tau^2 */
	double e0[3];           /* the error at the start beyond it */
};

static void servo_start(const struct mock_bench *b, const struct piece *p, const double x0[3],
			struct servo_piece *sp)
{
	double iw = b->inv_omega;

	sp->p = p;
	if (b->omega == 0)
		return;
	for (int k = 0; k < 3; k++) {
		/* dc/dt = q0 + q1 tau + q2 tau^2 */
		double q0 = p->c[1][k], q1 = 2 * p->c[2][k], q2 = 3 * p->c[3][k];
		double a2 = q2 * iw, a1 = (q1 - 2 * a2) * iw, a0 = (q0 - a1) * iw;
		sp->a[k][0] = a0;
		sp->a[k][1] = a1;
		sp->a[k][2] = a2;
		sp->e0[k] = (p->c[0][k] - x0[k]) - a0;
	}
}

/* The axes after tau of the piece. */
static void servo(const struct mock_bench *b, const struct servo_piece *sp, double tau,
		  double x[3])
{
	const struct piece *p = sp->p;

	if (b->omega == 0) {
		/* on the command; at a piece's end exactly where it ends */
		for (int k = 0; k < 3; k++)
			x[k] = tau == p->d ? p->end[k]
					   : p->c[0][k] + tau * (p->c[1][k] + tau * (p->c[2][k] + tau * p->c[3][k]));
		return;
	}
	double decay = exp(-b->omega * tau);
	for (int k = 0; k < 3; k++) {
		const double *a = sp->a[k];
		double c = p->c[0][k] + tau * (p->c[1][k] + tau * (p->c[2][k] + tau * p->c[3][k]));
		double e = a[0] + tau * (a[1] + tau * a[2]) + sp->e0[k] * decay;
		x[k] = c - e;
	}
}

static void ring_at(const struct mock_bench *b, double t, double r[3])
{
	r[0] = r[1] = r[2] = 0;
	if (!b->ring.on || t < b->ring.t0 || t >= b->ring.t_end)
		return;
	double s = t - b->ring.t0;
	double f = exp(-s / b->ring.tau) * cos(2 * M_PI * s / b->ring.period);
	for (int k = 0; k < 3; k++)
		r[k] = b->ring.amp[k] * f;
}

/* The cartesian position of the probe's reference point for axes m at t:
 * the ringing on top, the straightness of the x and y guides in z. */
static void cartesian(const struct mock_bench *b, const double m[3], double t, double c[3])
{
	double q[3], r[3];

	ring_at(b, t, r);
	for (int k = 0; k < 3; k++)
		q[k] = m[k] + r[k];
	if (b->sp.rtz) {
		c[0] = q[0] * cos(q[1]);
		c[1] = q[0] * sin(q[1]);
	} else {
		c[0] = q[0];
		c[1] = q[1];
	}
	c[2] = q[2];
	if (b->sp.straightness != 0) {
		double u = c[0] / b->sp.travel_xy, v = c[1] / b->sp.travel_xy;
		c[2] += b->sp.straightness / 2 * ((1 - u * u) + (1 - v * v));
	}
}

static double quantize(double v, double step)
{
	return step > 0 ? step * nearbyint(v / step) : v;
}

/* What the encoders read for axes m at t: the scale's error, the
 * resolution; the guides' straightness is not seen. */
static void encoders(const struct mock_bench *b, const double m[3], double t, double e[3])
{
	double r[3];

	ring_at(b, t, r);
	for (int k = 0; k < 3; k++) {
		double v = m[k] + r[k];
		if (b->sp.rtz && k == 1) {
			e[k] = v;       /* the rotary table's encoder: exact */
			continue;
		}
		e[k] = quantize(v * (1 + b->sp.scale_error), b->sp.encoder_resolution);
	}
}

/* ------------------------------------------------------ running pieces */

static int push_trace(struct mock_bench *b, double t, const double e[3], uint32_t source,
		      uint32_t trigger)
{
	if (b->trace_head + b->trace_n == b->trace_cap && b->trace_head > 0) {
		memmove(b->trace, b->trace + b->trace_head, b->trace_n * sizeof(*b->trace));
		b->trace_head = 0;
	}
	if (array_grow((void **)&b->trace, &b->trace_cap, b->trace_head + b->trace_n + 1,
		       sizeof(*b->trace), 64) < 0)
		return -ENOMEM;
	struct asph_position_sample *s = &b->trace[b->trace_head + b->trace_n++];
	s->t_ns = (uint64_t)llround(t * 1e9);
	memcpy(s->position, e, 3 * sizeof(double));
	s->source = source;
	s->trigger = trigger;
	return 0;
}

static struct mock_trigger *push_trigger(struct mock_bench *b)
{
	if (b->trig_head + b->trig_n == b->trig_cap && b->trig_head > 0) {
		memmove(b->trig, b->trig + b->trig_head, b->trig_n * sizeof(*b->trig));
		b->trig_unsampled = b->trig_unsampled > b->trig_head ? b->trig_unsampled - b->trig_head : 0;
		b->trig_head = 0;
	}
	if (array_grow((void **)&b->trig, &b->trig_cap, b->trig_head + b->trig_n + 1,
		       sizeof(*b->trig), 64) < 0)
		return NULL;
	return &b->trig[b->trig_head + b->trig_n++];
}

/* Samples of pending triggers that fall in [t0, t0 + p->d]. The samples
 * lie in the order of their triggers: the search starts at the first one
 * not taken and ends at the first one past the piece. */
static void take_samples(struct mock_bench *b, const struct servo_piece *sp, double t0)
{
	const struct piece *p = sp->p;
	size_t end = b->trig_head + b->trig_n;

	if (b->trig_unsampled < b->trig_head)
		b->trig_unsampled = b->trig_head;
	for (size_t i = b->trig_unsampled; i < end; i++) {
		struct mock_trigger *tr = &b->trig[i];
		if (tr->sampled)
			continue;
		double tau = tr->sample.t - t0;
		if (tau > p->d)
			break;
		if (tau < 0)
			continue;
		double m[3];
		servo(b, sp, tau, m);
		cartesian(b, m, tr->sample.t, tr->sample.pos);
		tr->sampled = true;
	}
	while (b->trig_unsampled < end && b->trig[b->trig_unsampled].sampled)
		b->trig_unsampled++;
}

static int log_encoders(struct mock_bench *b, const struct servo_piece *sp, double t0)
{
	const struct piece *p = sp->p;

	if (b->sp.capture != MOCK_CAPTURE_SAMPLED || !b->probe)
		return 0;
	if (b->next_log < t0)
		b->next_log = t0;
	while (b->next_log <= t0 + p->d) {
		double m[3], e[3];
		servo(b, sp, b->next_log - t0, m);
		encoders(b, m, b->next_log, e);
		if (push_trace(b, b->next_log, e, ASPH_POSITION_READ_BACK, 0) < 0)
			return -ENOMEM;
		b->next_log += SERVO_PERIOD;
	}
	return 0;
}

/* The trigger at the end of a piece, now (b->t, b->x). */
static int fire(struct mock_bench *b, struct asph_error *err)
{
	if (!b->probe)
		return 0;       /* nothing is wired to the trigger */
	double gap = b->t - b->last_trigger;
	if (b->pp.rate > 0 && gap < (1 / b->pp.rate) * (1 - 1e-9))
		return asph_error_set(err, -EPROTO,
				      "triggers %.6g ms apart, faster than the probe reads (%.6g Hz)",
				      gap * 1e3, b->pp.rate);
	struct mock_trigger *tr = push_trigger(b);
	if (!tr)
		return asph_error_set(err, -ENOMEM, "out of memory");
	tr->t = b->t;
	encoders(b, b->x, b->t, tr->latched);
	tr->sample.t = b->t + b->pp.latency;
	tr->sampled = false;
	if (b->pp.latency == 0) {
		cartesian(b, b->x, b->t, tr->sample.pos);
		tr->sampled = true;
	}
	b->last_trigger = b->t;
	if (b->sp.capture == MOCK_CAPTURE_LATCHED &&
	    push_trace(b, b->t, tr->latched, ASPH_POSITION_LATCHED, 0) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}

/* Runs pieces in order: the servo through each, the samples and logs that
 * fall in it, the triggers at their ends. */
static int run(struct mock_bench *b, const struct piece *p, size_t n, struct asph_error *err)
{
	for (size_t i = 0; i < n; i++) {
		struct servo_piece sp;
		servo_start(b, &p[i], b->x, &sp);
		take_samples(b, &sp, b->t);
		if (log_encoders(b, &sp, b->t) < 0)
			return asph_error_set(err, -ENOMEM, "out of memory");
		servo(b, &sp, p[i].d, b->x);
		b->t += p[i].d;
		if (p[i].trigger) {
			int r = fire(b, err);
			if (r < 0)
				return r;
		}
	}
	return 0;
}

/* At rest on the command for a while. */
static void hold(struct mock_bench *b, double seconds)
{
	struct piece p = { .d = seconds };

	if (!(seconds > 0))
		return;
	memcpy(p.c[0], b->cmd, sizeof(b->cmd));
	memcpy(p.end, b->cmd, sizeof(b->cmd));
	run(b, &p, 1, NULL);
}

void mock_bench_idle(struct mock_bench *b, double seconds)
{
	hold(b, seconds);
}

void mock_bench_home(struct mock_bench *b)
{
	memset(b->x, 0, sizeof(b->x));
	memset(b->cmd, 0, sizeof(b->cmd));
	memset(b->vel, 0, sizeof(b->vel));
	b->ring.on = false;
}

static struct piece *pieces(struct mock_bench *b, size_t n)
{
	if (array_grow((void **)&b->pcs, &b->pcs_cap, n, sizeof(*b->pcs), 64) < 0)
		return NULL;
	memset(b->pcs, 0, n * sizeof(*b->pcs));
	return b->pcs;
}

double mock_bench_move_duration(const struct mock_bench *b, const double target[3])
{
	struct asph_motion_move mv;

	asph_motion_move_plan(b->cmd, target, &b->sp.lim, &mv);
	return mv.profile.duration;
}

double mock_bench_move(struct mock_bench *b, const double target[3])
{
	struct asph_motion_move mv;
	struct piece *p = pieces(b, 7);

	asph_motion_move_plan(b->cmd, target, &b->sp.lim, &mv);
	if (!p || !(mv.length > 0)) {
		memcpy(b->cmd, target, sizeof(b->cmd));
		return 0;
	}
	/* the profile's phases, each cubic in time */
	const struct asph_motion_profile *pr = &mv.profile;
	size_t n = 0;
	for (int k = 0; k < 7; k++) {
		if (!(pr->t[k] > 0))
			continue;
		double s, v, a, jk;
		asph_motion_profile_phase(pr, k, &s, &v, &a, &jk);
		struct piece *q = &p[n++];
		q->d = pr->t[k];
		for (int ax = 0; ax < 3; ax++) {
			q->c[0][ax] = mv.from[ax] + mv.dir[ax] * s;
			q->c[1][ax] = mv.dir[ax] * v;
			q->c[2][ax] = mv.dir[ax] * a / 2;
			q->c[3][ax] = mv.dir[ax] * jk / 6;
			q->end[ax] = q->c[0][ax] + q->d * (q->c[1][ax] + q->d * (q->c[2][ax] + q->d * q->c[3][ax]));
		}
	}
	if (n)
		memcpy(p[n - 1].end, target, 3 * sizeof(double));
	/* the last phase ends exactly on the target */
	run(b, p, n, NULL);
	memcpy(b->cmd, target, sizeof(b->cmd));
	memset(b->vel, 0, sizeof(b->vel));
	if (b->sp.settle_time > 0) {
		double amp = RING_PER_SPEED * pr->v;
		if (amp > RING_END) {
			b->ring.on = true;
			b->ring.t0 = b->t;
			b->ring.tau = b->sp.settle_time / log(amp / RING_END);
			b->ring.period = b->sp.settle_time * RING_PERIOD;
			b->ring.life = b->ring.tau * log(amp / RING_NONE);
			b->ring.t_end = b->t + b->ring.life;
			for (int k = 0; k < 3; k++)
				b->ring.amp[k] = amp * mv.dir[k];
		}
	}
	return pr->duration;
}

double mock_bench_sweep(struct mock_bench *b, const double *pos, size_t n)
{
	struct piece *p = pieces(b, n);
	double total = 0;
	const double *from = b->cmd;

	if (!p)
		return 0;
	for (size_t i = 0; i < n; i++) {
		double d[3], len = 0, u[3];
		for (int k = 0; k < 3; k++) {
			d[k] = pos[3 * i + k] - from[k];
			len += d[k] * d[k];
		}
		len = sqrt(len);
		/* at the stage's speed along the segment, turning at once */
		double v = INFINITY;
		for (int k = 0; k < 3; k++) {
			u[k] = len > 0 ? d[k] / len : 0;
			if (fabs(u[k]) > 1e-15)
				v = fmin(v, b->sp.lim.speed[k] / fabs(u[k]));
		}
		p[i].d = len > 0 ? len / v : 0;
		for (int k = 0; k < 3; k++) {
			p[i].c[0][k] = from[k];
			p[i].c[1][k] = len > 0 ? d[k] / p[i].d : 0;
			p[i].end[k] = pos[3 * i + k];
		}
		p[i].trigger = true;
		total += p[i].d;
		from = pos + 3 * i;
	}
	/* an ABI 1.0 sweep: the probe reads along it at its own pace */
	double saved = b->pp.rate;
	b->pp.rate = 0;
	run(b, p, n, NULL);
	b->pp.rate = saved;
	if (n)
		memcpy(b->cmd, pos + 3 * (n - 1), sizeof(b->cmd));
	memset(b->vel, 0, sizeof(b->vel));
	return total;
}

int mock_bench_sweep_pvt(struct mock_bench *b, const struct asph_pvt *k, size_t n,
			 double *seconds, struct asph_error *err)
{
	struct piece *p = pieces(b, n + 1);
	double t = 0, pos[3], vel[3];
	size_t m = 0;

	*seconds = 0;
	if (!p)
		return asph_error_set(err, -ENOMEM, "out of memory");
	memcpy(pos, b->cmd, sizeof(pos));
	memcpy(vel, b->vel, sizeof(vel));
	for (size_t i = 0; i < n; i++) {
		double dt = k[i].t - t;
		if (!isfinite(k[i].t) || dt < 0 || (i > 0 && dt == 0))
			return asph_error_set(err, -EINVAL, "knot %zu at %.9g s: the knots' times must increase",
					      i, k[i].t);
		if (dt == 0) {
			/* the first knot at 0 is where the stage is */
			for (int a = 0; a < 3; a++)
				if (fabs(k[i].position[a] - pos[a]) > 1e-9 ||
				    fabs(k[i].velocity[a] - vel[a]) > 1e-9)
					return asph_error_set(err, -EINVAL,
							      "knot 0 at t = 0 is not where the stage is (%.9g %.9g %.9g, the stage at %.9g %.9g %.9g moving %.3g %.3g %.3g)", k[i].position[0], k[i].position[1], k[i].position[2], pos[0], pos[1], pos[2], vel[0], vel[1], vel[2]);
			if (k[i].trigger) {
				int r = fire(b, err);
				if (r < 0)
					return r;
			}
			continue;
		}
		struct piece *q = &p[m++];
		double id = 1 / dt;
		q->d = dt;
		q->trigger = k[i].trigger != 0;
		for (int a = 0; a < 3; a++) {
			double p0 = pos[a], p1 = k[i].position[a], v0 = vel[a], v1 = k[i].velocity[a];
			q->c[0][a] = p0;
			q->c[1][a] = v0;
			q->c[2][a] = (3 * (p1 - p0) * id - 2 * v0 - v1) * id;
			q->c[3][a] = (2 * (p0 - p1) * id + v0 + v1) * (id * id);
			q->end[a] = p1;
		}
		memcpy(pos, k[i].position, sizeof(pos));
		memcpy(vel, k[i].velocity, sizeof(vel));
		t = k[i].t;
	}
	int r = run(b, p, m, err);
	memcpy(b->cmd, pos, sizeof(pos));
	memcpy(b->vel, vel, sizeof(vel));
	*seconds = t;
	return r;
}

void mock_bench_read_position(struct mock_bench *b, double m[3])
{
	hold(b, MOCK_READ_S);
	encoders(b, b->x, b->t, m);
}

void mock_bench_true_position(struct mock_bench *b, double t, double c[3])
{
	if (t > b->t)
		hold(b, t - b->t);
	cartesian(b, b->x, b->t, c);
}

static bool at_rest(const struct mock_bench *b)
{
	return b->vel[0] == 0 && b->vel[1] == 0 && b->vel[2] == 0;
}

int mock_bench_take_triggers(struct mock_bench *b, size_t n, struct mock_trigger *out,
			     struct asph_error *err)
{
	if (n > b->trig_n)
		return asph_error_set(err, -EPROTO,
				      "%zu readings asked for, the probe was triggered %zu times",
				      n, b->trig_n);
	for (size_t i = 0; i < n; i++) {
		struct mock_trigger *tr = &b->trig[b->trig_head + i];
		if (tr->sampled)
			continue;
		if (!at_rest(b))
			return asph_error_set(err, -EPROTO,
					      "reading asked for before the probe sampled it (%.6g ms after its trigger, the stage still moving)",
					      b->pp.latency * 1e3);
		/* the stage waits at rest for the sample */
		hold(b, tr->sample.t - b->t);
	}
	memcpy(out, b->trig + b->trig_head, n * sizeof(*out));
	b->trig_head += n;
	b->trig_n -= n;
	if (b->trig_unsampled < b->trig_head)
		b->trig_unsampled = b->trig_head;
	if (b->trig_n == 0)
		b->trig_head = b->trig_unsampled = 0;
	return 0;
}

void mock_bench_trigger_now(struct mock_bench *b, struct mock_trigger *out)
{
	out->t = b->t;
	encoders(b, b->x, b->t, out->latched);
	hold(b, b->pp.latency);
	out->sample.t = b->t;
	cartesian(b, b->x, b->t, out->sample.pos);
	out->sampled = true;
	/* the reading takes the probe's period */
	if (b->pp.rate > 0 && 1 / b->pp.rate > b->pp.latency)
		hold(b, 1 / b->pp.rate - b->pp.latency);
	b->last_trigger = out->t;
}

size_t mock_bench_trace(struct mock_bench *b, struct asph_position_sample *out, size_t max)
{
	size_t n = b->trace_n < max ? b->trace_n : max;

	if (n == 0)
		return 0;
	memcpy(out, b->trace + b->trace_head, n * sizeof(*out));
	b->trace_head += n;
	b->trace_n -= n;
	if (b->trace_n == 0)
		b->trace_head = 0;
	return n;
}
