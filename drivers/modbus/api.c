/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Modbus stages (one drive per axis, a register map from a profile or the
 * configuration) and displacement sensors, over RTU or TCP. */
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "asph-driver/driver.h"
#include "protocol.h"
#include "sensor.h"
#include "stage.h"
#include "std.h"
#include "util-time.h"

enum {
	/* the bus */
	OPT_TRANSPORT, OPT_HOST, OPT_PORT, OPT_DEVICE, OPT_BAUD, OPT_PARITY, OPT_DATA_BITS,
	OPT_STOP_BITS, OPT_TIMEOUT, OPT_RETRIES, OPT_WORD_ORDER,
	/* the stage */
	OPT_PROFILE, OPT_SLAVE_X, OPT_SLAVE_Y, OPT_SLAVE_Z, OPT_KINEMATICS, OPT_COUNTS_PER_MM,
	OPT_COUNTS_PER_RAD, OPT_TRAVEL_XY, OPT_TRAVEL_Z, OPT_SPEED, OPT_ACCEL, OPT_CURRENT,
	OPT_START, OPT_WORD_SIZE, OPT_REG_DATA, OPT_REG_COMMAND, OPT_REG_STATUS, OPT_REG_POSITION,
	OPT_REG_ALARM, OPT_OPERATION_TYPE, OPT_BIT_START, OPT_BIT_ZHOME, OPT_BIT_STOP,
	OPT_BIT_ALM_RST, OPT_BIT_READY, OPT_BIT_BUSY, OPT_BIT_IN_POS, OPT_BIT_ALM,
	OPT_BIT_HOME_END, OPT_IN_POSITION, OPT_POLL, OPT_RESET_ALARM,
	/* the probe */
	OPT_SLAVE, OPT_SENSOR_PROFILE, OPT_PROBE, OPT_TIP_RADIUS, OPT_STANDOFF, OPT_RANGE, OPT_RATE,
	OPT_TABLE, OPT_REGISTER, OPT_TYPE, OPT_SCALE, OPT_OFFSET, OPT_VALID_REGISTER, OPT_VALID_BIT,
	OPT_STATUS_REGISTER,
	N_OPTIONS
};

static const char *const transports[] = { "tcp", "rtu", NULL };
static const char *const parities[] = { "none", "even", "odd", NULL };
static const char *const word_orders[] = { "high-first", "low-first", NULL };
static const char *const profiles[] = { "az", NULL };
static const char *const kinematics[] = { "xyz", "r-theta-z", NULL };
static const char *const starts[] = { "trigger", "start-bit", NULL };
static const char *const word_sizes[] = { "32", "16", NULL };
static const char *const probe_types[] = { "optical", "tactile", NULL };
static const char *const tables[] = { "input", "holding", NULL };
static const char *const value_types[] = { "s32", "u32", "s16", "u16", "f32", NULL };

#define P ASPH_ROLE_PROBE
#define S ASPH_ROLE_STAGE
#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)
#define REG(name, def, what) { name, ASPH_OPTION_INT, def, RANGE(0, 65535), .roles = S, \
			       .help = what ": register address, decimal; overrides the profile" }
#define BIT(name, def, what) { name, ASPH_OPTION_INT, def, RANGE(0, 31), .roles = S, \
			       .help = what ": bit number in the value; overrides the profile" }

