/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The predicted measuring time of a CAN instrument (asph_scan_estimate
 * with the driver's motion_time): its model against closed forms, its
 * SDO exchanges against those the driver makes (counted by the simulated
 * drives), and the prediction against the same plan measured on the
 * simulated CiA 402 drives (can-sim.c, on CLOCK_MONOTONIC, a bus of 500
 * kbit/s), streamed through buffered set points with touch-probe latching
 * and point by point.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph-engine/executor.h"
#include "asph-driver/instrument.h"
#include "can-sim.h"
#include "can/timing.h"
#include "scan-fixture.h"
#include "util-time.h"

static const uint8_t node_id[3] = { 5, 9, 12 };

static bool under_valgrind(void)
{
	const char *v = getenv("ASPH_UNDER_VALGRIND");
	return v && *v && strcmp(v, "0") != 0;
}

/* ------------------------------------------------- the model alone */

static void test_model_closed_forms(void **state)
{
	struct can_timing t = { .axis = { true, true, true }, .counts_per_mm = { 1e4, 1e4, 1e4 },
				.speed = 10, .acceleration = 100 };
	double o[3] = { 0, 0, 0 };

	/* a trapezoid from rest to rest: d / v + v / a; a triangle: 2 sqrt(d / a) */
	assert_float_equal(can_move_time(&t, o, (double[3]){ 10, 0, 0 }), 1.1, 1e-12);
	assert_float_equal(can_move_time(&t, o, (double[3]){ 0, 0.25, 0 }), 0.1, 1e-12);
	/* axes on their own profiles: the longest one */
	assert_float_equal(can_move_time(&t, o, (double[3]){ 3, -10, 0.25 }), 1.1, 1e-12);

	/* a sweep on through buffered set points in one direction: one
	 * trapezoid over the whole run, whatever the points between */
	double run[5 * 3] = { 0 };
	for (int k = 0; k < 5; k++)
		run[3 * k] = 2.0 * k + (k == 2 ? 0.5 : 0);
	assert_float_equal(can_sweep_time(&t, o, run, 5), 0.8 + 0.1, 1e-12);
	/* back where it came from: it stops at the turning point */
	double back[2 * 3] = { 2, 0, 0, 0, 0, 0 };
	assert_float_equal(can_sweep_time(&t, o, back, 2), 2 * (0.2 + 0.1), 1e-12);

	/* the bus: two 111-bit frames an exchange */
	assert_float_equal(can_sdo_exchange_s(500000), 222 / 500000.0, 1e-15);
	/* one axis' move: 4 exchanges of the handshake, it sets off after
	 * the second, then polled every exchange + poll until there */
	t.sdo_s = 1e-3;
	t.poll_s = 1e-3;
	double tm = can_move_time(&t, o, (double[3]){ 0, 0, 1 });
	/* there at 2 ms + 0.2 s; the polls end at 5 ms + 2k ms >= that */
	assert_float_equal(tm, 0.005 + 0.002 * ceil((0.202 - 0.005) / 0.002), 1e-12);
	/* a sweep the bus cannot keep up with lasts at least its exchanges:
	 * 25 of them per point and axis triple for three axes */
	t.speed = 1e4;
	t.acceleration = 1e6;
	t.latch = CAN_LATCH_CONTINUOUS;
	t.trigger = true;
	double fast = can_sweep_time(&t, o, run, 5);
	/* prepare 3 x 4 + 2, per point 3 x 4 (+ 3 at the first), per trigger
	 * 2 + 3 x 2 (5 of them), the polls (one each at least, 3 x 5), the
	 * touch probes off (3) */
	assert_true(fast >= (14 + 5 * 12 + 3 + 5 * 8 + 15 + 3) * 1e-3 - 1e-12);
}

/* A CAN stage on fd, the mock probe; extra: more stage options. */
static void instrument_json(char *buf, size_t size, int fd, double speed, const char *extra)
{
	snprintf(buf, size,
		 "{\"instruments\": [{\"stage\": {\"driver\": \"can\", \"options\": {"
		 "\"interface\": \"fd:%d\", \"x_node\": 5, \"y_node\": 9, \"z_node\": 12, "
		 "\"speed\": %g, \"acceleration\": 1000000, \"heartbeat\": 20, "
		 "\"heartbeat_timeout\": 2000, \"sdo_timeout\": 500%s}}, "
		 "\"probe\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0, "
		 "\"rate\": 100000}}}]}", fd, speed, extra);
}

/* The driver's motion_time() takes the model from its options: the
 * profile, the bus at bitrate, what is latched at a trigger. */
static void test_options(void **state)
{
	static const struct {
		const char *options;
		enum can_latch latch;
		bool trigger;
		double bitrate;
	} cases[] = {
		{ "", CAN_LATCH_CONTINUOUS, true, 500000 },
		{ ", \"touch_probe\": \"off\"", CAN_LATCH_NONE, true, 500000 },
		{ ", \"trigger_output\": 0", CAN_LATCH_NONE, false, 500000 },
		{ ", \"bitrate\": 125000", CAN_LATCH_CONTINUOUS, true, 125000 },
	};
	struct scan_fixture e;
	double p[4 * 3] = { 0, 0, 0, 1, 0.5, 0, 2, 2, 0, 2.5, 1, 0 }, from[3] = { 0, 0, 0 };
	char json[1024];

	scan_fixture_init(&e, 5, "can-estimate");
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		struct asph_config *c = NULL;
		struct asph_error err;
		double sweep, move;
		struct can_timing t = { .axis = { true, true, true },
					.counts_per_mm = { 1e4, 1e4, 1e4 }, .speed = 25,
					.acceleration = 1e6, .sdo_s = can_sdo_exchange_s(cases[i].bitrate),
					.poll_s = 1e-3, .latch = cases[i].latch,
					.trigger = cases[i].trigger };
		instrument_json(json, sizeof(json), 0, 25, cases[i].options);
		if (asph_config_parse(e.reg, json, strlen(json), "<test>", &c, &err) < 0)
			fail_msg("%s", err.message);
		const struct asph_instrument_config *ic = &c->instruments[0];
		const struct asph_option_value *o = asph_options_values(ic->stage_options);
		assert_int_equal(ic->stage_driver->stage->motion_time(ic->stage_driver, o, from, p, 4,
								      true, &sweep, NULL), 0);
		assert_int_equal(ic->stage_driver->stage->motion_time(ic->stage_driver, o, from, p, 4,
								      false, &move, NULL), 0);
		assert_float_equal(sweep, can_sweep_time(&t, from, p, 4), 1e-12);
		double moves = 0;
		for (int k = 0; k < 4; k++)
			moves += can_move_time(&t, k ? p + 3 * (k - 1) : from, p + 3 * k);
		assert_float_equal(move, moves, 1e-12);
		asph_config_free(c);
	}
	scan_fixture_fini(&e);
}

