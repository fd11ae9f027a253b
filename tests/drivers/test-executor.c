/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The executor with the mock and replay instruments: faults, limits,
 * pause/resume/abort from another thread, characterization of what the
 * mock measured, resumption and bit-identical replay. */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>
#include <jansson.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph/motion.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "scan-fixture.h"

static int setup(void **state)
{
	struct scan_fixture *e = calloc(1, sizeof(*e));

	assert_non_null(e);
	scan_fixture_init(e, 700, "executor");
	*state = e;
	return 0;
}

static int teardown(void **state)
{
	scan_fixture_fini(*state);
	free(*state);
	return 0;
}

static struct asph_scanfile_writer *new_writer(const char *path)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						  "{\"name\":\"mock\"}", NULL };
	struct asph_scanfile_writer *w;
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, NULL), 0);
	return w;
}

/* Runs the whole plan (from start) with the instrument of spec into path. */
static int scan_with(struct scan_fixture *e, const struct asph_registry *reg, const char *spec,
		     const char *path, const struct asph_scan_options *so,
		     struct asph_error *err)
{
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_error oerr;

	if (asph_instrument_spec_parse(reg, spec, &c, &oerr) < 0)
		fail_msg("%s: %s", spec, oerr.message);
	if (asph_instrument_open(&c->instruments[0], 1000, &inst, &oerr) < 0)
		fail_msg("%s: %s", spec, oerr.message);
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, so, &sc, NULL), 0);
	int r = asph_scan_run(sc, new_writer(path), err);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
	return r;
}

/* ------------------------------------------------------------ faults */

struct fault_case {
	const char *spec;
	int code;
	size_t n_points;        /* recorded */
	const char *words;
};

static void test_faults(void **state)
{
	static const struct fault_case cases[] = {
		/* faults by the number of the reading: no drift references */
		{ "mock:time_factor=0,drift_interval=off,fail_after=233", -ENODEV, 233,
		  "disconnected after 233" },
		{ "mock:time_factor=0,drift_interval=off,timeout_at=171", -ETIMEDOUT, 170,
		  "did not answer reading 171" },
		{ "mock:time_factor=0,drift_interval=off,out_of_range_at=97", -ERANGE, 97, "out of range" },
		{ "mock:time_factor=0,drift_interval=off,fail_after=233,stream=false", -ENODEV, 233,
		  "plan point 233: probe" },
		{ "mock:time_factor=0,drift_interval=off,timeout_at=171,probe=tactile", -ETIMEDOUT, 170,
		  "plan point 170" },
		/* the first reading is the vertex's, as a drift reference */
		{ "mock:time_factor=0,fail_after=233", -ENODEV, 232, "disconnected after 233" },
		{ "mock:time_factor=0,timeout_at=1", -ETIMEDOUT, 0, "drift reference 0 (0, 0)" },
		/* the bench of a good instrument fails the same way */
		{ "mock:time_factor=0,bench=realistic,drift_interval=off,fail_after=233", -ENODEV, 233,
		  "disconnected after 233" },
		{ "mock:time_factor=0,bench=realistic,drift_interval=off,out_of_range_at=97", -ERANGE, 97,
		  "out of range" },
		{ "mock:time_factor=0,bench=realistic,drift_interval=off,timeout_at=171,stream=false",
		  -ETIMEDOUT, 170, "plan point 170" },
	};
	struct scan_fixture *e = *state;
	char path[128];

	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
		struct asph_error err;
		const struct fault_case *fc = &cases[i];

		asph_error_clear(&err);
		int r = scan_with(e, e->reg, fc->spec, new_path(e, path, sizeof(path)), &so, &err);
		if (r != fc->code || !strstr(err.message, fc->words))
			fail_msg("%s: %d %s", fc->spec, r, err.message);
		struct asph_scanfile *s = read_scan(path);
		assert_int_equal(s->n, fc->n_points);
		assert_true(s->report.ended);
		assert_int_equal(s->report.outcome, ASPH_SCANFILE_FAILED);
		assert_non_null(strstr(s->report.reason, fc->words));
		for (size_t k = 0; k < s->n; k++)
			assert_int_equal(s->points[k].plan_index, k);
		if (fc->code == -ERANGE)
			assert_true(s->points[s->n - 1].flags & ASPH_SCANFILE_POINT_OUT_OF_RANGE);
		asph_scanfile_free(s);
	}
}

static void test_skip_out_of_range(void **state)
{
	struct scan_fixture *e = *state;
	struct asph_scan_options so = { .flags = ASPH_SCAN_SKIP_OUT_OF_RANGE };
	char path[128];

	assert_int_equal(scan_with(e, e->reg, "mock:time_factor=0,drift_interval=off,out_of_range_at=55",
				   new_path(e, path, sizeof(path)), &so, NULL), 0);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->n, e->plan->n);
	assert_int_equal(s->report.outcome, ASPH_SCANFILE_COMPLETED);
	assert_true(s->points[54].flags & ASPH_SCANFILE_POINT_OUT_OF_RANGE);
	assert_false(s->points[55].flags & ASPH_SCANFILE_POINT_OUT_OF_RANGE);
	asph_scanfile_free(s);
}

/* A stage whose move away from the part after the 37th reading fails:
 * that point is in the file, and counted done. */
static const struct asph_probe_ops *mock_probe;
static const struct asph_stage_ops *retreat_stage;
static atomic_int n_readings, fail_at_reading;

static int counting_read(struct asph_device *d, const struct asph_probe_context *ctx,
			 struct asph_reading *out, unsigned t, struct asph_error *err)
{
	int r = mock_probe->read(d, ctx, out, t, err);
	if (r == 0)
		atomic_fetch_add(&n_readings, 1);
	return r;
}