static const struct asph_option_desc modbus_options[N_OPTIONS] = {
	[OPT_TRANSPORT] = { "transport", ASPH_OPTION_ENUM, "tcp", .choices = transports,
			    .help = "tcp (Modbus TCP, or a gateway) or rtu (serial line)" },
	[OPT_HOST] = { "host", ASPH_OPTION_STRING, "127.0.0.1", .help = "tcp: host name or address" },
	[OPT_PORT] = { "port", ASPH_OPTION_INT, "502", RANGE(1, 65535), .help = "tcp: port" },
	[OPT_DEVICE] = { "device", ASPH_OPTION_STRING, "/dev/ttyUSB0",
			 .help = "rtu: serial port (the user needs the dialout group)" },
	[OPT_BAUD] = { "baud", ASPH_OPTION_INT, "115200", RANGE(300, 4000000), .unit = "bit/s",
		       .help = "rtu: baud rate" },
	[OPT_PARITY] = { "parity", ASPH_OPTION_ENUM, "even", .choices = parities,
			 .help = "rtu: parity" },
	[OPT_DATA_BITS] = { "data_bits", ASPH_OPTION_INT, "8", RANGE(7, 8), .help = "rtu: data bits" },
	[OPT_STOP_BITS] = { "stop_bits", ASPH_OPTION_INT, "1", RANGE(1, 2), .help = "rtu: stop bits" },
	[OPT_TIMEOUT] = { "timeout", ASPH_OPTION_INT, "200", RANGE(1, 60000), .unit = "ms",
			  .help = "response timeout of one request" },
	[OPT_RETRIES] = { "retries", ASPH_OPTION_INT, "2", RANGE(0, 20),
			  .help = "repeats of a request that timed out or came back garbled" },
	[OPT_WORD_ORDER] = { "word_order", ASPH_OPTION_ENUM, "high-first", .choices = word_orders,
			     .help = "32-bit values: upper 16 bits at the lower address (high-first) or not" },

	[OPT_PROFILE] = { "profile", ASPH_OPTION_ENUM, "az", .choices = profiles, .roles = S,
			  .help = "register map of the drives: az (Oriental Motor AZ, direct data operation)" },
	[OPT_SLAVE_X] = { "slave_x", ASPH_OPTION_INT, "1", RANGE(1, 247), .roles = S,
			  .help = "slave (RTU) or unit (TCP) id of the x (or r) axis drive" },
	[OPT_SLAVE_Y] = { "slave_y", ASPH_OPTION_INT, "2", RANGE(1, 247), .roles = S,
			  .help = "slave or unit id of the y (or theta) axis drive" },
	[OPT_SLAVE_Z] = { "slave_z", ASPH_OPTION_INT, "3", RANGE(1, 247), .roles = S,
			  .help = "slave or unit id of the z axis drive" },
	[OPT_KINEMATICS] = { "kinematics", ASPH_OPTION_ENUM, "xyz", .choices = kinematics, .roles = S,
			     .help = "stage axes: x, y, z or a rotary table r, theta, z" },
	[OPT_COUNTS_PER_MM] = { "counts_per_mm", ASPH_OPTION_DOUBLE, "1000", RANGE(1e-3, 1e9),
				.roles = S, .help = "drive position counts (steps) per mm of a linear axis" },
	[OPT_COUNTS_PER_RAD] = { "counts_per_rad", ASPH_OPTION_DOUBLE, "10000", RANGE(1e-3, 1e9),
				 .roles = S, .help = "drive position counts per radian of the rotary table" },
	[OPT_TRAVEL_XY] = { "travel_xy", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			    .roles = S, .help = "x and y (or r) travel: -travel_xy .. travel_xy (r: 0 .. travel_xy)" },
	[OPT_TRAVEL_Z] = { "travel_z", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			   .roles = S, .help = "z travel: -travel_z .. travel_z" },
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "10", RANGE(0.001, 10000), .unit = "mm/s",
			.roles = S, .help = "operating speed (rad/s for theta)" },
	[OPT_ACCEL] = { "accel", ASPH_OPTION_DOUBLE, "100", RANGE(0.001, 1e6), .unit = "mm/s^2",
			.roles = S, .help = "acceleration and deceleration (rad/s^2 for theta)" },
	[OPT_CURRENT] = { "current", ASPH_OPTION_DOUBLE, "100", RANGE(0, 100), .unit = "%",
			  .roles = S, .help = "operating current" },
	[OPT_START] = { "start", ASPH_OPTION_ENUM, "trigger", .choices = starts, .roles = S,
			.help = "how a move starts: writing the trigger (1) or a START bit handshake" },
	[OPT_WORD_SIZE] = { "word_size", ASPH_OPTION_ENUM, "32", .choices = word_sizes, .roles = S,
			    .help = "bits of each value of the drive's map (data, command, status, position)" },
	[OPT_REG_DATA] = REG("reg_data", "88", "first register of the direct data block (AZ: 0x0058)"),
	[OPT_REG_COMMAND] = REG("reg_command", "124", "driver input command (AZ: 0x007C)"),
	[OPT_REG_STATUS] = REG("reg_status", "126", "driver output status (AZ: 0x007E)"),
	[OPT_REG_POSITION] = REG("reg_position", "288", "feedback position (AZ: 0x0120)"),
	[OPT_REG_ALARM] = REG("reg_alarm", "128", "present alarm code (AZ: 0x0080)"),
	[OPT_OPERATION_TYPE] = { "operation_type", ASPH_OPTION_INT, "1", RANGE(0, 65535), .roles = S,
				 .help = "operation type written with a move (1: absolute positioning)" },
	[OPT_BIT_START] = BIT("bit_start", "3", "START command"),
	[OPT_BIT_ZHOME] = BIT("bit_zhome", "4", "ZHOME command (return to home)"),
	[OPT_BIT_STOP] = BIT("bit_stop", "5", "STOP command"),
	[OPT_BIT_ALM_RST] = BIT("bit_alm_rst", "7", "ALM-RST command (alarm reset)"),
	[OPT_BIT_READY] = BIT("bit_ready", "5", "READY status"),
	[OPT_BIT_BUSY] = BIT("bit_busy", "13", "BUSY status (MOVE on the AZ)"),
	[OPT_BIT_IN_POS] = BIT("bit_in_pos", "14", "IN-POS status"),
	[OPT_BIT_ALM] = BIT("bit_alm", "7", "ALM status (ALM-A on the AZ)"),
	[OPT_BIT_HOME_END] = BIT("bit_home_end", "4", "HOME-END status"),
	[OPT_IN_POSITION] = { "in_position", ASPH_OPTION_INT, "2", RANGE(0, 1e6), .unit = "counts",
			      .roles = S, .help = "a move is done when the feedback is this close to the target" },
	[OPT_POLL] = { "poll", ASPH_OPTION_INT, "2", RANGE(0, 1000), .unit = "ms", .roles = S,
		       .help = "pause between status reads while the drives move" },
	[OPT_RESET_ALARM] = { "reset_alarm", ASPH_OPTION_BOOL, "false", .roles = S,
			      .help = "homing first clears a drive alarm with ALM-RST" },

	[OPT_SLAVE] = { "slave", ASPH_OPTION_INT, "1", RANGE(1, 247), .roles = P,
			.help = "slave (RTU) or unit (TCP) id of the sensor" },
	[OPT_SENSOR_PROFILE] = { "sensor_profile", ASPH_OPTION_ENUM, "custom",
				 .choices = sensor_profile_names, .roles = P,
				 .help = "the sensor's register map: custom (the options below), "
					 "orbit-acs (Solartron Orbit ACS SI100/SI200: register and "
					 "status_register from its parameter map) or rf60x (RIFTEK "
					 "RF602/RF603, Acuity AR100); options set override it" },
	[OPT_PROBE] = { "probe", ASPH_OPTION_ENUM, "optical", .choices = probe_types, .roles = P,
			.help = "probe type" },
	[OPT_TIP_RADIUS] = { "tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0.001, 10), .unit = "mm",
			     .roles = P, .help = "tactile: tip ball radius" },
	[OPT_STANDOFF] = { "standoff", ASPH_OPTION_DOUBLE, "2", RANGE(-1000, 1000), .unit = "mm",
			   .roles = P, .help = "reading on the expected surface" },
	[OPT_RANGE] = { "range", ASPH_OPTION_DOUBLE, "1", RANGE(1e-6, 10000), .unit = "mm",
			.roles = P, .help = "measuring range, centred on the standoff" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e9), .unit = "Hz", .roles = P,
		       .help = "readings per second (0 = unknown)" },
	[OPT_TABLE] = { "table", ASPH_OPTION_ENUM, "input", .choices = tables, .roles = P,
			.help = "the value is in input registers (function 4) or holding registers (3)" },
	[OPT_REGISTER] = { "register", ASPH_OPTION_INT, "0", RANGE(0, 65535), .roles = P,
			   .help = "address of the value (decimal)" },
	[OPT_TYPE] = { "type", ASPH_OPTION_ENUM, "s32", .choices = value_types, .roles = P,
		       .help = "value: signed or unsigned, 32 or 16 bits, or an IEEE-754 float "
			       "(f32, two registers in word_order)" },
	[OPT_SCALE] = { "scale", ASPH_OPTION_DOUBLE, "0.0001", RANGE(-1e6, 1e6), .unit = "mm",
			.roles = P, .help = "mm per count: reading = value * scale + offset" },
	[OPT_OFFSET] = { "offset", ASPH_OPTION_DOUBLE, "0", RANGE(-1e6, 1e6), .unit = "mm",
			 .roles = P, .help = "added to the scaled value" },
	[OPT_VALID_REGISTER] = { "valid_register", ASPH_OPTION_INT, "-1", RANGE(-1, 65535),
				 .roles = P, .help = "register (same table) with the validity bit; -1 = none" },
	[OPT_VALID_BIT] = { "valid_bit", ASPH_OPTION_INT, "0", RANGE(0, 15), .roles = P,
			    .help = "bit of valid_register that is set while the value is valid" },
	[OPT_STATUS_REGISTER] = { "status_register", ASPH_OPTION_INT, "-1", RANGE(-1, 65535),
				  .roles = P,
				  .help = "orbit-acs: address of the reading status parameter "
					  "(0 valid, 18/19 under/over range, 246/247 no usable probe)" },
};