/* --------------------------------------------- against the simulator */

struct sim {
	struct can_sim *sim;
	int fd;
};

/* Simulated drives on a bus of 500 kbit/s; moving at their profile
 * velocity, or at their target the moment they take it (instant). */
static void sim_start(struct sim *s, bool trigger, bool instant, uint8_t touch_probe)
{
	struct can_sim_config c;
	int sv[2];

	memset(&c, 0, sizeof(c));
	c.n_nodes = 3;
	memcpy(c.nodes, node_id, 3);
	c.heartbeat_ms = 20;
	c.speed_factor = instant ? 0 : 1;
	c.bitrate = instant ? 0 : 500000;
	for (int k = 0; k < 3; k++)
		c.touch_probe[k] = touch_probe;
	if (trigger) {
		c.trigger_node = node_id[0];
		c.trigger_bit = 16;
	}
	assert_int_equal(socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv), 0);
	assert_int_equal(can_sim_new(sv[1], &c, &s->sim), 0);
	assert_int_equal(can_sim_run(s->sim), 0);
	s->fd = sv[0];
}

/* From the first set point the drives took (the scan's first move after
 * homing) to the end of the scan, on the simulator's clock. */
static double measure(struct scan_fixture *e, struct sim *s, const char *json,
		      const struct asph_scan_options *so, double *estimate)
{
	struct asph_config *c = NULL;
	struct asph_instrument *inst = NULL;
	struct asph_scan *sc;
	struct asph_scanfile_writer *w;
	struct asph_error err;
	struct asph_scanfile_header_info hi = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						"{\"name\":\"can\"}", NULL };
	char path[128];

	if (asph_config_parse(e->reg, json, strlen(json), "<test>", &c, &err) < 0)
		fail_msg("%s", err.message);
	if (asph_scan_estimate(&c->instruments[0], e->s, e->plan->xyz, e->plan->n, so, estimate,
			       &err) < 0)
		fail_msg("estimate: %s", err.message);
	if (asph_instrument_open(&c->instruments[0], 2000, &inst, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, so, &sc, NULL), 0);
	assert_int_equal(asph_scanfile_writer_create(new_path(e, path, sizeof(path)), &hi, NULL, &w,
						     NULL), 0);
	if (asph_scan_run(sc, w, &err) < 0)
		fail_msg("scan: %s", err.message);
	uint64_t end = now_monotonic_ns(), start = UINT64_MAX;
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
	for (int k = 0; k < 3; k++) {
		struct can_sim_node sn;
		can_sim_get(s->sim, node_id[k], &sn);
		if (sn.first_set_point_ns && sn.first_set_point_ns < start)
			start = sn.first_set_point_ns;
	}
	assert_true(start < end);
	can_sim_free(s->sim);
	close(s->fd);
	struct asph_scanfile *rec = read_scan(path);
	assert_int_equal(rec->n, e->plan->n);
	asph_scanfile_free(rec);
	return (double)(end - start) * 1e-9;
}

