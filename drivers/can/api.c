/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * CANopen CiA 402 drives on SocketCAN (or a gateway's unix socket): a
 * stage of up to three linear axes, one drive (node) per axis, in profile
 * position mode; and a probe reading one object of a node over SDO.
 * docs/driver-can.md has the options, the bench setup and the faults.
 */
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph-driver/driver.h"
#include "bus.h"
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
enum { TOUCH_PROBE_AUTO, TOUCH_PROBE_ON, TOUCH_PROBE_OFF };
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

/* Homing order: z first, so the probe leaves the part before x and y move. */
static const int home_order[3] = { 2, 0, 1 };
static const char *const axis_names[3] = { "x", "y", "z" };

struct axis {
	uint8_t node;           /* 0: no drive, the axis stays at 0 */
	double counts_per_mm, min, max;
	bool homed;
	bool pp;                /* profile position mode and its parameters set */
	bool target_valid;      /* target is where the drive was last sent */
	int32_t target;
	enum { TP_NONE, TP_SINGLE, TP_CONTINUOUS } tp;  /* its touch probe 1 */
	uint16_t tp_count;      /* 0x60D5 after the last latch */
};

struct asph_device {
	struct can_bus *bus;
	atomic_bool stopped;
	char *iface;            /* whole: a unix socket path must not be cut */
	uint8_t nodes[3];
	unsigned n_nodes;
	unsigned hb_ms, hb_timeout_ms, sdo_ms;
	int nmt_reset;
	/* stage */
	struct axis ax[3];
	double speed, acceleration, homing_speed;
	int homing_method;
	bool fault_reset;
	/* sweeps: the trigger line, the positions measured */
	int touch_probe;
	uint8_t trigger_node, trigger_bit;      /* bit 0: no trigger wiring */
	uint32_t outputs;                       /* 0x60FE:01 of trigger_node */
	struct asph_position_sample *trace;
	size_t trace_n, trace_read, trace_cap;
	/* probe */
	uint16_t p_index;
	uint8_t p_sub;
	int p_format;
	double p_scale, p_offset;
	struct asph_probe_info pinfo;
};

/* The wait between two polls of a statusword while an axis is under way. */
#define POLL_MS 1

/* -------------------------------------------------------- helpers */

static unsigned sdo_time(const struct asph_device *d, uint64_t deadline)
{
	unsigned left = transport_ms_left(deadline);
	return left < d->sdo_ms ? left : d->sdo_ms;
}

static const char *name(const struct asph_device *d, const struct axis *a)
{
	return can_bus_node_name(d->bus, a->node);
}

static int read_u16(struct asph_device *d, uint8_t node, uint16_t index, uint16_t *v,
		    uint64_t deadline, struct asph_error *err)
{
	uint32_t x;
	int r = can_bus_sdo_upload(d->bus, node, index, 0, &x, sdo_time(d, deadline), err);
	*v = (uint16_t)x;
	return r;
}

static int write_obj(struct asph_device *d, uint8_t node, uint16_t index, uint8_t sub,
		     uint32_t v, uint8_t size, uint64_t deadline, struct asph_error *err)
{
	return can_bus_sdo_download(d->bus, node, index, sub, v, size, sdo_time(d, deadline), err);
}

static int write_cw(struct asph_device *d, const struct axis *a, uint16_t cw, uint64_t deadline,
		    struct asph_error *err)
{
	return write_obj(d, a->node, CIA402_CONTROLWORD, 0, cw, 2, deadline, err);
}

/* -EPROTO naming the drive's error code (0x603F, else its last EMCY). */
static int drive_fault(struct asph_device *d, const struct axis *a, const char *why,
		       struct asph_error *err)
{
	uint16_t code = 0;

	if (read_u16(d, a->node, CIA402_ERROR_CODE, &code, transport_deadline(d->sdo_ms), NULL) < 0 ||
	    code == 0)
		code = can_bus_last_emcy(d->bus, a->node);
	return asph_error_set(err, -EPROTO, "%s: drive fault, error code 0x%04x (%s)%s", name(d, a),
			      code, canopen_error_text(code), why);
}

/* Quick stop to every drive still answering, after a fault. */
static void quick_stop_all(struct asph_device *d)
{
	uint8_t nodes[3];
	unsigned n = 0;

	for (int k = 0; k < 3; k++) {
		d->ax[k].target_valid = false;
		if (d->ax[k].node && !can_bus_node_lost(d->bus, d->ax[k].node))
			nodes[n++] = d->ax[k].node;
	}
	can_bus_sdo_download_all(d->bus, nodes, n, CIA402_CONTROLWORD, 0, CIA402_CW_QUICK_STOP, 2,
				 d->sdo_ms);
}

/* Ends a stage operation: a fault stops every axis; a stop keeps its
 * reason simple. */
static int finish(struct asph_device *d, int r, const char *what, struct asph_error *err)
{
	if (r == -ECANCELED || atomic_load(&d->stopped))
		return asph_error_set(err, -ECANCELED, "%s stopped", what);
	if (r < 0)
		quick_stop_all(d);
	return r;
}

static int check_stopped(struct asph_device *d, struct asph_error *err)
{
	if (atomic_load(&d->stopped))
		return asph_error_set(err, -ECANCELED, "stopped: close and reopen the instrument");
	return 0;
}

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
				       sdo_time(d, deadline), err);
		if (r == 0 && (type & 0xffff) != 402)
			r = asph_error_set(err, -EPROTO,
					   "%s is not a CiA 402 drive (device type 0x%08x: profile %u)",
					   can_bus_node_name(d->bus, d->nodes[i]), type, type & 0xffff);
	}
	for (unsigned i = 0; i < d->n_nodes && r == 0 && d->hb_ms; i++) {
		r = write_obj(d, d->nodes[i], CANOPEN_HEARTBEAT_TIME, 0, d->hb_ms, 2, deadline, err);
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

/* ----------------------------------------------------- touch probe */

#define ABORT_NO_OBJECT 0x06020000u

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

/* Whether a's drive has a touch probe (0x60B8), and its edge counter
 * (0x60D5) for the continuous mode: an SDO abort "object does not exist"
 * says it has not. */
static int detect_touch_probe(struct asph_device *d, struct axis *a, uint64_t deadline,
			      struct asph_error *err)
{
	uint32_t v;

	a->tp = TP_NONE;
	if (d->touch_probe == TOUCH_PROBE_OFF || !d->trigger_bit)
		return 0;
	int r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE_FUNCTION, 0, &v,
				   sdo_time(d, deadline), err);
	if (r == -EPROTO && can_bus_last_abort(d->bus) == ABORT_NO_OBJECT) {
		if (d->touch_probe == TOUCH_PROBE_ON)
			return asph_error_set(err, -EPROTO, "%s has no touch probe (0x60B8 does not "
					      "exist): touch_probe=on needs one in every axis' drive",
					      name(d, a));
		return 0;
	}
	if (r < 0)
		return r;
	r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POS_COUNT, 0, &v,
			       sdo_time(d, deadline), err);
	if (r == -EPROTO && can_bus_last_abort(d->bus) == ABORT_NO_OBJECT) {
		a->tp = TP_SINGLE;
		return 0;
	}
	a->tp = TP_CONTINUOUS;
	return r;
}