#undef P
#undef S

/* -------------------------------------------------------- the device */

struct asph_device {
	atomic_bool stop;
	struct mb_bus *bus;
	struct stage stage;
	/* probe */
	struct asph_probe_info pinfo;
	struct sensor sensor;
	enum mb_word_order order;
};

static int open_bus(const struct asph_option_value *o, struct mb_bus **out,
		    struct asph_error *err)
{
	static const char parity[] = { 'N', 'E', 'O' };
	struct mb_bus_params p = {
		.framing = o[OPT_TRANSPORT].i == 1 ? MB_FRAMING_RTU : MB_FRAMING_TCP,
		.device = o[OPT_DEVICE].s,
		.baud = (int)o[OPT_BAUD].i,
		.parity = parity[o[OPT_PARITY].i],
		.data_bits = (int)o[OPT_DATA_BITS].i,
		.stop_bits = (int)o[OPT_STOP_BITS].i,
		.host = o[OPT_HOST].s,
		.port = (int)o[OPT_PORT].i,
		.timeout_ms = (unsigned)o[OPT_TIMEOUT].i,
		.retries = (unsigned)o[OPT_RETRIES].i,
	};
	return mb_bus_open(&p, out, err);
}

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	mb_bus_free(d->bus);
	free(d);
}

/* A device with its bus open; NULL with *r and err set on failure. */
static struct asph_device *dev_new(const struct asph_option_value *o, int *r,
				   struct asph_error *err)
{
	struct asph_device *d = calloc(1, sizeof(*d));

