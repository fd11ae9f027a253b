/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The usb driver against a simulated USBTMC instrument on umockdev: the
 * real libusb code paths (enumeration, claiming, bulk and control URBs)
 * with a device model that checks what the host sends (bTag sequence,
 * bTagInverse, 4-byte alignment) and answers from a simulated part. The
 * faults: a stalled endpoint, a short read, a wrong bTag, a reply that
 * never comes, an unplug in the middle of a transfer; each must end the
 * operation with its reason, promptly, and leave the device usable (or,
 * unplugged, found again once plugged back).
 */
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
#include <unistd.h>

#include <cmocka.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph-driver/instrument.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "mock/protocol.h"
#include "umockdev-usb.h"
#include "usbtmc-sim.h"

#define SPEC "usb:vendor_id=4660,product_id=22136"      /* 1234:5678 */

static UMockdevTestbed *testbed;

/* A misaligned part with a form error: what the probe measures. */
static const struct mock_part_params part_params = {
	.lens = "strong",
	.pose = { .t = { 0.0271, -0.0163, 0.0089 }, .rx = 183.1e-6, .ry = -97.3e-6 },
	.form = "5:31.7;9:-17.3;12:8.9",
};
#define MOCK_SPEC "mock:time_factor=0,shift_x=0.0271,shift_y=-0.0163,shift_z=0.0089," \
		  "tilt_x=183.1,tilt_y=-97.3,form=5:31.7;9:-17.3;12:8.9"

struct env {
	struct usbtmc_sim sim;
	struct asph_registry *reg;
	struct asph_config *cfg;
	struct asph_instrument *inst;
};

static int setup(void **state)
{
	struct env *e = calloc(1, sizeof(*e));

	assert_non_null(e);
	assert_int_equal(mock_part_new(&part_params, &e->sim.part, NULL), 0);
	e->sim.usb = umu_usb_new(testbed, &usbtmc_sim_desc, &usbtmc_sim_ops, &e->sim);
	assert_int_equal(asph_registry_new(&e->reg, NULL), 0);
	*state = e;
	return 0;
}

static void env_close(struct env *e)
{
	asph_instrument_close(e->inst);
	asph_config_free(e->cfg);
	e->inst = NULL;
	e->cfg = NULL;
}

static int teardown(void **state)
{
	struct env *e = *state;

	env_close(e);
	asph_registry_free(e->reg);
	umu_usb_free(e->sim.usb);
	mock_part_free(e->sim.part);
	free(e);
	return 0;
}

static int env_open(struct env *e, const char *spec, struct asph_error *err)
{
	int r = asph_instrument_spec_parse(e->reg, spec, &e->cfg, err);

	if (r == 0)
		r = asph_instrument_open(&e->cfg->instruments[0], 2000, &e->inst, err);
	if (r < 0) {
		asph_config_free(e->cfg);
		e->cfg = NULL;
	}
	return r;
}