/* Every axis latches: positions during sweeps are the drives' own. */
static bool latching(const struct asph_device *d)
{
	for (int k = 0; k < 3; k++)
		if (d->ax[k].node && d->ax[k].tp == TP_NONE)
			return false;
	return d->trigger_bit != 0;
}

static int write_tp(struct asph_device *d, const struct axis *a, uint16_t f, uint64_t deadline,
		    struct asph_error *err)
{
	return write_obj(d, a->node, CIA402_TOUCH_PROBE_FUNCTION, 0, f, 2, deadline, err);
}

/* Touch probe 1 on the rising edge of its input, switched off first (a
 * drive refuses a change of mode while it is on); every edge in the
 * continuous mode, else the first one after each arming. */
static int arm_touch_probe(struct asph_device *d, struct axis *a, uint64_t deadline,
			   struct asph_error *err)
{
	uint16_t f = CIA402_TP_ENABLE | CIA402_TP_POSITIVE_EDGE, st = 0;
	uint32_t count;

	if (a->tp == TP_CONTINUOUS)
		f |= CIA402_TP_CONTINUOUS;
	int r = write_tp(d, a, 0, deadline, err);
	if (r == 0)
		r = write_tp(d, a, f, deadline, err);
	if (r == 0)
		r = read_u16(d, a->node, CIA402_TOUCH_PROBE_STATUS, &st, deadline, err);
	if (r == 0 && (!(st & CIA402_TPS_ENABLED) || (st & CIA402_TPS_POSITIVE_STORED)))
		return asph_error_set(err, -EPROTO, "%s: the touch probe did not arm (0x60B9 = "
				      "0x%04x after 0x60B8 = 0x%04x)", name(d, a), st, f);
	if (r == 0 && a->tp == TP_CONTINUOUS) {
		r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POS_COUNT, 0, &count,
				       sdo_time(d, deadline), err);
		a->tp_count = (uint16_t)count;
	}
	return r;
}

