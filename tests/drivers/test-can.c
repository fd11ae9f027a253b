/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The CAN driver against simulated CiA 402 drives on a socketpair: the
 * frame codec, enable / home / move / fault reset, every SDO abort path,
 * malformed answers, heartbeat loss (and heartbeats waiting for a busy
 * client), a drive that never answers, bus-off and error passive, stop
 * from another thread, the probe, a real interface on a kernel without
 * CAN, a gateway on a unix socket, the touch probe's objects, sweeps
 * with positions latched at the trigger (and read back where a drive has
 * no touch probe), and whole scans through the executor, stepped (compared
 * with the mock instrument's) and streamed.
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
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>
#include <linux/can/error.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph-driver/instrument.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "can-sim.h"
#include "scan-fixture.h"
#include "can/bus.h"

extern const struct asph_driver can_driver;

/* node ids and scales without symmetry */
static const uint8_t node_id[3] = { 5, 9, 12 };
static const double cpm[3] = { 8192.0, 12500.0, 20480.0 };

struct rig {
	struct can_sim *sim;
	struct asph_options *opts;
	struct asph_device *dev;
	int fd;
};

static double ms_since(const struct timespec *a)
{
	struct timespec b;
	clock_gettime(CLOCK_MONOTONIC, &b);
	return (double)(b.tv_sec - a->tv_sec) * 1e3 + (double)(b.tv_nsec - a->tv_nsec) / 1e6;
}

static void sim_config(struct can_sim_config *c, double speed_factor)
{
	memset(c, 0, sizeof(*c));
	c->n_nodes = 3;
	memcpy(c->nodes, node_id, 3);
	c->heartbeat_ms = 20;
	c->speed_factor = speed_factor;
	c->home_switch[0] = -3771;
	c->home_switch[1] = 2293;
	c->home_switch[2] = -911;
}

static void set_options(struct asph_options *o, const char *list)
{
	char buf[512], *save = NULL;
	struct asph_error err;

	snprintf(buf, sizeof(buf), "%s", list);
	for (char *kv = strtok_r(buf, ",", &save); kv; kv = strtok_r(NULL, ",", &save)) {
		char *eq = strchr(kv, '=');
		assert_non_null(eq);
		*eq = 0;
		if (asph_options_set(o, kv, eq + 1, &err) < 0)
			fail_msg("%s: %s", kv, err.message);
	}
}

/* The sim on one end of a socketpair, the options for the other. */
static void rig_start(struct rig *r, const struct can_sim_config *sc, const char *options)
{
	int sv[2];
	char base[256];

	memset(r, 0, sizeof(*r));
	assert_int_equal(socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv), 0);
	r->fd = sv[0];
	assert_int_equal(can_sim_new(sv[1], sc, &r->sim), 0);
	assert_int_equal(can_sim_run(r->sim), 0);
	assert_int_equal(asph_options_new(&can_driver, &r->opts, NULL), 0);
	snprintf(base, sizeof(base),
		 "interface=fd:%d,x_node=%u,y_node=%u,z_node=%u,x_counts_per_mm=%g,"
		 "y_counts_per_mm=%g,z_counts_per_mm=%g,heartbeat=20,heartbeat_timeout=400,"
		 "sdo_timeout=60,speed=40", r->fd, node_id[0], node_id[1], node_id[2], cpm[0], cpm[1],
		 cpm[2]);
	set_options(r->opts, base);
	if (options)
		set_options(r->opts, options);
}

static int rig_open(struct rig *r, unsigned timeout_ms, struct asph_error *err)
{
	return can_driver.stage->open(&can_driver, asph_options_values(r->opts), timeout_ms,
				      &r->dev, err);
}

static void rig_stop(struct rig *r)
{
	if (r->dev)
		can_driver.stage->close(r->dev);
	can_sim_free(r->sim);
	close(r->fd);
	asph_options_free(r->opts);
}

/* A rig with the stage open and homed. */
static void rig_ready(struct rig *r, double speed_factor, const char *options)
{
	struct can_sim_config sc;
	struct asph_error err;

	sim_config(&sc, speed_factor);
	rig_start(r, &sc, options);
	if (rig_open(r, 2000, &err) < 0 || can_driver.stage->home(r->dev, 5000, &err) < 0)
		fail_msg("%s", err.message);
}

static void expect_error(int r, int code, const struct asph_error *err, const char *words)
{
	if (r != code || !strstr(err->message, words))
		fail_msg("expected %d with '%s', got %d: %s", code, words, r, err->message);
}

/* Waits (bounded) until the sim has seen n quick stops on node. */
static unsigned quick_stops(struct can_sim *sim, uint8_t node, unsigned n)
{
	struct can_sim_node sn;
	for (int i = 0; i < 2000; i++) {
		can_sim_get(sim, node, &sn);
		if (sn.quick_stops >= n)
			break;
		usleep(1000);
	}
	return sn.quick_stops;
}

/* ------------------------------------------------------------ codec */

static void test_codec(void **state)
{
	struct can_frame f;
	struct can_event ev;

	for (uint8_t size = 1; size <= 4; size++) {
		canopen_sdo_frame(&f, 97, true, SDO_DOWNLOAD, 0x607a, 0x03, 0xa1b2c3d4u, size);
		assert_int_equal(f.can_id, 0x600 + 97);
		assert_int_equal(canopen_decode(&f, &ev), 0);
		assert_int_equal(ev.type, CAN_EV_SDO_REQUEST);
		assert_int_equal(ev.node, 97);
		assert_int_equal(ev.u.sdo.kind, SDO_DOWNLOAD);
		assert_int_equal(ev.u.sdo.index, 0x607a);
		assert_int_equal(ev.u.sdo.subindex, 3);
		assert_int_equal(ev.u.sdo.size, size);
		assert_int_equal(ev.u.sdo.value, 0xa1b2c3d4u & (size < 4 ? (1u << 8 * size) - 1 : ~0u));
		canopen_sdo_frame(&f, 33, false, SDO_UPLOAD, 0x6064, 0, 0x89abcdefu, size);
		assert_int_equal(canopen_decode(&f, &ev), 0);
		assert_int_equal(ev.type, CAN_EV_SDO_RESPONSE);
		assert_int_equal(ev.u.sdo.kind, SDO_UPLOAD);
		assert_int_equal(ev.u.sdo.size, size);
	}
	/* the bytes of CiA 301's examples */
	canopen_sdo_frame(&f, 5, true, SDO_UPLOAD, 0x6041, 0, 0, 0);
	assert_int_equal(f.data[0], 0x40);
	canopen_sdo_frame(&f, 5, true, SDO_DOWNLOAD, 0x6040, 0, 0x0f, 2);
	assert_int_equal(f.data[0], 0x2b);
	canopen_sdo_frame(&f, 5, false, SDO_DOWNLOAD, 0x6040, 0, 0, 0);
	assert_int_equal(f.data[0], 0x60);
	canopen_sdo_abort_frame(&f, 5, false, 0x6098, 0, 0x06090030);
	assert_int_equal(canopen_decode(&f, &ev), 0);
	assert_int_equal(ev.u.sdo.kind, SDO_ABORT);
	assert_int_equal(ev.u.sdo.abort_code, 0x06090030);
	/* segmented upload response: recognised, not taken for a value */
	f.data[0] = 0x41;
	assert_int_equal(canopen_decode(&f, &ev), 0);
	assert_int_equal(ev.u.sdo.kind, SDO_UNSUPPORTED);
	f.data[0] = 0xe0;       /* command specifier 7 does not exist */
	assert_int_equal(canopen_decode(&f, &ev), -EPROTO);
	f.can_dlc = 5;
	assert_int_equal(canopen_decode(&f, &ev), -EPROTO);
	f.can_dlc = 9;
	assert_int_equal(canopen_decode(&f, &ev), -EPROTO);

	canopen_nmt_frame(&f, CANOPEN_NMT_RESET_COMMUNICATION, 12);
	assert_int_equal(canopen_decode(&f, &ev), 0);
	assert_int_equal(ev.type, CAN_EV_NMT);
	assert_int_equal(ev.u.nmt.command, 0x82);
	assert_int_equal(ev.u.nmt.node, 12);
	canopen_heartbeat_frame(&f, 12, CANOPEN_STATE_OPERATIONAL);
	assert_int_equal(canopen_decode(&f, &ev), 0);
	assert_int_equal(ev.type, CAN_EV_HEARTBEAT);
	assert_int_equal(ev.u.state, 5);
	canopen_emcy_frame(&f, 12, 0x8611, 0x21);
	assert_int_equal(canopen_decode(&f, &ev), 0);
	assert_int_equal(ev.type, CAN_EV_EMCY);
	assert_int_equal(ev.u.emcy.code, 0x8611);
	assert_int_equal(ev.u.emcy.reg, 0x21);

	bool fatal;
	char text[160];
	memset(&f, 0, sizeof(f));
	f.can_id = CAN_ERR_FLAG | CAN_ERR_BUSOFF;
	f.can_dlc = 8;
	assert_int_equal(canopen_decode(&f, &ev), 0);
	assert_int_equal(ev.type, CAN_EV_BUS_ERROR);
	assert_non_null(strstr(canopen_bus_error_text(&ev, &fatal, text, sizeof(text)), "bus-off"));
	assert_true(fatal);
	f.can_id = CAN_ERR_FLAG | CAN_ERR_CRTL;
	f.data[1] = CAN_ERR_CRTL_TX_PASSIVE;
	canopen_decode(&f, &ev);
	assert_non_null(strstr(canopen_bus_error_text(&ev, &fatal, text, sizeof(text)), "error passive"));
	assert_true(fatal);
	f.data[1] = CAN_ERR_CRTL_RX_WARNING;
	canopen_decode(&f, &ev);
	canopen_bus_error_text(&ev, &fatal, text, sizeof(text));
	assert_false(fatal);

	assert_string_equal(canopen_abort_text(0x06020000),
			    "object does not exist in the object dictionary");
	assert_null(canopen_abort_text(0x06020001));
	assert_string_equal(canopen_error_text(0x8611), "following error");
	assert_string_equal(canopen_error_text(0x3333), "voltage");
	assert_string_equal(canopen_error_text(0xff42), "device specific");
}

