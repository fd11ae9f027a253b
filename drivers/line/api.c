/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Line-protocol stages and sensors: PI GCS, Newport, Aerotech, LinuxCNC,
 * Keyence, Sylvac, Mitutoyo and a lab's own devices, each described by a
 * profile file (profile.h), over TCP or a serial port. The dialogue is
 * dialogue.c's; here are the options, opening and the operations.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph-driver/driver.h"
#include "dialogue.h"
#include "files.h"
#include "std.h"
#include "util-mem.h"
#include "util-time.h"

enum {
	OPT_PROFILE, OPT_HOST, OPT_PORT, OPT_DEVICE, OPT_BAUD, OPT_DATA_BITS, OPT_PARITY,
	OPT_STOP_BITS, OPT_RTSCTS, OPT_DTR, OPT_AXES, OPT_TIMEOUT, OPT_RECONNECT, OPT_RECONNECT_MS,
	OPT_TRAVEL_XY, OPT_TRAVEL_Z, OPT_SPEED,
	OPT_PROBE, OPT_TIP_RADIUS, OPT_STANDOFF, OPT_RANGE, OPT_RATE, OPT_SCALE, OPT_OFFSET,
	OPT_TRIGGER, OPT_DTR_MS, OPT_READ_TIMEOUT,
	N_OPTIONS
};

static const char *const parities[] = { "profile", "none", "even", "odd", NULL };
static const char *const rtscts[] = { "profile", "on", "off", NULL };
static const char *const dtrs[] = { "on", "off", "leave", NULL };
static const char *const probe_types[] = { "optical", "tactile", NULL };
static const char *const triggers[] = { "request", "dtr", "operator", NULL };

#define P ASPH_ROLE_PROBE
#define S ASPH_ROLE_STAGE
#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)

