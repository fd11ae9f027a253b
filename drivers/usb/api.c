/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * USBTMC instruments: a probe (and a stage, where the instrument has one)
 * spoken to in SCPI over USB. The command strings are a profile of options
 * (docs/driver-usb.md); the defaults are the documented default profile.
 */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "asph-driver/driver.h"
#include "protocol.h"
#include "scpi.h"
#include "std.h"
#include "transport.h"
#include "util-time.h"

enum {
	OPT_VENDOR, OPT_PRODUCT, OPT_SERIAL, OPT_READ_CHUNK, OPT_CLEAR,
	OPT_CMD_INIT, OPT_CMD_IDN, OPT_CMD_MEASURE, OPT_CMD_MOVE, OPT_CMD_HOME,
	OPT_CMD_POSITION, OPT_CMD_STATUS, OPT_CMD_ERROR,
	OPT_MEASURE_SCALE, OPT_PROBE, OPT_TIP_RADIUS, OPT_STANDOFF, OPT_RANGE,
	OPT_MAX_SLOPE, OPT_RATE, OPT_TRAVEL_XY, OPT_TRAVEL_Z, OPT_SPEED, OPT_POLL_MS,
	N_OPTIONS
};

static const char *const probe_types[] = { "optical", "tactile", NULL };

#define P ASPH_ROLE_PROBE
#define S ASPH_ROLE_STAGE
#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)

static const struct asph_option_desc usb_options[N_OPTIONS] = {
	[OPT_VENDOR] = { "vendor_id", ASPH_OPTION_INT, "0", RANGE(0, 65535),
			 .help = "USB vendor id (decimal; 0: any USBTMC device)" },
	[OPT_PRODUCT] = { "product_id", ASPH_OPTION_INT, "0", RANGE(0, 65535),
			  .help = "USB product id (decimal; 0: any)" },
	[OPT_SERIAL] = { "serial", ASPH_OPTION_STRING, "",
			 .help = "USB serial number, to choose among devices of one id; empty: any" },
	[OPT_READ_CHUNK] = { "read_chunk", ASPH_OPTION_INT, "4096", RANGE(16, 1048576),
			     .unit = "bytes", .help = "message bytes asked for per bulk-IN transfer" },
	[OPT_CLEAR] = { "clear", ASPH_OPTION_BOOL, "true",
			.help = "device clear (USBTMC INITIATE_CLEAR) when opening" },
	[OPT_CMD_INIT] = { "cmd_init", ASPH_OPTION_STRING, "*CLS",
			   .help = "profile: sent once after opening (empty: nothing)" },
	[OPT_CMD_IDN] = { "cmd_idn", ASPH_OPTION_STRING, "*IDN?",
			  .help = "profile: identification query (maker,model,serial,firmware)" },
	[OPT_CMD_MEASURE] = { "cmd_measure", ASPH_OPTION_STRING, "MEAS:DIST?", .roles = P,
			      .help = "profile: one reading, a number in measure_scale units" },
	[OPT_CMD_MOVE] = { "cmd_move", ASPH_OPTION_STRING, "MOVE:ABS {0},{1},{2}", .roles = S,
			   .help = "profile: absolute move; {0} {1} {2} are x, y, z in mm" },
	[OPT_CMD_HOME] = { "cmd_home", ASPH_OPTION_STRING, "HOME", .roles = S,
			   .help = "profile: start homing" },
	[OPT_CMD_POSITION] = { "cmd_position", ASPH_OPTION_STRING, "POS?", .roles = S,
			       .help = "profile: position query, answers x,y,z in mm" },
	[OPT_CMD_STATUS] = { "cmd_status", ASPH_OPTION_STRING, "STAT?", .roles = S,
			     .help = "profile: status query, answers bits 1 moving, 2 homed, 4 fault" },
	[OPT_CMD_ERROR] = { "cmd_error", ASPH_OPTION_STRING, "SYST:ERR?",
			    .help = "profile: error queue query, read after every command (empty: never)" },
	[OPT_MEASURE_SCALE] = { "measure_scale", ASPH_OPTION_DOUBLE, "1", RANGE(1e-12, 1e12),
				.unit = "mm", .roles = P,
				.help = "mm per unit of the measure query's answer" },
	[OPT_PROBE] = { "probe", ASPH_OPTION_ENUM, "optical", .choices = probe_types, .roles = P,
			.help = "probe type" },
	[OPT_TIP_RADIUS] = { "tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0.01, 10), .unit = "mm",
			     .roles = P, .help = "tip ball radius of a tactile probe" },
	[OPT_STANDOFF] = { "standoff", ASPH_OPTION_DOUBLE, "2", RANGE(-1000, 1000), .unit = "mm",
			   .roles = P, .help = "reading the probe wants on the nominal surface" },
	[OPT_RANGE] = { "range", ASPH_OPTION_DOUBLE, "1", RANGE(0.001, 1000), .unit = "mm",
			.roles = P, .help = "measuring range, centred on the standoff" },
	[OPT_MAX_SLOPE] = { "max_slope", ASPH_OPTION_DOUBLE, "0", RANGE(0, 90), .unit = "deg",
			    .roles = P, .help = "steepest surface the probe reads (0 = any)" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e9), .unit = "Hz", .roles = P,
		       .help = "readings per second (0 = unknown)" },
	[OPT_TRAVEL_XY] = { "travel_xy", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			    .roles = S, .help = "x and y travel: -travel_xy .. travel_xy" },
	[OPT_TRAVEL_Z] = { "travel_z", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			   .roles = S, .help = "z travel: -travel_z .. travel_z" },
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "0", RANGE(0, 10000), .unit = "mm/s",
			.roles = S, .help = "stage speed (0 = unknown)" },
	[OPT_POLL_MS] = { "poll_ms", ASPH_OPTION_INT, "2", RANGE(0, 1000), .unit = "ms",
			  .roles = S, .help = "status polling interval while the stage moves" },
};