static int failing_retreat(struct asph_device *d, const double *p, unsigned t,
			   struct asph_error *err)
{
	if (atomic_load(&n_readings) == atomic_load(&fail_at_reading)) {
		atomic_store(&fail_at_reading, -1);
		return asph_error_set(err, -EIO, "the drive bus failed");
	}
	return retreat_stage->move_to(d, p, t, err);
}

static void last_progress(const struct asph_scan_progress *p, void *data)
{
	*(struct asph_scan_progress *)data = *p;
}

static void test_failed_retreat(void **state)
{
	struct scan_fixture *e = *state;
	const struct asph_driver *mock = asph_registry_find(e->reg, "mock");
	static struct asph_stage_ops stage_ops;
	static struct asph_probe_ops probe_ops;
	static struct asph_driver spy;
	struct asph_scan_progress last = { 0 };
	struct asph_scan_options so = { .progress = last_progress, .progress_data = &last };
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_error err;
	char path[128];

	retreat_stage = mock->stage;
	mock_probe = mock->probe;
	stage_ops = *mock->stage;
	stage_ops.move_to = failing_retreat;
	probe_ops = *mock->probe;
	probe_ops.read = counting_read;
	spy = *mock;
	spy.stage = &stage_ops;
	spy.probe = &probe_ops;
	atomic_store(&n_readings, 0);
	atomic_store(&fail_at_reading, 37);
	assert_int_equal(asph_instrument_spec_parse(e->reg, "mock:time_factor=0,stream=false,"
						    "drift_interval=off", &c, NULL), 0);
	c->instruments[0].stage_driver = &spy;
	c->instruments[0].probe_driver = &spy;
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, NULL), 0);
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, &so, &sc, NULL), 0);
	int r = asph_scan_run(sc, new_writer(new_path(e, path, sizeof(path))), &err);
	if (r != -EIO || !strstr(err.message, "plan point 36: stage: the drive bus failed"))
		fail_msg("%d %s", r, err.message);
	assert_int_equal(last.state, ASPH_SCAN_FAILED);
	assert_int_equal(last.done, 37);
	assert_int_equal(last.measured, 37);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->n, 37);
	assert_int_equal(s->points[36].plan_index, 36);
	asph_scanfile_free(s);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
}

/* ------------------------------------------------ limits, no motion */

/* A stage that counts motion and passes everything to the mock's. */
static atomic_int n_motions;
static const struct asph_stage_ops *mock_stage;

static int spy_home(struct asph_device *d, unsigned t, struct asph_error *err)
{
	atomic_fetch_add(&n_motions, 1);
	return mock_stage->home(d, t, err);
}

static int spy_move(struct asph_device *d, const double *p, unsigned t, struct asph_error *err)
{
	atomic_fetch_add(&n_motions, 1);
	return mock_stage->move_to(d, p, t, err);
}

static int spy_sweep(struct asph_device *d, const double *p, size_t n, unsigned t,
		     struct asph_error *err)
{
	atomic_fetch_add(&n_motions, 1);
	return mock_stage->sweep(d, p, n, t, err);
}

static int spy_sweep_pvt(struct asph_device *d, const struct asph_pvt *k, size_t n, unsigned t,
			 struct asph_error *err)
{
	atomic_fetch_add(&n_motions, 1);
	return mock_stage->sweep_pvt(d, k, n, t, err);
}

static void test_limits_before_motion(void **state)
{
	struct scan_fixture *e = *state;
	const struct asph_driver *mock = asph_registry_find(e->reg, "mock");
	static struct asph_stage_ops spy_ops;
	static struct asph_driver spy;
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_error err;
	char path[128];
	static const char *const specs[] = {
		"mock:time_factor=0,travel_xy=12",         /* the strong lens is 40 mm across */
		"mock:time_factor=0,travel_z=4",           /* its sag at the edge is > 5 mm */
		"mock:time_factor=0,max_slope=20",         /* steeper than 20 deg near the edge */
		"mock:time_factor=0,kinematics=r-theta-z,travel_xy=15", /* r up to 20 mm */
	};

	mock_stage = mock->stage;
	spy_ops = *mock->stage;
	spy_ops.home = spy_home;
	spy_ops.move_to = spy_move;
	spy_ops.sweep = spy_sweep;
	spy_ops.sweep_pvt = spy_sweep_pvt;
	spy = *mock;
	spy.stage = &spy_ops;
	for (size_t i = 0; i < sizeof(specs) / sizeof(specs[0]); i++) {
		assert_int_equal(asph_instrument_spec_parse(e->reg, specs[i], &c, NULL), 0);
		c->instruments[0].stage_driver = &spy;
		assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, NULL), 0);
		assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, NULL, &sc, NULL), 0);
		atomic_store(&n_motions, 0);
		asph_error_clear(&err);
		int r = asph_scan_run(sc, new_writer(new_path(e, path, sizeof(path))), &err);
		if (r != -ERANGE)
			fail_msg("%s: %d %s", specs[i], r, err.message);
		assert_int_equal(atomic_load(&n_motions), 0);
		assert_non_null(strstr(err.message, "plan point"));
		struct asph_scanfile *s = read_scan(path);
		assert_int_equal(s->n, 0);
		assert_int_equal(s->report.outcome, ASPH_SCANFILE_FAILED);
		asph_scanfile_free(s);
		asph_scan_free(sc);
		asph_instrument_close(inst);
		asph_config_free(c);
	}
}

/* -------------------------------------------- clearance of motion */

/* Every position the stage is sent to, in order (the stage's axes). */
static double *trail;
static size_t n_trail, cap_trail;