static const struct asph_option_desc line_options[N_OPTIONS] = {
	[OPT_PROFILE] = { "profile", ASPH_OPTION_STRING, "pi-gcs",
			  .help = "the device's profile: a profile file's path, or a name found in "
				  "$ASPH_LINE_PROFILE_PATH, the lab's profile directory or built in "
				  "(asph drivers lists them)" },
	[OPT_HOST] = { "host", ASPH_OPTION_STRING, "127.0.0.1",
		       .help = "TCP: the controller's host name or address (used when device is empty)" },
	[OPT_PORT] = { "port", ASPH_OPTION_INT, "50000", RANGE(1, 65535),
		       .help = "TCP port; unset, the profile's (pi-gcs: 50000)" },
	[OPT_DEVICE] = { "device", ASPH_OPTION_STRING, "",
			 .help = "serial port (e.g. /dev/ttyUSB0, /dev/ttyACM0); empty: TCP" },
	[OPT_BAUD] = { "baud", ASPH_OPTION_INT, "0", RANGE(0, 4000000), .unit = "bit/s",
		       .help = "serial: baud rate (0: the profile's)" },
	[OPT_DATA_BITS] = { "data_bits", ASPH_OPTION_INT, "0", RANGE(0, 8),
			    .help = "serial: data bits, 5 to 8 (0: the profile's)" },
	[OPT_PARITY] = { "parity", ASPH_OPTION_ENUM, "profile", .choices = parities,
			 .help = "serial: parity" },
	[OPT_STOP_BITS] = { "stop_bits", ASPH_OPTION_INT, "0", RANGE(0, 2),
			    .help = "serial: stop bits, 1 or 2 (0: the profile's)" },
	[OPT_RTSCTS] = { "rtscts", ASPH_OPTION_ENUM, "profile", .choices = rtscts,
			 .help = "serial: RTS/CTS hardware flow control" },
	[OPT_DTR] = { "dtr", ASPH_OPTION_ENUM, "on", .choices = dtrs,
		      .help = "serial: DTR while open (some cables draw power from it)" },
	[OPT_AXES] = { "axes", ASPH_OPTION_STRING, "",
		       .help = "a stage: the controller's axis ids for x, y, z, e.g. 1,2,3; a sensor: its "
			       "channel or head (empty: the profile's)" },
	[OPT_TIMEOUT] = { "timeout", ASPH_OPTION_INT, "1000", RANGE(1, 600000), .unit = "ms",
			  .help = "the longest wait for one reply" },
	[OPT_RECONNECT] = { "reconnect", ASPH_OPTION_BOOL, "true",
			    .help = "connect again (TCP) or open the port again (serial) after the connection "
				    "was lost, to stop the stage and for the next operation (a lost move is "
				    "never resumed)" },
	[OPT_RECONNECT_MS] = { "reconnect_ms", ASPH_OPTION_INT, "3000", RANGE(0, 600000), .unit = "ms",
			       .help = "how long connecting again may take; serial: how long to wait for "
				       "the port to come back (a USB adapter re-enumerating)" },
	[OPT_TRAVEL_XY] = { "travel_xy", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			    .roles = S, .help = "x and y travel: -travel_xy .. travel_xy" },
	[OPT_TRAVEL_Z] = { "travel_z", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			   .roles = S, .help = "z travel: -travel_z .. travel_z" },
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "0", RANGE(0, 10000), .unit = "mm/s",
			.roles = S, .help = "velocity set on the controller (0: the controller's own)" },
	[OPT_PROBE] = { "probe", ASPH_OPTION_ENUM, "optical", .choices = probe_types, .roles = P,
			.help = "probe type" },
	[OPT_TIP_RADIUS] = { "tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0, 10), .unit = "mm",
			     .roles = P, .help = "tactile: tip ball radius" },
	[OPT_STANDOFF] = { "standoff", ASPH_OPTION_DOUBLE, "0", RANGE(-1e4, 1e4), .unit = "mm",
			   .roles = P, .help = "reading wanted on the nominal surface" },
	[OPT_RANGE] = { "range", ASPH_OPTION_DOUBLE, "1", RANGE(1e-6, 1e4), .unit = "mm",
			.roles = P, .help = "measuring range, centred on the standoff" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e6), .unit = "Hz", .roles = P,
		       .help = "readings per second (0: unknown)" },
	[OPT_SCALE] = { "scale", ASPH_OPTION_DOUBLE, "1", RANGE(-1e6, 1e6), .roles = P,
			.help = "reading = device value (in the profile's unit, as mm) x scale + offset; "
				"-1 when the value grows towards the probe" },
	[OPT_OFFSET] = { "offset", ASPH_OPTION_DOUBLE, "0", RANGE(-1e4, 1e4), .unit = "mm",
			 .roles = P, .help = "added to every reading" },
	[OPT_TRIGGER] = { "trigger", ASPH_OPTION_ENUM, "request", .choices = triggers, .roles = P,
			  .help = "how a reading comes: the profile's request, a DTR pulse, or the "
				  "operator (foot switch, data button) within the read timeout" },
	[OPT_DTR_MS] = { "dtr_ms", ASPH_OPTION_INT, "20", RANGE(1, 1000), .unit = "ms", .roles = P,
			 .help = "trigger=dtr: length of the DTR pulse" },
	[OPT_READ_TIMEOUT] = { "read_timeout", ASPH_OPTION_INT, "0", RANGE(0, 3600000), .unit = "ms",
			       .roles = P,
			       .help = "the longest the host waits for one reading (0: its default, "
				       "2000 ms plus the reading's time at the rate); trigger=operator: "
				       "the time the operator has to press the data button or foot switch" },
};

#undef RANGE

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	transport_free(d->t);
	pthread_mutex_destroy(&d->lock);
	free(d);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_device *, dev_close)