#undef P
#undef S

/* The status query's bits (default profile). */
enum { STATUS_MOVING = 1, STATUS_HOMED = 2, STATUS_FAULT = 4 };

/*
 * One USBTMC interface, shared by the stage and the probe of an instrument
 * that plays both (an interface is claimed once). The table is the only
 * state the driver keeps outside its devices.
 */
struct link {
	struct link *next;
	unsigned refs;
	char key[192];
	pthread_mutex_t io;     /* one SCPI call at a time */
	struct usbtmc *t;
	char idn[SCPI_REPLY_MAX];
};

static pthread_mutex_t links_lock = PTHREAD_MUTEX_INITIALIZER;
static struct link *links;

struct asph_device {
	atomic_bool stop;
	struct link *link;
	/* a copy: the ABI keeps only the strings alive until close */
	struct asph_option_value o[N_OPTIONS];
	bool stage;
	struct asph_probe_info pinfo;
	double scale;
	unsigned poll_ms;
};

static void link_put(struct link *l)
{
	pthread_mutex_lock(&links_lock);
	if (--l->refs == 0) {
		for (struct link **p = &links; *p; p = &(*p)->next)
			if (*p == l) {
				*p = l->next;
				break;
			}
		usbtmc_close(l->t);
		pthread_mutex_destroy(&l->io);
		free(l);
	}
	pthread_mutex_unlock(&links_lock);
}

static int call(struct asph_device *d, const char *cmd, char *reply, size_t size,
		unsigned timeout_ms, struct asph_error *err)
{
	struct scpi_call c = { d->link->t, d->o[OPT_CMD_ERROR].s, &d->stop, timeout_ms };

	if (atomic_load(&d->stop))
		return asph_error_set(err, -ECANCELED, "%s: stopped", usbtmc_name(d->link->t));
	pthread_mutex_lock(&d->link->io);
	int r = scpi_call(&c, cmd, reply, size, err);
	pthread_mutex_unlock(&d->link->io);
	return r;
}

/* Opens the interface or takes the one the other role opened. */
static int link_get(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	const struct asph_option_value *o = d->o;
	struct usbtmc_params p = { .vendor = (uint16_t)o[OPT_VENDOR].i,
				   .product = (uint16_t)o[OPT_PRODUCT].i, .serial = o[OPT_SERIAL].s,
				   .read_chunk = (size_t)o[OPT_READ_CHUNK].i, .clear = o[OPT_CLEAR].b };
	char key[192];
	int r;

	snprintf(key, sizeof(key), "%04x:%04x:%s", p.vendor, p.product, p.serial);
	pthread_mutex_lock(&links_lock);
	for (struct link *l = links; l; l = l->next)
		if (!strcmp(l->key, key)) {
			l->refs++;
			d->link = l;
			pthread_mutex_unlock(&links_lock);
			return 0;
		}
	struct link *l = calloc(1, sizeof(*l));
	if (!l) {
		pthread_mutex_unlock(&links_lock);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	uint64_t deadline = transport_deadline(timeout_ms);
	r = usbtmc_open(&p, &d->stop, timeout_ms, &l->t, err);
	if (r < 0) {
		pthread_mutex_unlock(&links_lock);
		free(l);
		return r;
	}
	pthread_mutex_init(&l->io, NULL);
	snprintf(l->key, sizeof(l->key), "%s", key);
	l->refs = 1;
	l->next = links;
	links = l;
	d->link = l;
	/* the table stays locked until the link works, so that the other
	 * role waits for it rather than opening the device twice */
	if (*o[OPT_CMD_INIT].s)
		r = call(d, o[OPT_CMD_INIT].s, NULL, 0, transport_ms_left(deadline), err);
	if (r == 0)
		r = call(d, o[OPT_CMD_IDN].s, l->idn, sizeof(l->idn), transport_ms_left(deadline), err);
	pthread_mutex_unlock(&links_lock);
	if (r < 0) {
		link_put(l);
		d->link = NULL;
	}
	return r;
}

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	if (d->link)
		link_put(d->link);
	free(d);
}