static void trail_add(const double *p)
{
	if (n_trail == cap_trail) {
		cap_trail = cap_trail ? 2 * cap_trail : 1024;
		trail = realloc(trail, cap_trail * 3 * sizeof(double));
		assert_non_null(trail);
	}
	memcpy(trail + 3 * n_trail++, p, 3 * sizeof(double));
}

/* Where the command last was, at rest or moving. */
static struct asph_pvt last_knot;

static int trail_home(struct asph_device *d, unsigned t, struct asph_error *err)
{
	static const double zero[3];
	trail_add(zero);
	return mock_stage->home(d, t, err);
}

static int trail_move(struct asph_device *d, const double *p, unsigned t, struct asph_error *err)
{
	trail_add(p);
	memset(&last_knot, 0, sizeof(last_knot));
	memcpy(last_knot.position, p, sizeof(last_knot.position));
	return mock_stage->move_to(d, p, t, err);
}

static int trail_sweep(struct asph_device *d, const double *p, size_t n, unsigned t,
		       struct asph_error *err)
{
	for (size_t i = 0; i < n; i++)
		trail_add(p + 3 * i);
	return mock_stage->sweep(d, p, n, t, err);
}

/* A timed sweep: its knots, and the Hermite curve between them at 8 points
 * each (the command the stage follows). */
static int trail_sweep_pvt(struct asph_device *d, const struct asph_pvt *k, size_t n,
			   unsigned t, struct asph_error *err)
{
	for (size_t i = 0; i < n; i++) {
		struct asph_motion_knot a = { .t = 0 }, b = { .t = k[i].t };
		memcpy(a.position, last_knot.position, sizeof(a.position));
		memcpy(a.velocity, last_knot.velocity, sizeof(a.velocity));
		memcpy(b.position, k[i].position, sizeof(b.position));
		memcpy(b.velocity, k[i].velocity, sizeof(b.velocity));
		for (int s = 1; s <= 8 && k[i].t > 0; s++) {
			double p[3];
			asph_motion_knot_eval(&a, &b, k[i].t * s / 8, p, NULL, NULL, NULL);
			trail_add(p);
		}
		last_knot = k[i];
		last_knot.t = 0;
	}
	return mock_stage->sweep_pvt(d, k, n, t, err);
}

/* The gap of the probe at cartesian c, computed here from the sag alone. */
static double gap(const struct asph_surface *s, const double *c, double standoff, double tip)
{
	double d[3];
	asph_surface_sag_derivs(s, hypot(c[0], c[1]), d);
	return d[0] - c[2] - standoff - tip * sqrt(1 + d[1] * d[1]);
}

/* Every lateral segment of the trail keeps min_gap (dense samples). */
static void check_trail(const struct asph_surface *s, bool rtz, double standoff, double tip,
			double min_gap, size_t *n_lateral)
{
	*n_lateral = 0;
	for (size_t i = 1; i < n_trail; i++) {
		const double *a = trail + 3 * (i - 1), *b = trail + 3 * i;
		if (fabs(a[0] - b[0]) < 1e-12 && fabs(a[1] - b[1]) < 1e-12)
			continue;   /* straight up or down */
		(*n_lateral)++;
		for (int k = 0; k <= 200; k++) {
			double m[3], c[3], t = k / 200.0;
			for (int j = 0; j < 3; j++)
				m[j] = a[j] + t * (b[j] - a[j]);
			c[0] = rtz ? m[0] * cos(m[1]) : m[0];
			c[1] = rtz ? m[0] * sin(m[1]) : m[1];
			c[2] = m[2];
			double g = gap(s, c, standoff, tip);
			if (g < min_gap - 1e-9)
				fail_msg("segment %zu (%.4f %.4f %.4f) -> (%.4f %.4f %.4f): gap %.6f mm < %.6f",
					 i, a[0], a[1], a[2], b[0], b[1], b[2], g, min_gap);
		}
	}
}

struct clearance_case {
	const char *spec;
	unsigned flags;
	bool shuffle, rtz;
	double standoff, tip, min_gap;
};

static void test_clearance(void **state)
{
	static const struct clearance_case cases[] = {
		/* optical sweeps: at most half the standoff closer than measuring */
		{ "mock:time_factor=0", ASPH_SCAN_STREAM, false, false, 2, 0, -1 },
		{ "mock:time_factor=0", ASPH_SCAN_STREAM, true, false, 2, 0, -1 },
		/* point by point: lateral moves keep half the clearance */
		{ "mock:time_factor=0,probe=tactile,tip_radius=0.7", 0, true, false, 0, 0.7, 0.25 },
		{ "mock:time_factor=0,probe=tactile,tip_radius=0.7,kinematics=r-theta-z", 0, true, true,
		  0, 0.7, 0.25 },
		{ "mock:time_factor=0,stream=false", 0, false, false, 2, 0, 0.25 },
	};
	struct scan_fixture *e = *state;
	const struct asph_driver *mock = asph_registry_find(e->reg, "mock");
	static struct asph_stage_ops ops;
	static struct asph_driver spy;
	size_t n = 300;
	double *xyz = malloc(3 * n * sizeof(double));
	char path[128];

	assert_non_null(xyz);
	mock_stage = mock->stage;
	ops = *mock->stage;
	ops.home = trail_home;
	ops.move_to = trail_move;
	ops.sweep = trail_sweep;
	ops.sweep_pvt = trail_sweep_pvt;
	spy = *mock;
	spy.stage = &ops;
	for (size_t c = 0; c < sizeof(cases) / sizeof(cases[0]); c++) {
		const struct clearance_case *cc = &cases[c];
		struct asph_config *cfg;
		struct asph_instrument *inst;
		struct asph_scan *sc;
		struct asph_scan_options so = { .flags = cc->flags };
		struct asph_error err;

		/* the first 300 plan points, or a fixed scramble of them: long
		 * jumps across the part */
		for (size_t i = 0; i < n; i++) {
			size_t j = cc->shuffle ? (i * 181 + 37) % e->plan->n : i;
			memcpy(xyz + 3 * i, e->plan->xyz + 3 * j, 3 * sizeof(double));
		}
		assert_int_equal(asph_instrument_spec_parse(e->reg, cc->spec, &cfg, NULL), 0);
		cfg->instruments[0].stage_driver = &spy;
		assert_int_equal(asph_instrument_open(&cfg->instruments[0], 1000, &inst, NULL), 0);
		assert_int_equal(asph_scan_new(inst, e->s, xyz, n, &so, &sc, NULL), 0);
		n_trail = 0;
		if (asph_scan_run(sc, new_writer(new_path(e, path, sizeof(path))), &err) < 0)
			fail_msg("%s: %s", cc->spec, err.message);
		size_t lateral;
		check_trail(e->s, cc->rtz, cc->standoff, cc->tip, cc->min_gap, &lateral);
		assert_true(lateral >= n / 2);
		struct asph_scanfile *f = read_scan(path);
		assert_int_equal(f->n, n);
		asph_scanfile_free(f);
		asph_scan_free(sc);
		asph_instrument_close(inst);
		asph_config_free(cfg);
	}
	free(xyz);
	free(trail);
	trail = NULL;
	n_trail = cap_trail = 0;
}

