/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * CANopen CiA 402 drives on SocketCAN (or a gateway's unix socket): a
 * stage of up to three linear axes, one drive (node) per axis, in profile
 * position mode; and a probe reading one object of a node over SDO.
 * docs/driver-can.md has the options, the bench setup and the faults.
 * This file: the options and the driver table, the device's open and
 * close, its info and prediction, position and status, and the probe;
 * the stage's sequences are in files of their own (device.h).
 */
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "device.h"
#include "std.h"
#include "timing.h"
#include "transport.h"
#include "util-time.h"

enum {
	OPT_INTERFACE, OPT_X_NODE, OPT_Y_NODE, OPT_Z_NODE,
	OPT_X_COUNTS, OPT_Y_COUNTS, OPT_Z_COUNTS,
	OPT_X_MIN, OPT_X_MAX, OPT_Y_MIN, OPT_Y_MAX, OPT_Z_MIN, OPT_Z_MAX,
	OPT_SPEED, OPT_ACCELERATION, OPT_HOMING_METHOD, OPT_HOMING_SPEED,
	OPT_HEARTBEAT, OPT_HEARTBEAT_TIMEOUT, OPT_SDO_TIMEOUT, OPT_NMT_RESET, OPT_FAULT_RESET,
	OPT_TOUCH_PROBE, OPT_TRIGGER_NODE, OPT_TRIGGER_OUTPUT, OPT_BITRATE,
	OPT_PROBE_NODE, OPT_PROBE_INDEX, OPT_PROBE_SUBINDEX, OPT_PROBE_FORMAT, OPT_PROBE_SCALE,
	OPT_PROBE_OFFSET, OPT_PROBE_KIND, OPT_PROBE_TIP_RADIUS, OPT_PROBE_STANDOFF,
	OPT_PROBE_RANGE, N_OPTIONS
};

static const char *const nmt_resets[] = { "communication", "node", "none", NULL };
static const char *const formats[] = { "i16", "u16", "i32", "u32", "i8", "u8", NULL };
static const char *const kinds[] = { "optical", "tactile", NULL };
static const char *const touch_probes[] = { "auto", "on", "off", NULL };

#define P ASPH_ROLE_PROBE
#define S ASPH_ROLE_STAGE
#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)
#define NODE(n, def) { n "_node", ASPH_OPTION_INT, def, RANGE(0, 127), .roles = S, \
		       .help = "CANopen node id of the " n " drive (0: no " n " axis, it stays at 0)" }
#define COUNTS(n) { n "_counts_per_mm", ASPH_OPTION_DOUBLE, "10000", RANGE(1e-3, 1e9), \
		    .unit = "counts/mm", .roles = S, \
		    .help = "position units (counts) of the " n " drive per mm of travel" }
#define LIMIT(n, which, def) { n "_" which, ASPH_OPTION_DOUBLE, def, RANGE(-1e5, 1e5), \
			       .unit = "mm", .roles = S, \
			       .help = which "imum position of the " n " axis after homing" }

