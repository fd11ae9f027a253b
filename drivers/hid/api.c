/* SPDX-License-Identifier: GPL-3.0-or-later */
/* HID digital indicators and touch probes (hidapi, hidraw): one reading
 * per request, decoded with a profile of the device's reports. */
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "asph-driver/driver.h"
#include "keyboard.h"
#include "protocol.h"
#include "std.h"
#include "transport.h"
#include "util-mem.h"
#include "util-time.h"

enum {
	OPT_PATH, OPT_VENDOR_ID, OPT_PRODUCT_ID, OPT_SERIAL, OPT_PROFILE,
	OPT_REPORT_ID, OPT_VALUE_OFFSET, OPT_VALUE_SIZE, OPT_VALUE_SIGNED, OPT_BYTE_ORDER,
	OPT_SCALE, OPT_STATUS_OFFSET, OPT_VALID_MASK, OPT_RANGE_MASK, OPT_TOUCH_MASK,
	OPT_ERROR_MASK, OPT_CMD_REQUEST, OPT_CMD_ZERO, OPT_CMD_HOLD, OPT_ZERO_ON_OPEN,
	OPT_HOLD, OPT_OFFSET, OPT_PROBE, OPT_TIP_RADIUS, OPT_STANDOFF, OPT_RANGE, OPT_RATE,
	OPT_GRAB, OPT_UNIT_SCALE, OPT_READ_TIMEOUT,
	N_OPTIONS
};

/* the names of hid_builtin_profiles, then the keyboard wedge */
static const char *const profiles[] = { "default", "keyboard", NULL };
enum { PROFILE_KEYBOARD = 1 };
static const char *const byte_orders[] = { "little", "big", NULL };
static const char *const probe_types[] = { "tactile", "optical", NULL };

#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)

/* The layout defaults are those of the default profile
 * (hid_default_profile); a configured one overrides the profile's. */