/* ------------------------------------------ pause, resume, abort */

struct controller {
	struct asph_scan *sc;
	uint64_t paused_at, after_pause;
	enum asph_scan_state paused_state;
};

static void sleep_ms(int ms)
{
	struct timespec ts = { ms / 1000, (long)(ms % 1000) * 1000000L };
	nanosleep(&ts, NULL);
}

static uint64_t wait_done(struct asph_scan *sc, uint64_t at_least)
{
	struct asph_scan_progress p;
	for (;;) {
		asph_scan_get_progress(sc, &p);
		if (p.done >= at_least || p.state >= ASPH_SCAN_COMPLETED)
			return p.done;
		sleep_ms(2);
	}
}

static void *control(void *data)
{
	struct controller *c = data;
	struct asph_scan_progress p;

	wait_done(c->sc, 40);
	asph_scan_pause(c->sc);
	do {
		sleep_ms(5);
		asph_scan_get_progress(c->sc, &p);
	} while (p.state != ASPH_SCAN_PAUSED);
	c->paused_at = p.done;
	c->paused_state = p.state;
	sleep_ms(150);
	asph_scan_get_progress(c->sc, &p);
	c->after_pause = p.done;
	asph_scan_resume(c->sc);
	wait_done(c->sc, c->paused_at + 40);
	asph_scan_abort(c->sc);
	return NULL;
}

static void test_pause_resume_abort(void **state)
{
	struct scan_fixture *e = *state;
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_error err;
	struct controller ctl = { 0 };
	pthread_t th;
	char path[128];
	/* real time: 2 ms a reading, fast moves; point by point */
	struct asph_scan_options so = { .progress_interval_ns = 1000000 };

	assert_int_equal(asph_instrument_spec_parse(e->reg, "mock:rate=500,speed=5000", &c, NULL), 0);
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, NULL), 0);
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, &so, &sc, NULL), 0);
	ctl.sc = sc;
	assert_int_equal(pthread_create(&th, NULL, control, &ctl), 0);
	int r = asph_scan_run(sc, new_writer(new_path(e, path, sizeof(path))), &err);
	pthread_join(th, NULL);
	assert_int_equal(r, -ECANCELED);
	assert_int_equal(ctl.paused_state, ASPH_SCAN_PAUSED);
	assert_int_equal(ctl.after_pause, ctl.paused_at);
	struct asph_scan_progress p;
	asph_scan_get_progress(sc, &p);
	assert_int_equal(p.state, ASPH_SCAN_ABORTED);
	assert_true(p.done >= ctl.paused_at + 40 && p.done < e->plan->n);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->report.outcome, ASPH_SCANFILE_ABORTED);
	/* everything measured is kept: the point in flight when the abort
	 * came is either complete or not there */
	assert_true(s->n == p.done || s->n + 1 == p.done);
	asph_scanfile_free(s);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
}

/* -------------------------------------------------- characterization */

static void fit_scan(const struct asph_surface *surf, const char *path,
		     struct asph_fit_result *res)
{
	struct asph_scanfile *s = read_scan(path);
	struct asph_points *pts;
	struct asph_fit *w;
	struct asph_error err;
	struct asph_fit_options fo = { .dof = ASPH_FIT_DOF_RIGID };

	assert_int_equal(asph_scanfile_to_points(s, 0, &pts, NULL), 0);
	assert_int_equal(asph_fit_alloc(surf, pts->n, &fo, &w, NULL), 0);
	if (asph_fit_run(w, pts->xyz, pts->n, res, &err) < 0)
		fail_msg("fit: %s", err.message);
	asph_fit_free(w);
	asph_points_free(pts);
	asph_scanfile_free(s);
}

struct recovery_case {
	const char *spec;
	unsigned flags;
	double tol_mm, tol_rad, tol_nm;
};