/* The position a's drive latched on the trigger just fired, counts. */
static int read_latch(struct asph_device *d, struct axis *a, int32_t *at, uint64_t deadline,
		      struct asph_error *err)
{
	uint32_t v;
	uint16_t st, edges = 1;
	int r;

	if (a->tp == TP_CONTINUOUS) {
		r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POS_COUNT, 0, &v,
				       sdo_time(d, deadline), err);
		if (r < 0)
			return r;
		edges = (uint16_t)(v - a->tp_count);
		a->tp_count = (uint16_t)v;
	} else {
		r = read_u16(d, a->node, CIA402_TOUCH_PROBE_STATUS, &st, deadline, err);
		if (r < 0)
			return r;
		edges = (st & CIA402_TPS_POSITIVE_STORED) != 0;
	}
	if (edges == 0)
		return asph_error_set(err, -EPROTO, "%s: the touch probe latched no edge of the "
				      "trigger: check the wiring of output %u of node %u to its touch "
				      "probe 1 input", name(d, a), d->trigger_bit, d->trigger_node);
	if (edges > 1)
		return asph_error_set(err, -EPROTO, "%s: the touch probe latched %u edges for one "
				      "trigger (a bouncing or noisy trigger line)", name(d, a), edges);
	r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POSITIVE, 0, &v,
			       sdo_time(d, deadline), err);
	*at = (int32_t)v;
	/* first-event mode: a rising edge of bit 4 arms it again */
	if (r == 0 && a->tp == TP_SINGLE)
		r = write_tp(d, a, CIA402_TP_ENABLE, deadline, err);
	if (r == 0 && a->tp == TP_SINGLE)
		r = write_tp(d, a, CIA402_TP_ENABLE | CIA402_TP_POSITIVE_EDGE, deadline, err);
	return r;
}

/* ----------------------------------------------------------- stage */

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
						      axis_names[k], a->node);
		if (a->node)
			d->nodes[d->n_nodes++] = a->node;
		if (a->node && !(a->min < a->max))
			return asph_error_set(err, -EINVAL, "%s_min must be below %s_max",
					      axis_names[k], axis_names[k]);
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
			can_bus_label(d->bus, d->ax[k].node, axis_names[k]);
	if (r == 0)
		r = bring_up(d, true, timeout_ms, err);
	uint64_t deadline = transport_deadline(timeout_ms);
	for (int k = 0; k < 3 && r == 0; k++)
		if (d->ax[k].node)
			r = detect_touch_probe(d, &d->ax[k], deadline, err);
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
		snprintf(ai->name, sizeof(ai->name), "%s", axis_names[k]);
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

/* The CiA 402 state machine driven to "operation enabled", one transition
 * per statusword read. */