static void test_statusword(void **state)
{
	/* statuswords as drives send them (remote, target reached, ...) */
	static const struct { uint16_t sw; enum cia402_state s; } cases[] = {
		{ 0x0200, CIA402_NOT_READY_TO_SWITCH_ON }, { 0x0250, CIA402_SWITCH_ON_DISABLED },
		{ 0x0231, CIA402_READY_TO_SWITCH_ON }, { 0x0233, CIA402_SWITCHED_ON },
		{ 0x1637, CIA402_OPERATION_ENABLED }, { 0x0617, CIA402_QUICK_STOP_ACTIVE },
		{ 0x021f, CIA402_FAULT_REACTION_ACTIVE }, { 0x0218, CIA402_FAULT },
		{ 0x0208, CIA402_FAULT }, { 0x0225, CIA402_UNKNOWN },
	};
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++)
		assert_int_equal(cia402_decode_statusword(cases[i].sw), cases[i].s);
	for (int s = 0; s < CIA402_UNKNOWN; s++)
		assert_int_equal(cia402_decode_statusword(cia402_statusword_bits(s) | 0x1600), s);
	/* the enable path and a fault reset on the rising edge only */
	enum cia402_state s = CIA402_SWITCH_ON_DISABLED;
	s = cia402_next_state(s, 0, CIA402_CW_SHUTDOWN, true);
	s = cia402_next_state(s, 6, CIA402_CW_SWITCH_ON, true);
	s = cia402_next_state(s, 7, CIA402_CW_ENABLE_OPERATION, true);
	assert_int_equal(s, CIA402_OPERATION_ENABLED);
	assert_int_equal(cia402_next_state(s, 0x0f, CIA402_CW_QUICK_STOP, true),
			 CIA402_QUICK_STOP_ACTIVE);
	assert_int_equal(cia402_next_state(CIA402_FAULT, 0x80, 0x80, true), CIA402_FAULT);
	assert_int_equal(cia402_next_state(CIA402_FAULT, 0, 0x80, false), CIA402_FAULT);
	assert_int_equal(cia402_next_state(CIA402_FAULT, 0, 0x80, true), CIA402_SWITCH_ON_DISABLED);
}

/* ------------------------------------------- enable, home, move */

static void test_enable_home_move(void **state)
{
	struct rig r;
	struct asph_error err;
	struct can_sim_node sn;
	double pos[3];
	const double target[3] = { 3.1416, -2.7183, 1.4142 };
	struct asph_stage_info info;
	struct asph_stage_status st;

	/* homing on the switches at 60 % of the profile speed */
	rig_ready(&r, 0.6, "homing_method=17,homing_speed=30");
	for (int k = 0; k < 3; k++) {
		can_sim_get(r.sim, node_id[k], &sn);
		assert_int_equal(sn.state, CIA402_OPERATION_ENABLED);
		assert_int_equal(sn.nmt, CANOPEN_STATE_OPERATIONAL);
		assert_int_equal(sn.homing_method, 17);
		assert_true(sn.homed);
		assert_int_equal(sn.position, 0);
		assert_int_equal(sn.resets, 1);         /* NMT reset communication on open */
	}
	assert_int_equal(can_driver.stage->info(r.dev, &info, NULL), 0);
	assert_int_equal(info.n_axes, 3);
	assert_true(info.axes[0].max_speed == 40);

	struct timespec t0;
	clock_gettime(CLOCK_MONOTONIC, &t0);
	if (can_driver.stage->move_to(r.dev, target, 5000, &err) < 0)
		fail_msg("%s", err.message);
	/* the longest axis, 3.1416 mm at 0.6 * 40 mm/s, takes 131 ms */
	assert_true(ms_since(&t0) >= 125);
	assert_int_equal(can_driver.stage->position(r.dev, pos, 1000, NULL), 0);
	for (int k = 0; k < 3; k++) {
		can_sim_get(r.sim, node_id[k], &sn);
		assert_int_equal(sn.target, lround(target[k] * cpm[k]));
		assert_int_equal(sn.position, sn.target);
		assert_int_equal(sn.set_points, 1);
		assert_int_equal(sn.velocity, lround(40 * cpm[k]));
		assert_int_equal(sn.mode, CIA402_MODE_PROFILE_POSITION);
		/* the handshake ended with bit 4 down */
		assert_int_equal(sn.controlword, CIA402_CW_ENABLE_OPERATION);
		assert_true(fabs(pos[k] - target[k]) <= 0.5 / cpm[k]);
	}
	/* only the axes that change move */
	const double t2[3] = { target[0], target[1], -0.5772 };
	assert_int_equal(can_driver.stage->move_to(r.dev, t2, 5000, NULL), 0);
	can_sim_get(r.sim, node_id[0], &sn);
	assert_int_equal(sn.set_points, 1);
	can_sim_get(r.sim, node_id[2], &sn);
	assert_int_equal(sn.set_points, 2);
	assert_int_equal(sn.position, lround(-0.5772 * cpm[2]));

	assert_int_equal(can_driver.stage->status(r.dev, &st, 1000, NULL), 0);
	assert_int_equal(st.state, ASPH_STAGE_IDLE);
	assert_true(st.homed);
	assert_true(fabs(st.position[2] + 0.5772) < 1e-4);

	/* outside the travel: refused before anything moves */
	const double far[3] = { 50.25, 0, 0 };
	expect_error(can_driver.stage->move_to(r.dev, far, 1000, &err), -ERANGE, &err, "outside");
	rig_stop(&r);
}

static void test_not_homed_and_absent_axis(void **state)
{
	struct rig r;
	struct can_sim_config sc;
	struct asph_error err;
	struct asph_stage_info info;
	const double t[3] = { 1.25, 0, -0.75 };
	const double ty[3] = { 1.25, 0.5, -0.75 };

	sim_config(&sc, 0);
	rig_start(&r, &sc, "y_node=0");
	assert_int_equal(rig_open(&r, 2000, NULL), 0);
	expect_error(can_driver.stage->move_to(r.dev, t, 1000, &err), -EPROTO, &err, "not homed");
	assert_int_equal(can_driver.stage->home(r.dev, 2000, NULL), 0);
	assert_int_equal(can_driver.stage->info(r.dev, &info, NULL), 0);
	assert_true(info.axes[1].min == 0 && info.axes[1].max == 0);
	assert_int_equal(can_driver.stage->move_to(r.dev, t, 1000, NULL), 0);
	expect_error(can_driver.stage->move_to(r.dev, ty, 1000, &err), -ERANGE, &err, "y_node=0");
	struct can_sim_node sn;
	can_sim_get(r.sim, node_id[1], &sn);
	assert_int_equal(sn.nmt, CANOPEN_STATE_PRE_OPERATIONAL);       /* never touched */
	rig_stop(&r);

	rig_start(&r, &sc, "y_node=5");
	expect_error(rig_open(&r, 500, &err), -EINVAL, &err, "drives two axes");
	rig_stop(&r);
}

/* ------------------------------------------------------ faults */