static const struct asph_option_desc can_options[N_OPTIONS] = {
	[OPT_INTERFACE] = { "interface", ASPH_OPTION_STRING, "can0",
			    .help = "SocketCAN interface (can0); unix:PATH, a SOCK_SEQPACKET unix "
				    "socket of a CAN gateway or simulator carrying one struct can_frame "
				    "per datagram; or fd:N, a descriptor already open carrying them" },
	[OPT_X_NODE] = NODE("x", "1"),
	[OPT_Y_NODE] = NODE("y", "2"),
	[OPT_Z_NODE] = NODE("z", "3"),
	[OPT_X_COUNTS] = COUNTS("x"),
	[OPT_Y_COUNTS] = COUNTS("y"),
	[OPT_Z_COUNTS] = COUNTS("z"),
	[OPT_X_MIN] = LIMIT("x", "min", "-50"),
	[OPT_X_MAX] = LIMIT("x", "max", "50"),
	[OPT_Y_MIN] = LIMIT("y", "min", "-50"),
	[OPT_Y_MAX] = LIMIT("y", "max", "50"),
	[OPT_Z_MIN] = LIMIT("z", "min", "-50"),
	[OPT_Z_MAX] = LIMIT("z", "max", "50"),
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "10", RANGE(0.001, 10000), .unit = "mm/s",
			.roles = S, .help = "profile velocity of every axis (0x6081)" },
	[OPT_ACCELERATION] = { "acceleration", ASPH_OPTION_DOUBLE, "100", RANGE(0.001, 1e6),
			       .unit = "mm/s^2", .roles = S,
			       .help = "profile acceleration and deceleration (0x6083, 0x6084)" },
	[OPT_HOMING_METHOD] = { "homing_method", ASPH_OPTION_INT, "37", RANGE(-128, 127), .roles = S,
				.help = "CiA 402 homing method (0x6098): 37 (or 35) the current position "
					"is home, 17/18 the negative/positive limit switch, 1/2 the "
					"limit switch and the index pulse, ..." },
	[OPT_HOMING_SPEED] = { "homing_speed", ASPH_OPTION_DOUBLE, "2", RANGE(0.001, 10000),
			       .unit = "mm/s", .roles = S,
			       .help = "speed searching the home switch (0x6099:01; a tenth of it for "
				       "the index pulse, 0x6099:02)" },
	[OPT_HEARTBEAT] = { "heartbeat", ASPH_OPTION_INT, "100", RANGE(0, 10000), .unit = "ms",
			    .help = "heartbeat period the nodes are set to produce (0x1017; 0: none, "
				    "not watched)" },
	[OPT_HEARTBEAT_TIMEOUT] = { "heartbeat_timeout", ASPH_OPTION_INT, "0", RANGE(0, 60000),
				    .unit = "ms", .help = "a node silent this long is lost (0: three "
							  "heartbeat periods)" },
	[OPT_SDO_TIMEOUT] = { "sdo_timeout", ASPH_OPTION_INT, "100", RANGE(1, 10000), .unit = "ms",
			      .help = "longest wait for the answer to one SDO request" },
	[OPT_NMT_RESET] = { "nmt_reset", ASPH_OPTION_ENUM, "communication", .choices = nmt_resets,
			    .help = "NMT reset sent to each node on open before it is started: "
				    "communication (keeps the drive's position and home), node, none" },
	[OPT_FAULT_RESET] = { "fault_reset", ASPH_OPTION_BOOL, "true", .roles = S,
			      .help = "homing clears a drive fault (fault reset) before enabling; "
				      "false: a drive in fault refuses" },
	[OPT_TOUCH_PROBE] = { "touch_probe", ASPH_OPTION_ENUM, "auto", .choices = touch_probes,
			      .roles = S,
			      .help = "positions during sweeps latched by the drives' touch probe "
				      "(0x60B8) on the probe's trigger: auto where every axis' drive "
				      "has one (else read back, flagged), on: refuse a drive without, "
				      "off: read back" },
	[OPT_TRIGGER_NODE] = { "trigger_node", ASPH_OPTION_INT, "0", RANGE(0, 127), .roles = S,
			       .help = "the axis drive whose digital output fires the probe's "
				       "trigger line (wired to every axis' touch probe 1 input); 0: "
				       "the first axis' drive" },
	[OPT_TRIGGER_OUTPUT] = { "trigger_output", ASPH_OPTION_INT, "16", RANGE(0, 31), .roles = S,
				 .help = "bit of its digital outputs (0x60FE:01, 16..31) wired to the "
					 "trigger line; 0: no trigger wiring (no latching)" },
	[OPT_BITRATE] = { "bitrate", ASPH_OPTION_INT, "500000", RANGE(10000, 1000000),
			  .unit = "bit/s", .roles = S,
			  .help = "the bus's bit rate, for the predicted measuring time only (the "
				  "interface's own is set with ip link)" },
	[OPT_PROBE_NODE] = { "probe_node", ASPH_OPTION_INT, "4", RANGE(1, 127), .roles = P,
			     .help = "CANopen node id of the probe" },
	[OPT_PROBE_INDEX] = { "probe_index", ASPH_OPTION_INT, "28976", RANGE(0x1000, 0xffff), .roles = P,
			      .help = "object index of the reading (28976 = 0x7130, CiA 404 analogue "
				      "input process value)" },
	[OPT_PROBE_SUBINDEX] = { "probe_subindex", ASPH_OPTION_INT, "1", RANGE(0, 255), .roles = P,
				 .help = "object sub-index of the reading" },
	[OPT_PROBE_FORMAT] = { "probe_format", ASPH_OPTION_ENUM, "i16", .choices = formats,
			       .roles = P, .help = "data type of the reading" },
	[OPT_PROBE_SCALE] = { "probe_scale", ASPH_OPTION_DOUBLE, "0.001", RANGE(-1e6, 1e6),
			      .unit = "mm", .roles = P, .help = "mm per unit of the reading" },
	[OPT_PROBE_OFFSET] = { "probe_offset", ASPH_OPTION_DOUBLE, "0", RANGE(-1e6, 1e6),
			       .unit = "mm", .roles = P, .help = "mm added to the scaled reading" },
	[OPT_PROBE_KIND] = { "probe_kind", ASPH_OPTION_ENUM, "optical", .choices = kinds,
			     .roles = P, .help = "probe type" },
	[OPT_PROBE_TIP_RADIUS] = { "probe_tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0.01, 10),
				   .unit = "mm", .roles = P, .help = "tip ball radius of a tactile probe" },
	[OPT_PROBE_STANDOFF] = { "probe_standoff", ASPH_OPTION_DOUBLE, "2", RANGE(-1e4, 1e4),
				 .unit = "mm", .roles = P,
				 .help = "reading the probe wants on the nominal surface" },
	[OPT_PROBE_RANGE] = { "probe_range", ASPH_OPTION_DOUBLE, "1", RANGE(0.001, 1e4),
			      .unit = "mm", .roles = P, .help = "measuring range, centred on the standoff" },
};