static const struct asph_option_desc hid_options[N_OPTIONS] = {
	[OPT_PATH] = { "path", ASPH_OPTION_STRING, "",
		       .help = "hidraw device node (e.g. /dev/hidraw3); else vendor_id and product_id" },
	[OPT_VENDOR_ID] = { "vendor_id", ASPH_OPTION_INT, "0", RANGE(0, 65535),
			    .help = "USB vendor id (decimal)" },
	[OPT_PRODUCT_ID] = { "product_id", ASPH_OPTION_INT, "0", RANGE(0, 65535),
			     .help = "USB product id (decimal)" },
	[OPT_SERIAL] = { "serial", ASPH_OPTION_STRING, "",
			 .help = "serial number, to choose among devices of one vendor_id:product_id" },
	[OPT_PROFILE] = { "profile", ASPH_OPTION_ENUM, "default", .choices = profiles,
			  .help = "report layout and commands (docs/driver-hid.md); the options below override "
				  "it; keyboard: a gauge that types its reading as keystrokes" },
	[OPT_REPORT_ID] = { "report_id", ASPH_OPTION_INT, "1", RANGE(0, 255),
			    .help = "id of the input report with the reading (0: unnumbered reports)" },
	[OPT_VALUE_OFFSET] = { "value_offset", ASPH_OPTION_INT, "1", RANGE(0, 63), .unit = "bytes",
			       .help = "first byte of the value in the report (the id is byte 0)" },
	[OPT_VALUE_SIZE] = { "value_size", ASPH_OPTION_INT, "4", RANGE(1, 4), .unit = "bytes",
			     .help = "size of the value" },
	[OPT_VALUE_SIGNED] = { "value_signed", ASPH_OPTION_BOOL, "true",
			       .help = "the value is two's complement" },
	[OPT_BYTE_ORDER] = { "byte_order", ASPH_OPTION_ENUM, "little", .choices = byte_orders,
			     .help = "byte order of the value" },
	[OPT_SCALE] = { "scale", ASPH_OPTION_DOUBLE, "0.000001", RANGE(-1e3, 1e3), .unit = "mm",
			.help = "mm per count (negative when the value grows towards the probe)" },
	[OPT_STATUS_OFFSET] = { "status_offset", ASPH_OPTION_INT, "5", RANGE(-1, 63),
				.unit = "bytes", .help = "byte of status bits (-1: none)" },
	[OPT_VALID_MASK] = { "valid_mask", ASPH_OPTION_INT, "1", RANGE(0, 255),
			     .help = "status bits set when the value is a reading (0: always)" },
	[OPT_RANGE_MASK] = { "range_mask", ASPH_OPTION_INT, "2", RANGE(0, 255),
			     .help = "status bits set when the reading is out of range" },
	[OPT_TOUCH_MASK] = { "touch_mask", ASPH_OPTION_INT, "4", RANGE(0, 255),
			     .help = "status bits set while the tip touches (tactile probes)" },
	[OPT_ERROR_MASK] = { "error_mask", ASPH_OPTION_INT, "8", RANGE(0, 255),
			     .help = "status bits set when the device is in fault" },
	[OPT_CMD_REQUEST] = { "cmd_request", ASPH_OPTION_STRING, "output:0201",
			      .help = "report asking for a reading: none, output:HEX or feature:HEX (id first)" },
	[OPT_CMD_ZERO] = { "cmd_zero", ASPH_OPTION_STRING, "feature:0301",
			   .help = "report that zeroes the indicator" },
	[OPT_CMD_HOLD] = { "cmd_hold", ASPH_OPTION_STRING, "feature:0302",
			   .help = "report that holds (latches) the current value" },
	[OPT_ZERO_ON_OPEN] = { "zero_on_open", ASPH_OPTION_BOOL, "false",
			       .help = "send cmd_zero when the probe is opened" },
	[OPT_HOLD] = { "hold", ASPH_OPTION_BOOL, "false",
		       .help = "send cmd_hold before each request (latch the value at the point)" },
	[OPT_OFFSET] = { "offset", ASPH_OPTION_DOUBLE, "0", RANGE(-1e4, 1e4), .unit = "mm",
			 .help = "added to every reading (the reading at the indicator's zero)" },
	[OPT_PROBE] = { "probe", ASPH_OPTION_ENUM, "tactile", .choices = probe_types,
			.help = "probe type" },
	[OPT_TIP_RADIUS] = { "tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0, 10), .unit = "mm",
			     .help = "tip ball radius of a tactile probe" },
	[OPT_STANDOFF] = { "standoff", ASPH_OPTION_DOUBLE, "2", RANGE(-1e4, 1e4), .unit = "mm",
			   .help = "reading wanted on the nominal surface" },
	[OPT_RANGE] = { "range", ASPH_OPTION_DOUBLE, "1", RANGE(0.001, 1e4), .unit = "mm",
			.help = "measuring range, centred on the standoff" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e6), .unit = "Hz",
		       .help = "readings per second (0: unknown)" },
	[OPT_GRAB] = { "grab", ASPH_OPTION_BOOL, "true",
		       .help = "keyboard: grab the gauge's evdev node (EVIOCGRAB) so that its keystrokes "
			       "reach no other program" },
	[OPT_UNIT_SCALE] = { "unit_scale", ASPH_OPTION_DOUBLE, "1", RANGE(-1e6, 1e6), .unit = "mm",
			     .help = "keyboard: mm per typed unit (0.0254 for a gauge typing inches; "
				     "negative when the value grows towards the probe)" },
	[OPT_READ_TIMEOUT] = { "read_timeout", ASPH_OPTION_INT, "0", RANGE(0, 3600000), .unit = "ms",
			       .help = "the longest the host waits for one reading (0: its default, "
				       "2000 ms plus the reading's time at the rate); a keyboard gauge "
				       "without a request: the time the operator has to press its data "
				       "button or foot switch" },
};

#undef RANGE

struct asph_device {
	atomic_bool stop;
	struct hid_link *link;
	struct hid_profile prof;
	bool keyboard;
	struct hid_kbd kbd;
	int grab_fd;                    /* the grabbed evdev node, or -1 */
	double unit_scale;
	bool hold;
	double offset;
	struct asph_probe_info info;
};