static void test_fault_reset(void **state)
{
	struct rig r;
	struct asph_error err;
	struct can_sim_node sn;
	const double t[3] = { 0.61, 0.37, -1.13 };

	rig_ready(&r, 0, NULL);
	can_sim_fault(r.sim, node_id[1], 0x7121, false);
	expect_error(can_driver.stage->move_to(r.dev, t, 1000, &err), -EPROTO, &err,
		     "y (node 9): drive fault, error code 0x7121 (motor blocked)");
	/* the other axes got a quick stop */
	assert_true(quick_stops(r.sim, node_id[0], 1) >= 1);
	assert_true(quick_stops(r.sim, node_id[2], 1) >= 1);
	struct asph_stage_status st;
	assert_int_equal(can_driver.stage->status(r.dev, &st, 1000, NULL), 0);
	assert_int_equal(st.state, ASPH_STAGE_FAULT);
	assert_non_null(strstr(st.detail, "0x7121"));
	/* homing resets the fault and enables again */
	if (can_driver.stage->home(r.dev, 2000, &err) < 0)
		fail_msg("%s", err.message);
	can_sim_get(r.sim, node_id[1], &sn);
	assert_int_equal(sn.fault_resets, 1);
	assert_int_equal(sn.state, CIA402_OPERATION_ENABLED);
	assert_int_equal(can_driver.stage->move_to(r.dev, t, 1000, NULL), 0);

	/* a fault that stays */
	can_sim_fault(r.sim, node_id[2], 0x3210, true);
	expect_error(can_driver.stage->home(r.dev, 2000, &err), -EPROTO, &err,
		     "0x3210 (DC link over-voltage); a fault reset did not clear it");
	rig_stop(&r);

	rig_ready(&r, 0, "fault_reset=false");
	can_sim_fault(r.sim, node_id[0], 0x4310, false);
	expect_error(can_driver.stage->home(r.dev, 2000, &err), -EPROTO, &err, "fault_reset is off");
	can_sim_get(r.sim, node_id[0], &sn);
	assert_int_equal(sn.fault_resets, 0);
	rig_stop(&r);
}

static void test_quick_stop_on_fault(void **state)
{
	struct rig r;
	struct asph_error err;
	struct can_sim_node sn;
	const double t[3] = { 4.5, -3.25, 2.75 };

	rig_ready(&r, 1, NULL);
	can_sim_fault_on_move(r.sim, node_id[0], 0x8611);
	expect_error(can_driver.stage->move_to(r.dev, t, 3000, &err), -EPROTO, &err,
		     "x (node 5): drive fault, error code 0x8611 (following error)");
	for (int k = 1; k < 3; k++) {
		assert_true(quick_stops(r.sim, node_id[k], 1) >= 1);
		can_sim_get(r.sim, node_id[k], &sn);
		assert_int_equal(sn.state, CIA402_QUICK_STOP_ACTIVE);
		/* stopped on the way, short of the target */
		assert_true(fabs((double)sn.position) < fabs(t[k] * cpm[k]) - 1);
	}
	/* homing recovers from the quick stop and the fault */
	if (can_driver.stage->home(r.dev, 3000, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(can_driver.stage->move_to(r.dev, t, 3000, NULL), 0);
	rig_stop(&r);
}

static void test_homing_error(void **state)
{
	struct rig r;
	struct can_sim_config sc;
	struct asph_error err;

	sim_config(&sc, 0);
	rig_start(&r, &sc, NULL);
	assert_int_equal(rig_open(&r, 2000, NULL), 0);
	can_sim_homing_error(r.sim, node_id[2], true);
	expect_error(can_driver.stage->home(r.dev, 2000, &err), -EPROTO, &err,
		     "z (node 12): homing error (method 37)");
	rig_stop(&r);
}

/* ------------------------------------------------------ SDO aborts */

struct abort_case {
	uint8_t axis;
	uint16_t index;
	uint8_t sub;
	uint32_t code;
	const char *text;
};

static void test_sdo_aborts(void **state)
{
	/* every abort code of CiA 301 through the bus, on a read */
	static const uint32_t codes[] = {
		0x05030000, 0x05040000, 0x05040001, 0x05040002, 0x05040003, 0x05040004, 0x05040005,
		0x06010000, 0x06010001, 0x06010002, 0x06020000, 0x06040041, 0x06040042, 0x06040043,
		0x06040047, 0x06060000, 0x06070010, 0x06070012, 0x06070013, 0x06090011, 0x06090030,
		0x06090031, 0x06090032, 0x06090036, 0x060a0023, 0x08000000, 0x08000020, 0x08000021,
		0x08000022, 0x08000023, 0x08000024,
	};
	struct rig r;
	struct asph_error err;
	double pos[3];
	char want[64];

	rig_ready(&r, 0, NULL);
	for (size_t i = 0; i < sizeof(codes) / sizeof(codes[0]); i++) {
		can_sim_abort(r.sim, node_id[1], CIA402_POSITION_ACTUAL, 0, codes[i]);
		expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -EPROTO, &err,
			     canopen_abort_text(codes[i]));
		snprintf(want, sizeof(want), "read of 0x6064:00: SDO abort 0x%08x", codes[i]);
		expect_error(-EPROTO, -EPROTO, &err, want);
	}
	can_sim_abort(r.sim, node_id[1], CIA402_POSITION_ACTUAL, 0, 0x0badc0de);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -EPROTO, &err,
		     "0x0badc0de (a code CiA 301 does not define)");
	can_sim_abort(r.sim, node_id[1], 0, 0, 0);
	assert_int_equal(can_driver.stage->position(r.dev, pos, 1000, NULL), 0);

	/* writes refused during a move: a fault, the others stopped */
	const double t[3] = { 1.5, 2.5, -3.5 };
	can_sim_abort(r.sim, node_id[2], CIA402_TARGET_POSITION, 0, 0x06090031);
	expect_error(can_driver.stage->move_to(r.dev, t, 1000, &err), -EPROTO, &err,
		     "z (node 12) refused the write of 0x607a:00: SDO abort 0x06090031 (value of "
		     "parameter written too high)");
	assert_true(quick_stops(r.sim, node_id[0], 1) >= 1);
	rig_stop(&r);

	/* the drive's own refusals: a homing method it does not have */
	rig_ready(&r, 0, NULL);
	rig_stop(&r);
	struct can_sim_config sc;
	sim_config(&sc, 0);
	rig_start(&r, &sc, "homing_method=21");
	assert_int_equal(rig_open(&r, 2000, NULL), 0);
	expect_error(can_driver.stage->home(r.dev, 2000, &err), -EPROTO, &err,
		     "refused the write of 0x6098:00: SDO abort 0x06090030 (invalid value for parameter)");
	rig_stop(&r);

	/* on open: not a drive, and a heartbeat it cannot produce */
	static const struct abort_case open_cases[] = {
		{ 0, CANOPEN_DEVICE_TYPE, 0, 0x06060000, "access failed due to a hardware error" },
		{ 2, CANOPEN_HEARTBEAT_TIME, 0, 0x06010002, "attempt to write a read-only object" },
	};
	for (size_t i = 0; i < 2; i++) {
		const struct abort_case *c = &open_cases[i];
		rig_start(&r, &sc, NULL);
		can_sim_abort(r.sim, node_id[c->axis], c->index, c->sub, c->code);
		expect_error(rig_open(&r, 2000, &err), -EPROTO, &err, c->text);
		rig_stop(&r);
	}
	sc.device_type[1] = 0x00000194;         /* a CiA 404 device */
	rig_start(&r, &sc, NULL);
	expect_error(rig_open(&r, 2000, &err), -EPROTO, &err,
		     "y (node 9) is not a CiA 402 drive (device type 0x00000194: profile 404)");
	rig_stop(&r);
}

static void test_malformed_answers(void **state)
{
	struct rig r;
	struct asph_error err;
	double pos[3];

	rig_ready(&r, 0, NULL);
	can_sim_garble(r.sim, node_id[0], CAN_SIM_SHORT);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -EPROTO, &err,
		     "malformed SDO response (length 5)");
	can_sim_garble(r.sim, node_id[0], CAN_SIM_SEGMENTED);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -EPROTO, &err,
		     "with a segmented or block transfer");
	can_sim_garble(r.sim, node_id[0], CAN_SIM_OTHER_INDEX);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -ETIMEDOUT, &err,
		     "it answered about another object");
	/* a datagram longer than a frame is no frame, even with the answer in
	 * its first 16 bytes (a datagram socket would cut it to fit) */
	can_sim_garble(r.sim, node_id[0], CAN_SIM_LONG);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -ETIMEDOUT, &err,
		     "x (node 5): no answer to the SDO upload (read) of 0x6064:00");
	assert_int_equal(can_driver.stage->position(r.dev, pos, 1000, NULL), 0);
	rig_stop(&r);
}

/* ---------------------------------------------- lost and silent */