static void test_recovery(void **state)
{
	/*
	 * Noise-free misalignment alone: the pose within 1e-9 (the bound of
	 * characterization); tactile within 1e-7: the tip is compensated along
	 * the nominal normal, which puts a point off the surface by about
	 * tip * d^2 / 2, d the angle between the nominal normal and the part's
	 * (from tilt and, through the curvature, decentring): about 3e-4 rad
	 * here, 3.4e-8 mm (docs/scanning.md). With a form error the
	 * rigid fit also sees the form error's projection on the pose (the
	 * plan's points are not exactly orthogonal to it): the Zernike terms
	 * within 0.01 nm, and within 1 nm with 2 nm noise.
	 */
	static const struct recovery_case cases[] = {
		{ "mock:time_factor=0,shift_x=0.0371,shift_y=-0.0213,shift_z=0.0119,"
		  "tilt_x=231.7,tilt_y=-148.3", ASPH_SCAN_STREAM, 1e-9, 1e-9, 0.01 },
		{ "mock:time_factor=0,probe=tactile,tip_radius=0.75,kinematics=r-theta-z,"
		  "shift_x=-0.00291,shift_y=0.00407,shift_z=-0.0087,tilt_x=-57.9,tilt_y=36.1",
		  0, 1e-7, 1e-7, 0.05 },
		{ "mock:time_factor=0,shift_x=0.0371,shift_y=-0.0213,shift_z=0.0119,"
		  "tilt_x=231.7,tilt_y=-148.3,form=5:41.3;9:-23.7;12:17.9",
		  ASPH_SCAN_STREAM, 2e-5, 2e-6, 0.01 },
		{ "mock:time_factor=0,probe=tactile,tip_radius=0.75,kinematics=r-theta-z,"
		  "shift_x=-0.00291,shift_y=0.00407,shift_z=-0.0087,tilt_x=-57.9,tilt_y=36.1,"
		  "form=5:41.3;9:-23.7;12:17.9", 0, 2e-5, 2e-6, 0.05 },
		{ "mock:time_factor=0,shift_x=0.0371,tilt_y=-148.3,form=6:-63.1;10:12.2,noise=2,seed=4242",
		  ASPH_SCAN_STREAM, 2e-5, 2e-6, 1.0 },
	};
	static const double shift[][3] = {
		{ 0.0371, -0.0213, 0.0119 }, { -0.00291, 0.00407, -0.0087 },
		{ 0.0371, -0.0213, 0.0119 }, { -0.00291, 0.00407, -0.0087 }, { 0.0371, 0, 0 } };
	static const double tilt[][2] = {
		{ 231.7, -148.3 }, { -57.9, 36.1 }, { 231.7, -148.3 }, { -57.9, 36.1 }, { 0, -148.3 } };
	static const struct { int j; double nm; } form[][3] = {
		{ { 0, 0 } }, { { 0, 0 } },
		{ { 5, 41.3 }, { 9, -23.7 }, { 12, 17.9 } },
		{ { 5, 41.3 }, { 9, -23.7 }, { 12, 17.9 } },
		{ { 6, -63.1 }, { 10, 12.2 }, { 0, 0 } },
	};
	struct scan_fixture *e = *state;
	char path[128];

	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_scan_options so = { .flags = cases[i].flags };
		struct asph_fit_result res;
		struct asph_error err;

		if (scan_with(e, e->reg, cases[i].spec, new_path(e, path, sizeof(path)), &so, &err) < 0)
			fail_msg("%s: %s", cases[i].spec, err.message);
		fit_scan(e->s, path, &res);
		for (int k = 0; k < 3; k++)
			if (fabs(res.value[ASPH_FIT_TX + k] - shift[i][k]) > cases[i].tol_mm)
				fail_msg("case %zu: t%d %.12g vs %.12g", i, k, res.value[ASPH_FIT_TX + k],
					 shift[i][k]);
		for (int k = 0; k < 2; k++)
			if (fabs(res.value[ASPH_FIT_RX + k] - tilt[i][k] * 1e-6) > cases[i].tol_rad)
				fail_msg("case %zu: r%d %.12g vs %.12g", i, k, res.value[ASPH_FIT_RX + k],
					 tilt[i][k] * 1e-6);
		for (int k = 0; k < 3 && form[i][k].j; k++) {
			double got = res.zernike[form[i][k].j - 1].v;
			if (fabs(got - form[i][k].nm) > cases[i].tol_nm)
				fail_msg("case %zu: Z%d %.6f nm vs %.6f nm", i, form[i][k].j, got,
					 form[i][k].nm);
		}
		if (!form[i][0].j && !(res.rms.v < 0.01))
			fail_msg("case %zu: residual RMS %.6f nm", i, res.rms.v);
	}
}

/* Every field of two points the same to the bit. */
static void assert_same_point(const struct asph_scanfile_point *p, const struct asph_scanfile_point *q)
{
	assert_int_equal(p->plan_index, q->plan_index);
	assert_int_equal(p->flags, q->flags);
	assert_int_equal(p->t_ns, q->t_ns);
	assert_int_equal(p->position_source, q->position_source);
	assert_memory_equal(&p->x, &q->x, sizeof(double));
	assert_memory_equal(&p->y, &q->y, sizeof(double));
	assert_memory_equal(&p->z, &q->z, sizeof(double));
	assert_memory_equal(&p->raw, &q->raw, sizeof(double));
	assert_memory_equal(p->stage, q->stage, sizeof(p->stage));
}

/* A scan of the first n plan points with spec, going on with the scan at
 * path when resume (from the point after its last, with what the file
 * recovered, as asph scan --resume and asphd do), else into a new one;
 * -errno of the scan. */
static int scan_part(struct scan_fixture *e, const char *spec, size_t n, const char *path,
		     bool stream, bool resume, uint64_t *start)
{
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_scan_options so = { .flags = stream ? ASPH_SCAN_STREAM : 0 };
	struct asph_scanfile *rec = NULL;
	struct asph_scanfile_writer *w;

	if (resume) {
		/* as asph_scan_reopen() does after checking the header's plan */
		struct asph_scanfile_writer_options wo = { .flags = ASPH_SCANFILE_REOPEN_ENDED };
		assert_int_equal(asph_scanfile_writer_resume(path, &wo, &rec, &w, NULL), 0);
		*start = 0;
		for (size_t i = 0; i < rec->n; i++)
			if (rec->points[i].plan_index + 1 > *start)
				*start = rec->points[i].plan_index + 1;
		so.start_index = *start;
		so.recovered = rec;
	} else {
		w = new_writer(path);
	}
	assert_int_equal(asph_instrument_spec_parse(e->reg, spec, &c, NULL), 0);
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, NULL), 0);
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, n, &so, &sc, NULL), 0);
	int r = asph_scan_run(sc, w, NULL);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
	asph_scanfile_free(rec);
	return r;
}

