/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The mock instrument on its own: its readings against independent
 * geometry (the pose inverted, closest points), its noise statistics, its
 * stage limits, timeouts and stop, its fault injection. */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <cmocka.h>

#include "asph/fit.h"
#include "asph-driver/instrument.h"
#include "asph/prescription.h"
#include "asph/zernike.h"

struct mock {
	struct asph_registry *reg;
	struct asph_config *cfg;
	struct asph_instrument *inst;
};

static void mock_open(struct mock *m, const char *spec)
{
	struct asph_error err;

	assert_int_equal(asph_registry_new(&m->reg, NULL), 0);
	if (asph_instrument_spec_parse(m->reg, spec, &m->cfg, &err) < 0 ||
	    asph_instrument_open(&m->cfg->instruments[0], 1000, &m->inst, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
}

static void mock_close(struct mock *m)
{
	asph_instrument_close(m->inst);
	asph_config_free(m->cfg);
	asph_registry_free(m->reg);
}

static struct asph_surface *strong(void)
{
	struct asph_prescription p;
	struct asph_surface *s;
	assert_int_equal(asph_prescription_preset("strong", &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/* Moves the stage to (x, y, zs), homing it first when it is not. */
static void move(struct mock *m, double x, double y, double zs)
{
	const double t[3] = { x, y, zs };
	struct asph_stage_status st;
	struct asph_error err;
	const struct asph_stage_ops *ops = m->inst->stage_driver->stage;

	assert_int_equal(ops->status(m->inst->stage, &st, 100, NULL), 0);
	if (!st.homed)
		assert_int_equal(ops->home(m->inst->stage, 100, NULL), 0);
	if (ops->move_to(m->inst->stage, t, 100, &err) < 0)
		fail_msg("move: %s", err.message);
}

/* The measured point with the stage at machine (x, y), z = zs: the probe on
 * the mock stage reads where the stage is. */
static void read_at(struct mock *m, double x, double y, double zs, uint64_t index,
		    double p[3])
{
	struct asph_probe_context ctx = { .plan_index = index, .xyz = { x, y, zs } };
	struct asph_reading rd;
	struct asph_error err;

	move(m, x, y, zs);
	if (m->inst->probe_driver->probe->read(m->inst->probe, &ctx, &rd, 100, &err) < 0)
		fail_msg("read: %s", err.message);
	assert_false(rd.flags & ASPH_READING_OUT_OF_RANGE);
	p[0] = x;
	p[1] = y;
	p[2] = zs + rd.value;
}

/* High-entropy positions over most of the 40 mm aperture. */
static void position(int i, double *x, double *y)
{
	double r = 17.3 * sqrt((i + 0.37) / 40.0), t = 2.39996322972865332 * i + 0.11;
	*x = r * cos(t);
	*y = r * sin(t);
}

static void test_optical_pose(void **state)
{
	struct asph_surface *s = strong();
	struct asph_pose pose = { .t = { 0.0413, -0.0271, 0.0093 }, .rx = 287.1e-6, .ry = -163.9e-6 };
	struct mock m;

	mock_open(&m, "mock:time_factor=0,shift_x=0.0413,shift_y=-0.0271,shift_z=0.0093,"
		      "tilt_x=287.1,tilt_y=-163.9,range=20");
	for (int i = 0; i < 40; i++) {
		double x, y, p[3], q[3];
		position(i, &x, &y);
		read_at(&m, x, y, asph_surface_sag(s, hypot(x, y)) - 2.0, (uint64_t)i, p);
		/* undo the pose: the point lies on the nominal surface */
		asph_pose_apply_inverse(&pose, p, q);
		double dz = q[2] - asph_surface_sag(s, hypot(q[0], q[1]));
		if (fabs(dz) > 1e-11)
			fail_msg("point %d: %.3g mm off the surface", i, dz);
	}
	mock_close(&m);
	asph_surface_free(s);
}

static void test_tactile_pose(void **state)
{
	struct asph_surface *s = strong();
	struct asph_pose pose = { .t = { -0.0187, 0.0329, -0.0061 }, .rx = -121.3e-6, .ry = 244.7e-6 };
	struct mock m;
	const double tip = 0.85;

	mock_open(&m, "mock:time_factor=0,probe=tactile,tip_radius=0.85,shift_x=-0.0187,"
		      "shift_y=0.0329,shift_z=-0.0061,tilt_x=-121.3,tilt_y=244.7,range=20");
	assert_int_equal(m.inst->probe_info.type, ASPH_PROBE_TACTILE);
	assert_true(m.inst->probe_info.tip_radius == tip);
	for (int i = 0; i < 40; i++) {
		double x, y, c[3], q[3];
		struct asph_closest cl;
		position(i, &x, &y);
		x *= 0.9, y *= 0.9;
		read_at(&m, x, y, asph_surface_sag(s, hypot(x, y)) - 3.0, (uint64_t)i, c);
		/* the ball's centre is one tip radius before the part, along its normal */
		asph_pose_apply_inverse(&pose, c, q);
		assert_int_equal(asph_fit_closest_point(s, q, &cl), 0);
		if (fabs(cl.distance + tip) > 1e-10)
			fail_msg("point %d: centre %.12f mm from the surface", i, cl.distance);
	}
	mock_close(&m);
	asph_surface_free(s);
}

static void test_form_error(void **state)
{
	struct asph_surface *s = strong();
	double a = asph_surface_aperture_radius(s), coef[9] = { 0 };
	struct mock m;

	coef[4] = 47.3;         /* Z5 */
	coef[8] = -28.9;        /* Z9 */
	mock_open(&m, "mock:time_factor=0,form=5:47.3;9:-28.9,range=20");
	for (int i = 0; i < 40; i++) {
		double x, y, p[3];
		struct asph_closest cl;
		position(i, &x, &y);
		read_at(&m, x, y, asph_surface_sag(s, hypot(x, y)) - 2.0, (uint64_t)i, p);
		/* normal distance from the nominal surface = the form error at
		 * the foot (to second order in the error) */
		assert_int_equal(asph_fit_closest_point(s, p, &cl), 0);
		double e = asph_zernike_series(coef, 9, cl.foot_radius / a,
					       atan2(cl.foot[1], cl.foot[0]), NULL) * 1e-6;
		if (fabs(cl.distance - e) > 1e-12)
			fail_msg("point %d: %.6f nm, form error %.6f nm", i, cl.distance * 1e6, e * 1e6);
	}
	mock_close(&m);
	asph_surface_free(s);
}

static void test_noise(void **state)
{
	struct asph_surface *s = strong();
	struct mock m;
	const int n = 4000;
	double sum = 0, sum2 = 0, first = 0;

	mock_open(&m, "mock:time_factor=0,noise=13.7,seed=8081");
	for (int i = 0; i < n; i++) {
		double p[3];
		read_at(&m, 3.1, -4.7, asph_surface_sag(s, hypot(3.1, 4.7)) - 2.0, (uint64_t)i, p);
		double d = (p[2] - asph_surface_sag(s, hypot(3.1, 4.7))) * 1e6;
		if (i == 17)
			first = d;
		sum += d;
		sum2 += d * d;
	}
	double mean = sum / n, sd = sqrt(sum2 / n - mean * mean);
	/* 4000 draws: the mean within 4 standard errors, the deviation within 5 % */
	assert_true(fabs(mean) < 4 * 13.7 / sqrt(n));
	assert_true(fabs(sd / 13.7 - 1) < 0.05);
	/* the same plan point gets the same noise */
	double p[3];
	read_at(&m, 3.1, -4.7, asph_surface_sag(s, hypot(3.1, 4.7)) - 2.0, 17, p);
	assert_true((p[2] - asph_surface_sag(s, hypot(3.1, 4.7))) * 1e6 == first);
	mock_close(&m);
	asph_surface_free(s);
}

static void test_stage(void **state)
{
	struct mock m;
	struct asph_error err;
	double t[3] = { 12.5, -7.25, 3.125 }, pos[3];

	mock_open(&m, "mock:time_factor=0,travel_xy=20,travel_z=10");
	const struct asph_stage_ops *st = m.inst->stage_driver->stage;
	assert_int_equal(m.inst->stage_info.kinematics, ASPH_KINEMATICS_XYZ);
	assert_true(m.inst->stage_info.axes[0].max == 20 && m.inst->stage_info.axes[2].min == -10);
	assert_int_equal(st->move_to(m.inst->stage, t, 100, &err), -EPROTO);
	assert_non_null(strstr(err.message, "not homed"));
	assert_int_equal(st->home(m.inst->stage, 100, NULL), 0);
	assert_int_equal(st->move_to(m.inst->stage, t, 100, NULL), 0);
	assert_int_equal(st->position(m.inst->stage, pos, 100, NULL), 0);
	assert_memory_equal(pos, t, sizeof(t));
	t[2] = 10.5;
	assert_int_equal(st->move_to(m.inst->stage, t, 100, &err), -ERANGE);
	assert_non_null(strstr(err.message, "axis z"));
	struct asph_stage_status ss;
	assert_int_equal(st->status(m.inst->stage, &ss, 100, NULL), 0);
	assert_true(ss.homed && ss.position[2] == 3.125);
	mock_close(&m);
}

static void *stop_later(void *data)
{
	struct mock *m = data;
	struct timespec ts = { 0, 60000000 };
	nanosleep(&ts, NULL);
	m->inst->stage_driver->stage->stop(m->inst->stage, NULL);
	return NULL;
}

static void test_stage_timing(void **state)
{
	struct mock m;
	struct asph_error err;
	double t[3] = { 30, 0, 0 };
	pthread_t th;

	/* 30 mm at 1 mm/s: 30 s, far past a 50 ms timeout */
	mock_open(&m, "mock:speed=1");
	const struct asph_stage_ops *st = m.inst->stage_driver->stage;
	assert_int_equal(st->home(m.inst->stage, 100, NULL), 0);
	assert_int_equal(st->move_to(m.inst->stage, t, 50, &err), -ETIMEDOUT);
	/* stopped from another thread during a long move */
	assert_int_equal(pthread_create(&th, NULL, stop_later, &m), 0);
	assert_int_equal(st->move_to(m.inst->stage, t, 600000, &err), -ECANCELED);
	pthread_join(th, NULL);
	mock_close(&m);
}

static void test_faults(void **state)
{
	struct asph_surface *s = strong();
	struct mock m;
	struct asph_probe_context ctx = { .xyz = { 1.5, 2.5, 0 } };
	struct asph_reading rd;
	struct asph_error err;

	ctx.xyz[2] = asph_surface_sag(s, hypot(1.5, 2.5)) - 2.0;
	mock_open(&m, "mock:time_factor=0,fail_after=3,out_of_range_at=2");
	move(&m, 1.5, 2.5, ctx.xyz[2]);
	const struct asph_probe_ops *pr = m.inst->probe_driver->probe;
	assert_int_equal(pr->read(m.inst->probe, &ctx, &rd, 100, NULL), 0);
	assert_false(rd.flags & ASPH_READING_OUT_OF_RANGE);
	assert_int_equal(pr->read(m.inst->probe, &ctx, &rd, 100, NULL), 0);
	assert_true(rd.flags & ASPH_READING_OUT_OF_RANGE);
	assert_int_equal(pr->read(m.inst->probe, &ctx, &rd, 100, NULL), 0);
	assert_int_equal(pr->read(m.inst->probe, &ctx, &rd, 100, &err), -ENODEV);
	assert_non_null(strstr(err.message, "disconnected after 3"));
	mock_close(&m);

	/* a surface outside the range is flagged, not clipped */
	mock_open(&m, "mock:time_factor=0,range=0.2");
	ctx.xyz[2] -= 0.15;
	move(&m, 1.5, 2.5, ctx.xyz[2]);
	assert_int_equal(m.inst->probe_driver->probe->read(m.inst->probe, &ctx, &rd, 100, NULL), 0);
	assert_true(rd.flags & ASPH_READING_OUT_OF_RANGE);
	mock_close(&m);

	/* a form error that does not parse is refused at open, naming it */
	assert_int_equal(asph_registry_new(&m.reg, NULL), 0);
	assert_int_equal(asph_instrument_spec_parse(m.reg, "mock:form=5:4x", &m.cfg, NULL), 0);
	assert_int_equal(asph_instrument_open(&m.cfg->instruments[0], 100, &m.inst, &err), -EINVAL);
	assert_non_null(strstr(err.message, "form"));
	asph_config_free(m.cfg);
	asph_registry_free(m.reg);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_optical_pose),
		cmocka_unit_test(test_tactile_pose),
		cmocka_unit_test(test_form_error),
		cmocka_unit_test(test_noise),
		cmocka_unit_test(test_stage),
		cmocka_unit_test(test_stage_timing),
		cmocka_unit_test(test_faults),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