static int axis_enable(struct asph_device *d, struct axis *a, uint64_t deadline,
		       struct asph_error *err)
{
	bool reset_sent = false;

	for (;;) {
		uint16_t sw, cw = 0;
		bool wait = false;
		int r = read_u16(d, a->node, CIA402_STATUSWORD, &sw, deadline, err);
		if (r < 0)
			return r;
		enum cia402_state s = cia402_decode_statusword(sw);
		switch (s) {
		case CIA402_OPERATION_ENABLED:
			return 0;
		case CIA402_FAULT:
			if (!d->fault_reset)
				return drive_fault(d, a, "; fault_reset is off: clear it at the drive", err);
			if (reset_sent)
				return drive_fault(d, a, "; a fault reset did not clear it", err);
			reset_sent = true;
			/* the reset acts on the rising edge of bit 7 */
			r = write_cw(d, a, CIA402_CW_DISABLE_VOLTAGE, deadline, err);
			cw = CIA402_CW_FAULT_RESET;
			break;
		case CIA402_NOT_READY_TO_SWITCH_ON:
		case CIA402_FAULT_REACTION_ACTIVE:
			wait = true;
			break;
		case CIA402_SWITCH_ON_DISABLED:
			cw = CIA402_CW_SHUTDOWN;
			break;
		case CIA402_READY_TO_SWITCH_ON:
			cw = CIA402_CW_SWITCH_ON;
			break;
		case CIA402_SWITCHED_ON:
			cw = CIA402_CW_ENABLE_OPERATION;
			break;
		case CIA402_QUICK_STOP_ACTIVE:
			cw = CIA402_CW_DISABLE_VOLTAGE;
			break;
		default:
			return asph_error_set(err, -EPROTO, "%s: statusword 0x%04x is no CiA 402 state",
					      name(d, a), sw);
		}
		if (r == 0)
			r = wait ? can_bus_idle(d->bus, 2, err) : write_cw(d, a, cw, deadline, err);
		if (r < 0)
			return r;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT,
					      "%s did not become ready for operation in time (stuck in "
					      "'%s')", name(d, a), cia402_state_name(s));
	}
}

/* Reads the statusword of a drive that must stay enabled. */
static int enabled_sw(struct asph_device *d, const struct axis *a, uint16_t *sw, uint64_t deadline,
		      struct asph_error *err)
{
	int r = read_u16(d, a->node, CIA402_STATUSWORD, sw, deadline, err);
	if (r < 0)
		return r;
	enum cia402_state s = cia402_decode_statusword(*sw);
	if (s == CIA402_FAULT || s == CIA402_FAULT_REACTION_ACTIVE)
		return drive_fault(d, a, "", err);
	if (s != CIA402_OPERATION_ENABLED)
		return asph_error_set(err, -EPROTO, "%s left operation enabled: it is in '%s'",
				      name(d, a), cia402_state_name(s));
	return 0;
}

static int32_t counts(const struct axis *a, double mm)
{
	return (int32_t)llround(mm * a->counts_per_mm);
}

static int axis_home(struct asph_device *d, struct axis *a, uint64_t deadline,
		     struct asph_error *err)
{
	uint32_t v = (uint32_t)fmax(1, llround(d->homing_speed * a->counts_per_mm));
	uint32_t acc = (uint32_t)fmin(4294967295.0, fmax(1, round(d->acceleration * a->counts_per_mm)));
	uint16_t sw = 0;