/* bench=realistic: a scan cut off by the probe and resumed with a fresh
 * instrument equals the uninterrupted scan to the bit: points, measured
 * positions, times and drift references. The resumed scan takes up the
 * interrupted one's motion after its last round of references, with the
 * clock that one had (streamed, the cut inside a sweep; and point by
 * point). */
static void test_resume_realistic(void **state)
{
	struct scan_fixture *e = *state;
	static const struct {
		bool stream;
		size_t n;
		unsigned cut;           /* readings before the probe fails */
	} cases[] = { { true, 700, 430 }, { false, 60, 41 } };

	for (size_t c = 0; c < sizeof(cases) / sizeof(cases[0]); c++) {
		char whole[128], cut[128], spec[256];
		const char *base = cases[c].stream ? "mock:time_factor=0,bench=realistic,noise=1.5,"
						     "seed=909,drift_interval=150points"
						   : "mock:time_factor=0,bench=realistic,noise=1.5,"
						     "seed=909,drift_interval=15points";
		uint64_t start = 0;

		assert_int_equal(scan_part(e, base, cases[c].n, new_path(e, whole, sizeof(whole)),
					   cases[c].stream, false, NULL), 0);
		snprintf(spec, sizeof(spec), "%s,fail_after=%u", base, cases[c].cut);
		assert_int_equal(scan_part(e, spec, cases[c].n, new_path(e, cut, sizeof(cut)),
					   cases[c].stream, false, NULL), -ENODEV);
		assert_int_equal(scan_part(e, base, cases[c].n, cut, cases[c].stream, true, &start), 0);
		/* cut after a round of references and inside the points after it */
		assert_true(start > 0 && start < cases[c].n);

		struct asph_scanfile *a = read_scan(whole), *b = read_scan(cut);
		assert_int_equal(b->report.outcome, ASPH_SCANFILE_COMPLETED);
		assert_int_equal(b->report.n_resumes, 1);
		assert_int_equal(a->n, cases[c].n);
		assert_int_equal(a->n, b->n);
		for (size_t i = 0; i < a->n; i++)
			assert_same_point(&a->points[i], &b->points[i]);
		assert_true(a->n_references >= 4);
		assert_int_equal(a->n_references, b->n_references);
		for (size_t i = 0; i < a->n_references; i++)
			assert_same_point(&a->references[i], &b->references[i]);
		/* the bench's following error and drift are in what is compared */
		size_t latched = 0;
		for (size_t i = 0; i < a->n; i++)
			latched += a->points[i].position_source ==
				   (cases[c].stream ? ASPH_POSITION_LATCHED : ASPH_POSITION_READ_BACK);
		assert_int_equal(latched, a->n);
		assert_true(a->references[a->n_references - 1].raw != a->references[0].raw);
		asph_scanfile_free(a);
		asph_scanfile_free(b);
	}
}

/* --------------------------------------------------------- settling */

/* The settling in effect for spec: the instrument's account of its
 * acquisition (mm, s). */
static void settling_of(const struct asph_instrument_config *ic, double *window, double *dwell)
{
	char *text;

	assert_int_equal(asph_instrument_config_to_json(ic, &text), 0);
	json_t *root = json_loads(text, 0, NULL);
	assert_non_null(root);
	json_t *acq = json_object_get(root, "acquisition");
	*window = json_number_value(json_object_get(acq, "settle_window_um")) * 1e-3;
	*dwell = json_number_value(json_object_get(acq, "settle_dwell_s"));
	json_decref(root);
	free(text);
}

/* Step and measure over the first n plan points; the largest distance of
 * a point's read-back position from its target (mm). */
static double settled_off(struct scan_fixture *e, const char *spec, size_t n, double *window,
			  double *dwell)
{
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_scan_options so = { 0 };
	char path[128];

	assert_int_equal(asph_instrument_spec_parse(e->reg, spec, &c, NULL), 0);
	settling_of(&c->instruments[0], window, dwell);
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, NULL), 0);
	double standoff = inst->probe_info.standoff;
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, n, &so, &sc, NULL), 0);
	assert_int_equal(asph_scan_run(sc, new_writer(new_path(e, path, sizeof(path))), NULL), 0);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);

	struct asph_scanfile *f = read_scan(path);
	double off = 0;
	assert_int_equal(f->n, n);
	for (size_t k = 0; k < f->n; k++) {
		const struct asph_scanfile_point *p = &f->points[k];
		const double *t = e->plan->xyz + 3 * p->plan_index;
		assert_int_equal(p->position_source, ASPH_POSITION_READ_BACK);
		off = fmax(off, hypot(hypot(p->stage[0] - t[0], p->stage[1] - t[1]),
				      p->stage[2] - (t[2] - standoff)));
	}
	asph_scanfile_free(f);
	return off;
}

/* bench=realistic's stage rings after a move and advises its settling: a
 * window of 10 nm kept for a period of the ringing (settle_time / 4). It
 * applies where the instrument sets none, and the points are read back
 * within it; an instrument's own window and dwell win, and with a window
 * of 1 um the readings are taken on the ringing. */