static void test_heartbeat_lost(void **state)
{
	struct rig r;
	struct asph_error err;
	struct timespec t0;
	const double t[3] = { 9.75, -8.5, 6.25 };

	/* a slow move, during which y's heartbeat stops */
	rig_ready(&r, 0.25, "heartbeat_timeout=150");
	can_sim_heartbeat(r.sim, node_id[1], false);
	clock_gettime(CLOCK_MONOTONIC, &t0);
	expect_error(can_driver.stage->move_to(r.dev, t, 10000, &err), -ENODEV, &err,
		     "y (node 9): heartbeat lost (none for 150 ms)");
	assert_true(ms_since(&t0) < 900);       /* the move would take 975 ms */
	assert_true(quick_stops(r.sim, node_id[0], 1) >= 1);
	assert_true(quick_stops(r.sim, node_id[2], 1) >= 1);
	struct can_sim_node sn;
	can_sim_get(r.sim, node_id[1], &sn);
	assert_int_equal(sn.quick_stops, 0);    /* not answering: not asked */
	rig_stop(&r);

	/* a drive that restarts on its own has lost its state and home */
	rig_ready(&r, 0, "nmt_reset=node");
	can_sim_reboot(r.sim, node_id[2]);
	for (int i = 0; i < 200; i++) {
		can_sim_get(r.sim, node_id[2], &sn);
		if (sn.resets == 2)
			break;
		usleep(1000);
	}
	assert_int_equal(sn.resets, 2);
	double pos[3];
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -EPROTO, &err,
		     "z (node 12) restarted (boot-up message)");
	rig_stop(&r);
}

/* A client busy elsewhere (a slow probe) for longer than the heartbeat
 * timeout finds the heartbeats that came meanwhile waiting: not a loss. */
static void test_busy_client(void **state)
{
	struct rig r;
	struct asph_error err;
	double pos[3];
	const double t[3] = { 1.375, -2.125, 0.625 };

	rig_ready(&r, 0, "heartbeat_timeout=150");
	for (int i = 0; i < 3; i++) {
		usleep(400000);
		if ((i == 1 ? can_driver.stage->move_to(r.dev, t, 2000, &err)
			    : can_driver.stage->position(r.dev, pos, 1000, &err)) < 0)
			fail_msg("after 400 ms away: %s", err.message);
	}
	/* a heartbeat that stops is still noticed */
	can_sim_heartbeat(r.sim, node_id[2], false);
	usleep(400000);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -ENODEV, &err,
		     "z (node 12): heartbeat lost (none for 150 ms)");
	rig_stop(&r);
}

static void test_silent_drive(void **state)
{
	struct rig r;
	struct can_sim_config sc;
	struct asph_error err;
	struct timespec t0;
	double pos[3];

	sim_config(&sc, 0);
	rig_start(&r, &sc, NULL);
	can_sim_silence(r.sim, node_id[2], true);
	clock_gettime(CLOCK_MONOTONIC, &t0);
	expect_error(rig_open(&r, 300, &err), -ETIMEDOUT, &err,
		     "z (node 12) sent no boot-up message within 300 ms");
	assert_true(ms_since(&t0) < 1000);
	rig_stop(&r);

	rig_start(&r, &sc, "nmt_reset=none");
	can_sim_silence(r.sim, node_id[0], true);
	expect_error(rig_open(&r, 300, &err), -ETIMEDOUT, &err,
		     "x (node 5): no answer to the SDO upload (read) of 0x1000:00 within 60 ms");
	rig_stop(&r);

	/* goes quiet after homing: every call ends in its time */
	rig_ready(&r, 0, NULL);
	can_sim_silence(r.sim, node_id[1], true);
	clock_gettime(CLOCK_MONOTONIC, &t0);
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -ETIMEDOUT, &err,
		     "y (node 9): no answer");
	struct asph_stage_status st;
	assert_int_equal(can_driver.stage->status(r.dev, &st, 1000, NULL), 0);
	assert_int_equal(st.state, ASPH_STAGE_DISCONNECTED);
	const double t[3] = { 1, 2, 3 };
	int rc = can_driver.stage->move_to(r.dev, t, 1000, &err);
	assert_true(rc == -ETIMEDOUT || rc == -ENODEV);
	assert_true(ms_since(&t0) < 2500);
	/* a timeout of 0 polls once and returns */
	clock_gettime(CLOCK_MONOTONIC, &t0);
	rc = can_driver.stage->position(r.dev, pos, 0, &err);
	assert_true(rc == -ETIMEDOUT || rc == -ENODEV);
	assert_true(ms_since(&t0) < 200);
	rig_stop(&r);
}

static void test_bus_errors(void **state)
{
	struct rig r;
	struct asph_error err;
	const double t[3] = { 7.25, 6.5, -5.75 };

	rig_ready(&r, 0.25, NULL);
	can_sim_error_frame(r.sim, CAN_ERR_BUSOFF, 0);
	expect_error(can_driver.stage->move_to(r.dev, t, 5000, &err), -EIO, &err, "bus-off");
	expect_error(can_driver.stage->move_to(r.dev, t, 5000, &err), -EIO, &err, "fd:");
	rig_stop(&r);

	rig_ready(&r, 0.25, NULL);
	can_sim_error_frame(r.sim, CAN_ERR_CRTL, CAN_ERR_CRTL_RX_PASSIVE);
	expect_error(can_driver.stage->move_to(r.dev, t, 5000, &err), -EIO, &err, "error passive");
	assert_true(quick_stops(r.sim, node_id[0], 1) >= 1);
	rig_stop(&r);

	/* a warning is no fault, but explains a silence */
	rig_ready(&r, 0, NULL);
	can_sim_error_frame(r.sim, CAN_ERR_ACK, 0);
	assert_int_equal(can_driver.stage->move_to(r.dev, t, 5000, NULL), 0);
	can_sim_silence(r.sim, node_id[0], true);
	double pos[3];
	expect_error(can_driver.stage->position(r.dev, pos, 1000, &err), -ETIMEDOUT, &err,
		     "no node acknowledges");
	rig_stop(&r);
}

struct stopper {
	struct asph_device *dev;
	unsigned delay_ms;
};

static void *stop_later(void *data)
{
	struct stopper *s = data;
	usleep(s->delay_ms * 1000);
	can_driver.stage->stop(s->dev, NULL);
	return NULL;
}

static void test_stop(void **state)
{
	struct rig r;
	struct asph_error err;
	struct timespec t0;
	pthread_t th;
	const double t[3] = { 12.5, -11.25, 10.75 };

	rig_ready(&r, 0.25, NULL);
	struct stopper s = { r.dev, 60 };
	assert_int_equal(pthread_create(&th, NULL, stop_later, &s), 0);
	clock_gettime(CLOCK_MONOTONIC, &t0);
	expect_error(can_driver.stage->move_to(r.dev, t, 10000, &err), -ECANCELED, &err, "stopped");
	assert_true(ms_since(&t0) < 800);
	pthread_join(th, NULL);
	for (int k = 0; k < 3; k++) {
		struct can_sim_node sn;
		assert_true(quick_stops(r.sim, node_id[k], 1) >= 1);
		can_sim_get(r.sim, node_id[k], &sn);
		assert_int_equal(sn.state, CIA402_QUICK_STOP_ACTIVE);
	}
	expect_error(can_driver.stage->move_to(r.dev, t, 1000, &err), -ECANCELED, &err, "reopen");
	rig_stop(&r);
}

/* ------------------------------------------------------ probe, kernel */