/* The profile named by the options, with the options that were set. */
static int build_profile(const struct asph_option_value *o, struct hid_profile *p,
			 struct asph_error *err)
{
	*p = *hid_builtin_profiles[o[OPT_PROFILE].i];
	if (o[OPT_REPORT_ID].set)
		p->report_id = (uint8_t)o[OPT_REPORT_ID].i;
	if (o[OPT_VALUE_OFFSET].set)
		p->value_offset = (unsigned)o[OPT_VALUE_OFFSET].i;
	if (o[OPT_VALUE_SIZE].set)
		p->value_size = (unsigned)o[OPT_VALUE_SIZE].i;
	if (o[OPT_VALUE_SIGNED].set)
		p->value_signed = o[OPT_VALUE_SIGNED].b;
	if (o[OPT_BYTE_ORDER].set)
		p->big_endian = o[OPT_BYTE_ORDER].i == 1;
	if (o[OPT_SCALE].set)
		p->scale = o[OPT_SCALE].d;
	if (o[OPT_STATUS_OFFSET].set)
		p->status_offset = (int)o[OPT_STATUS_OFFSET].i;
	if (o[OPT_VALID_MASK].set)
		p->valid_mask = (uint8_t)o[OPT_VALID_MASK].i;
	if (o[OPT_RANGE_MASK].set)
		p->range_mask = (uint8_t)o[OPT_RANGE_MASK].i;
	if (o[OPT_TOUCH_MASK].set)
		p->touch_mask = (uint8_t)o[OPT_TOUCH_MASK].i;
	if (o[OPT_ERROR_MASK].set)
		p->error_mask = (uint8_t)o[OPT_ERROR_MASK].i;
	int r = 0;
	if (o[OPT_CMD_REQUEST].set)
		r = hid_command_parse(o[OPT_CMD_REQUEST].s, &p->request, err);
	if (r == 0 && o[OPT_CMD_ZERO].set)
		r = hid_command_parse(o[OPT_CMD_ZERO].s, &p->zero, err);
	if (r == 0 && o[OPT_CMD_HOLD].set)
		r = hid_command_parse(o[OPT_CMD_HOLD].s, &p->hold, err);
	return r < 0 ? r : hid_profile_check(p, err);
}

/* A keyboard wedge has no layout: its report id (0 unless set) and the
 * request it may take (none unless set: the operator triggers). */
static int keyboard_profile(const struct asph_option_value *o, struct hid_profile *p,
			    struct asph_error *err)
{
	memset(p, 0, sizeof(*p));
	p->report_id = o[OPT_REPORT_ID].set ? (uint8_t)o[OPT_REPORT_ID].i : 0;
	return o[OPT_CMD_REQUEST].set ? hid_command_parse(o[OPT_CMD_REQUEST].s, &p->request, err) : 0;
}

static void fill_info(struct asph_device *d, const struct asph_option_value *o,
		      const struct hid_link_info *li)
{
	struct asph_probe_info *pi = &d->info;
	bool tactile = o[OPT_PROBE].i == 0;

	std_probe_geometry(pi, tactile, o[OPT_TIP_RADIUS].d, o[OPT_STANDOFF].d, o[OPT_RANGE].d);
	pi->rate = o[OPT_RATE].d;
	snprintf(pi->model, sizeof(pi->model), "HID %.59s", li->product[0] ? li->product : li->path);
	snprintf(pi->serial, sizeof(pi->serial), "%s", li->serial);
}

static void probe_close(struct asph_device *d)
{
	if (!d)
		return;
	if (d->grab_fd >= 0)
		close(d->grab_fd);      /* releases the grab */
	hid_link_close(d->link);
	free(d);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_device *, probe_close)

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct hid_link_info li;
	const char *path = o[OPT_PATH].s;

	if (!*path && (o[OPT_VENDOR_ID].i == 0 || o[OPT_PRODUCT_ID].i == 0))
		return asph_error_set(err, -EINVAL,
				      "hid: set path, or vendor_id and product_id, of the device");
	_cleanup_(probe_closep) struct asph_device *d = calloc(1, sizeof(*d));
	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	atomic_init(&d->stop, false);
	d->grab_fd = -1;
	d->keyboard = o[OPT_PROFILE].i == PROFILE_KEYBOARD;
	int r = d->keyboard ? keyboard_profile(o, &d->prof, err) : build_profile(o, &d->prof, err);
	if (r < 0)
		return r;
	r = hid_link_open(path, (unsigned)o[OPT_VENDOR_ID].i, (unsigned)o[OPT_PRODUCT_ID].i,
			  o[OPT_SERIAL].s, &d->stop, &d->link, &li, err);
	if (r < 0)
		return r;
	char node[300];
	if (d->keyboard && o[OPT_GRAB].b && (r = hid_kbd_grab(li.path, &d->grab_fd, node,
								  sizeof(node), err)) < 0)
		return r;
	d->unit_scale = o[OPT_UNIT_SCALE].d;
	if (o[OPT_ZERO_ON_OPEN].b && (r = hid_link_send(d->link, &d->prof.zero, err)) < 0)
		return r;
	d->hold = o[OPT_HOLD].b;
	d->offset = o[OPT_OFFSET].d;
	fill_info(d, o, &li);
	*out = steal_ptr(d);
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out,
		      struct asph_error *err)
{
	*out = d->info;
	return 0;
}