static void test_settling_advised(void **state)
{
	struct scan_fixture *e = *state;
	const size_t n = 40;
	double window, dwell;

	double off = settled_off(e, "mock:time_factor=0,bench=realistic,drift_interval=off", n,
				 &window, &dwell);
	assert_true(fabs(window - 1e-5) <= 1e-15);
	assert_true(fabs(dwell - 0.02 / 4) <= 1e-15);
	assert_true(off <= 1e-5);

	off = settled_off(e, "mock:time_factor=0,bench=realistic,drift_interval=off,"
			     "settle_window=1,settle_dwell=0", n, &window, &dwell);
	assert_true(fabs(window - 1e-3) <= 1e-15);
	assert_true(dwell == 0);
	/* the ringing after a move at up to 20 mm/s starts at 1 um */
	assert_true(off > 1e-4 && off <= 1e-3);

	/* only the window given: the dwell stays the stage's */
	settled_off(e, "mock:time_factor=0,bench=realistic,drift_interval=off,settle_window=0.5", 1,
		    &window, &dwell);
	assert_true(fabs(window - 5e-4) <= 1e-15);
	assert_true(fabs(dwell - 0.005) <= 1e-15);

	/* a stage that does not ring advises nothing: the defaults */
	settled_off(e, "mock:time_factor=0,drift_interval=off", 1, &window, &dwell);
	assert_true(fabs(window - 1e-3) <= 1e-15);
	assert_true(dwell == 0);
}

/* ------------------------------------------------ resume and replay */

static void assert_same_points(const struct asph_scanfile *a, const struct asph_scanfile *b)
{
	assert_int_equal(a->n, b->n);
	for (size_t i = 0; i < a->n; i++) {
		const struct asph_scanfile_point *p = &a->points[i], *q = &b->points[i];
		assert_int_equal(p->plan_index, q->plan_index);
		assert_int_equal(p->flags, q->flags);
		assert_memory_equal(&p->x, &q->x, sizeof(double));
		assert_memory_equal(&p->y, &q->y, sizeof(double));
		assert_memory_equal(&p->z, &q->z, sizeof(double));
		assert_memory_equal(&p->raw, &q->raw, sizeof(double));
	}
}

static void test_resume(void **state)
{
	struct scan_fixture *e = *state;
	char whole[128], cut[128];
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM, .stream_batch = 64 };
	const char *base = "mock:time_factor=0,drift_interval=off,tilt_x=77.7,form=8:-19.5,"
			   "noise=1.5,seed=909";
	char faulty[160];

	assert_int_equal(scan_with(e, e->reg, base, new_path(e, whole, sizeof(whole)), &so, NULL), 0);
	snprintf(faulty, sizeof(faulty), "%s,fail_after=301", base);
	assert_int_equal(scan_with(e, e->reg, faulty, new_path(e, cut, sizeof(cut)), &so, NULL),
			 -ENODEV);

	/* continue from the last recorded point with a fresh instrument: the
	 * noise of a point depends on its plan index, not on the readings
	 * taken before, so the result equals the uninterrupted scan */
	struct asph_scanfile_writer_options wo = { .flags = ASPH_SCANFILE_REOPEN_ENDED };
	struct asph_scanfile *rec;
	struct asph_scanfile_writer *w;
	assert_int_equal(asph_scanfile_writer_resume(cut, &wo, &rec, &w, NULL), 0);
	uint64_t start = rec->points[rec->n - 1].plan_index + 1;
	assert_int_equal(start, 301);
	asph_scanfile_free(rec);
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	assert_int_equal(asph_instrument_spec_parse(e->reg, base, &c, NULL), 0);
	assert_int_equal(asph_instrument_open(&c->instruments[0], 1000, &inst, NULL), 0);
	so.start_index = start;
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, &so, &sc, NULL), 0);
	assert_int_equal(asph_scan_run(sc, w, NULL), 0);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);

	struct asph_scanfile *a = read_scan(whole), *b = read_scan(cut);
	assert_int_equal(b->report.outcome, ASPH_SCANFILE_COMPLETED);
	assert_int_equal(b->report.n_resumes, 1);
	assert_same_points(a, b);
	asph_scanfile_free(a);
	asph_scanfile_free(b);
}

/* A scan cut off after plan points 0 .. last - 1 (and one more measured
 * out of order, kept as recorded), under a header whose plan is plan_json. */
static void write_cut_scan(const char *path, const char *plan_json, uint64_t last)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", plan_json,
						  "{\"name\":\"mock\"}", NULL };
	struct asph_scanfile_writer *w;
	struct asph_scanfile_point pt = { .x = 1.5, .y = -2.25, .z = 0.125, .raw = 0.125 };

	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, NULL), 0);
	for (uint64_t i = 0; i < last; i++) {
		pt.plan_index = i == 3 ? last : (i == last - 1 ? 3 : i);
		pt.t_ns = 1000 * i;
		assert_int_equal(asph_scanfile_writer_append(w, &pt, 1, NULL), 0);
	}
	assert_int_equal(asph_scanfile_writer_close(w, NULL), 0);
}

static long file_size(const char *path)
{
	struct stat st;

	assert_int_equal(stat(path, &st), 0);
	return (long)st.st_size;
}

/* asph_scan_reopen(): after the last plan index, with the plan of the
 * header in the shape asphd and asph scan write now and in the one asph
 * scan wrote before; another plan is refused before anything is written. */