static void test_probe(void **state)
{
	struct can_sim_config sc = { .n_nodes = 1, .nodes = { 23 }, .device_type = { 0x00010194 },
				     .heartbeat_ms = 20 };
	struct asph_options *o;
	struct can_sim *sim;
	struct asph_device *dev;
	struct asph_probe_info pi;
	struct asph_reading rd;
	struct asph_probe_context ctx = { 0 };
	struct asph_error err;
	int sv[2];
	char opt[160];

	assert_int_equal(socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv), 0);
	assert_int_equal(can_sim_new(sv[1], &sc, &sim), 0);
	assert_int_equal(can_sim_run(sim), 0);
	assert_int_equal(asph_options_new(&can_driver, &o, NULL), 0);
	snprintf(opt, sizeof(opt), "interface=fd:%d,probe_node=23,probe_scale=0.00025,"
		 "probe_offset=1.75,probe_standoff=2.5,probe_range=4", sv[0]);
	set_options(o, opt);
	if (can_driver.probe->open(&can_driver, asph_options_values(o), 1000, &dev, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(can_driver.probe->info(dev, &pi, NULL), 0);
	assert_true(pi.range_min == 0.5 && pi.range_max == 4.5);
	can_sim_set_probe(sim, 23, -1234);
	assert_int_equal(can_driver.probe->read(dev, &ctx, &rd, 500, NULL), 0);
	assert_true(rd.raw == -1234);
	assert_true(fabs(rd.value - (1.75 - 1234 * 0.00025)) < 1e-12);
	assert_false(rd.flags & ASPH_READING_OUT_OF_RANGE);
	can_sim_set_probe(sim, 23, 31111);
	assert_int_equal(can_driver.probe->read(dev, &ctx, &rd, 500, NULL), 0);
	assert_true(rd.flags & ASPH_READING_OUT_OF_RANGE);
	can_sim_abort(sim, 23, 0x7130, 1, 0x08000024);
	expect_error(can_driver.probe->read(dev, &ctx, &rd, 500, &err), -EPROTO, &err,
		     "probe (node 23) refused the read of 0x7130:01: SDO abort 0x08000024 (no data available)");
	can_driver.probe->close(dev);
	asph_options_free(o);
	can_sim_free(sim);
	close(sv[0]);
}

static void test_real_interface(void **state)
{
	struct asph_options *o;
	struct asph_device *dev = NULL;
	struct asph_error err;

	assert_int_equal(asph_options_new(&can_driver, &o, NULL), 0);
	int r = can_driver.stage->open(&can_driver, asph_options_values(o), 200, &dev, &err);
	assert_int_equal(r, -ENODEV);
	/* this kernel has no CAN, or has it and no can0 */
	if (!strstr(err.message, "CAN is not supported by this kernel"))
		assert_non_null(strstr(err.message, "can0"));
	set_options(o, "interface=fd:xyz");
	expect_error(can_driver.stage->open(&can_driver, asph_options_values(o), 200, &dev, &err),
		     -EINVAL, &err, "expected fd:N");
	asph_options_free(o);
}

/* ------------------------------------------- a unix socket gateway */

/* Hands the next connection to a new sim. */
struct gateway {
	int listen_fd;
	struct can_sim *sim;
	pthread_t thread;
};

static void *gateway_accept(void *data)
{
	struct gateway *g = data;
	struct can_sim_config sc;
	int fd = accept4(g->listen_fd, NULL, NULL, SOCK_CLOEXEC);

	g->sim = NULL;
	sim_config(&sc, 0);
	if (fd >= 0 && can_sim_new(fd, &sc, &g->sim) == 0)
		can_sim_run(g->sim);
	else if (fd >= 0)
		close(fd);
	return NULL;
}

static int listen_unix(const char *path, int type)
{
	struct sockaddr_un addr = { .sun_family = AF_UNIX };
	int fd = socket(AF_UNIX, type | SOCK_CLOEXEC, 0);

	assert_true(fd >= 0 && strlen(path) < sizeof(addr.sun_path));
	memcpy(addr.sun_path, path, strlen(path));
	assert_int_equal(bind(fd, (struct sockaddr *)&addr, sizeof(addr)), 0);
	assert_int_equal(listen(fd, 4), 0);
	return fd;
}

/* Opens the stage through the gateway's next connection. */
static int gateway_open(struct gateway *g, struct asph_options *o, struct asph_device **dev,
			struct asph_error *err)
{
	assert_int_equal(pthread_create(&g->thread, NULL, gateway_accept, g), 0);
	int r = can_driver.stage->open(&can_driver, asph_options_values(o), 2000, dev, err);
	if (r < 0)
		shutdown(g->listen_fd, SHUT_RD);        /* no connection comes: end the accept */
	pthread_join(g->thread, NULL);
	return r;
}

static void test_unix_gateway(void **state)
{
	char dir[] = "/tmp/asph-test-can-XXXXXX", path[64], opt[320];
	const double t[3] = { 2.375, -1.625, 0.875 };
	struct gateway g = { 0 };
	struct asph_options *o;
	struct asph_device *dev = NULL;
	struct asph_error err;
	struct can_sim_node sn;

	assert_non_null(mkdtemp(dir));
	snprintf(path, sizeof(path), "%s/can0.sock", dir);
	assert_int_equal(asph_options_new(&can_driver, &o, NULL), 0);
	snprintf(opt, sizeof(opt), "interface=unix:%s,x_node=%u,y_node=%u,z_node=%u,heartbeat=20,"
		 "sdo_timeout=200", path, node_id[0], node_id[1], node_id[2]);
	set_options(o, opt);
	expect_error(can_driver.stage->open(&can_driver, asph_options_values(o), 500, &dev, &err),
		     -ENODEV, &err, "no CAN gateway listens there");
	assert_non_null(strstr(err.message, path));
	int stream = listen_unix(path, SOCK_STREAM);
	expect_error(can_driver.stage->open(&can_driver, asph_options_values(o), 500, &dev, &err),
		     -ENODEV, &err, "not a SOCK_SEQPACKET socket");
	close(stream);
	unlink(path);

	/* every open connects anew; the drives move */
	g.listen_fd = listen_unix(path, SOCK_SEQPACKET);
	for (int k = 0; k < 2; k++) {
		if (gateway_open(&g, o, &dev, &err) < 0 || can_driver.stage->home(dev, 2000, &err) < 0 ||
		    can_driver.stage->move_to(dev, t, 2000, &err) < 0)
			fail_msg("open %d: %s", k, err.message);
		can_sim_get(g.sim, node_id[1], &sn);
		assert_int_equal(sn.position, -16250);  /* 10000 counts/mm by default */
		can_driver.stage->close(dev);
		can_sim_free(g.sim);
	}
	/* the gateway goes away during a job */
	if (gateway_open(&g, o, &dev, &err) < 0 || can_driver.stage->home(dev, 2000, &err) < 0)
		fail_msg("%s", err.message);
	can_sim_free(g.sim);
	expect_error(can_driver.stage->move_to(dev, t, 2000, &err), -ENODEV, &err,
		     "the device closed the connection");
	assert_non_null(strstr(err.message, path));
	can_driver.stage->close(dev);
	close(g.listen_fd);
	unlink(path);
	rmdir(dir);

	snprintf(opt, sizeof(opt), "interface=unix:/tmp/%0120d", 7);
	set_options(o, opt);
	expect_error(can_driver.stage->open(&can_driver, asph_options_values(o), 500, &dev, &err),
		     -EINVAL, &err, "a socket path of 1 to 107 bytes");
	asph_options_free(o);
}


/* ----------------------------------------------- touch probe, sweeps */

static uint64_t now_ns(void)
{
	struct timespec t;
	clock_gettime(CLOCK_MONOTONIC, &t);
	return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

/* A raw CANopen client on a simulated drive, for the objects themselves. */
struct raw {
	struct can_sim *sim;
	struct can_bus *bus;
	int fd;
};

static void raw_start(struct raw *w, const struct can_sim_config *sc)
{
	int sv[2];

	assert_int_equal(socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv), 0);
	w->fd = sv[0];
	assert_int_equal(can_sim_new(sv[1], sc, &w->sim), 0);
	assert_int_equal(can_sim_run(w->sim), 0);
	char iface[32];
	snprintf(iface, sizeof(iface), "fd:%d", sv[0]);
	assert_int_equal(can_bus_open(iface, sc->nodes, sc->n_nodes, &w->bus, NULL), 0);
}

static void raw_stop(struct raw *w)
{
	can_bus_free(w->bus);
	can_sim_free(w->sim);
	close(w->fd);
}

static void raw_write(struct raw *w, uint8_t node, uint16_t index, uint8_t sub, uint32_t v,
		      uint8_t size)
{
	struct asph_error err;

	if (can_bus_sdo_download(w->bus, node, index, sub, v, size, 500, &err) < 0)
		fail_msg("0x%04x:%02x = 0x%x: %s", index, sub, v, err.message);
}

static uint32_t raw_read(struct raw *w, uint8_t node, uint16_t index, uint8_t sub)
{
	struct asph_error err;
	uint32_t v = 0;

	if (can_bus_sdo_upload(w->bus, node, index, sub, &v, 500, &err) < 0)
		fail_msg("0x%04x:%02x: %s", index, sub, err.message);
	return v;
}

/* The write (size > 0) or read is refused with this abort code. */
static void raw_refused(struct raw *w, uint8_t node, uint16_t index, uint8_t sub, uint32_t v,
			uint8_t size, uint32_t code)
{
	struct asph_error err;
	uint32_t got;
	int r = size ? can_bus_sdo_download(w->bus, node, index, sub, v, size, 500, &err)
		     : can_bus_sdo_upload(w->bus, node, index, sub, &got, 500, &err);

	if (r != -EPROTO || can_bus_last_abort(w->bus) != code)
		fail_msg("0x%04x:%02x (0x%x, %u bytes): expected abort 0x%08x, got %d (0x%08x)",
			 index, sub, v, size, code, r, can_bus_last_abort(w->bus));
}

/* The drive enabled in profile position mode, a set point reached at once. */
static void raw_move(struct raw *w, uint8_t node, int32_t target)
{
	raw_write(w, node, CIA402_TARGET_POSITION, 0, (uint32_t)target, 4);
	raw_write(w, node, CIA402_CONTROLWORD, 0, 0x1f, 2);
	raw_write(w, node, CIA402_CONTROLWORD, 0, 0x0f, 2);
}

static void test_touch_probe_objects(void **state)
{
	struct can_sim_config sc;
	struct raw w;
	const uint8_t n = node_id[0];

	sim_config(&sc, 0);
	sc.touch_probe[1] = CAN_SIM_TP_NO_COUNTER;
	sc.touch_probe[2] = CAN_SIM_TP_NONE;
	sc.trigger_node = n;
	sc.trigger_bit = 17;
	raw_start(&w, &sc);
	raw_write(&w, n, CIA402_CONTROLWORD, 0, CIA402_CW_SHUTDOWN, 2);
	raw_write(&w, n, CIA402_CONTROLWORD, 0, CIA402_CW_SWITCH_ON, 2);
	raw_write(&w, n, CIA402_CONTROLWORD, 0, CIA402_CW_ENABLE_OPERATION, 2);
	raw_write(&w, n, CIA402_MODE, 0, CIA402_MODE_PROFILE_POSITION, 1);

	/* refusals, with the abort codes of CiA 301 */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x11, 4, 0x06070012);
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x11, 1, 0x06070013);
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 1, 0x11, 2, 0x06090011);
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0015, 2, 0x06090030); /* zero impulse */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0019, 2, 0x06090030); /* 0x60D0 */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x001d, 2, 0x06090030); /* reserved */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0111, 2, 0x06090030); /* probe 2 */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0051, 2, 0x06090030); /* bit 6 */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_STATUS, 0, 0, 2, 0x06010002);
	raw_refused(&w, n, CIA402_TOUCH_PROBE1_POSITIVE, 0, 0, 4, 0x06010002);
	raw_refused(&w, n, CIA402_TOUCH_PROBE1_NEGATIVE, 0, 0, 4, 0x06010002);
	raw_refused(&w, n, CIA402_TOUCH_PROBE1_POS_COUNT, 0, 0, 2, 0x06010002);
	raw_refused(&w, n, CIA402_DIGITAL_OUTPUTS, 0, 2, 1, 0x06010002);
	raw_refused(&w, n, CIA402_DIGITAL_OUTPUTS, 1, 1u << 3, 4, 0x06090030); /* reserved bit */
	raw_refused(&w, n, CIA402_DIGITAL_OUTPUTS, 3, 0, 0, 0x06090011);
	raw_refused(&w, node_id[2], CIA402_TOUCH_PROBE_FUNCTION, 0, 0, 0, 0x06020000);
	raw_refused(&w, node_id[2], CIA402_TOUCH_PROBE_FUNCTION, 0, 0x11, 2, 0x06020000);
	raw_refused(&w, node_id[1], CIA402_TOUCH_PROBE1_POS_COUNT, 0, 0, 0, 0x06020000);
	assert_int_equal(raw_read(&w, node_id[1], CIA402_TOUCH_PROBE_FUNCTION, 0), 0);

	/* switched off, or on without an edge: nothing is latched */
	raw_move(&w, n, 777);
	can_sim_trigger(w.sim, true);
	can_sim_trigger(w.sim, false);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0);
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, CIA402_TP_ENABLE, 2);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), CIA402_TPS_ENABLED);
	can_sim_trigger(w.sim, true);
	can_sim_trigger(w.sim, false);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), CIA402_TPS_ENABLED);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE1_POS_COUNT, 0), 0);

	/* first event: one rising edge latches, later ones do not */
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0011, 2);
	raw_move(&w, n, 1234);
	can_sim_trigger(w.sim, true);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0x0003);
	assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_POSITIVE, 0), 1234);
	raw_move(&w, n, -2000);
	can_sim_trigger(w.sim, false);
	can_sim_trigger(w.sim, true);
	assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_POSITIVE, 0), 1234);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE1_POS_COUNT, 0), 1);
	/* no change of mode while switched on */
	raw_refused(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0013, 2, 0x08000022);
	/* a rising edge of bit 4 arms it again and clears the stored flag */
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0001, 2);
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0011, 2);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0x0001);
	can_sim_trigger(w.sim, false);
	can_sim_trigger(w.sim, true);
	assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_POSITIVE, 0), -2000);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0x0003);

	/* both edges, first event each: the falling one into 0x60BB */
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0, 2);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0);
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0031, 2);
	raw_move(&w, n, 3000);
	can_sim_trigger(w.sim, false);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0x0005);
	assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_NEGATIVE, 0), 3000);
	raw_move(&w, n, 3500);
	can_sim_trigger(w.sim, true);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0x0007);
	assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_POSITIVE, 0), 3500);
	assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_NEGATIVE, 0), 3000);

	/* continuous: every rising edge overwrites and counts */
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0, 2);
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0x0013, 2);
	uint32_t c0 = raw_read(&w, n, CIA402_TOUCH_PROBE1_POS_COUNT, 0);
	for (int32_t k = 1; k <= 3; k++) {
		raw_move(&w, n, 100 * k);
		can_sim_trigger(w.sim, false);
		can_sim_trigger(w.sim, true);
		assert_int_equal((int32_t)raw_read(&w, n, CIA402_TOUCH_PROBE1_POSITIVE, 0), 100 * k);
		assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE1_POS_COUNT, 0), c0 + (uint32_t)k);
		assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0x0003);
	}
	raw_write(&w, n, CIA402_TOUCH_PROBE_FUNCTION, 0, 0, 2);
	assert_int_equal(raw_read(&w, n, CIA402_TOUCH_PROBE_STATUS, 0), 0);

	/* the trigger output: only an enabled output (0x60FE:02) drives the line */
	can_sim_trigger(w.sim, false);
	struct can_sim_edge e[64];
	size_t before = can_sim_edges(w.sim, e, 64);
	raw_write(&w, n, CIA402_DIGITAL_OUTPUTS, 1, 1u << 17, 4);
	assert_int_equal(can_sim_edges(w.sim, e, 64), before);
	raw_write(&w, n, CIA402_DIGITAL_OUTPUTS, 2, 1u << 17, 4);
	assert_int_equal(can_sim_edges(w.sim, e, 64), before + 1);
	assert_true(e[before].rising);
	raw_write(&w, n, CIA402_DIGITAL_OUTPUTS, 1, 1u << 16, 4);
	assert_int_equal(can_sim_edges(w.sim, e, 64), before + 2);
	assert_false(e[before + 1].rising);
	raw_write(&w, node_id[1], CIA402_DIGITAL_OUTPUTS, 2, 1u << 17, 4);
	raw_write(&w, node_id[1], CIA402_DIGITAL_OUTPUTS, 1, 1u << 17, 4);
	assert_int_equal(can_sim_edges(w.sim, e, 64), before + 2);    /* not wired */
	raw_stop(&w);
}