static int parse_axes(struct asph_device *d, const char *text, struct asph_error *err)
{
	char buf[64];
	int n = 0;

	for (int k = 0; k < 3; k++)
		memcpy(d->ids[k], d->prof.axes[k], sizeof(d->ids[k]));
	if (!*text)
		return 0;
	snprintf(buf, sizeof(buf), "%s", text);
	char *save = NULL;
	for (char *id = strtok_r(buf, ",", &save); id; id = strtok_r(NULL, ",", &save), n++) {
		if (n == 3 || strlen(id) >= sizeof(d->ids[0]) || strpbrk(id, " {}\\")) {
			n = -1;
			break;
		}
		snprintf(d->ids[n], sizeof(d->ids[n]), "%s", id);
	}
	if (d->stage ? n != 3 : n < 1)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "axes",
					 "option 'axes': %s separated by commas (e.g. %s), not '%s'",
					 d->stage ? "three axis ids for x, y, z" : "the sensor's channel first",
					 d->stage ? "1,2,3" : "1", text);
	return 0;
}

/* ------------------------------------------------------------ common */

/* Runs operation id on every axis if the profile defines it. */
static int run_defined(struct asph_device *d, enum line_op_id id, uint64_t deadline,
		       unsigned timeout_ms, struct asph_error *err)
{
	struct line_match m;
	bool oor = false;

	memset(&m, 0, sizeof(m));
	if (!d->prof.ops[id].defined)
		return 0;
	return line_run_op(d, id, 7, &m, &oor, deadline, timeout_ms, err);
}

static int dev_open(const struct asph_option_value *o, bool stage, unsigned timeout_ms,
		    struct asph_device **out, struct asph_error *err)
{
	_cleanup_(dev_closep) struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	atomic_init(&d->stop, false);
	pthread_mutex_init(&d->lock, NULL);
	d->stage = stage;
	int r = line_profile_load(o[OPT_PROFILE].s, &d->prof, err);
	if (r < 0)
		return r;
	if (!(d->prof.roles & (stage ? LINE_ROLE_STAGE : LINE_ROLE_PROBE)))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "profile",
					 "profile '%s' describes a %s, not a %s", d->prof.name,
					 stage ? "probe" : "stage", stage ? "stage" : "probe");
	r = parse_axes(d, o[OPT_AXES].s, err);
	if (r < 0)
		return r;
	snprintf(d->host, sizeof(d->host), "%s", o[OPT_HOST].s);
	snprintf(d->path, sizeof(d->path), "%s", o[OPT_DEVICE].s);
	d->lp = (struct line_link_params){
		.serial = *d->path != '\0', .host = d->host, .device = d->path,
		.port = o[OPT_PORT].set || !d->prof.tcp_port ? (int)o[OPT_PORT].i : d->prof.tcp_port,
		.baud = o[OPT_BAUD].i ? (int)o[OPT_BAUD].i : d->prof.baud,
		.data_bits = o[OPT_DATA_BITS].i ? (int)o[OPT_DATA_BITS].i : d->prof.data_bits,
		.stop_bits = o[OPT_STOP_BITS].i ? (int)o[OPT_STOP_BITS].i : d->prof.stop_bits,
		.parity = o[OPT_PARITY].i == 0 ? d->prof.parity : "NNEO"[o[OPT_PARITY].i],
		.rtscts = o[OPT_RTSCTS].i == 0 ? d->prof.rtscts : o[OPT_RTSCTS].i == 1,
		.dtr = o[OPT_DTR].i == 0 ? 1 : o[OPT_DTR].i == 1 ? 0 : -1,
	};
	if (d->lp.data_bits < 5)
		return asph_error_set_at(err, -ERANGE, NULL, 0, 0, "data_bits",
					 "option 'data_bits': 5 to 8");
	for (int k = 0; k < 3; k++)
		d->vars.axis_ids[k] = d->ids[k];
	d->vars.axis = -1;
	d->vars.decimals = d->prof.decimals;
	d->reply_ms = (unsigned)o[OPT_TIMEOUT].i;
	d->reconnect = o[OPT_RECONNECT].b;
	d->reconnect_ms = (unsigned)o[OPT_RECONNECT_MS].i;
	r = line_dev_connect(d, timeout_ms, err);
	if (r == 0)
		r = run_defined(d, LINE_OP_CONNECT, transport_deadline(timeout_ms), timeout_ms, err);
	if (r < 0)
		return r;
	*out = steal_ptr(d);
	return 0;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	pthread_mutex_lock(&d->lock);
	/* a link made to stop the stage is already doing what stop() asks */
	if (d->t && !d->stopping)
		transport_cancel(d->t);
	pthread_mutex_unlock(&d->lock);
	return 0;
}

