/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The reports of HID indicators, and hidapi (hidraw) underneath. */
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include <wchar.h>

#include <hidapi/hidapi.h>

#include "protocol.h"
#include "util-time.h"

const struct hid_profile hid_default_profile = {
	.report_id = 0x01,
	.value_offset = 1,
	.value_size = 4,
	.value_signed = true,
	.big_endian = false,
	.scale = 1e-6,
	.status_offset = 5,
	.valid_mask = 0x01,
	.range_mask = 0x02,
	.touch_mask = 0x04,
	.error_mask = 0x08,
	.request = { HID_COMMAND_OUTPUT, 2, { 0x02, 0x01 } },
	.zero = { HID_COMMAND_FEATURE, 2, { 0x03, 0x01 } },
	.hold = { HID_COMMAND_FEATURE, 2, { 0x03, 0x02 } },
};

const struct hid_profile *const hid_builtin_profiles[] = {
	&hid_default_profile,
};

/* ---------------------------------------------------------- decoding */

static size_t report_needs(const struct hid_profile *p)
{
	size_t n = p->value_offset + p->value_size;

	if (p->status_offset >= 0 && (size_t)p->status_offset + 1 > n)
		n = (size_t)p->status_offset + 1;
	return n;
}

int hid_profile_check(const struct hid_profile *p, struct asph_error *err)
{
	if (p->value_size < 1 || p->value_size > 4)
		return asph_error_set(err, -EINVAL, "value_size %u: a reading is 1 to 4 bytes",
				      p->value_size);
	if (p->report_id && p->value_offset == 0)
		return asph_error_set(err, -EINVAL,
				      "value_offset 0 is the report id of a numbered report");
	if (report_needs(p) > HID_REPORT_MAX)
		return asph_error_set(err, -EINVAL, "the reading lies beyond a %d-byte report",
				      HID_REPORT_MAX);
	if (p->report_id && p->status_offset == 0)
		return asph_error_set(err, -EINVAL,
				      "status_offset 0 is the report id of a numbered report");
	if (!(p->scale != 0 && p->scale == p->scale))
		return asph_error_set(err, -EINVAL, "scale must not be 0");
	return 0;
}

/* The value of a checked profile: 1 to 4 bytes, the most significant
 * first (big endian) or last. */
static int64_t field(const struct hid_profile *p, const uint8_t *b)
{
	unsigned n = p->value_size;
	uint8_t msb = p->big_endian ? b[0] : b[n - 1];
	/* a negative two's complement value: ones above its bytes */
	int64_t v = p->value_signed && (msb & 0x80) ? -1 : 0;

	for (unsigned k = 0; k < n; k++)
		v = v * 256 + b[p->big_endian ? k : n - 1 - k];
	return v;
}

int hid_decode_report(const struct hid_profile *p, const uint8_t *buf, size_t n,
		      struct hid_sample *out, struct asph_error *err)
{
	size_t need = report_needs(p);

	memset(out, 0, sizeof(*out));
	/* a profile that is not checked could read outside the report or
	 * shift by more than a value's width */
	int r = hid_profile_check(p, err);
	if (r < 0)
		return r;
	if (n == 0)
		return asph_error_set(err, -EPROTO, "empty input report");
	if (p->report_id && buf[0] != p->report_id)
		return asph_error_set(err, -EPROTO, "input report id %u, the profile reads id %u",
				      buf[0], p->report_id);
	if (n < need)
		return asph_error_set(err, -EPROTO,
				      "short input report: %zu bytes, the profile needs %zu", n, need);
	if (p->status_offset >= 0) {
		uint8_t st = buf[p->status_offset];
		if (st & p->error_mask)
			return asph_error_set(err, -EPROTO, "the device reports a fault (status 0x%02x)",
					      st);
		if (p->valid_mask && !(st & p->valid_mask))
			return asph_error_set(err, -EPROTO,
					      "the device marks the reading invalid (status 0x%02x)", st);
		if (st & p->range_mask)
			out->status |= HID_STATUS_OUT_OF_RANGE;
		if (st & p->touch_mask)
			out->status |= HID_STATUS_TOUCHED;
	}
	out->counts = field(p, buf + p->value_offset);
	out->mm = (double)out->counts * p->scale;
	return 0;
}

