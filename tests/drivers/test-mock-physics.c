/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The mock's physics, each effect on its own against its closed form: the
 * servo's following error against speed and acceleration, the probe's
 * latency against the lateral offset of what it samples, the drift against
 * measurements of the vertex over time, the slope bias against the slope,
 * the encoders' resolution and scale, the guides' straightness, the
 * dropouts' probability, the settling after a move.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph-driver/instrument.h"
#include "asph/prescription.h"

struct vi {
	struct asph_registry *reg;
	struct asph_config *cfg;
	struct asph_instrument *inst;
	const struct asph_stage_ops *st;
};

static void vi_open(struct vi *m, const char *spec)
{
	struct asph_error err;

	assert_int_equal(asph_registry_new(&m->reg, NULL), 0);
	if (asph_instrument_spec_parse(m->reg, spec, &m->cfg, &err) < 0 ||
	    asph_instrument_open(&m->cfg->instruments[0], 1000, &m->inst, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
	m->st = &m->inst->stage_ops;
	assert_true(m->inst->attached);
	assert_int_equal(m->st->home(m->inst->stage, 100, NULL), 0);
}

static void vi_close(struct vi *m)
{
	asph_instrument_close(m->inst);
	asph_config_free(m->cfg);
	asph_registry_free(m->reg);
}

static void move(struct vi *m, double x, double y, double z)
{
	const double t[3] = { x, y, z };
	struct asph_error err;

	if (m->st->move_to(m->inst->stage, t, 100, &err) < 0)
		fail_msg("move: %s", err.message);
}

/* The part the mock measures by default. */
static struct asph_surface *strong;

static int strong_setup(void **state)
{
	struct asph_prescription p;

	if (asph_prescription_preset("strong", &p) < 0 || asph_surface_alloc(&p, &strong, NULL) < 0)
		return -1;
	return 0;
}

static int strong_teardown(void **state)
{
	asph_surface_free(strong);
	return 0;
}

static double sag(double r)
{
	return asph_surface_sag(strong, r);
}

/*
 * A sweep along x from rest at x0: a ramp knot, then n knots at speed v,
 * dt apart, each a trigger, at height z; the encoders latched at them in
 * lat (n), the readings' values in val (n, may be NULL).
 */
static void constant_sweep(struct vi *m, double x0, double z, double v, double dt, size_t n,
			   double *lat, double *val)
{
	struct asph_pvt k[64];
	struct asph_position_sample tr[64];
	struct asph_probe_context ctx[64];
	struct asph_reading rd[64];
	struct asph_error err;
	size_t got;

	assert_true(n + 3 <= 64);
	move(m, x0, 0, z);
	memset(k, 0, sizeof(k));
	/* from rest to speed over 2 dt: the Hermite from (x0, 0) to (x0 + v dt, v) */
	k[0].t = 2 * dt;
	k[0].position[0] = x0 + v * dt;
	k[0].position[2] = z;
	k[0].velocity[0] = v;
	for (size_t i = 1; i <= n; i++) {
		k[i] = k[0];
		k[i].t = k[i - 1].t + dt;
		k[i].position[0] = k[i - 1].position[0] + v * dt;
		k[i].trigger = 1;
	}
	/* on at speed past the last trigger's sample, and to rest */
	k[n + 1] = k[n];
	k[n + 1].t = k[n].t + dt;
	k[n + 1].position[0] += v * dt;
	k[n + 1].trigger = 0;
	k[n + 2] = k[n + 1];
	k[n + 2].t = k[n + 1].t + 2 * dt;
	k[n + 2].position[0] += v * dt;
	k[n + 2].velocity[0] = 0;
	if (m->st->sweep_pvt(m->inst->stage, k, n + 3, 1000, &err) < 0)
		fail_msg("sweep: %s", err.message);
	assert_int_equal(m->st->sweep_trace(m->inst->stage, tr, 64, &got, 100, NULL), 0);
	assert_int_equal(got, n);
	for (size_t i = 0; i < n; i++) {
		assert_int_equal(tr[i].source, ASPH_POSITION_LATCHED);
		lat[i] = tr[i].position[0];
	}
	memset(ctx, 0, sizeof(ctx));
	for (size_t i = 0; i < n; i++)
		ctx[i].plan_index = i;
	if (asph_instrument_stream(m->inst, ctx, n, rd, &got, 100, &err) < 0)
		fail_msg("stream: %s", err.message);
	for (size_t i = 0; val && i < n; i++)
		val[i] = rd[i].value;
}

/* At speed v the axis lags its command by v / (2 pi f). */
static void test_following_error(void **state)
{
	const double f = 211.3, w = 2 * M_PI * f;
	const double speeds[] = { 3.7, 13.9, 27.1 };
	struct vi m;
	char spec[128];

	snprintf(spec, sizeof(spec), "mock:time_factor=0,servo_bandwidth=%g", f);
	vi_open(&m, spec);
	for (size_t s = 0; s < 3; s++) {
		double v = speeds[s], lat[40], dt = 0.004;
		constant_sweep(&m, -6, -3, v, dt, 40, lat, NULL);
		/* after the start's transient (e^(-w t) < 1e-15 past 30 ms) */
		for (size_t i = 8; i < 40; i++) {
			double cmd = -6 + v * dt * (double)(i + 2);
			double lag = cmd - lat[i];
			if (fabs(lag - v / w) > 1e-12)
				fail_msg("%g mm/s, trigger %zu: lag %.15g mm, closed form %.15g", v, i, lag,
					 v / w);
		}
	}
	vi_close(&m);
}

/* Under a constant acceleration a the lag is v / w - a / w^2 (the first
 * order loop's response to a parabola). */
static void test_following_error_accelerating(void **state)
{
	const double f = 97.0, w = 2 * M_PI * f, a = 311.0;
	struct vi m;
	struct asph_pvt k[40];
	struct asph_position_sample tr[64];
	char spec[128];
	size_t got;

	snprintf(spec, sizeof(spec), "mock:time_factor=0,servo_bandwidth=%g", f);
	vi_open(&m, spec);
	move(&m, -10, 0, -3);
	memset(k, 0, sizeof(k));
	/* x = -10 + a t^2 / 2: knots every 5 ms with its speed a t */
	for (int i = 0; i < 40; i++) {
		double t = 0.005 * (i + 1);
		k[i].t = t;
		k[i].position[0] = -10 + a * t * t / 2;
		k[i].position[2] = -3;
		k[i].velocity[0] = a * t;
		k[i].trigger = 1;
	}
	assert_int_equal(m.st->sweep_pvt(m.inst->stage, k, 40, 1000, NULL), 0);
	assert_int_equal(m.st->sweep_trace(m.inst->stage, tr, 64, &got, 100, NULL), 0);
	assert_int_equal(got, 40);
	for (int i = 20; i < 40; i++) {
		double t = 0.005 * (i + 1), v = a * t;
		double lag = (-10 + a * t * t / 2) - tr[i].position[0];
		/* the transient from rest: (a / w^2) e^(-w t), below 1e-12 by then */
		if (fabs(lag - (v / w - a / (w * w))) > 1e-11)
			fail_msg("at %g s: lag %.15g mm, closed form %.15g", t, lag, v / w - a / (w * w));
	}
	/* the stage came to rest with its knots: a last one at rest */
	struct asph_pvt stop = k[39];
	stop.t = k[39].t + 0.02;
	stop.position[0] += a * 0.2 * 0.01;
	stop.velocity[0] = 0;
	stop.trigger = 0;
	assert_int_equal(m.st->sweep_pvt(m.inst->stage, &stop, 1, 1000, NULL), 0);
	vi_close(&m);
}

/* A probe with latency L samples v L further along than its trigger. */
static void test_latency(void **state)
{
	const double L = 0.00073, v = 17.3, dt = 0.002, z = -2.5;
	double lat[30], val[30];
	struct vi m;
	char spec[160];

	snprintf(spec, sizeof(spec), "mock:time_factor=0,latency=%g,range=20", L);
	vi_open(&m, spec);
	constant_sweep(&m, 3.1, z, v, dt, 30, lat, val);
	for (size_t i = 0; i < 30; i++) {
		double sampled = lat[i] + v * L;
		double want = sag(fabs(sampled)) - z;
		if (fabs(val[i] - want) > 1e-12)
			fail_msg("trigger %zu: reading %.15g, the surface at x + v L %.15g (at x: %.15g)",
				 i, val[i], want, sag(fabs(lat[i])) - z);
	}
	/* the lateral offset is what a pairing without the latency misses:
	 * the slope times v L, here microns */
	assert_true(fabs(val[10] - (sag(fabs(lat[10])) - z)) > 1e-4);
	vi_close(&m);
}

/* The vertex read again over time: the drift's closed form, r (t + 60 s
 * sin(2 pi t / 1200 s)) along z, in nm per minute. */
static void test_drift(void **state)
{
	const double r = 23.7; /* nm/min */
	struct vi m;
	struct asph_probe_context ctx = { 0 };
	struct asph_reading rd;
	char spec[128];
	uint64_t t0;

	snprintf(spec, sizeof(spec), "mock:time_factor=0,drift_z=%g,rate=0.01", r);
	vi_open(&m, spec);
	move(&m, 0, 0, -2);
	ctx.kind = ASPH_MEASURE_REFERENCE;
	assert_int_equal(m.st->clock(m.inst->stage, &t0), 0);
	for (int k = 0; k < 12; k++) {
		/* each reading takes 1 / rate = 100 s of the simulated clock */
		uint64_t t;
		assert_int_equal(m.st->clock(m.inst->stage, &t), 0);
		ctx.attempt = (uint32_t)k;
		assert_int_equal(asph_instrument_read(m.inst, &ctx, &rd, 100, NULL), 0);
		double ts = (double)t * 1e-9;
		double want = r * 1e-6 / 60 * (ts + 60 * sin(2 * M_PI * ts / 1200));
		if (fabs(rd.value - 2 - want) > 1e-13)
			fail_msg("at %g s: %.6g nm, closed form %.6g nm", ts, (rd.value - 2) * 1e6,
				 want * 1e6);
	}
	vi_close(&m);
}

/* The slope bias: B theta^2, theta the surface's slope in degrees. */
static void test_slope_bias(void **state)
{
	const double B = 3.9; /* nm / deg^2 */
	struct vi m;
	struct asph_reading rd;
	char spec[128];

	snprintf(spec, sizeof(spec), "mock:time_factor=0,slope_bias=%g,range=20", B);
	vi_open(&m, spec);
	for (int i = 0; i < 9; i++) {
		double rr = 0.7 + 2.1 * i, h = 1e-6;
		struct asph_probe_context ctx = { .plan_index = (uint64_t)i };
		move(&m, rr, 0, sag(rr) - 2);
		assert_int_equal(asph_instrument_read(m.inst, &ctx, &rd, 100, NULL), 0);
		double slope = atan((sag(rr + h) - sag(rr - h)) / (2 * h)) * 180 / M_PI;
		double bias = (rd.value - 2) * 1e6;
		if (fabs(bias - B * slope * slope) > 1e-4)
			fail_msg("slope %.4f deg: bias %.6f nm, closed form %.6f nm", slope, bias,
				 B * slope * slope);
	}
	vi_close(&m);
}

/* Encoders: steps of the resolution, the scale's error proportional to
 * the position; the guides' bow in z unseen by them. */
static void test_encoders_and_guides(void **state)
{
	struct vi m;
	double p[3];
	const double res = 0.000137, ppm = 41.0, bow = 3.3, travel = 50;
	char spec[160];

	snprintf(spec, sizeof(spec), "mock:time_factor=0,encoder_resolution=%g,scale_error=%g,"
		 "straightness=%g,range=20", res, ppm, bow);
	vi_open(&m, spec);
	move(&m, 17.3, -9.1, -2.5);
	assert_int_equal(m.st->position(m.inst->stage, p, 100, NULL), 0);
	const double want[3] = { 17.3, -9.1, -2.5 };
	for (int k = 0; k < 3; k++) {
		double e = res * nearbyint(want[k] * (1 + ppm * 1e-6) / res);
		assert_true(fabs(p[k] - e) < 1e-12);
	}
	/* the probe reads from where the carriage truly is: z higher by the
	 * bow, (S / 2) (2 - (x / T)^2 - (y / T)^2) */
	struct asph_probe_context ctx = { 0 };
	struct asph_reading rd;
	assert_int_equal(asph_instrument_read(m.inst, &ctx, &rd, 100, NULL), 0);
	double up = bow * 1e-3 / 2 * (2 - pow(17.3 / travel, 2) - pow(9.1 / travel, 2));
	double surf = sag(hypot(17.3, 9.1));
	assert_true(fabs(rd.value - (surf - (-2.5 + up))) < 1e-12);
	vi_close(&m);
}

/* Dropouts: at the steepest readable slope with the probability given,
 * falling as the sixth power of slope / max_slope. */
static void test_dropout(void **state)
{
	struct vi m;
	struct asph_reading rd;
	const double p = 0.37, max_deg = 30;
	char spec[160];

	snprintf(spec, sizeof(spec), "mock:time_factor=0,dropout=%g,max_slope=%g,range=20", p,
		 max_deg);
	vi_open(&m, spec);
	/* a radius where the slope is 24 degrees, (24/30)^6 of p (the slope
	 * of "strong" rises to 25.7 degrees at 16 mm) */
	double lo = 0, hi = 12;
	for (int i = 0; i < 60; i++) {
		double mid = (lo + hi) / 2, h = 1e-6;
		double s = atan((sag(mid + h) - sag(mid - h)) / (2 * h)) * 180 / M_PI;
		if (s < 24)
			lo = mid;
		else
			hi = mid;
	}
	move(&m, lo, 0, sag(lo) - 2);
	int n = 4000, bad = 0, both = 0;
	for (int i = 0; i < n; i++) {
		struct asph_probe_context ctx = { .plan_index = (uint64_t)i };
		assert_int_equal(asph_instrument_read(m.inst, &ctx, &rd, 100, NULL), 0);
		bool first = rd.flags & ASPH_READING_INVALID;
		if (first) {
			bad++;
			assert_true(isnan(rd.value));
		}
		/* the same measurement again: the same outcome */
		struct asph_reading again;
		assert_int_equal(asph_instrument_read(m.inst, &ctx, &again, 100, NULL), 0);
		assert_int_equal(rd.flags & ASPH_READING_INVALID, again.flags & ASPH_READING_INVALID);
		/* its next attempt: an outcome of its own */
		ctx.attempt = 1;
		assert_int_equal(asph_instrument_read(m.inst, &ctx, &again, 100, NULL), 0);
		if (first && (again.flags & ASPH_READING_INVALID))
			both++;
	}
	double q = p * pow(24.0 / max_deg, 6), sd = sqrt(q * (1 - q) / n);
	if (fabs((double)bad / n - q) > 4 * sd)
		fail_msg("%d of %d invalid, probability %.4f", bad, n, q);
	double q2 = q * q, sd2 = sqrt(q2 * (1 - q2) / n);
	if (fabs((double)both / n - q2) > 4 * sd2)
		fail_msg("%d of %d invalid twice, probability %.4f", both, n, q2);
	vi_close(&m);
}

/* After a move the stage rings about its target and is within 1 nm by
 * settle_time; read back, the ringing shows. */
static void test_settling(void **state)
{
	struct vi m;
	double p[3];
	const double settle = 0.03;
	char spec[128];

	snprintf(spec, sizeof(spec), "mock:time_factor=0,settle_time=%g", settle);
	vi_open(&m, spec);
	move(&m, 0, 0, 0);
	move(&m, 12, 0, 0);
	/* read-backs 0.5 ms apart: the first ones off, then in */
	double first = -1, last = 0;
	for (int i = 0; i < 80; i++) {
		assert_int_equal(m.st->position(m.inst->stage, p, 100, NULL), 0);
		double off = fabs(p[0] - 12);
		if (i == 0)
			first = off;
		if ((i + 1) * 0.0005 >= settle)
			last = fmax(last, off);
	}
	assert_true(first > 1e-5);
	assert_true(last <= 1e-6 * 1.0001);
	vi_close(&m);
}

/* clock_align (driver ABI 1.2): the clock jumps, every state keeps its
 * age. Two benches make the same move; one then has its clock set 7.25 s
 * on. Their read-backs through the ringing agree to the rounding of times
 * 7 s apart (1e-12 mm, the ringing's amplitude being 1e-3 mm), its clock
 * goes on from the time set, and the drift follows that clock (closed
 * form as in test_drift). */
static void test_clock_align(void **state)
{
	const double r = 23.7, shift = 7.25;
	const char *spec = "mock:time_factor=0,settle_time=0.03,servo_bandwidth=80,drift_z=23.7,rate=0.01";
	struct vi a, b;
	struct asph_probe_context ctx = { .kind = ASPH_MEASURE_REFERENCE };
	struct asph_reading ra, rb;
	uint64_t ta, tb, t;

	vi_open(&a, spec);
	vi_open(&b, spec);
	move(&a, 0, 0, -2);
	move(&a, 12, 3, -2);
	move(&b, 0, 0, -2);
	move(&b, 12, 3, -2);
	assert_non_null(b.st->clock_align);
	assert_int_equal(a.st->clock(a.inst->stage, &ta), 0);
	assert_int_equal(b.st->clock(b.inst->stage, &tb), 0);
	assert_int_equal(ta, tb);
	uint64_t set = tb + (uint64_t)llround(shift * 1e9);
	assert_int_equal(b.st->clock_align(b.inst->stage, set, NULL), 0);
	assert_int_equal(b.st->clock(b.inst->stage, &t), 0);
	assert_int_equal(t, set);
	double first = 0;
	for (int i = 0; i < 40; i++) {
		double pa[3], pb[3];
		assert_int_equal(a.st->position(a.inst->stage, pa, 100, NULL), 0);
		assert_int_equal(b.st->position(b.inst->stage, pb, 100, NULL), 0);
		for (int k = 0; k < 3; k++)
			if (fabs(pa[k] - pb[k]) > 1e-12)
				fail_msg("read-back %d, axis %d: %.17g and %.17g", i, k, pa[k], pb[k]);
		if (i == 0)
			first = fabs(pa[0] - 12);
	}
	/* the ringing and the servo's lag were there to compare */
	assert_true(first > 1e-5);
	assert_int_equal(b.st->clock(b.inst->stage, &t), 0);
	assert_int_equal(a.st->clock(a.inst->stage, &ta), 0);
	assert_true(fabs((double)(t - ta) * 1e-9 - shift) < 1e-6);
	/* a reading: the drift at the clock set, not at the bench's age */
	assert_int_equal(asph_instrument_read(a.inst, &ctx, &ra, 100, NULL), 0);
	assert_int_equal(asph_instrument_read(b.inst, &ctx, &rb, 100, NULL), 0);
	double sa = (double)ra.t_ns * 1e-9, sb = (double)rb.t_ns * 1e-9;
	double da = r * 1e-6 / 60 * (sa + 60 * sin(2 * M_PI * sa / 1200));
	double db = r * 1e-6 / 60 * (sb + 60 * sin(2 * M_PI * sb / 1200));
	assert_true(fabs(sb - sa - shift) < 1e-6);
	assert_true(fabs((rb.value - ra.value) - (db - da)) < 1e-13);
	vi_close(&a);
	vi_close(&b);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_following_error),
		cmocka_unit_test(test_following_error_accelerating),
		cmocka_unit_test(test_latency),
		cmocka_unit_test(test_drift),
		cmocka_unit_test(test_slope_bias),
		cmocka_unit_test(test_encoders_and_guides),
		cmocka_unit_test(test_dropout),
		cmocka_unit_test(test_settling),
		cmocka_unit_test(test_clock_align),
	};
	return cmocka_run_group_tests(tests, strong_setup, strong_teardown);
}