static void must_open(struct env *e, const char *spec)
{
	struct asph_error err;

	if (env_open(e, spec, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
}

static struct usbtmc_sim *sim_lock(struct env *e)
{
	umu_usb_lock(e->sim.usb);
	return &e->sim;
}

static void sim_unlock(struct env *e)
{
	umu_usb_unlock(e->sim.usb);
}

static double now_s(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int move(struct env *e, double x, double y, double z, struct asph_error *err)
{
	double t[3] = { x, y, z };
	return e->inst->stage_driver->stage->move_to(e->inst->stage, t, 2000, err);
}

static int probe(struct env *e, double x, double y, double z, struct asph_reading *rd,
		 unsigned timeout_ms, struct asph_error *err)
{
	struct asph_probe_context ctx = { .xyz = { x, y, z }, .machine = { x, y, z } };
	return e->inst->probe_driver->probe->read(e->inst->probe, &ctx, rd, timeout_ms, err);
}

/* Moves there with the instrument's stage and reads, which must work. */
static double read_at(struct env *e, double x, double y, double z)
{
	struct asph_reading rd;
	struct asph_error err;

	if (move(e, x, y, z, &err) < 0 || probe(e, x, y, z, &rd, 2000, &err) < 0)
		fail_msg("at %g %g %g: %s", x, y, z, err.message);
	return rd.value;
}

/* The height the mock driver reads at (x, y) from stage height z. */
static double mock_reading(double x, double y, double z)
{
	struct mock_part *p;
	double h;

	assert_int_equal(mock_part_new(&part_params, &p, NULL), 0);
	assert_int_equal(mock_part_probe_z(p, x, y, 0, &h), 0);
	mock_part_free(p);
	return h - z;
}

static void assert_clean_protocol(struct env *e)
{
	struct usbtmc_sim *s = sim_lock(e);
	unsigned tags = s->n_tag_errors, align = s->n_align_errors;
	sim_unlock(e);
	assert_int_equal(tags, 0);
	assert_int_equal(align, 0);
}

/* --------------------------------------------------------- basics */

static void test_open_identify(void **state)
{
	struct env *e = *state;
	struct umu_usb_counts c;

	must_open(e, SPEC);
	assert_string_equal(e->inst->probe_info.model, "ASPH USBTMC-SIM");
	assert_string_equal(e->inst->probe_info.serial, "SN4711");
	assert_string_equal(e->inst->stage_info.serial, "SN4711");
	assert_int_equal(e->inst->probe_info.type, ASPH_PROBE_OPTICAL);
	umu_usb_counts(e->sim.usb, &c);
	/* stage and probe share the one claimed interface */
	assert_int_equal(c.claims, 1);
	struct usbtmc_sim *s = sim_lock(e);
	unsigned clears = s->n_clear;
	sim_unlock(e);
	assert_int_equal(clears, 1);
	env_close(e);
	umu_usb_counts(e->sim.usb, &c);
	assert_int_equal(c.releases, 1);
	assert_int_equal(c.in_flight, 0);
	assert_clean_protocol(e);
}

static void test_readings(void **state)
{
	struct env *e = *state;
	struct asph_error err;

	must_open(e, SPEC);
	assert_int_equal(e->inst->stage_driver->stage->home(e->inst->stage, 2000, &err), 0);
	for (int i = 0; i < 12; i++) {
		double r = 14.3 * sqrt((i + 0.41) / 12.0), t = 2.39996322972865332 * i + 0.17;
		double x = r * cos(t), y = r * sin(t);
		double z = mock_reading(x, y, 0) - 2.0 + 0.0131 * i;
		double got = read_at(e, x, y, z);
		/* the number crosses USB as text that reads back exactly */
		assert_true(got == mock_reading(x, y, z));
		double pos[3];
		assert_int_equal(e->inst->stage_driver->stage->position(e->inst->stage, pos, 2000,
									 &err), 0);
		assert_true(pos[0] == x && pos[1] == y && pos[2] == z);
	}
	/* beyond the probe's range */
	struct asph_reading rd;
	assert_int_equal(move(e, 7.9, 0.3, -10.3, &err), 0);
	assert_int_equal(probe(e, 7.9, 0.3, -10.3, &rd, 2000, &err), 0);
	assert_true(rd.value == mock_reading(7.9, 0.3, -10.3));
	if (!(rd.flags & ASPH_READING_OUT_OF_RANGE))
		fail_msg("out of range: %.17g", rd.value);
	assert_clean_protocol(e);
}

/* Replies and commands longer than one transfer; bTag past 255. */
static void test_transfers(void **state)
{
	struct env *e = *state;
	struct asph_error err;

	must_open(e, SPEC ",read_chunk=16");
	assert_string_equal(e->inst->probe_info.model, "ASPH USBTMC-SIM");
	struct usbtmc_sim *s = sim_lock(e);
	s->max_chunk = 12;      /* the device splits too */
	unsigned before = s->n_transfers_in, q0 = s->n_queries;
	sim_unlock(e);
	/* a 70-byte move command in 16-byte messages, EOM on the last */
	double x = -3.1415926535897931, y = 2.7182818284590451, z = -1.4142135623730951;
	read_at(e, x, y, z);
	double pos[3];
	assert_int_equal(e->inst->stage_driver->stage->position(e->inst->stage, pos, 2000, &err), 0);
	assert_true(pos[0] == x && pos[1] == y && pos[2] == z);
	s = sim_lock(e);
	unsigned transfers = s->n_transfers_in - before, queries = s->n_queries - q0;
	s->max_chunk = 0;
	sim_unlock(e);
	assert_true(transfers > queries);
	/* 70 readings of 4 bulk-OUT transfers each: bTag wraps 255 -> 1 */
	for (int i = 0; i < 70; i++) {
		struct asph_reading rd;
		if (probe(e, x, y, z, &rd, 2000, &err) < 0)
			fail_msg("query %d: %s", i, err.message);
	}
	assert_clean_protocol(e);
}

/* ----------------------------------------------------- refusals */

static void test_scpi_errors(void **state)
{
	struct env *e = *state;
	struct asph_reading rd;
	struct asph_error err;

	must_open(e, SPEC ",cmd_measure=MEAS:BOGUS?,travel_xy=100");
	double t0 = now_s();
	assert_int_equal(probe(e, 0, 0, 0, &rd, 400, &err), -EPROTO);
	assert_true(now_s() - t0 < 1.0);
	assert_non_null(strstr(err.message, "MEAS:BOGUS?"));
	assert_non_null(strstr(err.message, "-113,\"Undefined header\""));
	/* a target the device refuses: SCPI -222 is a travel limit */
	assert_int_equal(move(e, 75.3, 0, 0, &err), -ERANGE);
	assert_non_null(strstr(err.message, "-222,\"Data out of range\""));
	/* and the device still works */
	double pos[3];
	assert_int_equal(e->inst->stage_driver->stage->position(e->inst->stage, pos, 2000, &err), 0);
	struct usbtmc_sim *s = sim_lock(e);
	unsigned aborts = s->n_abort_in;
	sim_unlock(e);
	assert_true(aborts >= 1);
	assert_clean_protocol(e);
}

static void test_no_device(void **state)
{
	struct env *e = *state;
	struct asph_error err;

	assert_int_equal(env_open(e, SPEC ",serial=SN0000", &err), -ENODEV);
	assert_non_null(strstr(err.message, "serial SN0000"));
	assert_int_equal(env_open(e, "usb:vendor_id=4660,product_id=1", &err), -ENODEV);
	assert_non_null(strstr(err.message, "1234:0001"));
	/* found by serial */
	must_open(e, SPEC ",serial=SN4711");
}

/* ---------------------------------------------------------- faults */

struct fault_case {
	enum usbtmc_sim_fault fault;
	int code;
	const char *words;
};

static void test_faults(void **state)
{
	static const struct fault_case cases[] = {
		{ SIM_FAULT_STALL_IN, -EIO, "stalled" },
		{ SIM_FAULT_SHORT_READ, -EPROTO, "short read" },
		{ SIM_FAULT_WRONG_TAG, -EPROTO, "bTag" },
		{ SIM_FAULT_SILENT, -ETIMEDOUT, "no answer" },
		{ SIM_FAULT_STUCK_OUT, -ETIMEDOUT, "sending a message: no answer" },
	};
	struct env *e = *state;
	double x = 4.17, y = -6.93, z = mock_reading(4.17, -6.93, 0) - 1.83;

	must_open(e, SPEC);
	read_at(e, x, y, z);
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_reading rd;
		struct asph_error err;
		struct usbtmc_sim *s = sim_lock(e);
		usbtmc_sim_fault(s, cases[i].fault, 1);
		unsigned clears = s->n_clear, aborts = s->n_abort_in, aborts_out = s->n_abort_out;
		sim_unlock(e);
		double t0 = now_s();
		int r = probe(e, x, y, z, &rd, 400, &err);
		if (r != cases[i].code || !strstr(err.message, cases[i].words))
			fail_msg("case %zu: %d %s", i, r, err.message);
		assert_true(now_s() - t0 < 1.0);
		/* recovered before the next call, which reads right */
		assert_true(probe(e, x, y, z, &rd, 2000, &err) == 0 && rd.value == mock_reading(x, y, z));
		s = sim_lock(e);
		bool recovered = cases[i].fault == SIM_FAULT_SILENT ? s->n_abort_in > aborts
				 : cases[i].fault == SIM_FAULT_STUCK_OUT ? s->n_abort_out > aborts_out
				 : s->n_clear > clears;
		sim_unlock(e);
		assert_true(recovered);
	}
	struct umu_usb_counts c;
	umu_usb_counts(e->sim.usb, &c);
	assert_true(c.halts_cleared[1 | 16] >= 1);       /* 0x81 after its stall */
	assert_true(c.halts_cleared[2] >= 1);            /* 0x02 after the abort */
	assert_int_equal(c.discarded, 2);                /* the silent and the stuck */
	assert_clean_protocol(e);
}

struct stopper {
	struct env *e;
	int delay_ms;
};

static void *stop_later(void *data)
{
	struct stopper *st = data;
	struct timespec ts = { 0, st->delay_ms * 1000000L };
	nanosleep(&ts, NULL);
	st->e->inst->probe_driver->probe->stop(st->e->inst->probe, NULL);
	return NULL;
}

static void test_stop(void **state)
{
	struct env *e = *state;
	struct stopper st = { e, 150 };
	struct asph_reading rd;
	struct asph_error err;
	pthread_t th;

	must_open(e, SPEC);
	struct usbtmc_sim *s = sim_lock(e);
	usbtmc_sim_fault(s, SIM_FAULT_SILENT, 1);
	sim_unlock(e);
	double t0 = now_s();
	assert_int_equal(pthread_create(&th, NULL, stop_later, &st), 0);
	assert_int_equal(probe(e, 0, 0, 0, &rd, 20000, &err), -ECANCELED);
	pthread_join(th, NULL);
	assert_true(now_s() - t0 < 2.0);
	assert_int_equal(probe(e, 0, 0, 0, &rd, 2000, &err), -ECANCELED);
}

static void test_unplug(void **state)
{
	struct env *e = *state;
	struct asph_reading rd;
	struct asph_error err;

	must_open(e, SPEC);
	read_at(e, 1.3, 2.9, 0);
	struct usbtmc_sim *s = sim_lock(e);
	usbtmc_sim_fault(s, SIM_FAULT_UNPLUG, 1);
	sim_unlock(e);
	double t0 = now_s();
	assert_int_equal(probe(e, 1.3, 2.9, 0, &rd, 2000, &err), -ENODEV);
	assert_non_null(strstr(err.message, "unplugged"));
	assert_true(now_s() - t0 < 1.5);
	assert_int_equal(probe(e, 1.3, 2.9, 0, &rd, 2000, &err), -ENODEV);
	assert_int_equal(move(e, 1.3, 2.9, 0, &err), -ENODEV);
	struct asph_stage_status st;
	assert_int_equal(e->inst->stage_driver->stage->status(e->inst->stage, &st, 2000, &err), 0);
	assert_int_equal(st.state, ASPH_STAGE_DISCONNECTED);
	env_close(e);
	/* the next job does not find it ... */
	assert_int_equal(env_open(e, SPEC, &err), -ENODEV);
	assert_non_null(strstr(err.message, "no USBTMC device"));
	/* ... until it is plugged back */
	umu_usb_plug(e->sim.usb);
	must_open(e, SPEC);
	assert_true(read_at(e, 1.3, 2.9, 0) == mock_reading(1.3, 2.9, 0));
}

static void test_kernel_driver(void **state)
{
	struct env *e = *state;
	struct umu_usb_counts c;

	umu_usb_bind_driver(e->sim.usb, "usbtmc");
	must_open(e, SPEC);
	umu_usb_counts(e->sim.usb, &c);
	assert_int_equal(c.detaches, 1);
	assert_int_equal(c.attaches, 0);
	env_close(e);
	umu_usb_counts(e->sim.usb, &c);
	assert_int_equal(c.attaches, 1);
}

/* ------------------------------------------------------ end to end */

/* The mock's stage, telling the simulated instrument where it is. */
static const struct asph_stage_ops *mock_stage;
static double world[3];
static struct umu_usb *world_usb;

static void tell(const double *p)
{
	umu_usb_lock(world_usb);
	memcpy(world, p, sizeof(world));
	umu_usb_unlock(world_usb);
}

static int world_home(struct asph_device *d, unsigned t, struct asph_error *err)
{
	static const double zero[3];
	int r = mock_stage->home(d, t, err);
	if (r == 0)
		tell(zero);
	return r;
}

static int world_move(struct asph_device *d, const double *p, unsigned t, struct asph_error *err)
{
	int r = mock_stage->move_to(d, p, t, err);
	if (r == 0)
		tell(p);
	return r;
}

static struct asph_plan *plan_for(const struct asph_surface *s)
{
	struct asph_plan *p;
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, 90 };
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	assert_int_equal(asph_plan_compute_opts(s, ASPH_PLAN_FERMAT, d, &po, &p, NULL), 0);
	return p;
}

/* Scans the first n points of the plan with the instrument of c into path. */
static int scan_file(struct asph_config *c, const struct asph_surface *s,
		     const struct asph_plan *plan, size_t n, const char *path,
		     struct asph_error *err)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						  "{\"name\":\"usb\"}", NULL };
	struct asph_instrument *inst;
	struct asph_scanfile_writer *w;
	struct asph_scan *sc;

	if (asph_instrument_open(&c->instruments[0], 2000, &inst, err) < 0)
		fail_msg("open: %s", err->message);
	assert_int_equal(asph_scan_new(inst, s, plan->xyz, n, NULL, &sc, NULL), 0);
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, NULL), 0);
	int r = asph_scan_run(sc, w, err);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	return r;
}