static int hex_digit(char c)
{
	if (c >= '0' && c <= '9')
		return c - '0';
	if (c >= 'a' && c <= 'f')
		return c - 'a' + 10;
	if (c >= 'A' && c <= 'F')
		return c - 'A' + 10;
	return -1;
}

int hid_command_parse(const char *text, struct hid_command *out, struct asph_error *err)
{
	const char *hex;

	memset(out, 0, sizeof(*out));
	if (!text || !*text || !strcmp(text, "none"))
		return 0;
	if (!strncmp(text, "output:", 7)) {
		out->kind = HID_COMMAND_OUTPUT;
		hex = text + 7;
	} else if (!strncmp(text, "feature:", 8)) {
		out->kind = HID_COMMAND_FEATURE;
		hex = text + 8;
	} else {
		return asph_error_set(err, -EINVAL,
				      "command '%s': expected none, output:HEX or feature:HEX", text);
	}
	size_t len = strlen(hex);
	if (len == 0 || len % 2 || len / 2 > HID_REPORT_MAX)
		return asph_error_set(err, -EINVAL,
				      "command '%s': 1 to %d bytes as pairs of hex digits", text,
				      HID_REPORT_MAX);
	for (size_t i = 0; i < len / 2; i++) {
		int hi = hex_digit(hex[2 * i]), lo = hex_digit(hex[2 * i + 1]);
		if (hi < 0 || lo < 0)
			return asph_error_set(err, -EINVAL, "command '%s': '%c%c' is not a hex byte",
					      text, hex[2 * i], hex[2 * i + 1]);
		out->bytes[i] = (uint8_t)(hi << 4 | lo);
	}
	out->len = len / 2;
	return 0;
}

/* ------------------------------------------------------------ hidapi */

/* hidapi keeps process-wide state: initialized with the first device
 * open, released with the last. */
static pthread_mutex_t hidapi_lock = PTHREAD_MUTEX_INITIALIZER;
static unsigned hidapi_users;

struct hid_link {
	hid_device *dev;
	atomic_bool *stop;
	char path[128];
};

static int hidapi_get(void)
{
	int r = 0;

	pthread_mutex_lock(&hidapi_lock);
	if (hidapi_users == 0 && hid_init() < 0)
		r = -EIO;
	else
		hidapi_users++;
	pthread_mutex_unlock(&hidapi_lock);
	return r;
}

static void hidapi_put(void)
{
	pthread_mutex_lock(&hidapi_lock);
	if (hidapi_users && --hidapi_users == 0)
		hid_exit();
	pthread_mutex_unlock(&hidapi_lock);
}

static void wide(char *dst, size_t size, const wchar_t *w)
{
	snprintf(dst, size, "%ls", w ? w : L"");
}

static bool node_gone(const char *path)
{
	struct stat st;
	return stat(path, &st) < 0 && errno == ENOENT;
}

/* A failed hidapi call: the device is gone when its node went away or
 * hidraw said so (a hung-up poll), else a transport error. */
static int link_fail(struct hid_link *l, const char *what, struct asph_error *err)
{
	char why[128];

	wide(why, sizeof(why), hid_error(l->dev));
	if (node_gone(l->path) || strstr(why, "disconnected"))
		return asph_error_set(err, -ENODEV, "HID device %s is gone (unplugged?) during %s",
				      l->path, what);
	return asph_error_set(err, -EIO, "HID device %s: %s failed: %s", l->path, what, why);
}

/* Finds the path of vendor:product (serial) and the device's strings. */
static int find_device(unsigned vid, unsigned pid, const char *serial, const char *path,
		       struct hid_link_info *info, struct asph_error *err)
{
	struct hid_device_info *all = hid_enumerate((unsigned short)vid, (unsigned short)pid);
	int r = -ENODEV;

	for (struct hid_device_info *d = all; d; d = d->next) {
		char sn[64];
		wide(sn, sizeof(sn), d->serial_number);
		if (path && *path ? strcmp(d->path, path) != 0
			       : serial && *serial && strcmp(sn, serial) != 0)
			continue;
		snprintf(info->path, sizeof(info->path), "%s", d->path);
		wide(info->product, sizeof(info->product), d->product_string);
		snprintf(info->serial, sizeof(info->serial), "%s", sn);
		r = 0;
		break;
	}
	hid_free_enumeration(all);
	if (r < 0 && path && *path) {
		/* not listed (no udev data): open it by its path anyway */
		snprintf(info->path, sizeof(info->path), "%s", path);
		return 0;
	}
	if (r < 0)
		return asph_error_set(err, r, "no HID device %04x:%04x%s%s is connected", vid, pid,
				      serial && *serial ? " with serial " : "",
				      serial && *serial ? serial : "");
	return 0;
}