static void to_reading(const struct asph_device *d, const struct hid_sample *s,
		       struct asph_reading *out)
{
	const struct asph_probe_info *pi = &d->info;

	out->raw = (double)s->counts;
	out->value = s->mm + d->offset;
	std_reading_check_range(out, pi);
	if ((s->status & HID_STATUS_OUT_OF_RANGE) ||
	    (pi->type == ASPH_PROBE_TACTILE && d->prof.touch_mask && d->prof.status_offset >= 0 &&
	     !(s->status & HID_STATUS_TOUCHED)))
		out->flags |= ASPH_READING_OUT_OF_RANGE;
}

/* A keyboard wedge: what it types until Enter, asked for by the request
 * report when there is one, else typed when the operator presses the
 * gauge's data button or foot switch. */
static int keyboard_read(struct asph_device *d, struct asph_reading *out, unsigned timeout_ms,
			 struct asph_error *err)
{
	uint8_t buf[HID_REPORT_MAX];
	uint64_t deadline = transport_deadline(timeout_ms);
	double v;

	hid_kbd_reset(&d->kbd);
	int r = hid_link_drain(d->link, err);
	if (r == 0)
		r = hid_link_send(d->link, &d->prof.request, err);
	while (r == 0) {
		unsigned left = transport_ms_left(deadline);
		if (left == 0)
			return asph_error_set(err, -ETIMEDOUT, "no reading typed within %u ms%s",
					      timeout_ms, d->prof.request.kind == HID_COMMAND_NONE
					      ? " (press the gauge's data button or foot switch; the "
						"read_timeout option gives the operator longer)" : "");
		r = hid_link_read(d->link, buf, sizeof(buf), left, err);
		if (r == -ETIMEDOUT) {
			r = 0;
			continue;
		}
		if (r < 0)
			return r;
		r = hid_kbd_feed(&d->kbd, d->prof.report_id, buf, (size_t)r, &v, err);
		if (r == 1) {
			struct hid_sample s = { .mm = v * d->unit_scale };
			out->t_ns = now_monotonic_ns();
			to_reading(d, &s, out);
			out->raw = v;   /* what the gauge typed, not counts */
			return 0;
		}
	}
	return r;
}

/* Asks for a reading (the reports queued before are stale) and decodes
 * the answer; a real probe has no use for the context. */
static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	uint8_t buf[HID_REPORT_MAX];
	struct hid_sample s;

	memset(out, 0, sizeof(*out));
	if (atomic_load(&d->stop))
		return asph_error_set(err, -ECANCELED, "reading stopped");
	if (d->keyboard)
		return keyboard_read(d, out, timeout_ms, err);
	int r = hid_link_drain(d->link, err);
	if (r == 0 && d->hold)
		r = hid_link_send(d->link, &d->prof.hold, err);
	if (r == 0)
		r = hid_link_send(d->link, &d->prof.request, err);
	if (r == 0)
		r = hid_link_read(d->link, buf, sizeof(buf), timeout_ms, err);
	if (r < 0)
		return r;
	out->t_ns = now_monotonic_ns();
	r = hid_decode_report(&d->prof, buf, (size_t)r, &s, err);
	if (r < 0)
		return r;
	to_reading(d, &s, out);
	return 0;
}

static int probe_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	return 0;
}

static const struct asph_probe_ops hid_probe = {
	.open = probe_open,
	.close = probe_close,
	.info = probe_info,
	.read = probe_read,
	.stop = probe_stop,
};

const struct asph_driver hid_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "hid",
	.description = "HID digital indicators and touch probes (hidapi, hidraw)",
	.version = "1.0",
	.roles = ASPH_ROLE_PROBE,
	.options = hid_options,
	.n_options = N_OPTIONS,
	.probe = &hid_probe,
};