/*
 * The tolerance: the simulated bus (can-sim.c, bitrate) sends every frame
 * with its stuff bits, which the prediction leaves out (up to 24 bits on
 * the 111 of a frame, about 10 % for these SDO frames); the bus is about
 * a third of these scans' time, so some 4 % too short. On top come the
 * simulator's sleeps, which overrun by tens of microseconds, and the
 * computation between two exchanges, which the prediction does not know:
 * 10 %. Under valgrind that computation grows tenfold and more: 15 %.
 */
static double tolerance(void)
{
	return under_valgrind() ? 0.15 : 0.10;
}

/* Set by --bench (meson test --benchmark can-estimate). */
static bool bench_mode;

/*
 * The simulated run takes wall-clock time (the bus and the drives sleep in
 * real time), which a loaded machine only lengthens. So the test asserts
 * that the prediction does not exceed the run by more than the tolerance;
 * that it does not fall short is the benchmark's check, on an idle
 * machine, beside the exact counts of test_exchanges().
 */
static void check(const char *what, double est, double sim, double tol)
{
	print_message("%s: predicted %.3f s, measured %.3f s on the simulator (%+.1f %%, "
		      "ratio %.3f)\n", what, est, sim, 100 * (est - sim) / sim, est / sim);
	if (!(est - sim <= tol * sim) || (bench_mode && !(sim - est <= tol * sim)))
		fail_msg("%s: predicted %.4f s, the simulator took %.4f s (%.1f %% off, %.0f %% allowed)",
			 what, est, sim, 100 * fabs(est - sim) / sim, 100 * tol);
}

/* A scan of n points (n_vg under valgrind) predicted and run on the
 * simulated drives, streamed with latched positions or point by point. */
static void compare(const char *what, bool stream, double n, double n_vg)
{
	bool vg = under_valgrind();
	struct scan_fixture e;
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	struct sim s;
	char json[1024];
	double est;

	scan_fixture_init(&e, vg ? n_vg : n, "can-estimate");
	sim_start(&s, stream, false, CAN_SIM_TP_FULL);
	instrument_json(json, sizeof(json), s.fd, vg ? 40 : 150, "");
	double t = measure(&e, &s, json, stream ? &so : NULL, &est);
	check(what, est, t, tolerance());
	scan_fixture_fini(&e);
}

static void test_streamed(void **state)
{
	compare("streamed", true, 30, 12);
}

static void test_point_by_point(void **state)
{
	compare("point by point", false, 12, 6);
}

/* The SDO requests the drives answered so far, all nodes. */
static unsigned sdo_requests(struct can_sim *sim)
{
	unsigned n = 0;

	for (int k = 0; k < 3; k++) {
		struct can_sim_node sn;
		can_sim_get(sim, node_id[k], &sn);
		n += sn.sdo_requests;
	}
	return n;
}