#undef P
#undef S

/* ------------------------------------------------------- bring-up */

static int bring_up(struct asph_device *d, bool drives, unsigned timeout_ms,
		    struct asph_error *err)
{
	static const uint8_t resets[] = { CANOPEN_NMT_RESET_COMMUNICATION, CANOPEN_NMT_RESET_NODE };
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = 0;

	if (d->nmt_reset < 2) {
		can_bus_expect_bootup(d->bus);
		for (unsigned i = 0; i < d->n_nodes && r == 0; i++)
			r = can_bus_nmt(d->bus, resets[d->nmt_reset], d->nodes[i], err);
		if (r == 0)
			r = can_bus_wait_bootup(d->bus, d->nodes, d->n_nodes, timeout_ms, err);
	}
	for (unsigned i = 0; i < d->n_nodes && r == 0 && drives; i++) {
		uint32_t type;
		r = can_bus_sdo_upload(d->bus, d->nodes[i], CANOPEN_DEVICE_TYPE, 0, &type,
				       can_sdo_time(d, deadline), err);
		if (r == 0 && (type & 0xffff) != 402)
			r = asph_error_set(err, -EPROTO,
					   "%s is not a CiA 402 drive (device type 0x%08x: profile %u)",
					   can_bus_node_name(d->bus, d->nodes[i]), type, type & 0xffff);
	}
	for (unsigned i = 0; i < d->n_nodes && r == 0 && d->hb_ms; i++) {
		r = can_write_obj(d, d->nodes[i], CANOPEN_HEARTBEAT_TIME, 0, d->hb_ms, 2, deadline, err);
		can_bus_watch(d->bus, d->nodes[i], d->hb_timeout_ms);
	}
	for (unsigned i = 0; i < d->n_nodes && r == 0; i++)
		r = can_bus_nmt(d->bus, CANOPEN_NMT_START, d->nodes[i], err);
	return r;
}