	if (!d) {
		*r = asph_error_set(err, -ENOMEM, "out of memory");
		return NULL;
	}
	atomic_init(&d->stop, false);
	d->order = o[OPT_WORD_ORDER].i == 1 ? MB_LOW_WORD_FIRST : MB_HIGH_WORD_FIRST;
	*r = open_bus(o, &d->bus, err);
	if (*r < 0) {
		free(d);
		return NULL;
	}
	return d;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	return 0;
}

/* ------------------------------------------------------------ stage */

/* The profile's map, then every register and bit option the
 * configuration sets. */
static void stage_map(const struct asph_option_value *o, struct stage_map *m)
{
	static const struct { int opt; size_t off; } over[] = {
		{ OPT_REG_DATA, offsetof(struct stage_map, reg_data) },
		{ OPT_REG_COMMAND, offsetof(struct stage_map, reg_command) },
		{ OPT_REG_STATUS, offsetof(struct stage_map, reg_status) },
		{ OPT_REG_POSITION, offsetof(struct stage_map, reg_position) },
		{ OPT_REG_ALARM, offsetof(struct stage_map, reg_alarm) },
		{ OPT_OPERATION_TYPE, offsetof(struct stage_map, operation_type) },
		{ OPT_BIT_START, offsetof(struct stage_map, bit_start) },
		{ OPT_BIT_ZHOME, offsetof(struct stage_map, bit_zhome) },
		{ OPT_BIT_STOP, offsetof(struct stage_map, bit_stop) },
		{ OPT_BIT_ALM_RST, offsetof(struct stage_map, bit_alm_rst) },
		{ OPT_BIT_READY, offsetof(struct stage_map, bit_ready) },
		{ OPT_BIT_BUSY, offsetof(struct stage_map, bit_busy) },
		{ OPT_BIT_IN_POS, offsetof(struct stage_map, bit_in_pos) },
		{ OPT_BIT_ALM, offsetof(struct stage_map, bit_alm) },
		{ OPT_BIT_HOME_END, offsetof(struct stage_map, bit_home_end) },
	};

	*m = stage_profiles[o[OPT_PROFILE].i];
	if (o[OPT_WORD_SIZE].set)
		m->wide = o[OPT_WORD_SIZE].i == 0;
	if (o[OPT_WORD_ORDER].set)
		m->order = o[OPT_WORD_ORDER].i == 1 ? MB_LOW_WORD_FIRST : MB_HIGH_WORD_FIRST;
	if (o[OPT_START].set)
		m->start_bit = o[OPT_START].i == 1;
	for (size_t k = 0; k < sizeof(over) / sizeof(over[0]); k++)
		if (o[over[k].opt].set)
			*(int *)((char *)m + over[k].off) = (int)o[over[k].opt].i;
}