/* The model makes the exchanges the driver makes: with motion that takes
 * no time (the simulated drives at their target the moment they take it)
 * and exchanges of 1 s without polls between, the predicted time is the
 * number of exchanges, which the drives count as they answer them. */
static void test_exchanges(void **state)
{
	static const struct {
		uint8_t sim_tp;
		const char *options;
		enum can_latch latch;
	} modes[] = {
		{ CAN_SIM_TP_FULL, "", CAN_LATCH_CONTINUOUS },
		/* drives without edge counters: first-event mode, re-armed */
		{ CAN_SIM_TP_NO_COUNTER, "", CAN_LATCH_SINGLE },
		/* nothing latched: 0x6064 read back at each trigger */
		{ CAN_SIM_TP_FULL, ", \"touch_probe\": \"off\"", CAN_LATCH_NONE },
	};
	struct scan_fixture e;
	char json[1024];

	scan_fixture_init(&e, 5, "can-estimate");
	for (size_t mode = 0; mode < sizeof(modes) / sizeof(modes[0]); mode++) {
		struct sim s;
		struct asph_config *c = NULL;
		struct asph_instrument *inst = NULL;
		struct asph_error err;
		struct can_timing t = { .axis = { true, true, true },
					.counts_per_mm = { 1e4, 1e4, 1e4 }, .speed = 1e12,
					.acceleration = 1e30, .sdo_s = 1, .latch = modes[mode].latch,
					.trigger = true };
		double from[3] = { 0, 0, 0 }, p[5 * 3];

		sim_start(&s, true, true, modes[mode].sim_tp);
		instrument_json(json, sizeof(json), s.fd, 10, modes[mode].options);
		if (asph_config_parse(e.reg, json, strlen(json), "<test>", &c, &err) < 0 ||
		    asph_instrument_open(&c->instruments[0], 2000, &inst, &err) < 0)
			fail_msg("%s", err.message);
		const struct asph_stage_ops *ops = inst->stage_driver->stage;
		if (ops->home(inst->stage, 5000, &err) < 0)
			fail_msg("%s", err.message);
		/* the first move puts the drives in profile position mode: then
		 * a move of two axes, one that keeps still */
		assert_int_equal(ops->move_to(inst->stage, from, 5000, NULL), 0);
		unsigned n0 = sdo_requests(s.sim);
		double to[3] = { 1.5, -2.25, 0 };
		assert_int_equal(ops->move_to(inst->stage, to, 5000, NULL), 0);
		unsigned moved = sdo_requests(s.sim) - n0;
		assert_int_equal(moved, (unsigned)lround(can_move_time(&t, from, to)));
		/* a sweep from there; after a first one, which also enables the
		 * trigger output (0x60FE:02) once for the open */
		if (ops->sweep(inst->stage, to, 1, 5000, &err) < 0)
			fail_msg("%s", err.message);
		for (int k = 0; k < 5; k++) {
			p[3 * k] = 1.5 + 0.5 * k;
			p[3 * k + 1] = -2.25 + 0.25 * k * k;
			p[3 * k + 2] = -0.1 * k;
		}
		n0 = sdo_requests(s.sim);
		if (ops->sweep(inst->stage, p, 5, 5000, &err) < 0)
			fail_msg("%s", err.message);
		unsigned swept = sdo_requests(s.sim) - n0;
		print_message("exchanges (latch %d): move %u, sweep of 5 points %u\n",
			      modes[mode].latch, moved, swept);
		assert_int_equal(swept, (unsigned)lround(can_sweep_time(&t, to, p, 5)));
		asph_instrument_close(inst);
		asph_config_free(c);
		can_sim_free(s.sim);
		close(s.fd);
	}
	scan_fixture_fini(&e);
}

int main(int argc, char **argv)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_model_closed_forms),
		cmocka_unit_test(test_exchanges),
		cmocka_unit_test(test_options),
		cmocka_unit_test(test_streamed),
		cmocka_unit_test(test_point_by_point),
	};
	const struct CMUnitTest bench[] = {
		cmocka_unit_test(test_streamed),
		cmocka_unit_test(test_point_by_point),
	};

	if (argc > 1 && strcmp(argv[1], "--bench") == 0) {
		bench_mode = true;
		return cmocka_run_group_tests(bench, NULL, NULL);
	}
	return cmocka_run_group_tests(tests, NULL, NULL);
}