static struct asph_device *dev_new(const struct asph_option_value *o)
{
	struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return NULL;
	d->iface = strdup(o[OPT_INTERFACE].s);
	if (!d->iface) {
		free(d);
		return NULL;
	}
	atomic_init(&d->stopped, false);
	d->hb_ms = (unsigned)o[OPT_HEARTBEAT].i;
	d->hb_timeout_ms = o[OPT_HEARTBEAT_TIMEOUT].i ? (unsigned)o[OPT_HEARTBEAT_TIMEOUT].i
						      : 3 * d->hb_ms;
	d->sdo_ms = (unsigned)o[OPT_SDO_TIMEOUT].i;
	d->nmt_reset = (int)o[OPT_NMT_RESET].i;
	return d;
}

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	can_bus_free(d->bus);
	free(d->trace);
	free(d->iface);
	free(d);
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	struct can_frame f[3];
	unsigned n = 0;

	atomic_store(&d->stopped, true);
	for (int k = 0; k < 3; k++)
		if (d->ax[k].node)
			canopen_sdo_frame(&f[n++], d->ax[k].node, true, SDO_DOWNLOAD,
					  CIA402_CONTROLWORD, 0, CIA402_CW_QUICK_STOP, 2);
	can_bus_cancel(d->bus, f, n);
	return 0;
}

/* ----------------------------------------------------------- stage */

/* The trigger wiring and touch_probe. */
static int trigger_options(struct asph_device *d, const struct asph_option_value *o,
			   struct asph_error *err)
{
	unsigned node = (unsigned)o[OPT_TRIGGER_NODE].i, bit = (unsigned)o[OPT_TRIGGER_OUTPUT].i;
	bool axis = false;

	d->touch_probe = (int)o[OPT_TOUCH_PROBE].i;
	if (bit >= 1 && bit <= 15)
		return asph_error_set(err, -EINVAL, "trigger_output: bit %u of 0x60FE:01 is not an "
				      "output (0: the brake, 1..15: reserved by CiA 402; 16..31: "
				      "the drive's own outputs)", bit);
	if (!bit && d->touch_probe == TOUCH_PROBE_ON)
		return asph_error_set(err, -EINVAL, "touch_probe=on needs the trigger wiring "
				      "(trigger_output 16..31)");
	for (int k = 0; k < 3; k++)
		axis = axis || (node && d->ax[k].node == node);
	if (node && !axis)
		return asph_error_set(err, -EINVAL, "trigger_node %u is not one of the axes' drives",
				      node);
	d->trigger_bit = (uint8_t)bit;
	d->trigger_node = (uint8_t)node;
	for (int k = 0; k < 3 && !d->trigger_node; k++)
		d->trigger_node = d->ax[k].node;
	return 0;
}

/* The stage as its options describe it: axes, profile, trigger wiring. */
static int stage_configure(struct asph_device *d, const struct asph_option_value *o,
			   struct asph_error *err)
{
	for (int k = 0; k < 3; k++) {
		struct axis *a = &d->ax[k];
		a->node = (uint8_t)o[OPT_X_NODE + k].i;
		a->counts_per_mm = o[OPT_X_COUNTS + k].d;
		a->min = o[OPT_X_MIN + 2 * k].d;
		a->max = o[OPT_X_MAX + 2 * k].d;
		for (unsigned i = 0; i < d->n_nodes && a->node; i++)
			if (d->nodes[i] == a->node)
				return asph_error_set(err, -EINVAL, "%s_node: node %u drives two axes",
						      can_axis_names[k], a->node);
		if (a->node)
			d->nodes[d->n_nodes++] = a->node;
		if (a->node && !(a->min < a->max))
			return asph_error_set(err, -EINVAL, "%s_min must be below %s_max",
					      can_axis_names[k], can_axis_names[k]);
	}
	if (!d->n_nodes)
		return asph_error_set(err, -EINVAL, "no axis: set x_node, y_node or z_node");
	d->speed = o[OPT_SPEED].d;
	d->acceleration = o[OPT_ACCELERATION].d;
	d->homing_method = (int)o[OPT_HOMING_METHOD].i;
	d->homing_speed = o[OPT_HOMING_SPEED].d;
	d->fault_reset = o[OPT_FAULT_RESET].b;
	return trigger_options(d, o, err);
}

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = dev_new(o);

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	int r = stage_configure(d, o, err);
	if (r == 0)
		r = can_bus_open(d->iface, d->nodes, d->n_nodes, &d->bus, err);
	for (int k = 0; k < 3 && r == 0; k++)
		if (d->ax[k].node)
			can_bus_label(d->bus, d->ax[k].node, can_axis_names[k]);
	if (r == 0)
		r = bring_up(d, true, timeout_ms, err);
	uint64_t deadline = transport_deadline(timeout_ms);
	for (int k = 0; k < 3 && r == 0; k++)
		if (d->ax[k].node)
			r = can_detect_touch_probe(d, &d->ax[k], deadline, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out, struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->kinematics = ASPH_KINEMATICS_XYZ;
	out->n_axes = 3;
	for (int k = 0; k < 3; k++) {
		struct asph_axis_info *ai = &out->axes[k];
		snprintf(ai->name, sizeof(ai->name), "%s", can_axis_names[k]);
		snprintf(ai->unit, sizeof(ai->unit), "mm");
		if (d->ax[k].node) {
			ai->min = d->ax[k].min;
			ai->max = d->ax[k].max;
			ai->max_speed = d->speed;
			out->max_accel[k] = d->acceleration;
		}
	}
	snprintf(out->model, sizeof(out->model), "CiA 402 drives on %.40s", d->iface);
	snprintf(out->serial, sizeof(out->serial), "nodes x=%u y=%u z=%u", d->ax[0].node,
		 d->ax[1].node, d->ax[2].node);
	return 0;
}