static int dev_open(const struct asph_option_value *o, bool stage, unsigned timeout_ms,
		    struct asph_device **out, struct asph_error *err)
{
	static const int templates[] = { OPT_CMD_MOVE };
	struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	atomic_init(&d->stop, false);
	memcpy(d->o, o, sizeof(d->o));
	d->stage = stage;
	for (size_t i = 0; i < sizeof(templates) / sizeof(templates[0]); i++)
		if (stage && scpi_check_template(o[templates[i]].s, 3) < 0) {
			dev_close(d);
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0,
						 usb_options[templates[i]].name,
						 "option '%s': '%s' may use only {0}, {1}, {2}",
						 usb_options[templates[i]].name, o[templates[i]].s);
		}
	int r = link_get(d, timeout_ms, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	usbtmc_wake(d->link->t);
	return 0;
}

/* "maker,model,serial,firmware" into model and serial (the USB serial
 * when the instrument gives none). */
static void identify(const struct asph_device *d, char *model, size_t msize,
		     char *serial, size_t ssize)
{
	const char *idn = d->link->idn;
	size_t a = strcspn(idn, ","), b = idn[a] ? strcspn(idn + a + 1, ",") : 0;
	const char *s = idn[a] && idn[a + 1 + b] ? idn + a + 2 + b : "";
	size_t c = strcspn(s, ",");

	snprintf(model, msize, "%.*s%s%.*s", (int)a, idn, b ? " " : "", (int)b,
		 idn[a] ? idn + a + 1 : "");
	if (c && !(c == 1 && *s == '0'))
		snprintf(serial, ssize, "%.*s", (int)c, s);
	else
		snprintf(serial, ssize, "%s", usbtmc_serial(d->link->t));
}

/* ----------------------------------------------------------- stage */

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	int r = dev_open(o, true, timeout_ms, out, err);

	if (r == 0)
		(*out)->poll_ms = (unsigned)o[OPT_POLL_MS].i;
	return r;
}

static void axis(struct asph_axis_info *a, const char *name, double travel, double speed)
{
	snprintf(a->name, sizeof(a->name), "%s", name);
	snprintf(a->unit, sizeof(a->unit), "mm");
	a->min = -travel;
	a->max = travel;
	a->max_speed = speed;
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out,
		      struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->kinematics = ASPH_KINEMATICS_XYZ;
	out->n_axes = 3;
	axis(&out->axes[0], "x", d->o[OPT_TRAVEL_XY].d, d->o[OPT_SPEED].d);
	axis(&out->axes[1], "y", d->o[OPT_TRAVEL_XY].d, d->o[OPT_SPEED].d);
	axis(&out->axes[2], "z", d->o[OPT_TRAVEL_Z].d, d->o[OPT_SPEED].d);
	identify(d, out->model, sizeof(out->model), out->serial, sizeof(out->serial));
	return 0;
}

static int query_status(struct asph_device *d, long *bits, unsigned timeout_ms,
			struct asph_error *err)
{
	char reply[SCPI_REPLY_MAX];
	double v;
	int r = call(d, d->o[OPT_CMD_STATUS].s, reply, sizeof(reply), timeout_ms, err);

	if (r < 0)
		return r;
	if (scpi_parse_numbers(reply, &v, 1) < 0 || !(v >= 0 && v < 65536))
		return asph_error_set(err, -EPROTO, "%s: '%s' answered '%s', not a status number",
				      usbtmc_name(d->link->t), d->o[OPT_CMD_STATUS].s, reply);
	*bits = (long)v;
	return 0;
}

/* Polls the status until the stage stands (and is homed when homing). */
static int settle(struct asph_device *d, bool homing, uint64_t deadline, unsigned timeout_ms,
		  struct asph_error *err)
{
	for (;;) {
		long bits;
		int r = query_status(d, &bits, transport_ms_left(deadline), err);
		if (r < 0)
			return r;
		if (bits & STATUS_FAULT)
			return asph_error_set(err, -EPROTO, "%s: the stage reports a fault (status %ld)",
					      usbtmc_name(d->link->t), bits);
		if (!(bits & STATUS_MOVING) && (!homing || (bits & STATUS_HOMED)))
			return 0;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s: the stage did not %s within %u ms",
					      usbtmc_name(d->link->t), homing ? "home" : "arrive",
					      timeout_ms);
		msleep(d->poll_ms);
	}
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = call(d, d->o[OPT_CMD_HOME].s, NULL, 0, timeout_ms, err);

	return r < 0 ? r : settle(d, true, deadline, timeout_ms, err);
}