/* A zigzag of n points from the origin, 0.8 mm apart in x. */
static void zigzag(double *p, size_t n)
{
	for (size_t k = 0; k < n; k++) {
		p[3 * k] = 0.8 * (double)(k + 1);
		p[3 * k + 1] = (k % 2 ? 0.3 : -0.2);
		p[3 * k + 2] = -0.05 * (double)k;
	}
}

/* The sweep's trace against the simulator's edges: one latched position
 * per trigger, each the encoders at that rising edge, to the count. */
static size_t check_latched(struct rig *r, const double *p, size_t n)
{
	struct asph_position_sample tr[32];
	struct can_sim_edge e[64];
	size_t got = 0, moving = 0, m = 0;

	assert_int_equal(can_driver.stage->sweep_trace(r->dev, tr, 32, &got, 100, NULL), 0);
	assert_int_equal(got, n);
	size_t ne = can_sim_edges(r->sim, e, 64);
	for (size_t k = 0; k < ne; k++)
		if (e[k].rising)
			e[m++] = e[k];
	assert_int_equal(m, n);
	for (size_t k = 0; k < n; k++) {
		assert_int_equal(tr[k].source, ASPH_POSITION_LATCHED);
		assert_int_equal(tr[k].trigger, k);
		bool off = false;
		for (int a = 0; a < 3; a++) {
			double c = tr[k].position[a] * cpm[a];
			if (fabs(c - (double)e[k].encoder[a]) > 1e-6)
				fail_msg("trigger %zu axis %d: latched %.3f counts, encoder %d", k, a, c,
					 e[k].encoder[a]);
			off = off || fabs(c - nearbyint(p[3 * k + a] * cpm[a])) > 2;
		}
		moving += off;
	}
	/* the last trigger fires at rest, on the last point */
	for (int a = 0; a < 3; a++)
		assert_true(fabs(tr[n - 1].position[a] * cpm[a] -
				 nearbyint(p[3 * (n - 1) + a] * cpm[a])) < 1e-6);
	assert_int_equal(can_driver.stage->sweep_trace(r->dev, tr, 32, &got, 100, NULL), 0);
	assert_int_equal(got, 0);
	return moving;
}

static void sweep_rig(struct rig *r, uint8_t tp_y, const char *options)
{
	struct can_sim_config sc;
	struct asph_error err;

	sim_config(&sc, 1);
	sc.touch_probe[1] = tp_y;
	sc.trigger_node = node_id[0];
	sc.trigger_bit = 16;
	rig_start(r, &sc, options);
	if (rig_open(r, 2000, &err) < 0 || can_driver.stage->home(r->dev, 5000, &err) < 0)
		fail_msg("%s", err.message);
}