/* ------------------------------------------------------------- stage */

static void axis(struct asph_axis_info *a, const char *name, double travel, double speed)
{
	snprintf(a->name, sizeof(a->name), "%s", name);
	snprintf(a->unit, sizeof(a->unit), "mm");
	a->min = -travel;
	a->max = travel;
	a->max_speed = speed;
}

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	_cleanup_(dev_closep) struct asph_device *d = NULL;
	int r = dev_open(o, true, timeout_ms, &d, err);

	if (r < 0)
		return r;
	d->speed = o[OPT_SPEED].d;
	d->info.kinematics = ASPH_KINEMATICS_XYZ;
	d->info.n_axes = 3;
	axis(&d->info.axes[0], "x", o[OPT_TRAVEL_XY].d, d->speed);
	axis(&d->info.axes[1], "y", o[OPT_TRAVEL_XY].d, d->speed);
	axis(&d->info.axes[2], "z", o[OPT_TRAVEL_Z].d, d->speed);
	snprintf(d->info.model, sizeof(d->info.model), "%.63s", d->prof.description[0]
		 ? d->prof.description : d->prof.name);
	line_dev_name(d, d->info.serial, sizeof(d->info.serial));
	uint64_t deadline = transport_deadline(timeout_ms);
	d->vars.speed = d->speed / d->prof.unit_mm;
	r = run_defined(d, LINE_OP_ENABLE, deadline, timeout_ms, err);
	if (r == 0 && d->speed > 0)
		r = run_defined(d, LINE_OP_VELOCITY, deadline, timeout_ms, err);
	if (r < 0)
		return r;
	*out = steal_ptr(d);
	return 0;
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out, struct asph_error *err)
{
	*out = d->info;
	return 0;
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	int r = line_dev_ready(d, err);

	d->homed = false;
	if (r == 0)
		r = run_defined(d, LINE_OP_HOME, transport_deadline(timeout_ms), timeout_ms, err);
	d->homed = r == 0;
	return line_dev_finish(d, r, err);
}

static int stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		      struct asph_error *err)
{
	int r = line_dev_ready(d, err);

	if (r < 0)
		return r;
	if (!d->homed)
		return asph_error_set(err, -EPROTO, "stage is not homed");
	for (int k = 0; k < 3; k++) {
		const struct asph_axis_info *a = &d->info.axes[k];
		if (!(t[k] >= a->min && t[k] <= a->max))
			return asph_error_set(err, -ERANGE, "axis %s: target %.6f mm is outside "
					      "%.6g .. %.6g", a->name, t[k], a->min, a->max);
		d->vars.target[k] = t[k] / d->prof.unit_mm;
	}
	r = run_defined(d, LINE_OP_MOVE, transport_deadline(timeout_ms), timeout_ms, err);
	return line_dev_finish(d, r, err);
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	struct line_match m;
	bool oor = false;
	int r = line_dev_ready(d, err);

	memset(&m, 0, sizeof(m));
	if (r == 0)
		r = line_run_op(d, LINE_OP_POSITION, 7, &m, &oor, transport_deadline(timeout_ms),
				timeout_ms, err);
	if (r < 0)
		return line_dev_finish(d, r, err);
	for (int k = 0; k < 3; k++) {
		if (!m.has_pos[k])
			return asph_error_set(err, -EPROTO, "position: no position of axis %s in the "
					      "replies", d->info.axes[k].name);
		/* read back from the controller, not the target */
		pos[k] = m.pos[k] * d->prof.unit_mm;
	}
	return 0;
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	struct asph_error e;

	memset(out, 0, sizeof(*out));
	out->homed = d->homed;
	asph_error_clear(&e);
	int r = stage_position(d, out->position, timeout_ms, &e);
	if (r == -ENODEV || r == -EPROTO) {
		out->state = r == -ENODEV ? ASPH_STAGE_DISCONNECTED : ASPH_STAGE_FAULT;
		snprintf(out->detail, sizeof(out->detail), "%.127s", e.message);
		return 0;
	}
	if (r < 0)
		return asph_error_set(err, r, "%s", e.message);
	out->state = d->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	return 0;
}