static void axis(struct asph_axis_info *a, const char *name, const char *unit, double lo,
		 double hi, double speed)
{
	snprintf(a->name, sizeof(a->name), "%s", name);
	snprintf(a->unit, sizeof(a->unit), "%s", unit);
	a->min = lo;
	a->max = hi;
	a->max_speed = speed;
}

static void stage_fill_info(struct stage *s, const struct asph_option_value *o)
{
	struct asph_stage_info *in = &s->info;
	double xy = o[OPT_TRAVEL_XY].d, z = o[OPT_TRAVEL_Z].d, v = o[OPT_SPEED].d;
	bool rtz = o[OPT_KINEMATICS].i == 1;

	in->kinematics = rtz ? ASPH_KINEMATICS_RTZ : ASPH_KINEMATICS_XYZ;
	in->n_axes = 3;
	if (rtz) {
		axis(&in->axes[0], "r", "mm", 0, xy, v);
		axis(&in->axes[1], "theta", "rad", -1e3, 1e3, v);
	} else {
		axis(&in->axes[0], "x", "mm", -xy, xy, v);
		axis(&in->axes[1], "y", "mm", -xy, xy, v);
	}
	axis(&in->axes[2], "z", "mm", -z, z, v);
	snprintf(in->model, sizeof(in->model), "Modbus stage (%s)", profiles[o[OPT_PROFILE].i]);
	snprintf(in->serial, sizeof(in->serial), "units %lld,%lld,%lld",
		 (long long)o[OPT_SLAVE_X].i, (long long)o[OPT_SLAVE_Y].i,
		 (long long)o[OPT_SLAVE_Z].i);
	for (int k = 0; k < 3; k++) {
		double c = rtz && k == 1 ? o[OPT_COUNTS_PER_RAD].d : o[OPT_COUNTS_PER_MM].d;
		s->axes[k].counts_per_unit = c;
		s->axes[k].speed = v * c;
		s->axes[k].accel = o[OPT_ACCEL].d * c;
	}
}

/* Speed, acceleration and current in the drive's units must fit its
 * registers: refused here, before anything moves, never wrapped. */
static int check_settings(const struct stage *s, const struct asph_option_value *o,
			  struct asph_error *err)
{
	int r = 0;

	for (int k = 0; r == 0 && k < 3; k++) {
		bool rotary = s->info.kinematics == ASPH_KINEMATICS_RTZ && k == 1;
		r = stage_check_setting(s, "speed", o[OPT_SPEED].d, rotary ? "rad/s" : "mm/s",
					s->axes[k].speed, err);
		if (r == 0)
			r = stage_check_setting(s, "accel", o[OPT_ACCEL].d,
						rotary ? "rad/s^2" : "mm/s^2", s->axes[k].accel, err);
	}
	if (r == 0)
		r = stage_check_setting(s, "current", o[OPT_CURRENT].d, "%", o[OPT_CURRENT].d * 10,
					err);
	return r;
}

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct stage checked = { 0 };

	/* the settings are checked before the bus is opened */
	stage_map(o, &checked.map);
	stage_fill_info(&checked, o);
	int r = check_settings(&checked, o, err);
	if (r < 0)
		return r;
	struct asph_device *d = dev_new(o, &r, err);

	if (!d)
		return r;
	struct stage *s = &d->stage;
	s->bus = d->bus;
	s->stop = &d->stop;
	stage_map(o, &s->map);
	stage_fill_info(s, o);
	s->axes[0].unit = (int)o[OPT_SLAVE_X].i;
	s->axes[1].unit = (int)o[OPT_SLAVE_Y].i;
	s->axes[2].unit = (int)o[OPT_SLAVE_Z].i;
	s->current = o[OPT_CURRENT].d;
	s->window = o[OPT_IN_POSITION].i;
	s->poll_ms = (unsigned)o[OPT_POLL].i;
	s->reset_alarm = o[OPT_RESET_ALARM].b;
	r = stage_connect(s, timeout_ms, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out, struct asph_error *err)
{
	*out = d->stage.info;
	return 0;
}