	a->homed = a->pp = a->target_valid = false;
	int r = axis_enable(d, a, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_MODE, 0, CIA402_MODE_HOMING, 1, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_HOMING_METHOD, 0, (uint32_t)d->homing_method & 0xff,
			      1, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_HOMING_SPEEDS, 1, v, 4, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_HOMING_SPEEDS, 2, v / 10 ? v / 10 : 1, 4, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_HOMING_ACCELERATION, 0, acc, 4, deadline, err);
	/* homing starts on the rising edge of bit 4 */
	if (r == 0)
		r = write_cw(d, a, CIA402_CW_ENABLE_OPERATION, deadline, err);
	if (r == 0)
		r = write_cw(d, a, CIA402_CW_ENABLE_OPERATION | CIA402_CW_NEW_SET_POINT, deadline, err);
	while (r == 0) {
		r = enabled_sw(d, a, &sw, deadline, err);
		if (r < 0)
			break;
		if (sw & CIA402_SW_BIT13)
			return asph_error_set(err, -EPROTO, "%s: homing error (method %d): check the "
					      "home switch and homing_method", name(d, a), d->homing_method);
		if ((sw & CIA402_SW_BIT12) && (sw & CIA402_SW_TARGET_REACHED))
			break;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s: homing did not finish in time",
					      name(d, a));
		r = can_bus_idle(d->bus, 1, err);
	}
	if (r == 0)
		r = write_cw(d, a, CIA402_CW_ENABLE_OPERATION, deadline, err);
	a->homed = r == 0;
	return r;
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = check_stopped(d, err);

	for (int i = 0; i < 3 && r == 0; i++)
		if (d->ax[home_order[i]].node)
			r = axis_home(d, &d->ax[home_order[i]], deadline, err);
	return finish(d, r, "homing", err);
}

/* Profile position mode with the profile's speed and accelerations. */
static int axis_pp(struct asph_device *d, struct axis *a, uint64_t deadline,
		   struct asph_error *err)
{
	uint32_t v = (uint32_t)fmin(4294967295.0, fmax(1, round(d->speed * a->counts_per_mm)));
	uint32_t acc = (uint32_t)fmin(4294967295.0, fmax(1, round(d->acceleration * a->counts_per_mm)));

	if (a->pp)
		return 0;
	int r = write_obj(d, a->node, CIA402_MODE, 0, CIA402_MODE_PROFILE_POSITION, 1, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_PROFILE_VELOCITY, 0, v, 4, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_PROFILE_ACCELERATION, 0, acc, 4, deadline, err);
	if (r == 0)
		r = write_obj(d, a->node, CIA402_PROFILE_DECELERATION, 0, acc, 4, deadline, err);
	a->pp = r == 0;
	return r;
}

static int check_target(const struct asph_device *d, const double *t, struct asph_error *err)
{
	for (int k = 0; k < 3; k++) {
		const struct axis *a = &d->ax[k];
		if (!a->node && t[k] != 0)
			return asph_error_set(err, -ERANGE, "axis %s has no drive (%s_node=0): it stays at 0",
					      axis_names[k], axis_names[k]);
		if (a->node && !(t[k] >= a->min && t[k] <= a->max))
			return asph_error_set(err, -ERANGE, "axis %s: target %.6f mm is outside %.6g .. %.6g",
					      axis_names[k], t[k], a->min, a->max);
		if (a->node && !a->homed)
			return asph_error_set(err, -EPROTO, "axis %s is not homed", axis_names[k]);
	}
	return 0;
}

/*
 * The set-point handshake of profile position mode: the new target, bit 4
 * up; the drive acknowledges with bit 12; bit 4 down; the drive drops bit
 * 12 and raises bit 10 when it is there.
 */
static int send_set_point(struct asph_device *d, struct axis *a, int32_t target,
			  uint64_t deadline, struct asph_error *err)
{
	uint16_t sw;
	int r = axis_pp(d, a, deadline, err);

	a->target_valid = false;
	if (r == 0)
		r = write_obj(d, a->node, CIA402_TARGET_POSITION, 0, (uint32_t)target, 4, deadline, err);
	if (r == 0)
		r = write_cw(d, a, CIA402_CW_ENABLE_OPERATION | CIA402_CW_NEW_SET_POINT, deadline, err);
	if (r < 0)
		return r;
	for (;;) {
		r = enabled_sw(d, a, &sw, deadline, err);
		if (r < 0)
			return r;
		if (sw & CIA402_SW_BIT12)
			break;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s did not acknowledge the new set point "
					      "in time", name(d, a));
		r = can_bus_idle(d->bus, POLL_MS, err);
		if (r < 0)
			return r;
	}
	a->target = target;
	a->target_valid = true;
	return write_cw(d, a, CIA402_CW_ENABLE_OPERATION, deadline, err);
}