static int stage_move(struct asph_device *d, const double *target, unsigned timeout_ms,
		      struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	char cmd[SCPI_REPLY_MAX];

	for (int k = 0; k < 3; k++) {
		double lim = k < 2 ? d->o[OPT_TRAVEL_XY].d : d->o[OPT_TRAVEL_Z].d;
		if (!(fabs(target[k]) <= lim))
			return asph_error_set(err, -ERANGE, "axis %c: target %.6f mm is outside "
					      "-%g .. %g", "xyz"[k], target[k], lim, lim);
	}
	if (scpi_format(d->o[OPT_CMD_MOVE].s, target, 3, cmd, sizeof(cmd)) < 0)
		return asph_error_set(err, -EINVAL, "move command too long");
	int r = call(d, cmd, NULL, 0, timeout_ms, err);
	return r < 0 ? r : settle(d, false, deadline, timeout_ms, err);
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	char reply[SCPI_REPLY_MAX];
	int r = call(d, d->o[OPT_CMD_POSITION].s, reply, sizeof(reply), timeout_ms, err);

	if (r < 0)
		return r;
	if (scpi_parse_numbers(reply, pos, 3) < 0 || isnan(pos[0] + pos[1] + pos[2]))
		return asph_error_set(err, -EPROTO, "%s: '%s' answered '%s', not x,y,z",
				      usbtmc_name(d->link->t), d->o[OPT_CMD_POSITION].s, reply);
	return 0;
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	long bits;
	int r;

	memset(out, 0, sizeof(*out));
	r = query_status(d, &bits, timeout_ms, err);
	if (r == -ENODEV) {
		out->state = ASPH_STAGE_DISCONNECTED;
		snprintf(out->detail, sizeof(out->detail), "%.120s", err ? err->message : "unplugged");
		return 0;
	}
	if (r == 0)
		r = stage_position(d, out->position, transport_ms_left(deadline), err);
	if (r < 0)
		return r;
	out->homed = bits & STATUS_HOMED;
	out->state = bits & STATUS_FAULT ? ASPH_STAGE_FAULT
		     : bits & STATUS_MOVING ? ASPH_STAGE_MOVING
		     : out->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	snprintf(out->detail, sizeof(out->detail), "status %ld", bits);
	return 0;
}

/* ----------------------------------------------------------- probe */

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	int r = dev_open(o, false, timeout_ms, out, err);

	if (r < 0)
		return r;
	struct asph_device *d = *out;
	struct asph_probe_info *pi = &d->pinfo;
	bool tactile = o[OPT_PROBE].i == 1;
	std_probe_geometry(pi, tactile, o[OPT_TIP_RADIUS].d, o[OPT_STANDOFF].d, o[OPT_RANGE].d);
	pi->max_slope = o[OPT_MAX_SLOPE].d * M_PI / 180;
	pi->rate = o[OPT_RATE].d;
	identify(d, pi->model, sizeof(pi->model), pi->serial, sizeof(pi->serial));
	d->scale = o[OPT_MEASURE_SCALE].d;
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out,
		      struct asph_error *err)
{
	*out = d->pinfo;
	return 0;
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	char reply[SCPI_REPLY_MAX];
	double v;
	int r = call(d, d->o[OPT_CMD_MEASURE].s, reply, sizeof(reply), timeout_ms, err);

	if (r < 0)
		return r;
	if (scpi_parse_numbers(reply, &v, 1) < 0)
		return asph_error_set(err, -EPROTO, "%s: '%s' answered '%s', not a number",
				      usbtmc_name(d->link->t), d->o[OPT_CMD_MEASURE].s, reply);
	memset(out, 0, sizeof(*out));
	out->t_ns = now_monotonic_ns();
	out->raw = v;
	out->value = v * d->scale;
	std_reading_check_range(out, &d->pinfo);
	return 0;
}

static const struct asph_stage_ops usb_stage = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = stage_home,
	.move_to = stage_move,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
};

static const struct asph_probe_ops usb_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stop = dev_stop,
};

const struct asph_driver usb_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "usb",
	.description = "USBTMC instrument (USB Test and Measurement Class) spoken to in SCPI",
	.version = "1.0",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = usb_options,
	.n_options = N_OPTIONS,
	.stage = &usb_stage,
	.probe = &usb_probe,
};