static void test_sweep_latched(void **state)
{
	struct rig r;
	struct asph_error err;
	struct can_sim_node sn;
	double p[3 * 8];

	/* continuous mode (every drive counts its edges), then the first-event
	 * mode re-armed after each trigger where y's drive has no counter */
	for (int pass = 0; pass < 2; pass++) {
		sweep_rig(&r, pass ? CAN_SIM_TP_NO_COUNTER : CAN_SIM_TP_FULL, "speed=20");
		zigzag(p, 8);
		if (can_driver.stage->sweep(r.dev, p, 8, 10000, &err) < 0)
			fail_msg("%s", err.message);
		/* the axes ran on past each point (but the last) when it fired */
		assert_true(check_latched(&r, p, 8) >= 4);
		can_sim_get(r.sim, node_id[0], &sn);
		assert_true(sn.buffered_set_points >= 4);
		assert_int_equal(sn.tp_function, 0);   /* switched off after the sweep */
		can_sim_get(r.sim, node_id[1], &sn);
		assert_int_equal(sn.position, (int32_t)nearbyint(p[3 * 7 + 1] * cpm[1]));
		/* a move after it starts from where the sweep left the stage */
		const double t[3] = { 1, 1, 0 };
		assert_int_equal(can_driver.stage->move_to(r.dev, t, 5000, NULL), 0);
		rig_stop(&r);
	}
}