/* The statusword of an axis in motion, which must not have a following
 * error or a limit. */
static int motion_sw(struct asph_device *d, const struct axis *a, uint16_t *out,
		     uint64_t deadline, struct asph_error *err)
{
	uint16_t sw;
	int r = enabled_sw(d, a, &sw, deadline, err);

	*out = sw;
	if (r < 0)
		return r;
	if (sw & CIA402_SW_BIT13)
		return asph_error_set(err, -EPROTO, "%s: following error: the axis lags its profile "
				      "(blocked, or speed/acceleration too high)", name(d, a));
	if (sw & CIA402_SW_INTERNAL_LIMIT)
		return asph_error_set(err, -ERANGE, "%s: internal limit active (a limit switch or the "
				      "drive's software limits)", name(d, a));
	return 0;
}

/* 1 when the axis is at its target, 0 while it moves. */
static int axis_arrived(struct asph_device *d, const struct axis *a, uint64_t deadline,
			struct asph_error *err)
{
	uint16_t sw;
	int r = motion_sw(d, a, &sw, deadline, err);

	if (r < 0)
		return r;
	return (sw & CIA402_SW_TARGET_REACHED) && !(sw & CIA402_SW_BIT12);
}

static int stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		      struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	bool moving[3] = { false };
	int r = check_stopped(d, err);

	if (r == 0)
		r = check_target(d, t, err);
	if (r < 0)
		return r;
	for (int k = 0; k < 3 && r == 0; k++) {
		struct axis *a = &d->ax[k];
		int32_t c = counts(a, t[k]);
		/* an axis already sent there keeps still */
		if (a->node && !(a->target_valid && a->target == c)) {
			moving[k] = true;
			r = send_set_point(d, a, c, deadline, err);
		}
	}
	while (r == 0) {
		bool all = true;
		for (int k = 0; k < 3 && r == 0; k++) {
			if (!moving[k])
				continue;
			int there = axis_arrived(d, &d->ax[k], deadline, err);
			r = there < 0 ? there : 0;
			moving[k] = there == 0;
			all = all && there == 1;
		}
		if (r < 0 || all)
			break;
		r = transport_ms_left(deadline) ? can_bus_idle(d->bus, POLL_MS, err)
			: asph_error_set(err, -ETIMEDOUT, "move did not finish within %u ms", timeout_ms);
	}
	return finish(d, r, "motion", err);
}

/* ----------------------------------------------------------- sweeps */

/*
 * A sweep is profile position mode with buffered set points: each axis
 * gets the next target while it runs to the one before (controlword bit 5
 * low: after the one in process; bit 9: through its target without
 * stopping). Statusword bit 12 stays up while a set point waits in the
 * buffer, so its fall says the axis passed the target before. Once every
 * axis passed point k, the trigger line fires (a digital output of one
 * drive, 0x60FE, wired to the probe's trigger input and every axis' touch
 * probe 1 input): each drive latches its encoder at that edge, and the
 * probe takes reading k there. docs/driver-can.md.
 */

#define SWEEP_CW (CIA402_CW_ENABLE_OPERATION | CIA402_CW_CHANGE_ON_SET_POINT)

/* Waits until a's set-point buffer is free: the targets sent before the
 * last one are passed. */
static int buffer_free(struct asph_device *d, const struct axis *a, uint64_t deadline,
		       struct asph_error *err)
{
	for (;;) {
		uint16_t sw;
		int r = motion_sw(d, a, &sw, deadline, err);
		if (r < 0 || !(sw & CIA402_SW_BIT12))
			return r;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s: the sweep did not pass its set "
					      "points in time", name(d, a));
		r = can_bus_idle(d->bus, POLL_MS, err);
		if (r < 0)
			return r;
	}
}