/* The device the options describe, not opened. */
static int stage_described(const struct asph_option_value *o, struct asph_device **out,
			   struct asph_error *err)
{
	struct asph_device *d = dev_new(o);

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	int r = stage_configure(d, o, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int stage_describe(const struct asph_driver *drv, const struct asph_option_value *o,
			  struct asph_stage_info *out, struct asph_error *err)
{
	struct asph_device *d;
	int r = stage_described(o, &d, err);

	if (r == 0)
		r = stage_info(d, out, err);
	dev_close(d);
	return r;
}

/*
 * The time of moves and sweeps, predicted from the options. Whether the
 * drives have touch probes with edge counters is only known once they
 * answer: with touch_probe auto or on and a trigger wired, they are taken
 * to have them. docs/driver-can.md, "Predicted measuring time".
 */
static int stage_motion_time(const struct asph_driver *drv, const struct asph_option_value *o,
			     const double *from, const double *p, size_t n, bool sweep,
			     double *seconds, struct asph_error *err)
{
	struct asph_device *d;
	int r = stage_described(o, &d, err);

	*seconds = 0;
	if (r < 0)
		return r;
	struct can_timing t = {
		.speed = d->speed, .acceleration = d->acceleration,
		.sdo_s = can_sdo_exchange_s((double)o[OPT_BITRATE].i), .poll_s = POLL_MS * 1e-3,
		.trigger = d->trigger_bit != 0,
		.latch = d->trigger_bit && d->touch_probe != TOUCH_PROBE_OFF ? CAN_LATCH_CONTINUOUS
									    : CAN_LATCH_NONE,
	};
	for (int k = 0; k < 3; k++) {
		t.axis[k] = d->ax[k].node != 0;
		t.counts_per_mm[k] = d->ax[k].counts_per_mm;
	}
	dev_close(d);
	if (sweep) {
		*seconds = can_sweep_time(&t, from, p, n);
		return 0;
	}
	for (size_t k = 0; k < n; k++)
		*seconds += can_move_time(&t, k ? p + 3 * (k - 1) : from, p + 3 * k);
	return 0;
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = can_check_stopped(d, err);

	for (int k = 0; k < 3 && r == 0; k++) {
		uint32_t c = 0;
		if (d->ax[k].node)
			r = can_bus_sdo_upload(d->bus, d->ax[k].node, CIA402_POSITION_ACTUAL, 0, &c,
					       can_sdo_time(d, deadline), err);
		pos[k] = (double)(int32_t)c / d->ax[k].counts_per_mm;
	}
	return r == -ECANCELED ? can_finish(d, r, "position", err) : r;
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	bool homed = true, moving = false;

	memset(out, 0, sizeof(*out));
	for (int k = 0; k < 3; k++) {
		struct axis *a = &d->ax[k];
		uint16_t sw;
		if (!a->node)
			continue;
		homed = homed && a->homed;
		int r = can_read_u16(d, a->node, CIA402_STATUSWORD, &sw, deadline, err);
		if (r == -ENODEV || r == -ETIMEDOUT || r == -EIO) {
			out->state = ASPH_STAGE_DISCONNECTED;
			snprintf(out->detail, sizeof(out->detail), "%.120s", err ? err->message : "");
			return 0;
		}
		if (r < 0)
			return r;
		enum cia402_state s = cia402_decode_statusword(sw);
		if (s == CIA402_FAULT || s == CIA402_FAULT_REACTION_ACTIVE) {
			struct asph_error fe;
			can_drive_fault(d, a, "", &fe);
			out->state = ASPH_STAGE_FAULT;
			snprintf(out->detail, sizeof(out->detail), "%.120s", fe.message);
			return 0;
		}
		moving = moving || (s == CIA402_OPERATION_ENABLED && !(sw & CIA402_SW_TARGET_REACHED));
	}
	out->homed = homed;
	out->state = !homed ? ASPH_STAGE_NOT_HOMED : moving ? ASPH_STAGE_MOVING : ASPH_STAGE_IDLE;
	return stage_position(d, out->position, transport_ms_left(deadline), err);
}

/* ----------------------------------------------------------- probe */

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = dev_new(o);

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	d->nodes[d->n_nodes++] = (uint8_t)o[OPT_PROBE_NODE].i;
	d->p_index = (uint16_t)o[OPT_PROBE_INDEX].i;
	d->p_sub = (uint8_t)o[OPT_PROBE_SUBINDEX].i;
	d->p_format = (int)o[OPT_PROBE_FORMAT].i;
	d->p_scale = o[OPT_PROBE_SCALE].d;
	d->p_offset = o[OPT_PROBE_OFFSET].d;
	struct asph_probe_info *pi = &d->pinfo;
	std_probe_geometry(pi, o[OPT_PROBE_KIND].i == 1, o[OPT_PROBE_TIP_RADIUS].d,
			   o[OPT_PROBE_STANDOFF].d, o[OPT_PROBE_RANGE].d);
	snprintf(pi->model, sizeof(pi->model), "CANopen probe on %.40s", d->iface);
	snprintf(pi->serial, sizeof(pi->serial), "node %u 0x%04x:%02x", d->nodes[0], d->p_index,
		 d->p_sub);
	int r = can_bus_open(d->iface, d->nodes, 1, &d->bus, err);
	if (r == 0) {
		can_bus_label(d->bus, d->nodes[0], "probe");
		r = bring_up(d, false, timeout_ms, err);
	}
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out, struct asph_error *err)
{
	*out = d->pinfo;
	return 0;
}

static double probe_raw(int format, uint32_t v)
{
	switch (format) {
	case 0: return (int16_t)v;
	case 1: return (uint16_t)v;
	case 2: return (int32_t)v;
	case 3: return v;
	case 4: return (int8_t)v;
	default: return (uint8_t)v;
	}
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	uint32_t v;
	int r = can_check_stopped(d, err);

	if (r == 0)
		r = can_bus_sdo_upload(d->bus, d->nodes[0], d->p_index, d->p_sub, &v,
				       timeout_ms < d->sdo_ms ? timeout_ms : d->sdo_ms, err);
	if (r == -ECANCELED)
		return asph_error_set(err, r, "reading stopped");
	if (r < 0)
		return r;
	memset(out, 0, sizeof(*out));
	out->raw = probe_raw(d->p_format, v);
	out->value = out->raw * d->p_scale + d->p_offset;
	out->t_ns = now_monotonic_ns();
	std_reading_check_range(out, &d->pinfo);
	return 0;
}

static const struct asph_stage_ops can_stage = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = can_stage_home,
	.move_to = can_stage_move,
	.sweep = can_stage_sweep,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
	.sweep_trace = can_stage_trace,
	.describe = stage_describe,
	.motion_time = stage_motion_time,
};

static const struct asph_probe_ops can_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stop = dev_stop,
};

const struct asph_driver can_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "can",
	.description = "CANopen CiA 402 drives on SocketCAN (one node per axis, profile position "
		       "mode; sweeps with positions latched by the drives' touch probes), and a "
		       "probe read over SDO",
	.version = "1.1",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = can_options,
	.n_options = N_OPTIONS,
	.stage = &can_stage,
	.probe = &can_probe,
};