static void test_sweep_fallback(void **state)
{
	struct rig r;
	struct asph_error err;
	struct asph_position_sample tr[16];
	struct can_sim_edge e[64];
	struct can_sim_config sc;
	double p[3 * 4];
	size_t got;

	/* y's drive has no touch probe: positions read back right after each
	 * trigger, by time (the probe is still triggered) */
	sweep_rig(&r, CAN_SIM_TP_NONE, "speed=20");
	zigzag(p, 4);
	uint64_t t0 = now_ns();
	if (can_driver.stage->sweep(r.dev, p, 4, 10000, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(can_driver.stage->sweep_trace(r.dev, tr, 16, &got, 100, NULL), 0);
	assert_int_equal(got, 4);
	size_t ne = can_sim_edges(r.sim, e, 64);
	assert_int_equal(ne, 8);
	for (size_t k = 0; k < 4; k++) {
		assert_int_equal(tr[k].source, ASPH_POSITION_READ_BACK);
		assert_true(tr[k].t_ns > (k ? tr[k - 1].t_ns : t0));
		/* read after the edge: x at or past where it was then */
		assert_true(tr[k].position[0] * cpm[0] >= e[2 * k].encoder[0] - 1e-6);
		for (int a = 0; a < 3; a++)
			assert_true(fabs(tr[k].position[a] * cpm[a] - nearbyint(tr[k].position[a] * cpm[a])) < 1e-6);
	}
	rig_stop(&r);

	/* touch_probe=on refuses a drive without one; off never latches */
	sim_config(&sc, 1);
	sc.touch_probe[1] = CAN_SIM_TP_NONE;
	rig_start(&r, &sc, "touch_probe=on");
	expect_error(rig_open(&r, 2000, &err), -EPROTO, &err,
		     "y (node 9) has no touch probe (0x60B8 does not exist)");
	rig_stop(&r);
	sweep_rig(&r, CAN_SIM_TP_FULL, "touch_probe=off,speed=20");
	if (can_driver.stage->sweep(r.dev, p, 2, 10000, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(can_driver.stage->sweep_trace(r.dev, tr, 16, &got, 100, NULL), 0);
	assert_int_equal(got, 2);
	assert_int_equal(tr[0].source, ASPH_POSITION_READ_BACK);
	rig_stop(&r);
	/* no trigger wiring: no edges at all */
	sweep_rig(&r, CAN_SIM_TP_FULL, "trigger_output=0,speed=20");
	if (can_driver.stage->sweep(r.dev, p, 2, 10000, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(can_sim_edges(r.sim, e, 64), 0);
	assert_int_equal(can_driver.stage->sweep_trace(r.dev, tr, 16, &got, 100, NULL), 0);
	assert_int_equal(tr[1].source, ASPH_POSITION_READ_BACK);
	rig_stop(&r);
}

static void test_sweep_faults(void **state)
{
	struct rig r;
	struct asph_error err;
	struct can_sim_config sc;
	double p[3 * 3];

	zigzag(p, 3);
	/* the options */
	static const char *const bad[][2] = {
		{ "trigger_output=7", "bit 7 of 0x60FE:01 is not an output" },
		{ "trigger_node=77", "trigger_node 77 is not one of the axes' drives" },
		{ "touch_probe=on,trigger_output=0", "touch_probe=on needs the trigger wiring" },
	};
	sim_config(&sc, 0);
	for (size_t i = 0; i < 3; i++) {
		rig_start(&r, &sc, bad[i][0]);
		expect_error(rig_open(&r, 2000, &err), -EINVAL, &err, bad[i][1]);
		rig_stop(&r);
	}
	/* the output is not wired to the touch probes: no edge latched, the
	 * axes stopped */
	sim_config(&sc, 1);
	rig_start(&r, &sc, "speed=20");
	if (rig_open(&r, 2000, &err) < 0 || can_driver.stage->home(r.dev, 5000, &err) < 0)
		fail_msg("%s", err.message);
	expect_error(can_driver.stage->sweep(r.dev, p, 3, 10000, &err), -EPROTO, &err,
		     "x (node 5): the touch probe latched no edge of the trigger: check the wiring "
		     "of output 16 of node 5");
	assert_true(quick_stops(r.sim, node_id[1], 1) >= 1);
	rig_stop(&r);
	/* a drive refusing its touch probe function mid-scan */
	sweep_rig(&r, CAN_SIM_TP_FULL, "speed=20");
	can_sim_abort(r.sim, node_id[2], CIA402_TOUCH_PROBE_FUNCTION, 0, 0x08000022);
	expect_error(can_driver.stage->sweep(r.dev, p, 3, 10000, &err), -EPROTO, &err,
		     "z (node 12) refused the write of 0x60b8:00: SDO abort 0x08000022");
	/* a bouncing trigger line: two latches for one trigger */
	can_sim_abort(r.sim, node_id[2], 0, 0, 0);
	if (can_driver.stage->home(r.dev, 5000, &err) < 0)       /* out of the quick stop */
		fail_msg("%s", err.message);
	can_sim_bounce(r.sim, true);
	p[3] = 1.6;
	expect_error(can_driver.stage->sweep(r.dev, p, 3, 10000, &err), -EPROTO, &err,
		     "the touch probe latched 2 edges for one trigger (a bouncing or noisy trigger "
		     "line)");
	can_sim_bounce(r.sim, false);
	/* a target off the travel is refused before anything moves */
	p[3] = 400;
	expect_error(can_driver.stage->sweep(r.dev, p, 3, 10000, &err), -ERANGE, &err,
		     "axis x: target 400.000000 mm is outside");
	/* stopped from another thread in the middle: at once, quick stops */
	if (can_driver.stage->home(r.dev, 5000, &err) < 0)
		fail_msg("%s", err.message);
	double far[3 * 4];
	zigzag(far, 4);
	for (size_t k = 0; k < 4; k++)
		far[3 * k] *= 10;
	pthread_t th;
	struct stopper st = { r.dev, 60 };
	struct timespec t0;
	assert_int_equal(pthread_create(&th, NULL, stop_later, &st), 0);
	clock_gettime(CLOCK_MONOTONIC, &t0);
	expect_error(can_driver.stage->sweep(r.dev, far, 4, 10000, &err), -ECANCELED, &err,
		     "sweep stopped");
	assert_true(ms_since(&t0) < 800);
	pthread_join(th, NULL);
	for (int k = 0; k < 3; k++)
		assert_true(quick_stops(r.sim, node_id[k], 1) >= 1);
	rig_stop(&r);
}

/* ------------------------------------------------- end to end */

static void scan_config_opts(struct scan_fixture *e, const char *json, const char *path,
			     const struct asph_scan_options *so)
{
	struct asph_config *c = NULL;
	struct asph_instrument *inst = NULL;
	struct asph_scan *sc;
	struct asph_scanfile_writer *w;
	struct asph_error err;
	struct asph_scanfile_header_info hi = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						"{\"name\":\"can\"}", NULL };

	if (asph_config_parse(e->reg, json, strlen(json), "<test>", &c, &err) < 0 ||
	    asph_instrument_open(&c->instruments[0], 2000, &inst, &err) < 0)
		fail_msg("%s", err.message);
	assert_int_equal(asph_scan_new(inst, e->s, e->plan->xyz, e->plan->n, so, &sc, NULL), 0);
	assert_int_equal(asph_scanfile_writer_create(path, &hi, NULL, &w, NULL), 0);
	if (asph_scan_run(sc, w, &err) < 0)
		fail_msg("scan: %s", err.message);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
}

static void scan_config(struct scan_fixture *e, const char *json, const char *path)
{
	scan_config_opts(e, json, path, NULL);
}

static void test_scan_end_to_end(void **state)
{
	static const char probe[] =
		"\"probe\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0, "
		"\"shift_x\": 0.0371, \"shift_y\": -0.0213, \"shift_z\": 0.0119, "
		"\"tilt_x\": 231.7, \"tilt_y\": -148.3, \"form\": \"5:41.3;9:-23.7\"}}";
	struct scan_fixture e;
	struct can_sim_config sc;
	struct can_sim *sim;
	char json[1024], can_path[128], mock_path[128];
	int sv[2];

	scan_fixture_init(&e, 300, "can");
	new_path(&e, can_path, sizeof(can_path));
	new_path(&e, mock_path, sizeof(mock_path));

	sim_config(&sc, 0);
	assert_int_equal(socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv), 0);
	assert_int_equal(can_sim_new(sv[1], &sc, &sim), 0);
	assert_int_equal(can_sim_run(sim), 0);
	snprintf(json, sizeof(json),
		 "{\"instruments\": [{\"stage\": {\"driver\": \"can\", \"options\": {"
		 "\"interface\": \"fd:%d\", \"x_node\": 5, \"y_node\": 9, \"z_node\": 12, "
		 "\"x_counts_per_mm\": 8192, \"y_counts_per_mm\": 12500, \"z_counts_per_mm\": 20480, "
		 "\"heartbeat\": 20, \"heartbeat_timeout\": 2000, \"sdo_timeout\": 500}}, %s}]}",
		 sv[0], probe);
	scan_config(&e, json, can_path);
	can_sim_free(sim);
	close(sv[0]);
	/* each point rests on the drives' position actual value (0x6064),
	 * read back after the move: whole counts of each axis, not the
	 * commanded target */
	struct asph_scanfile *rec;
	static const double counts[3] = { 8192, 12500, 20480 };
	if (asph_scanfile_read(can_path, &rec, NULL) < 0)
		fail_msg("%s: not readable", can_path);
	size_t off_grid = 0;
	for (size_t i = 0; i < rec->n; i++) {
		const struct asph_scanfile_point *pt = &rec->points[i];
		assert_int_equal(pt->position_source, ASPH_SCANFILE_POSITION_READ_BACK);
		assert_false(pt->flags & ASPH_SCANFILE_POINT_COMMANDED);
		for (int k = 0; k < 3; k++) {
			double c = pt->stage[k] * counts[k];
			assert_true(fabs(c - nearbyint(c)) < 1e-6);
		}
		/* the plan's own x is off the count grid almost everywhere */
		double cx = e.plan->xyz[3 * pt->plan_index] * counts[0];
		off_grid += fabs(cx - nearbyint(cx)) > 1e-3;
	}
	assert_true(off_grid > rec->n / 2);
	asph_scanfile_free(rec);
	snprintf(json, sizeof(json),
		 "{\"instruments\": [{\"stage\": {\"driver\": \"mock\", \"options\": "
		 "{\"time_factor\": 0}}, %s}]}", probe);
	scan_config(&e, json, mock_path);

	/* every point is on the part either way (the probe measures from the
	 * position the stage reports, which the drives' counts quantize): the
	 * same pose and form error */
	struct asph_fit_result a, b;
	fixture_fit_rigid(&e, can_path, e.plan->n, &a);
	fixture_fit_rigid(&e, mock_path, e.plan->n, &b);
	for (int k = 0; k < 3; k++)
		if (fabs(a.value[ASPH_FIT_TX + k] - b.value[ASPH_FIT_TX + k]) > 1e-9)
			fail_msg("t%d: %.12g vs %.12g", k, a.value[ASPH_FIT_TX + k], b.value[ASPH_FIT_TX + k]);
	for (int k = 0; k < 2; k++)
		assert_true(fabs(a.value[ASPH_FIT_RX + k] - b.value[ASPH_FIT_RX + k]) < 1e-9);
	assert_true(fabs(a.value[ASPH_FIT_TX] - 0.0371) < 2e-5);
	assert_true(fabs(a.zernike[4].v - b.zernike[4].v) < 0.01);
	assert_true(fabs(a.zernike[8].v - b.zernike[8].v) < 0.01);
	assert_true(fabs(a.rms.v - b.rms.v) < 0.01);

	scan_fixture_fini(&e);
}

/* A streamed scan: every point on the position the drives latched at its
 * trigger; where a drive has no touch probe, none is latched and each is
 * interpolated or flagged commanded. */
static void test_scan_streamed(void **state)
{
	static const char probe[] =
		"\"probe\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0, "
		"\"rate\": 100000}}";
	struct scan_fixture e;
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	char json[1024], path[128];

	scan_fixture_init(&e, 40, "can");
	for (int pass = 0; pass < 2; pass++) {
		new_path(&e, path, sizeof(path));
		struct can_sim_config sc;
		struct can_sim *sim;
		int sv[2];
		sim_config(&sc, 1);
		sc.trigger_node = node_id[0];
		sc.trigger_bit = 16;
		sc.touch_probe[2] = pass ? CAN_SIM_TP_NONE : CAN_SIM_TP_FULL;
		assert_int_equal(socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv), 0);
		assert_int_equal(can_sim_new(sv[1], &sc, &sim), 0);
		assert_int_equal(can_sim_run(sim), 0);
		snprintf(json, sizeof(json),
			 "{\"instruments\": [{\"stage\": {\"driver\": \"can\", \"options\": {"
			 "\"interface\": \"fd:%d\", \"x_node\": 5, \"y_node\": 9, \"z_node\": 12, "
			 "\"x_counts_per_mm\": 8192, \"y_counts_per_mm\": 12500, "
			 "\"z_counts_per_mm\": 20480, \"speed\": 300, \"heartbeat\": 20, "
			 "\"heartbeat_timeout\": 2000, \"sdo_timeout\": 500}}, %s}]}", sv[0], probe);
		scan_config_opts(&e, json, path, &so);
		size_t rising = 0;
		struct can_sim_edge *edges = calloc(4096, sizeof(*edges));
		assert_non_null(edges);
		size_t ne = can_sim_edges(sim, edges, 4096);
		for (size_t k = 0; k < ne; k++)
			if (edges[k].rising)
				edges[rising++] = edges[k];
		can_sim_free(sim);
		close(sv[0]);

		struct asph_scanfile *rec;
		if (asph_scanfile_read(path, &rec, NULL) < 0)
			fail_msg("%s: not readable", path);
		assert_int_equal(rec->n, e.plan->n);
		/* one trigger per point */
		assert_int_equal(rising, rec->n);
		size_t latched = 0, interpolated = 0, commanded = 0;
		for (size_t i = 0; i < rec->n; i++) {
			const struct asph_scanfile_point *pt = &rec->points[i];
			bool flagged = pt->flags & ASPH_SCANFILE_POINT_COMMANDED;
			latched += pt->position_source == ASPH_SCANFILE_POSITION_LATCHED;
			interpolated += pt->position_source == ASPH_SCANFILE_POSITION_INTERPOLATED;
			commanded += pt->position_source == ASPH_SCANFILE_POSITION_COMMANDED;
			/* commanded, and only commanded, is flagged */
			assert_int_equal(flagged, pt->position_source == ASPH_SCANFILE_POSITION_COMMANDED);
			/* the encoders at the point's trigger, in the order measured */
			for (int a = 0; a < 3 && pass == 0 && i < rising; a++) {
				double c = pt->stage[a] * cpm[a];
				if (fabs(c - edges[i].encoder[a]) > 1e-6)
					fail_msg("point %zu axis %d: %.3f counts, the encoder %d at its "
						 "trigger", i, a, c, edges[i].encoder[a]);
			}
		}
		free(edges);
		if (pass == 0) {
			assert_int_equal(latched, rec->n);
		} else {
			assert_int_equal(latched, 0);
			assert_int_equal(interpolated + commanded, rec->n);
		}
		asph_scanfile_free(rec);
	}
	scan_fixture_fini(&e);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_codec),
		cmocka_unit_test(test_statusword),
		cmocka_unit_test(test_enable_home_move),
		cmocka_unit_test(test_not_homed_and_absent_axis),
		cmocka_unit_test(test_fault_reset),
		cmocka_unit_test(test_quick_stop_on_fault),
		cmocka_unit_test(test_homing_error),
		cmocka_unit_test(test_sdo_aborts),
		cmocka_unit_test(test_malformed_answers),
		cmocka_unit_test(test_heartbeat_lost),
		cmocka_unit_test(test_busy_client),
		cmocka_unit_test(test_silent_drive),
		cmocka_unit_test(test_bus_errors),
		cmocka_unit_test(test_stop),
		cmocka_unit_test(test_probe),
		cmocka_unit_test(test_real_interface),
		cmocka_unit_test(test_unix_gateway),
		cmocka_unit_test(test_touch_probe_objects),
		cmocka_unit_test(test_sweep_latched),
		cmocka_unit_test(test_sweep_fallback),
		cmocka_unit_test(test_sweep_faults),
		cmocka_unit_test(test_scan_end_to_end),
		cmocka_unit_test(test_scan_streamed),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