/* The set-point handshake of a buffered target. */
static int queue_set_point(struct asph_device *d, struct axis *a, int32_t target,
			   uint64_t deadline, struct asph_error *err)
{
	uint16_t sw;
	int r = write_obj(d, a->node, CIA402_TARGET_POSITION, 0, (uint32_t)target, 4, deadline, err);

	a->target_valid = false;
	if (r == 0)
		r = write_cw(d, a, SWEEP_CW | CIA402_CW_NEW_SET_POINT, deadline, err);
	while (r == 0) {
		r = motion_sw(d, a, &sw, deadline, err);
		if (r < 0 || (sw & CIA402_SW_BIT12))
			break;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s did not acknowledge the new set point "
					      "in time", name(d, a));
		r = can_bus_idle(d->bus, POLL_MS, err);
	}
	if (r == 0)
		r = write_cw(d, a, SWEEP_CW, deadline, err);
	a->target = target;
	return r;
}

static int write_outputs(struct asph_device *d, uint32_t v, uint64_t deadline,
			 struct asph_error *err)
{
	int r = write_obj(d, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 1, v, 4, deadline, err);
	if (r == 0)
		d->outputs = v;
	return r;
}

/* Every axis in profile position mode; the touch probes armed; the
 * trigger output enabled (0x60FE:02) and low, the other outputs kept. */
static int sweep_prepare(struct asph_device *d, uint64_t deadline, struct asph_error *err)
{
	uint32_t mask, bit = 1u << d->trigger_bit;
	int r = 0;

	for (int k = 0; k < 3 && r == 0; k++)
		if (d->ax[k].node)
			r = axis_pp(d, &d->ax[k], deadline, err);
	for (int k = 0; k < 3 && r == 0 && latching(d); k++)
		if (d->ax[k].node)
			r = arm_touch_probe(d, &d->ax[k], deadline, err);
	if (r < 0 || !d->trigger_bit)
		return r;
	r = can_bus_sdo_upload(d->bus, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 2, &mask,
			       sdo_time(d, deadline), err);
	if (r == 0 && !(mask & bit))
		r = write_obj(d, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 2, mask | bit, 4, deadline,
			      err);
	if (r == 0)
		r = can_bus_sdo_upload(d->bus, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 1,
				       &d->outputs, sdo_time(d, deadline), err);
	if (r == 0 && (d->outputs & bit))
		r = write_outputs(d, d->outputs & ~bit, deadline, err);
	return r;
}

/* Fires the trigger for point k and records where the axes were: latched
 * by the drives, else read back right after (at the instant of the reads). */
static int fire(struct asph_device *d, size_t k, uint64_t deadline, struct asph_error *err)
{
	struct asph_position_sample *s = &d->trace[d->trace_n];
	uint32_t bit = 1u << d->trigger_bit;
	bool latch = latching(d);
	int r = 0;

	memset(s, 0, sizeof(*s));
	s->trigger = (uint32_t)k;
	uint64_t t0 = now_monotonic_ns();
	if (d->trigger_bit) {
		r = write_outputs(d, d->outputs | bit, deadline, err);
		/* the edge is somewhere within the write's exchange */
		s->t_ns = t0 + (now_monotonic_ns() - t0) / 2;
		if (r == 0)
			r = write_outputs(d, d->outputs & ~bit, deadline, err);
		t0 = now_monotonic_ns();
	}
	for (int a = 0; a < 3 && r == 0; a++) {
		struct axis *ax = &d->ax[a];
		int32_t c = 0;
		uint32_t v;
		if (!ax->node)
			continue;
		if (latch) {
			r = read_latch(d, ax, &c, deadline, err);
		} else {
			r = can_bus_sdo_upload(d->bus, ax->node, CIA402_POSITION_ACTUAL, 0, &v,
					       sdo_time(d, deadline), err);
			c = (int32_t)v;
		}
		s->position[a] = c / ax->counts_per_mm;
	}
	if (r < 0)
		return r;
	s->source = latch ? ASPH_POSITION_LATCHED : ASPH_POSITION_READ_BACK;
	if (!latch)
		s->t_ns = t0 + (now_monotonic_ns() - t0) / 2;
	d->trace_n++;
	return 0;
}