static void test_reopen(void **state)
{
	struct scan_fixture *e = *state;
	const struct asph_plan *p = e->plan;
	char now[128], before[128], *plan_json = NULL, old_json[256];
	struct asph_scanfile_writer *w;
	struct asph_error err;
	uint64_t start = 0;

	assert_int_equal(asph_plan_to_json(p, &plan_json), 0);
	snprintf(old_json, sizeof(old_json),
		 "{\"method\":\"fermat\",\"density\":{\"kind\":\"points\",\"value\":%.17g},"
		 "\"spacing_mm\":%.17g,\"points\":%zu}", p->density.value, p->spacing_mm, p->n);
	write_cut_scan(new_path(e, now, sizeof(now)), plan_json, 40);
	write_cut_scan(new_path(e, before, sizeof(before)), old_json, 57);
	free(plan_json);

	assert_int_equal(asph_scan_reopen(now, p, NULL, &w, &start, NULL, &err), 0);
	assert_int_equal(start, 41);
	assert_int_equal(asph_scanfile_writer_close(w, NULL), 0);
	assert_int_equal(asph_scan_reopen(before, p, NULL, &w, &start, NULL, &err), 0);
	assert_int_equal(start, 58);
	assert_int_equal(asph_scanfile_writer_close(w, NULL), 0);
	struct asph_scanfile *rec = read_scan(before);
	assert_int_equal(rec->report.n_resumes, 1);
	assert_int_equal(rec->n, 57);
	asph_scanfile_free(rec);

	/* another plan of the same method: refused, the file untouched */
	struct asph_plan *other;
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, 650 };
	assert_int_equal(asph_plan_compute(e->s, ASPH_PLAN_FERMAT, d, 0, &other, NULL), 0);
	long size = file_size(now);
	asph_error_clear(&err);
	w = NULL;
	assert_int_equal(asph_scan_reopen(now, other, NULL, &w, &start, NULL, &err), -EINVAL);
	assert_null(w);
	assert_string_equal(err.field, "plan");
	assert_string_equal(err.source, now);
	assert_non_null(strstr(err.message, "two plans"));
	assert_int_equal(file_size(now), size);
	asph_plan_free(other);

	/* a header whose plan says nothing usable */
	char bare[128];
	write_cut_scan(new_path(e, bare, sizeof(bare)), "{\"method\":\"fermat\"}", 5);
	assert_int_equal(asph_scan_reopen(bare, p, NULL, &w, &start, NULL, &err), -EINVAL);
	assert_string_equal(err.field, "plan.density");
}

static void test_replay_identical(void **state)
{
	struct scan_fixture *e = *state;
	char orig[128], again[128], again2[128], spec[200];
	struct asph_scan_options stream = { .flags = ASPH_SCAN_STREAM };
	struct asph_scan_options points = { 0 };

	assert_int_equal(scan_with(e, e->reg,
				   "mock:time_factor=0,probe=tactile,tip_radius=1.25,tilt_y=311,noise=3,seed=77",
				   new_path(e, orig, sizeof(orig)), &points, NULL), 0);
	snprintf(spec, sizeof(spec), "replay:file=%s", orig);
	assert_int_equal(scan_with(e, e->reg, spec, new_path(e, again, sizeof(again)), &stream, NULL), 0);
	assert_int_equal(scan_with(e, e->reg, spec, new_path(e, again2, sizeof(again2)), &points, NULL), 0);
	struct asph_scanfile *a = read_scan(orig), *b = read_scan(again), *c = read_scan(again2);
	assert_true(a->points[0].flags & ASPH_SCANFILE_POINT_TIP_COMPENSATED);
	assert_same_points(a, b);
	assert_same_points(a, c);
	asph_scanfile_free(a);
	asph_scanfile_free(b);
	asph_scanfile_free(c);

	/* a plan the recording does not cover */
	struct asph_error err;
	struct asph_plan *bigger;
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, 900 };
	assert_int_equal(asph_plan_compute(e->s, ASPH_PLAN_FERMAT, d, 0, &bigger, NULL), 0);
	struct asph_plan *keep = e->plan;
	e->plan = bigger;
	assert_int_equal(scan_with(e, e->reg, spec, new_path(e, again, sizeof(again)), &points, &err),
			 -ENODATA);
	assert_non_null(strstr(err.message, "no point for plan point"));
	e->plan = keep;
	asph_plan_free(bigger);
}

static void test_tip_on_surface(void **state)
{
	struct scan_fixture *e = *state;
	char path[128];

	/* nominal part, tactile, rotary: compensated points lie on the surface */
	assert_int_equal(scan_with(e, e->reg,
				   "mock:time_factor=0,probe=tactile,tip_radius=2.5,kinematics=r-theta-z",
				   new_path(e, path, sizeof(path)), NULL, NULL), 0);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->n, e->plan->n);
	for (size_t i = 0; i < s->n; i++) {
		const struct asph_scanfile_point *p = &s->points[i];
		double z = asph_surface_sag(e->s, hypot(p->x, p->y));
		if (fabs(p->z - z) > 1e-9 || !(p->flags & ASPH_SCANFILE_POINT_TIP_COMPENSATED))
			fail_msg("point %zu: z %.12f, surface %.12f", i, p->z, z);
		/* and where the plan wanted them */
		assert_true(fabs(p->x - e->plan->xyz[3 * p->plan_index]) < 1e-9);
	}
	asph_scanfile_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_faults),
		cmocka_unit_test(test_skip_out_of_range),
		cmocka_unit_test(test_failed_retreat),
		cmocka_unit_test(test_limits_before_motion),
		cmocka_unit_test(test_clearance),
		cmocka_unit_test(test_pause_resume_abort),
		cmocka_unit_test(test_recovery),
		cmocka_unit_test(test_tip_on_surface),
		cmocka_unit_test(test_resume),
		cmocka_unit_test(test_resume_realistic),
		cmocka_unit_test(test_settling_advised),
		cmocka_unit_test(test_reopen),
		cmocka_unit_test(test_replay_identical),
	};
	return cmocka_run_group_tests(tests, setup, teardown);
}