/* ------------------------------------------------------------- probe */

enum { TRIGGER_REQUEST, TRIGGER_DTR, TRIGGER_OPERATOR };

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = NULL;
	int r = dev_open(o, false, timeout_ms, &d, err);

	if (r < 0)
		return r;
	struct asph_probe_info *pi = &d->pinfo;
	std_probe_geometry(pi, o[OPT_PROBE].i == 1, o[OPT_TIP_RADIUS].d, o[OPT_STANDOFF].d,
			   o[OPT_RANGE].d);
	pi->rate = o[OPT_RATE].d;
	snprintf(pi->model, sizeof(pi->model), "%.63s", d->prof.description[0]
		 ? d->prof.description : d->prof.name);
	line_dev_name(d, pi->serial, sizeof(pi->serial));
	d->scale = o[OPT_SCALE].d;
	d->offset = o[OPT_OFFSET].d;
	d->trigger = (int)o[OPT_TRIGGER].i;
	d->dtr_ms = (unsigned)o[OPT_DTR_MS].i;
	*out = d;
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out, struct asph_error *err)
{
	*out = d->pinfo;
	return 0;
}

/* The reply patterns of the read operation's last query or read step:
 * what a DTR pulse or the operator's button brings. */
static const struct line_step *reading_step(const struct asph_device *d)
{
	const struct line_op *op = &d->prof.ops[LINE_OP_READ];

	for (unsigned i = op->n; i-- > 0;)
		if (op->steps[i].kind == LINE_STEP_QUERY || op->steps[i].kind == LINE_STEP_READ)
			return &op->steps[i];
	return NULL;
}

/* A line the device sends when triggered by a DTR pulse or by hand,
 * within the deadline. */
static int triggered_reading(struct asph_device *d, struct line_match *m, bool *oor,
			     uint64_t deadline, struct asph_error *err)
{
	const struct line_step *st = reading_step(d);
	int r = 0;

	if (d->trigger == TRIGGER_DTR)
		r = line_link_dtr_pulse(d->t, d->dtr_ms, err);
	else
		line_reader_clear(&d->rd);
	if (r == 0 && st)
		r = line_query(d, NULL, st->reply, st->range, m, oor, deadline, err);
	return r;
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	struct line_match m;
	bool oor = false;
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = line_dev_ready(d, err);

	memset(out, 0, sizeof(*out));
	memset(&m, 0, sizeof(m));
	if (r == 0 && d->trigger == TRIGGER_REQUEST)
		r = line_run_op(d, LINE_OP_READ, 7, &m, &oor, deadline, timeout_ms, err);
	else if (r == 0)
		r = triggered_reading(d, &m, &oor, deadline, err);
	if (r == -ENODEV)
		line_dev_drop(d);
	if (r < 0)
		return r;
	out->t_ns = now_monotonic_ns();
	if (oor || !m.has_value) {
		out->value = out->raw = NAN;
		out->flags = ASPH_READING_OUT_OF_RANGE;
		return 0;
	}
	out->raw = m.value;
	out->value = m.value * d->prof.unit_mm * d->scale + d->offset;
	std_reading_check_range(out, &d->pinfo);
	return 0;
}

static const struct asph_stage_ops line_stage = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = stage_home,
	.move_to = stage_move,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
};

static const struct asph_probe_ops line_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stop = dev_stop,
};

const struct asph_driver line_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "line",
	.description = "ASCII line-protocol stages and sensors over TCP or a serial port, "
		       "described by profile files (PI GCS, Newport, Aerotech, LinuxCNC, Keyence, "
		       "Sylvac, Mitutoyo, and a lab's own)",
	.version = "1.1",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = line_options,
	.n_options = N_OPTIONS,
	.stage = &line_stage,
	.probe = &line_probe,
};