static int op_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	return stage_home(&d->stage, timeout_ms, err);
}

static int op_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		   struct asph_error *err)
{
	return stage_move(&d->stage, t, timeout_ms, err);
}

static int op_position(struct asph_device *d, double *pos, unsigned timeout_ms,
		       struct asph_error *err)
{
	return stage_position(&d->stage, pos, timeout_ms, err);
}

static int op_status(struct asph_device *d, struct asph_stage_status *out, unsigned timeout_ms,
		     struct asph_error *err)
{
	return stage_status(&d->stage, out, timeout_ms, err);
}

/* ------------------------------------------------------------ probe */

static void sensor_config(const struct asph_option_value *o, enum mb_word_order order,
			  struct sensor_config *c)
{
	enum sensor_profile_id id = (enum sensor_profile_id)o[OPT_SENSOR_PROFILE].i;

	*c = (struct sensor_config){
		.profile = id,
		.unit = (int)o[OPT_SLAVE].i,
		.input = o[OPT_TABLE].i == 0,
		/* a profile that names no address takes none by default */
		.reg = id == SENSOR_CUSTOM || o[OPT_REGISTER].set ? (int)o[OPT_REGISTER].i : -1,
		.type = (enum sensor_type)o[OPT_TYPE].i,
		.order = order,
		.scale = o[OPT_SCALE].d,
		.scale_set = o[OPT_SCALE].set,
		.offset = o[OPT_OFFSET].d,
		.valid_reg = (int)o[OPT_VALID_REGISTER].i,
		.valid_bit = (int)o[OPT_VALID_BIT].i,
		.status_reg = (int)o[OPT_STATUS_REGISTER].i,
	};
}

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct sensor_config sc;
	int r;
	struct asph_device *d = dev_new(o, &r, err);

	if (!d)
		return r;
	sensor_config(o, d->order, &sc);
	r = sensor_open(&d->sensor, d->bus, &sc, timeout_ms, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	/* a sensor that knows its range is measured within it, from the
	 * start of the range, unless the configuration says otherwise */
	double range = o[OPT_RANGE].set || !d->sensor.range_mm ? o[OPT_RANGE].d : d->sensor.range_mm;
	double standoff = o[OPT_STANDOFF].set || !d->sensor.range_mm ? o[OPT_STANDOFF].d
			  : d->sensor.range_mm / 2 + o[OPT_OFFSET].d;
	struct asph_probe_info *pi = &d->pinfo;
	std_probe_geometry(pi, o[OPT_PROBE].i == 1, o[OPT_TIP_RADIUS].d, standoff, range);
	pi->rate = o[OPT_RATE].d;
	snprintf(pi->model, sizeof(pi->model), "%s", d->sensor.model);
	snprintf(pi->serial, sizeof(pi->serial), "%s", d->sensor.serial);
	/* one read proves the sensor answers and the map fits it */
	struct asph_reading rd;
	struct asph_probe_context ctx = { 0 };
	r = drv->probe->read(d, &ctx, &rd, timeout_ms, err);
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

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	bool oor;

	if (atomic_load(&d->stop))
		return asph_error_set(err, -ECANCELED, "reading stopped");
	memset(out, 0, sizeof(*out));
	int r = sensor_read(&d->sensor, timeout_ms, &out->raw, &out->value, &oor, err);
	if (r < 0)
		return r;
	out->t_ns = now_monotonic_ns();
	if (oor) {
		out->value = NAN;
		out->flags = ASPH_READING_OUT_OF_RANGE;
		return 0;
	}
	std_reading_check_range(out, &d->pinfo);
	return 0;
}

static const struct asph_stage_ops modbus_stage_ops = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = op_home,
	.move_to = op_move,
	.position = op_position,
	.status = op_status,
	.stop = dev_stop,
};

static const struct asph_probe_ops modbus_probe_ops = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stop = dev_stop,
};

const struct asph_driver modbus_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "modbus",
	.description = "Modbus RTU/TCP stage drives (Oriental Motor AZ or a configured map) "
		       "and displacement sensors",
	.version = "1.0",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = modbus_options,
	.n_options = N_OPTIONS,
	.stage = &modbus_stage_ops,
	.probe = &modbus_probe_ops,
};