int hid_link_open(const char *path, unsigned vendor_id, unsigned product_id,
		  const char *serial, atomic_bool *stop, struct hid_link **out,
		  struct hid_link_info *info, struct asph_error *err)
{
	struct hid_link *l;
	int r;

	memset(info, 0, sizeof(*info));
	if (hidapi_get() < 0)
		return asph_error_set(err, -EIO, "hidapi does not initialize");
	r = find_device(vendor_id, product_id, serial, path, info, err);
	if (r < 0) {
		hidapi_put();
		return r;
	}
	l = calloc(1, sizeof(*l));
	if (!l) {
		hidapi_put();
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	snprintf(l->path, sizeof(l->path), "%s", info->path);
	l->stop = stop;
	l->dev = hid_open_path(l->path);
	if (!l->dev) {
		int code = access(l->path, R_OK | W_OK) < 0 && errno == EACCES ? -EACCES : -ENODEV;
		char why[128];
		wide(why, sizeof(why), hid_error(NULL));
		/* hidapi 0.13 loses the reason when HIDIOCGRDESCSIZE fails */
		if (!strcmp(why, "Success"))
			snprintf(why, sizeof(why), "not a hidraw device");
		free(l);
		hidapi_put();
		return asph_error_set(err, code, "cannot open HID device %s: %s%s", info->path, why,
				      code == -EACCES ? " (see docs/driver-hid.md, permissions)" : "");
	}
	*out = l;
	return 0;
}

void hid_link_close(struct hid_link *l)
{
	if (!l)
		return;
	hid_close(l->dev);
	free(l);
	hidapi_put();
}

int hid_link_send(struct hid_link *l, const struct hid_command *c, struct asph_error *err)
{
	int n;

	if (c->kind == HID_COMMAND_NONE)
		return 0;
	if (c->kind == HID_COMMAND_OUTPUT)
		n = hid_write(l->dev, c->bytes, c->len);
	else
		n = hid_send_feature_report(l->dev, c->bytes, c->len);
	if (n < 0)
		return link_fail(l, c->kind == HID_COMMAND_OUTPUT ? "an output report"
								    : "a feature report", err);
	return 0;
}

/* A slice short enough for stop() to be prompt. */
#define SLICE_MS 20

int hid_link_read(struct hid_link *l, uint8_t *buf, size_t size, unsigned timeout_ms,
		  struct asph_error *err)
{
	uint64_t start = now_monotonic_ms(), deadline = start + timeout_ms;

	memset(buf, 0, size);           /* no stale bytes in a short report */
	for (;;) {
		if (atomic_load(l->stop))
			return asph_error_set(err, -ECANCELED, "reading stopped");
		uint64_t t = now_monotonic_ms();
		int wait = t >= deadline ? 0 : (int)(deadline - t < SLICE_MS ? deadline - t : SLICE_MS);
		int n = hid_read_timeout(l->dev, buf, size, wait);
		if (n > 0)
			return n;
		if (n < 0)
			return link_fail(l, "a read", err);
		if (now_monotonic_ms() >= deadline)
			return asph_error_set(err, -ETIMEDOUT, "no input report from %s within %u ms",
					      l->path, timeout_ms);
		/* A read that came back empty before its time: the node is
		 * always readable (not a hidraw node); do not spin. */
		if (now_monotonic_ms() < t + (unsigned)wait)
			msleep(1);
	}
}

int hid_link_drain(struct hid_link *l, struct asph_error *err)
{
	uint8_t buf[HID_REPORT_MAX] = { 0 };

	/* hidraw queues at most 64 reports; a device that sends without
	 * pause would otherwise keep this going */
	for (int k = 0; k < 64; k++) {
		int n = hid_read_timeout(l->dev, buf, sizeof(buf), 0);
		if (n == 0)
			return 0;
		if (n < 0)
			return link_fail(l, "a read", err);
	}
	return 0;
}