static void scan_and_fit(struct asph_config *c, const struct asph_surface *s,
			 const struct asph_plan *plan, const char *path,
			 struct asph_fit_result *res)
{
	struct asph_scanfile *f;
	struct asph_points *pts;
	struct asph_fit *fit;
	struct asph_fit_options fo = { .dof = ASPH_FIT_DOF_RIGID };
	struct asph_error err;

	if (scan_file(c, s, plan, plan->n, path, &err) < 0)
		fail_msg("scan: %s", err.message);
	assert_int_equal(asph_scanfile_read(path, &f, NULL), 0);
	assert_int_equal(f->n, plan->n);
	assert_int_equal(asph_scanfile_to_points(f, 0, &pts, NULL), 0);
	assert_int_equal(asph_fit_alloc(s, pts->n, &fo, &fit, NULL), 0);
	if (asph_fit_run(fit, pts->xyz, pts->n, res, &err) < 0)
		fail_msg("fit: %s", err.message);
	asph_fit_free(fit);
	asph_points_free(pts);
	asph_scanfile_free(f);
	unlink(path);
}

/* The measured points of the first n plan points with the instrument of
 * spec (malloc'd, 3 n). */
static double *scan_points(struct env *e, const char *spec, const struct asph_surface *s,
			   const struct asph_plan *plan, size_t n, const char *path)
{
	struct asph_config *c;
	struct asph_scanfile *f;
	struct asph_points *pts;
	struct asph_error err;

	assert_int_equal(asph_instrument_spec_parse(e->reg, spec, &c, NULL), 0);
	if (scan_file(c, s, plan, n, path, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
	asph_config_free(c);
	assert_int_equal(asph_scanfile_read(path, &f, NULL), 0);
	assert_int_equal(asph_scanfile_to_points(f, 0, &pts, NULL), 0);
	assert_int_equal(pts->n, n);
	double *xyz = malloc(3 * n * sizeof(double));
	assert_non_null(xyz);
	memcpy(xyz, pts->xyz, 3 * n * sizeof(double));
	asph_points_free(pts);
	asph_scanfile_free(f);
	unlink(path);
	return xyz;
}

static void assert_same_fit(const struct asph_fit_result *a, const struct asph_fit_result *b)
{
	/* the same points in the same order: the same numbers */
	for (int k = 0; k < ASPH_FIT_N_DOF; k++)
		if (a->value[k] != b->value[k])
			fail_msg("dof %d: %.17g vs %.17g", k, a->value[k], b->value[k]);
	assert_int_equal(a->n_zernike, b->n_zernike);
	assert_true(a->n_zernike >= 12);
	for (int j = 0; j < a->n_zernike; j++)
		if (a->zernike[j].v != b->zernike[j].v)
			fail_msg("Z%d: %.17g vs %.17g", j + 1, a->zernike[j].v, b->zernike[j].v);
	assert_true(a->rms.v == b->rms.v);
}

static void test_end_to_end(void **state)
{
	static const char mixed[] =
		"{ \"instruments\": [ { \"name\": \"mixed\","
		"  \"stage\": { \"driver\": \"mock\", \"options\": { \"time_factor\": 0 } },"
		"  \"probe\": { \"driver\": \"usb\", \"options\": { \"vendor_id\": 4660,"
		"    \"product_id\": 22136 } } } ] }";
	struct env *e = *state;
	struct asph_prescription pr;
	struct asph_surface *s;
	struct asph_config *c;
	struct asph_fit_result ref, via_usb;
	struct asph_error err;
	char dir[] = "/tmp/asph-test-usb-XXXXXX", path[64];

	assert_non_null(mkdtemp(dir));
	snprintf(path, sizeof(path), "%s/scan.asph", dir);
	assert_int_equal(asph_prescription_preset("strong", &pr), 0);
	assert_int_equal(asph_surface_alloc(&pr, &s, NULL), 0);
	struct asph_plan *plan = plan_for(s);

	assert_int_equal(asph_instrument_spec_parse(e->reg, MOCK_SPEC, &c, NULL), 0);
	scan_and_fit(c, s, plan, path, &ref);
	asph_config_free(c);

	/* the mock stage carries the USB probe */
	const struct asph_driver *mock = asph_registry_find(e->reg, "mock");
	static struct asph_stage_ops world_ops;
	static struct asph_driver world_stage;
	mock_stage = mock->stage;
	world_ops = *mock->stage;
	world_ops.home = world_home;
	world_ops.move_to = world_move;
	world_ops.sweep = NULL;
	world_stage = *mock;
	world_stage.stage = &world_ops;
	world_usb = e->sim.usb;
	struct usbtmc_sim *sim = sim_lock(e);
	sim->world_xyz = world;
	sim_unlock(e);
	if (asph_config_parse(e->reg, mixed, sizeof(mixed) - 1, "<mixed>", &c, &err) < 0)
		fail_msg("%s", err.message);
	c->instruments[0].stage_driver = &world_stage;
	scan_and_fit(c, s, plan, path, &via_usb);
	asph_config_free(c);
	assert_same_fit(&ref, &via_usb);

	/* the USB instrument's own stage and probe measure the same points
	 * (a part of the plan: its stage is polled, which takes longer) */
	sim = sim_lock(e);
	sim->world_xyz = NULL;
	sim_unlock(e);
	double *mock_pts = scan_points(e, MOCK_SPEC, s, plan, 30, path);
	double *usb_pts = scan_points(e, SPEC, s, plan, 30, path);
	for (size_t i = 0; i < 3 * 30; i++)
		if (mock_pts[i] != usb_pts[i])
			fail_msg("point %zu: %.17g vs %.17g", i / 3, mock_pts[i], usb_pts[i]);
	free(mock_pts);
	free(usb_pts);
	assert_true(fabs(ref.value[ASPH_FIT_TX] - 0.0271) < 1e-4);
	assert_clean_protocol(e);

	asph_plan_free(plan);
	asph_surface_free(s);
	rmdir(dir);
}

/* Unplugged in the middle of a scan: the scan ends with the reason and
 * keeps what it measured; the next job finds the device once it is back. */
static void test_scan_unplug(void **state)
{
	struct env *e = *state;
	struct asph_prescription pr;
	struct asph_surface *s;
	struct asph_config *c;
	struct asph_scanfile *f;
	struct asph_error err;
	char dir[] = "/tmp/asph-test-usb-XXXXXX", path[64];

	assert_non_null(mkdtemp(dir));
	snprintf(path, sizeof(path), "%s/scan.asph", dir);
	assert_int_equal(asph_prescription_preset("strong", &pr), 0);
	assert_int_equal(asph_surface_alloc(&pr, &s, NULL), 0);
	struct asph_plan *plan = plan_for(s);
	assert_int_equal(asph_instrument_spec_parse(e->reg, SPEC, &c, NULL), 0);

	struct usbtmc_sim *sim = sim_lock(e);
	usbtmc_sim_fault(sim, SIM_FAULT_UNPLUG, 160);   /* replies, open included */
	sim_unlock(e);
	assert_int_equal(scan_file(c, s, plan, 24, path, &err), -ENODEV);
	assert_non_null(strstr(err.message, "unplugged"));
	assert_int_equal(asph_scanfile_read(path, &f, NULL), 0);
	assert_int_equal(f->report.outcome, ASPH_SCANFILE_FAILED);
	assert_true(f->n > 0 && f->n < 24);
	assert_non_null(strstr(f->report.reason, "unplugged"));
	asph_scanfile_free(f);
	unlink(path);

	umu_usb_plug(e->sim.usb);
	if (scan_file(c, s, plan, 24, path, &err) < 0)
		fail_msg("after replugging: %s", err.message);
	unlink(path);
	rmdir(dir);
	asph_config_free(c);
	asph_plan_free(plan);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_open_identify, setup, teardown),
		cmocka_unit_test_setup_teardown(test_readings, setup, teardown),
		cmocka_unit_test_setup_teardown(test_transfers, setup, teardown),
		cmocka_unit_test_setup_teardown(test_scpi_errors, setup, teardown),
		cmocka_unit_test_setup_teardown(test_no_device, setup, teardown),
		cmocka_unit_test_setup_teardown(test_faults, setup, teardown),
		cmocka_unit_test_setup_teardown(test_stop, setup, teardown),
		cmocka_unit_test_setup_teardown(test_unplug, setup, teardown),
		cmocka_unit_test_setup_teardown(test_kernel_driver, setup, teardown),
		cmocka_unit_test_setup_teardown(test_end_to_end, setup, teardown),
		cmocka_unit_test_setup_teardown(test_scan_unplug, setup, teardown),
	};

	testbed = umt_testbed_new();
	int r = cmocka_run_group_tests(tests, NULL, NULL);
	g_object_unref(testbed);
	return r;
}