static int sweep_run(struct asph_device *d, const double *p, size_t n, uint64_t deadline,
		     struct asph_error *err)
{
	int r = 0;

	for (size_t k = 0; k < n && r == 0; k++) {
		for (int a = 0; a < 3 && r == 0; a++) {
			struct axis *ax = &d->ax[a];
			if (!ax->node)
				continue;
			if (k == 0)
				r = buffer_free(d, ax, deadline, err);
			if (r == 0)
				r = queue_set_point(d, ax, counts(ax, p[3 * k + a]), deadline, err);
		}
		/* point k - 1 is passed once every buffer took point k */
		for (int a = 0; a < 3 && r == 0 && k > 0; a++)
			if (d->ax[a].node)
				r = buffer_free(d, &d->ax[a], deadline, err);
		if (r == 0 && k > 0)
			r = fire(d, k - 1, deadline, err);
	}
	for (int a = 0; a < 3 && r == 0; a++) {
		struct axis *ax = &d->ax[a];
		int there = 0;
		while (ax->node && r == 0 && there == 0) {
			there = axis_arrived(d, ax, deadline, err);
			r = there < 0 ? there : 0;
			if (r == 0 && there == 0)
				r = transport_ms_left(deadline) ? can_bus_idle(d->bus, POLL_MS, err)
					: asph_error_set(err, -ETIMEDOUT, "%s: the sweep did not "
							 "end in time", name(d, ax));
		}
	}
	if (r == 0)
		r = fire(d, n - 1, deadline, err);
	return r;
}

static int stage_sweep(struct asph_device *d, const double *p, size_t n, unsigned timeout_ms,
		       struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = check_stopped(d, err);

	d->trace_n = d->trace_read = 0;
	for (size_t k = 0; k < n && r == 0; k++)
		r = check_target(d, p + 3 * k, err);
	if (r < 0 || n == 0)
		return r;
	if (n > d->trace_cap) {
		struct asph_position_sample *t = realloc(d->trace, n * sizeof(*t));
		if (!t)
			return asph_error_set(err, -ENOMEM, "out of memory");
		d->trace = t;
		d->trace_cap = n;
	}
	r = sweep_prepare(d, deadline, err);
	if (r == 0)
		r = sweep_run(d, p, n, deadline, err);
	for (int a = 0; a < 3 && r == 0; a++) {
		struct axis *ax = &d->ax[a];
		ax->target_valid = ax->node != 0;
		if (ax->node && latching(d))
			r = write_tp(d, ax, 0, deadline, err);
	}
	return finish(d, r, "sweep", err);
}

/* The positions of the last sweep, one per trigger, each handed out once. */
static int stage_trace(struct asph_device *d, struct asph_position_sample *out, size_t max,
		       size_t *n, unsigned timeout_ms, struct asph_error *err)
{
	size_t k = d->trace_n - d->trace_read;

	if (k > max)
		k = max;
	memcpy(out, d->trace + d->trace_read, k * sizeof(*out));
	d->trace_read += k;
	*n = k;
	return 0;
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = check_stopped(d, err);

	for (int k = 0; k < 3 && r == 0; k++) {
		uint32_t c = 0;
		if (d->ax[k].node)
			r = can_bus_sdo_upload(d->bus, d->ax[k].node, CIA402_POSITION_ACTUAL, 0, &c,
					       sdo_time(d, deadline), err);
		pos[k] = (double)(int32_t)c / d->ax[k].counts_per_mm;
	}
	return r == -ECANCELED ? finish(d, r, "position", err) : r;
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
		int r = read_u16(d, a->node, CIA402_STATUSWORD, &sw, deadline, err);
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
			drive_fault(d, a, "", &fe);
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
	int r = check_stopped(d, err);

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
	.home = stage_home,
	.move_to = stage_move,
	.sweep = stage_sweep,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
	.sweep_trace = stage_trace,
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
