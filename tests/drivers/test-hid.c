/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The HID probe driver through the real hidapi (hidraw backend) against an
 * indicator emulated with umockdev: the report decoding against an
 * independent computation, opening by id, serial and path, zero and hold,
 * the faults (unplug during a read, status bits, short report, wrong
 * report id, silence, stop), and a scan of the strong preset with the mock
 * stage and the emulated indicator, fitted like the mock instrument's.
 *
 * The indicator measures the mock's simulated part (drivers/mock) at the
 * position the mock stage reports; a wrapper around the mock stage tells
 * it where the stage is.
 */
#include <errno.h>
#include <linux/hidraw.h>
#include <linux/input.h>
#include <math.h>
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <time.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "hid/keyboard.h"
#include "hid/protocol.h"
#include "mock/protocol.h"
#include "umockdev-util.h"

/* ------------------------------------------------ the emulated device */

/* The default profile's device (docs/driver-hid.md): vendor page 0xff00,
 * input report 1 (5 bytes), output report 2 (1 byte), feature report 3
 * (1 byte). */
static const uint8_t descriptor[] = {
	0x06, 0x00, 0xff, 0x09, 0x01, 0xa1, 0x01,
	0x85, 0x01, 0x09, 0x02, 0x15, 0x00, 0x26, 0xff, 0x00, 0x75, 0x08, 0x95, 0x05, 0x81, 0x02,
	0x85, 0x02, 0x09, 0x03, 0x95, 0x01, 0x91, 0x02,
	0x85, 0x03, 0x09, 0x04, 0x95, 0x01, 0xb1, 0x02,
	0xc0,
};

enum fault {
	FAULT_NONE = 0, FAULT_UNPLUG, FAULT_ERROR_BIT, FAULT_RANGE_BIT, FAULT_SHORT,
	FAULT_WRONG_ID, FAULT_SILENT,
};

struct indicator {
	pthread_mutex_t lock;
	UMockdevTestbed *tb;
	char syspath[160];
	struct mock_part *part;
	double scale;                   /* mm per count */
	double pos[3];                  /* where the stage is */
	int64_t zero;                   /* counts at the last zero */
	bool held;
	int64_t held_counts;
	int pending;                    /* requests not answered */
	int n_requests, n_zero, n_hold;
	uint8_t last_feature;
	enum fault fault;
	int fault_at;                   /* request number */
	bool unplugged;
};

/* What the indicator shows: the distance from the stage to the part. */
static int64_t counts_now(struct indicator *ind, bool *miss)
{
	double z;

	*miss = mock_part_probe_z(ind->part, ind->pos[0], ind->pos[1], 0, &z) < 0;
	if (*miss)
		return 0;
	return llround((z - ind->pos[2]) / ind->scale);
}

static size_t input_report(struct indicator *ind, uint8_t rep[6])
{
	bool miss;
	int64_t c = ind->held ? ind->held_counts : counts_now(ind, &miss) - ind->zero;
	double mm = (double)c * ind->scale;
	uint8_t st = 0x01 | 0x04;

	if (!ind->held && miss)
		st = 0x01 | 0x02;
	else if (!(mm >= 0 && mm <= 4))
		st = 0x01 | 0x02;
	ind->held = false;
	uint32_t u = (uint32_t)(int32_t)c;
	rep[0] = 0x01;
	for (int k = 0; k < 4; k++)
		rep[1 + k] = (uint8_t)(u >> (8 * k));
	rep[5] = st;
	switch (ind->fault_at == ind->n_requests ? ind->fault : FAULT_NONE) {
	case FAULT_ERROR_BIT: rep[5] |= 0x08; break;
	case FAULT_RANGE_BIT: rep[5] = 0x01 | 0x02; break;
	case FAULT_WRONG_ID: rep[0] = 0x04; break;
	case FAULT_SHORT: return 3;
	default: break;
	}
	return 6;
}

static gboolean on_read(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	struct indicator *ind = data;
	size_t len, n = 0;
	uint8_t *buf = umt_arg(c, &len), rep[6];
	int err = 0;

	pthread_mutex_lock(&ind->lock);
	if (ind->unplugged) {
		err = EIO;
	} else if (ind->pending == 0) {
		err = EAGAIN;                   /* nothing queued */
	} else {
		ind->pending--;
		ind->n_requests++;
		enum fault f = ind->fault_at == ind->n_requests ? ind->fault : FAULT_NONE;
		if (f == FAULT_UNPLUG) {
			umockdev_testbed_remove_device(ind->tb, ind->syspath);
			ind->unplugged = true;
			err = EIO;              /* what hidraw says once it is gone */
		} else if (f == FAULT_SILENT) {
			err = EAGAIN;
		} else {
			n = input_report(ind, rep);
			memcpy(buf, rep, n < len ? n : len);
		}
	}
	pthread_mutex_unlock(&ind->lock);
	umockdev_ioctl_client_complete(c, err ? -1 : (glong)n, err);
	return TRUE;
}

static gboolean on_write(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	struct indicator *ind = data;
	size_t len;
	uint8_t *buf = umt_arg(c, &len);
	int err = 0;

	pthread_mutex_lock(&ind->lock);
	if (ind->unplugged)
		err = ENODEV;
	else if (len == 2 && buf[0] == 0x02 && buf[1] == 0x01)
		ind->pending++;
	else
		err = EINVAL;
	pthread_mutex_unlock(&ind->lock);
	umockdev_ioctl_client_complete(c, err ? -1 : (glong)len, err);
	return TRUE;
}

static void set_feature(struct indicator *ind, const uint8_t *f, size_t n)
{
	bool miss;

	ind->last_feature = n >= 2 ? f[1] : 0;
	if (n == 2 && f[0] == 0x03 && f[1] == 0x01) {
		ind->zero = counts_now(ind, &miss);
		ind->n_zero++;
	} else if (n == 2 && f[0] == 0x03 && f[1] == 0x02) {
		ind->held_counts = counts_now(ind, &miss) - ind->zero;
		ind->held = true;
		ind->n_hold++;
	}
}

static gboolean on_ioctl(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	struct indicator *ind = data;
	unsigned long req = umockdev_ioctl_client_get_request(c);
	UMockdevIoctlData *d;
	glong ret = 0;

	if (req == HIDIOCGRDESCSIZE) {
		d = umt_arg_resolve(c, 0, sizeof(int));
		*(int *)d->data = (int)sizeof(descriptor);
	} else if (req == HIDIOCGRDESC) {
		d = umt_arg_resolve(c, 0, sizeof(struct hidraw_report_descriptor));
		struct hidraw_report_descriptor *r = (void *)d->data;
		r->size = sizeof(descriptor);
		memcpy(r->value, descriptor, sizeof(descriptor));
	} else if (_IOC_TYPE(req) == 'H' && (_IOC_NR(req) == 6 || _IOC_NR(req) == 7)) {
		size_t n = _IOC_SIZE(req);
		d = umt_arg_resolve(c, 0, n);
		pthread_mutex_lock(&ind->lock);
		if (_IOC_NR(req) == 6) {        /* HIDIOCSFEATURE */
			set_feature(ind, d->data, n);
		} else if (n >= 2) {            /* HIDIOCGFEATURE: the last command */
			d->data[0] = 0x03;
			d->data[1] = ind->last_feature;
		}
		pthread_mutex_unlock(&ind->lock);
		ret = (glong)n;
	} else {
		return FALSE;
	}
	g_object_unref(d);
	umockdev_ioctl_client_complete(c, ret, 0);
	return TRUE;
}

#define DEVICE_TEXT \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-%d\n" \
	"E: SUBSYSTEM=usb\nE: DEVTYPE=usb_device\n" \
	"A: idVendor=1209\nA: idProduct=0001\nA: serial=%s\n" \
	"A: manufacturer=asphd test\nA: product=HID indicator\n\n" \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-%d/0003:1209:0001.000%d\n" \
	"E: SUBSYSTEM=hid\nE: HID_ID=0003:00001209:00000001\n" \
	"E: HID_NAME=asphd test HID indicator\nE: HID_UNIQ=%s\n\n" \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-%d/0003:1209:0001.000%d/hidraw/hidraw%d\n" \
	"N: hidraw%d=00\n" \
	"E: SUBSYSTEM=hidraw\nE: DEVNAME=/dev/hidraw%d\nE: MAJOR=241\nE: MINOR=%d\n" \
	"A: dev=241:%d\nL: device=../..\n"

/* hidraw<k> of an indicator with serial sn on USB port 1-<k+1>; a regular
 * file as node, so that poll() finds it ready and read() reaches
 * on_read(), which says EAGAIN when it has nothing. */
static void indicator_add(struct indicator *ind, UMockdevTestbed *tb, int k, const char *sn)
{
	char text[2048], hid[96], node[32];
	struct mock_part_params pp = { .lens = "strong" };
	UMockdevIoctlBase *h;

	memset(ind, 0, sizeof(*ind));
	pthread_mutex_init(&ind->lock, NULL);
	ind->tb = tb;
	ind->scale = 1e-6;
	snprintf(text, sizeof(text), DEVICE_TEXT, k + 1, sn, k + 1, k + 1, sn, k + 1, k + 1, k,
		 k, k, k, k);
	umt_add(tb, text);
	snprintf(hid, sizeof(hid), "/sys/devices/pci0000:00/0000:00:14.0/usb1/1-%d/0003:1209:0001.000%d",
		 k + 1, k + 1);
	umockdev_testbed_set_attribute_binary(tb, hid, "report_descriptor", (guint8 *)descriptor,
					      sizeof(descriptor));
	snprintf(ind->syspath, sizeof(ind->syspath), "%s/hidraw/hidraw%d", hid, k);
	assert_int_equal(mock_part_new(&pp, &ind->part, NULL), 0);
	h = umockdev_ioctl_base_new();
	g_signal_connect(h, "handle-ioctl", G_CALLBACK(on_ioctl), ind);
	g_signal_connect(h, "handle-read", G_CALLBACK(on_read), ind);
	g_signal_connect(h, "handle-write", G_CALLBACK(on_write), ind);
	snprintf(node, sizeof(node), "/dev/hidraw%d", k);
	umt_attach(tb, node, h);
	g_object_unref(h);
}

static void indicator_free(struct indicator *ind)
{
	mock_part_free(ind->part);
	pthread_mutex_destroy(&ind->lock);
}

static void indicator_at(struct indicator *ind, const double *p)
{
	pthread_mutex_lock(&ind->lock);
	memcpy(ind->pos, p, sizeof(ind->pos));
	pthread_mutex_unlock(&ind->lock);
}

static void indicator_fault(struct indicator *ind, enum fault f, int after)
{
	pthread_mutex_lock(&ind->lock);
	ind->fault = f;
	ind->fault_at = ind->n_requests + after;
	pthread_mutex_unlock(&ind->lock);
}

/* ----------------------------------------------------------- fixture */

struct env {
	UMockdevTestbed *tb;
	struct indicator ind[2];        /* IND-0001 on hidraw0, IND-0002 on hidraw1 */
	struct asph_registry *reg;
	const struct asph_driver *hid;
};

static int setup(void **state)
{
	struct env *e = calloc(1, sizeof(*e));

	assert_non_null(e);
	e->tb = umt_testbed_new();
	indicator_add(&e->ind[0], e->tb, 0, "IND-0001");
	indicator_add(&e->ind[1], e->tb, 1, "IND-0002");
	assert_int_equal(asph_registry_new(&e->reg, NULL), 0);
	e->hid = asph_registry_find(e->reg, "hid");
	assert_non_null(e->hid);
	*state = e;
	return 0;
}

static int teardown(void **state)
{
	struct env *e = *state;

	asph_registry_free(e->reg);
	g_object_unref(e->tb);
	indicator_free(&e->ind[0]);
	indicator_free(&e->ind[1]);
	free(e);
	return 0;
}

/* Opens the HID probe with options "k=v,k=v". */
static int open_hid(struct env *e, const char *opts, struct asph_device **d,
		    struct asph_error *err)
{
	struct asph_options *o;
	char buf[512], *save = NULL;

	assert_int_equal(asph_options_new(e->hid, &o, NULL), 0);
	snprintf(buf, sizeof(buf), "%s", opts);
	for (char *kv = strtok_r(buf, ",", &save); kv; kv = strtok_r(NULL, ",", &save)) {
		char *eq = strchr(kv, '=');
		assert_non_null(eq);
		*eq = 0;
		if (asph_options_set(o, kv, eq + 1, err) < 0)
			fail_msg("%s: %s", kv, err->message);
	}
	int r = e->hid->probe->open(e->hid, asph_options_values(o), 1000, d, err);
	asph_options_free(o);
	return r;
}

/* The timeout of a read that must succeed: generous, as a loaded machine
 * or valgrind may take seconds to pass a report through umockdev, and the
 * read returns as soon as the reading is complete (a read meant to time
 * out or fail says its own, short timeout). */
#define READ_OK_MS 60000

static int read_once(struct env *e, struct asph_device *d, struct asph_reading *rd,
		     unsigned timeout_ms, struct asph_error *err)
{
	struct asph_probe_context ctx = { 0 };
	return e->hid->probe->read(d, &ctx, rd, timeout_ms, err);
}

#define ID0 "vendor_id=4617,product_id=1"

/* ----------------------------------------------------------- decoding */

/* An independent reading of a field: the bytes as an integer of the
 * given order, sign-extended by arithmetic on doubles. */
static double expect_field(const uint8_t *b, unsigned n, bool sgn, bool big)
{
	double v = 0;
	for (unsigned k = 0; k < n; k++)
		v = v * 256 + b[big ? k : n - 1 - k];
	if (sgn && v >= ldexp(1, (int)(8 * n - 1)))
		v -= ldexp(1, (int)(8 * n));
	return v;
}

static void test_decode(void **state)
{
	uint8_t rep[12];
	struct hid_sample s;
	struct asph_error err;
	uint64_t x = 0x9e3779b97f4a7c15u;

	for (int i = 0; i < 400; i++) {
		struct hid_profile p = hid_default_profile;
		p.value_size = 1 + (unsigned)i % 4;
		p.value_signed = (i / 4) % 2;
		p.big_endian = (i / 8) % 2;
		p.value_offset = 1 + (unsigned)(i / 16) % 3;
		p.status_offset = 9;
		p.scale = (i % 3 ? -1.0 : 1.0) * 3.7e-5;
		for (size_t k = 0; k < sizeof(rep); k++) {
			x ^= x << 13, x ^= x >> 7, x ^= x << 17;
			rep[k] = (uint8_t)(x >> 24);
		}
		rep[0] = 0x01;
		rep[9] = (uint8_t)(0x01 | (i % 5 == 0 ? 0x02 : 0) | (i % 7 == 0 ? 0x04 : 0));
		assert_int_equal(hid_decode_report(&p, rep, 10, &s, &err), 0);
		double want = expect_field(rep + p.value_offset, p.value_size, p.value_signed,
					   p.big_endian);
		assert_true((double)s.counts == want);
		assert_true(fabs(s.mm - want * p.scale) <= 1e-15 * fabs(want * p.scale));
		assert_int_equal(!!(s.status & HID_STATUS_OUT_OF_RANGE), i % 5 == 0);
		assert_int_equal(!!(s.status & HID_STATUS_TOUCHED), i % 7 == 0);
	}
}

static void test_decode_errors(void **state)
{
	const struct hid_profile *p = &hid_default_profile;
	uint8_t rep[6] = { 0x01, 0x39, 0x30, 0x00, 0x00, 0x05 };
	struct hid_sample s;
	struct asph_error err;

	assert_int_equal(hid_decode_report(p, rep, 6, &s, &err), 0);
	assert_int_equal(s.counts, 12345);
	assert_int_equal(hid_decode_report(p, rep, 5, &s, &err), -EPROTO);
	assert_non_null(strstr(err.message, "short input report: 5 bytes, the profile needs 6"));
	assert_int_equal(hid_decode_report(p, rep, 0, &s, &err), -EPROTO);
	rep[0] = 0x07;
	assert_int_equal(hid_decode_report(p, rep, 6, &s, &err), -EPROTO);
	assert_non_null(strstr(err.message, "input report id 7, the profile reads id 1"));
	rep[0] = 0x01;
	rep[5] = 0x09;
	assert_int_equal(hid_decode_report(p, rep, 6, &s, &err), -EPROTO);
	assert_non_null(strstr(err.message, "fault (status 0x09)"));
	rep[5] = 0x04;
	assert_int_equal(hid_decode_report(p, rep, 6, &s, &err), -EPROTO);
	assert_non_null(strstr(err.message, "invalid"));

	/* unnumbered reports: the value from byte 0, no status */
	struct hid_profile q = hid_default_profile;
	q.report_id = 0;
	q.value_offset = 0;
	q.value_size = 3;
	q.big_endian = true;
	q.status_offset = -1;
	uint8_t raw[3] = { 0xff, 0xfe, 0x1d };
	assert_int_equal(hid_decode_report(&q, raw, 3, &s, &err), 0);
	assert_int_equal(s.counts, -483);
	assert_int_equal(s.status, 0);

	q.value_size = 5;
	assert_int_equal(hid_profile_check(&q, &err), -EINVAL);
	q.value_size = 4;
	q.value_offset = 62;
	assert_int_equal(hid_profile_check(&q, &err), -EINVAL);
	assert_int_equal(hid_profile_check(&hid_default_profile, &err), 0);
}

/* The decoder checks the profile itself: a zero-width value once shifted
 * by 2^32 - 1 bits, a 5-byte one overflowed 32 bits. */
static void test_decode_profile_widths(void **state)
{
	struct hid_profile q = hid_default_profile;
	uint8_t raw[8] = { 0x80, 0x00, 0x00, 0x00, 0x7f, 0xff, 0xff, 0xfe };
	struct hid_sample s;
	struct asph_error err;

	q.report_id = 0;
	q.value_offset = 0;
	q.status_offset = -1;
	q.value_signed = true;
	q.big_endian = true;
	for (unsigned size = 0; size <= 5; size += 5) {
		q.value_size = size;
		asph_error_clear(&err);
		assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), -EINVAL);
		assert_non_null(strstr(err.message, "a reading is 1 to 4 bytes"));
	}
	/* the 32-bit extremes, signed and not, both byte orders */
	q.value_size = 4;
	assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), 0);
	assert_true(s.counts == -2147483648LL);
	q.value_offset = 4;
	assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), 0);
	assert_true(s.counts == 2147483646LL);
	q.big_endian = false;
	assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), 0);
	assert_true(s.counts == 0xfeffff7fLL - 0x100000000LL);
	q.value_signed = false;
	assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), 0);
	assert_true(s.counts == 0xfeffff7fLL);
	/* a 1-byte signed value at both ends of its range */
	q.value_signed = true;
	q.value_size = 1;
	q.value_offset = 0;
	assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), 0);
	assert_true(s.counts == -128);
	q.value_offset = 4;
	assert_int_equal(hid_decode_report(&q, raw, sizeof(raw), &s, &err), 0);
	assert_true(s.counts == 127);
}

static void test_command_parse(void **state)
{
	struct hid_command c;
	struct asph_error err;

	assert_int_equal(hid_command_parse("output:02a1Ff", &c, &err), 0);
	assert_int_equal(c.kind, HID_COMMAND_OUTPUT);
	assert_int_equal(c.len, 3);
	assert_int_equal(c.bytes[0], 0x02);
	assert_int_equal(c.bytes[1], 0xa1);
	assert_int_equal(c.bytes[2], 0xff);
	assert_int_equal(hid_command_parse("feature:0302", &c, &err), 0);
	assert_int_equal(c.kind, HID_COMMAND_FEATURE);
	assert_int_equal(hid_command_parse("none", &c, &err), 0);
	assert_int_equal(c.kind, HID_COMMAND_NONE);
	assert_int_equal(hid_command_parse("output:021", &c, &err), -EINVAL);
	assert_int_equal(hid_command_parse("output:0g", &c, &err), -EINVAL);
	assert_non_null(strstr(err.message, "'0g' is not a hex byte"));
	assert_int_equal(hid_command_parse("input:02", &c, &err), -EINVAL);
}

/* ------------------------------------------------------------ opening */

static void test_open(void **state)
{
	struct env *e = *state;
	struct asph_device *d;
	struct asph_probe_info pi;
	struct asph_reading rd;
	struct asph_error err;

	if (open_hid(e, ID0 ",serial=IND-0002", &d, &err) < 0)
		fail_msg("open: %s", err.message);
	assert_int_equal(e->hid->probe->info(d, &pi, &err), 0);
	assert_string_equal(pi.serial, "IND-0002");
	assert_string_equal(pi.model, "HID HID indicator");
	assert_int_equal(pi.type, ASPH_PROBE_TACTILE);
	if (read_once(e, d, &rd, READ_OK_MS, &err) < 0)
		fail_msg("read: %s", err.message);
	assert_int_equal(e->ind[1].n_requests, 1);
	assert_int_equal(e->ind[0].n_requests, 0);
	e->hid->probe->close(d);

	if (open_hid(e, "path=/dev/hidraw0", &d, &err) < 0)
		fail_msg("open: %s", err.message);
	assert_int_equal(e->hid->probe->info(d, &pi, &err), 0);
	assert_string_equal(pi.serial, "IND-0001");
	e->hid->probe->close(d);

	assert_int_equal(open_hid(e, ID0 ",serial=IND-9999", &d, &err), -ENODEV);
	assert_non_null(strstr(err.message, "no HID device 1209:0001 with serial IND-9999"));
	assert_int_equal(open_hid(e, "vendor_id=4617,product_id=2", &d, &err), -ENODEV);
	assert_int_equal(open_hid(e, "path=/dev/hidraw7", &d, &err), -ENODEV);
	assert_non_null(strstr(err.message, "/dev/hidraw7"));
	assert_int_equal(open_hid(e, "vendor_id=4617", &d, &err), -EINVAL);
	assert_int_equal(open_hid(e, ID0 ",cmd_zero=feature:03z1", &d, &err), -EINVAL);
	assert_int_equal(open_hid(e, ID0 ",value_offset=62", &d, &err), -EINVAL);
}

/* Readings at high-entropy positions against the part's own geometry. */
static void test_readings(void **state)
{
	struct env *e = *state;
	struct indicator *ind = &e->ind[0];
	struct asph_device *d;
	struct asph_reading rd;
	struct asph_error err;

	if (open_hid(e, ID0 ",probe=optical,standoff=2,range=3", &d, &err) < 0)
		fail_msg("open: %s", err.message);
	for (int i = 0; i < 25; i++) {
		double r = 16.9 * sqrt((i + 0.41) / 25.0), t = 2.39996322972865332 * i + 0.7;
		double p[3] = { r * cos(t), r * sin(t), 0 }, z;
		assert_int_equal(mock_part_probe_z(ind->part, p[0], p[1], 0, &z), 0);
		p[2] = z - 1.61 - 0.037 * i;    /* inside 0.5 .. 3.5 */
		indicator_at(ind, p);
		if (read_once(e, d, &rd, READ_OK_MS, &err) < 0)
			fail_msg("read %d: %s", i, err.message);
		assert_false(rd.flags & ASPH_READING_OUT_OF_RANGE);
		if (fabs(rd.value - (z - p[2])) > 0.5e-6 + 1e-12)
			fail_msg("read %d: %.9f mm, the part is %.9f mm away", i, rd.value, z - p[2]);
		assert_true(rd.t_ns > 0);
	}
	/* beyond the range the driver is given: flagged */
	double far[3] = { 3.3, -2.1, 0 }, z;
	assert_int_equal(mock_part_probe_z(ind->part, far[0], far[1], 0, &z), 0);
	far[2] = z - 3.71;
	indicator_at(ind, far);
	assert_int_equal(read_once(e, d, &rd, READ_OK_MS, &err), 0);
	assert_true(rd.flags & ASPH_READING_OUT_OF_RANGE);
	e->hid->probe->close(d);
}

static void test_zero_hold(void **state)
{
	struct env *e = *state;
	struct indicator *ind = &e->ind[0];
	struct asph_device *d;
	struct asph_reading rd;
	struct asph_error err;
	double p[3] = { 4.7, 1.9, 0 }, z;

	assert_int_equal(mock_part_probe_z(ind->part, p[0], p[1], 0, &z), 0);
	p[2] = z - 1.234;
	indicator_at(ind, p);
	if (open_hid(e, ID0 ",zero_on_open=true,hold=true,offset=2,probe=optical", &d, &err) < 0)
		fail_msg("open: %s", err.message);
	assert_int_equal(ind->n_zero, 1);
	/* zeroed here: the reading is the offset, then follows the motion */
	assert_int_equal(read_once(e, d, &rd, READ_OK_MS, &err), 0);
	assert_true(fabs(rd.value - 2) <= 1e-12);
	p[2] -= 0.3179;
	indicator_at(ind, p);
	assert_int_equal(read_once(e, d, &rd, READ_OK_MS, &err), 0);
	assert_true(fabs(rd.value - 2.3179) <= 0.5e-6 + 1e-12);
	assert_int_equal(ind->n_hold, 2);
	assert_int_equal(ind->last_feature, 0x02);
	e->hid->probe->close(d);
	ind->zero = 0;
}

/* ------------------------------------------------------------- faults */

struct fault_case {
	enum fault fault;
	int code;
	const char *words;
};

static void test_faults(void **state)
{
	static const struct fault_case cases[] = {
		{ FAULT_ERROR_BIT, -EPROTO, "the device reports a fault (status 0x0d)" },
		{ FAULT_SHORT, -EPROTO, "short input report: 3 bytes, the profile needs 6" },
		{ FAULT_WRONG_ID, -EPROTO, "input report id 4, the profile reads id 1" },
		{ FAULT_SILENT, -ETIMEDOUT, "no input report from /dev/hidraw0 within 150 ms" },
		{ FAULT_UNPLUG, -ENODEV, "HID device /dev/hidraw0 is gone (unplugged?) during a read" },
	};
	struct env *e = *state;
	struct indicator *ind = &e->ind[0];
	struct asph_device *d;
	struct asph_reading rd;
	struct asph_error err;
	double p[3] = { -6.1, 3.3, 0 }, z;

	assert_int_equal(mock_part_probe_z(ind->part, p[0], p[1], 0, &z), 0);
	p[2] = z - 2.05;
	indicator_at(ind, p);
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		if (open_hid(e, ID0, &d, &err) < 0)
			fail_msg("open: %s", err.message);
		assert_int_equal(read_once(e, d, &rd, READ_OK_MS, &err), 0);
		indicator_fault(ind, cases[i].fault, 2);
		assert_int_equal(read_once(e, d, &rd, READ_OK_MS, &err), 0);
		int r = read_once(e, d, &rd, 150, &err);
		if (r != cases[i].code || !strstr(err.message, cases[i].words))
			fail_msg("case %zu: %d %s", i, r, err.message);
		if (cases[i].fault == FAULT_UNPLUG) {
			/* a write to a gone device: the same reason */
			assert_int_equal(read_once(e, d, &rd, 150, &err), -ENODEV);
		} else {
			/* the device goes on */
			indicator_fault(ind, FAULT_NONE, 0);
			if (read_once(e, d, &rd, READ_OK_MS, &err) < 0)
				fail_msg("case %zu, after: %s", i, err.message);
		}
		e->hid->probe->close(d);
	}
	/* the unplugged device is not found again */
	assert_int_equal(open_hid(e, ID0 ",serial=IND-0001", &d, &err), -ENODEV);
	/* an out-of-range report is a reading, flagged */
	if (open_hid(e, ID0 ",serial=IND-0002", &d, &err) < 0)
		fail_msg("open: %s", err.message);
	indicator_at(&e->ind[1], p);
	indicator_fault(&e->ind[1], FAULT_RANGE_BIT, 1);
	assert_int_equal(read_once(e, d, &rd, READ_OK_MS, &err), 0);
	assert_true(rd.flags & ASPH_READING_OUT_OF_RANGE);
	e->hid->probe->close(d);
}

struct stopper {
	const struct asph_driver *drv;
	struct asph_device *d;
};

static void *stop_later(void *data)
{
	struct stopper *s = data;
	struct timespec ts = { 0, 60000000 };

	nanosleep(&ts, NULL);
	s->drv->probe->stop(s->d, NULL);
	return NULL;
}

static void test_stop(void **state)
{
	struct env *e = *state;
	struct indicator *ind = &e->ind[1];
	struct stopper s = { e->hid, NULL };
	struct asph_reading rd;
	struct asph_error err;
	pthread_t th;

	if (open_hid(e, ID0 ",serial=IND-0002", &s.d, &err) < 0)
		fail_msg("open: %s", err.message);
	indicator_fault(ind, FAULT_SILENT, 1);
	assert_int_equal(pthread_create(&th, NULL, stop_later, &s), 0);
	int r = read_once(e, s.d, &rd, 600000, &err);
	pthread_join(th, NULL);
	assert_int_equal(r, -ECANCELED);
	assert_int_equal(read_once(e, s.d, &rd, 100, &err), -ECANCELED);
	e->hid->probe->close(s.d);
	indicator_fault(ind, FAULT_NONE, 0);
}

/* ---------------------------------------------------------- end to end */

/* The mock stage, telling the indicator where it is. */
static struct indicator *tracked;
static const struct asph_stage_ops *mock_stage;

static void track(struct asph_device *d)
{
	double p[3];
	if (mock_stage->position(d, p, 0, NULL) == 0)
		indicator_at(tracked, p);
}

static int track_home(struct asph_device *d, unsigned t, struct asph_error *err)
{
	int r = mock_stage->home(d, t, err);
	track(d);
	return r;
}

static int track_move(struct asph_device *d, const double *p, unsigned t, struct asph_error *err)
{
	int r = mock_stage->move_to(d, p, t, err);
	track(d);
	return r;
}

static int track_sweep(struct asph_device *d, const double *p, size_t n, unsigned t,
		       struct asph_error *err)
{
	int r = mock_stage->sweep(d, p, n, t, err);
	track(d);
	return r;
}

static void fit_scan(const struct asph_surface *s, const char *path, struct asph_fit_result *res)
{
	struct asph_scanfile *sf;
	struct asph_points *pts;
	struct asph_fit *w;
	struct asph_error err;
	struct asph_fit_options fo = { .dof = ASPH_FIT_DOF_RIGID };

	if (asph_scanfile_read(path, &sf, &err) < 0)
		fail_msg("%s: %s", path, err.message);
	assert_int_equal(asph_scanfile_to_points(sf, 0, &pts, NULL), 0);
	assert_int_equal(asph_fit_alloc(s, pts->n, &fo, &w, NULL), 0);
	if (asph_fit_run(w, pts->xyz, pts->n, res, &err) < 0)
		fail_msg("fit: %s", err.message);
	asph_fit_free(w);
	asph_points_free(pts);
	asph_scanfile_free(sf);
}

static void scan(struct env *e, const char *json, bool track_stage, const struct asph_surface *s,
		 const struct asph_plan *plan, const char *path)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						  "{\"name\":\"e2e\"}", NULL };
	static struct asph_stage_ops ops;
	static struct asph_driver tracking;
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_scanfile_writer *w;
	struct asph_error err;

	if (asph_config_parse(e->reg, json, strlen(json), "e2e", &c, &err) < 0)
		fail_msg("config: %s", err.message);
	if (track_stage) {
		mock_stage = c->instruments[0].stage_driver->stage;
		ops = *mock_stage;
		ops.home = track_home;
		ops.move_to = track_move;
		ops.sweep = track_sweep;
		tracking = *c->instruments[0].stage_driver;
		tracking.stage = &ops;
		c->instruments[0].stage_driver = &tracking;
	}
	if (asph_instrument_open(&c->instruments[0], 1000, &inst, &err) < 0)
		fail_msg("open: %s", err.message);
	assert_int_equal(asph_scan_new(inst, s, plan->xyz, plan->n, NULL, &sc, NULL), 0);
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, NULL), 0);
	if (asph_scan_run(sc, w, &err) < 0)
		fail_msg("scan: %s", err.message);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);
}

#define POSE "\"shift_x\": 0.0371, \"shift_y\": -0.0213, \"shift_z\": 0.0119, " \
	"\"tilt_x\": 231.7, \"tilt_y\": -148.3"

static void test_strong_end_to_end(void **state)
{
	static const char mock_json[] =
		"{\"instruments\": [{\"stage\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0}},"
		" \"probe\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0, " POSE "}}}]}";
	static const char hid_json[] =
		"{\"instruments\": [{\"stage\": {\"driver\": \"mock\", \"options\": {\"time_factor\": 0}},"
		" \"probe\": {\"driver\": \"hid\", \"options\": {\"vendor_id\": 4617, \"product_id\": 1,"
		" \"serial\": \"IND-0002\", \"probe\": \"optical\", \"scale\": 1e-8}},"
		" \"acquisition\": {\"drift_interval\": \"off\"}}]}";
	struct env *e = *state;
	struct indicator *ind = &e->ind[1];
	struct mock_part_params pp = {
		.lens = "strong",
		.pose = { .t = { 0.0371, -0.0213, 0.0119 }, .rx = 231.7e-6, .ry = -148.3e-6 },
	};
	struct asph_prescription pr;
	struct asph_surface *s;
	struct asph_plan *plan;
	struct asph_fit_result a, b;
	char dir[] = "/tmp/asph-test-hid-XXXXXX", pa[64], pb[64];

	/* the indicator measures the same misaligned part, in 10 pm counts */
	mock_part_free(ind->part);
	assert_int_equal(mock_part_new(&pp, &ind->part, NULL), 0);
	ind->scale = 1e-8;
	tracked = ind;
	assert_int_equal(asph_prescription_preset("strong", &pr), 0);
	assert_int_equal(asph_surface_alloc(&pr, &s, NULL), 0);
	struct asph_plan_density dens = { ASPH_DENSITY_POINTS, 240 };
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	assert_int_equal(asph_plan_compute_opts(s, ASPH_PLAN_FERMAT, dens, &po, &plan, NULL), 0);
	assert_non_null(mkdtemp(dir));
	snprintf(pa, sizeof(pa), "%s/mock.asph", dir);
	snprintf(pb, sizeof(pb), "%s/hid.asph", dir);
	scan(e, mock_json, false, s, plan, pa);
	scan(e, hid_json, true, s, plan, pb);
	fit_scan(s, pa, &a);
	fit_scan(s, pb, &b);
	/* 10 pm counts: the same pose to 1e-8 mm / rad, against the injected
	 * one to the mock's own bound (test-executor) */
	for (int k = 0; k < 5; k++) {
		if (fabs(a.value[ASPH_FIT_TX + k] - b.value[ASPH_FIT_TX + k]) > 1e-8)
			fail_msg("dof %d: mock %.12g, hid %.12g", k, a.value[ASPH_FIT_TX + k],
				 b.value[ASPH_FIT_TX + k]);
	}
	assert_true(fabs(b.value[ASPH_FIT_TX] - 0.0371) < 1e-8);
	assert_true(fabs(b.value[ASPH_FIT_RX] - 231.7e-6) < 1e-8);
	assert_int_equal(a.n_used, b.n_used);
	assert_true(b.rms.v < 0.01);
	assert_int_equal(ind->n_requests, (int)plan->n);
	unlink(pa);
	unlink(pb);
	rmdir(dir);
	asph_plan_free(plan);
	asph_surface_free(s);
}

/* ------------------------------------------------- keyboard wedge */

/* A boot-protocol keyboard (what a gauge's keyboard cable is): input
 * reports of 8 bytes, an LED output report. */
static const uint8_t kbd_descriptor[] = {
	0x05, 0x01, 0x09, 0x06, 0xa1, 0x01, 0x05, 0x07, 0x19, 0xe0, 0x29, 0xe7, 0x15, 0x00,
	0x25, 0x01, 0x75, 0x01, 0x95, 0x08, 0x81, 0x02, 0x95, 0x01, 0x75, 0x08, 0x81, 0x01,
	0x95, 0x05, 0x75, 0x01, 0x05, 0x08, 0x19, 0x01, 0x29, 0x05, 0x91, 0x02, 0x95, 0x01,
	0x75, 0x03, 0x91, 0x01, 0x95, 0x06, 0x75, 0x08, 0x15, 0x00, 0x25, 0x65, 0x05, 0x07,
	0x19, 0x00, 0x29, 0x65, 0x81, 0x00, 0xc0,
};

struct keyboard {
	pthread_mutex_t lock;
	uint8_t queue[64][8];
	int head, tail;
	int grabs;                      /* EVIOCGRAB 1 seen */
	int requests;                   /* output reports (the data request) */
	const char *on_request;         /* typed when asked */
	unsigned empty_reads;           /* reads that found nothing queued */
};

/* Key codes of usage page 7 for a character, with shift when asked. */
static void press(struct keyboard *kb, uint8_t mod, uint8_t code)
{
	uint8_t down[8] = { mod, 0, code }, up[8] = { 0 };

	memcpy(kb->queue[kb->tail++ % 64], down, 8);
	memcpy(kb->queue[kb->tail++ % 64], up, 8);
}

static void type(struct keyboard *kb, const char *text, bool keypad, bool shifted)
{
	pthread_mutex_lock(&kb->lock);
	for (const char *c = text; *c; c++) {
		uint8_t code = 0, mod = shifted ? 0x02 : 0;
		if (*c >= '1' && *c <= '9')
			code = (uint8_t)((keypad ? 0x59 : 0x1e) + (*c - '1'));
		else if (*c == '0')
			code = keypad ? 0x62 : 0x27;
		else if (*c == '-')
			code = keypad ? 0x56 : 0x2d, mod = 0;
		else if (*c == '.')
			code = keypad ? 0x63 : 0x37, mod = 0;
		else if (*c == ',')
			code = 0x36, mod = 0;
		else if (*c == '\n')
			code = keypad ? 0x58 : 0x28, mod = 0;
		else if (*c == 'q')
			code = 0x14, mod = 0;
		press(kb, mod, code);
	}
	pthread_mutex_unlock(&kb->lock);
}

static gboolean kbd_read(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	struct keyboard *kb = data;
	size_t len, n = 0;
	uint8_t *buf = umt_arg(c, &len);

	pthread_mutex_lock(&kb->lock);
	if (kb->head != kb->tail) {
		n = len < 8 ? len : 8;
		memcpy(buf, kb->queue[kb->head++ % 64], n);
	} else {
		kb->empty_reads++;
	}
	pthread_mutex_unlock(&kb->lock);
	umockdev_ioctl_client_complete(c, n ? (glong)n : -1, n ? 0 : EAGAIN);
	return TRUE;
}

static gboolean kbd_write(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	struct keyboard *kb = data;
	size_t len;

	umt_arg(c, &len);
	pthread_mutex_lock(&kb->lock);
	kb->requests++;
	const char *t = kb->on_request;
	pthread_mutex_unlock(&kb->lock);
	if (t)
		type(kb, t, false, false);
	umockdev_ioctl_client_complete(c, (glong)len, 0);
	return TRUE;
}

static gboolean kbd_ioctl(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	unsigned long req = umockdev_ioctl_client_get_request(c);
	UMockdevIoctlData *d;

	if (req == HIDIOCGRDESCSIZE) {
		d = umt_arg_resolve(c, 0, sizeof(int));
		*(int *)d->data = (int)sizeof(kbd_descriptor);
	} else if (req == HIDIOCGRDESC) {
		d = umt_arg_resolve(c, 0, sizeof(struct hidraw_report_descriptor));
		struct hidraw_report_descriptor *r = (void *)d->data;
		r->size = sizeof(kbd_descriptor);
		memcpy(r->value, kbd_descriptor, sizeof(kbd_descriptor));
	} else {
		return FALSE;
	}
	g_object_unref(d);
	umockdev_ioctl_client_complete(c, 0, 0);
	return TRUE;
}

static gboolean evdev_ioctl(UMockdevIoctlBase *h, UMockdevIoctlClient *c, gpointer data)
{
	struct keyboard *kb = data;

	if (umockdev_ioctl_client_get_request(c) != EVIOCGRAB)
		return FALSE;
	pthread_mutex_lock(&kb->lock);
	kb->grabs++;
	pthread_mutex_unlock(&kb->lock);
	umockdev_ioctl_client_complete(c, 0, 0);
	return TRUE;
}

#define KBD_TEXT \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-5\n" \
	"E: SUBSYSTEM=usb\nE: DEVTYPE=usb_device\n" \
	"A: idVendor=0fe7\nA: idProduct=4001\nA: serial=KBD-0001\n" \
	"A: manufacturer=Mitutoyo\nA: product=USB-ITN\n\n" \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-5/0003:0FE7:4001.0005\n" \
	"E: SUBSYSTEM=hid\nE: HID_ID=0003:00000FE7:00004001\n" \
	"E: HID_NAME=Mitutoyo USB-ITN\nE: HID_UNIQ=KBD-0001\n\n" \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-5/0003:0FE7:4001.0005/hidraw/hidraw4\n" \
	"N: hidraw4=00\n" \
	"E: SUBSYSTEM=hidraw\nE: DEVNAME=/dev/hidraw4\nE: MAJOR=241\nE: MINOR=4\n" \
	"A: dev=241:4\nL: device=../..\n\n" \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-5/0003:0FE7:4001.0005/input/input9\n" \
	"E: SUBSYSTEM=input\nE: NAME=\"Mitutoyo USB-ITN\"\n\n" \
	"P: /devices/pci0000:00/0000:00:14.0/usb1/1-5/0003:0FE7:4001.0005/input/input9/event9\n" \
	"N: input/event9=00\n" \
	"E: SUBSYSTEM=input\nE: DEVNAME=/dev/input/event9\nE: MAJOR=13\nE: MINOR=73\n" \
	"A: dev=13:73\n"

static UMockdevTestbed *keyboard_add(struct keyboard *kb)
{
	UMockdevTestbed *tb = umt_testbed_new();
	UMockdevIoctlBase *h = umockdev_ioctl_base_new(), *ev = umockdev_ioctl_base_new();

	memset(kb, 0, sizeof(*kb));
	pthread_mutex_init(&kb->lock, NULL);
	umt_add(tb, KBD_TEXT);
	umockdev_testbed_set_attribute_binary(tb,
		"/sys/devices/pci0000:00/0000:00:14.0/usb1/1-5/0003:0FE7:4001.0005",
		"report_descriptor", (guint8 *)kbd_descriptor, sizeof(kbd_descriptor));
	g_signal_connect(h, "handle-ioctl", G_CALLBACK(kbd_ioctl), kb);
	g_signal_connect(h, "handle-read", G_CALLBACK(kbd_read), kb);
	g_signal_connect(h, "handle-write", G_CALLBACK(kbd_write), kb);
	umt_attach(tb, "/dev/hidraw4", h);
	g_signal_connect(ev, "handle-ioctl", G_CALLBACK(evdev_ioctl), kb);
	umt_attach(tb, "/dev/input/event9", ev);
	g_object_unref(h);
	g_object_unref(ev);
	return tb;
}

/* The decoder alone, against readings typed key by key. */
static void test_keyboard_decode(void **state)
{
	struct keyboard kb;
	struct hid_kbd k;
	struct asph_error err;
	double v = 0;
	static const struct {
		const char *text;
		bool keypad, shifted;
		double want;
	} cases[] = {
		{ "-12.345\n", false, false, -12.345 }, { "0.0071\n", true, false, 0.0071 },
		{ "983,25\n", false, true, 983.25 }, { "-0.5\n", true, false, -0.5 },
		{ "1122.3003\n", false, false, 1122.3003 },     /* repeated keys */
	};

	memset(&kb, 0, sizeof(kb));
	pthread_mutex_init(&kb.lock, NULL);
	hid_kbd_reset(&k);
	for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
		type(&kb, cases[i].text, cases[i].keypad, cases[i].shifted);
		int r = 0;
		while (kb.head != kb.tail && r == 0)
			r = hid_kbd_feed(&k, 0, kb.queue[kb.head++ % 64], 8, &v, &err);
		assert_int_equal(r, 1);
		assert_true(v == cases[i].want);
		/* Enter's release */
		assert_int_equal(hid_kbd_feed(&k, 0, kb.queue[kb.head++ % 64], 8, &v, &err), 0);
		assert_int_equal(kb.head, kb.tail);
	}
	/* two keys in one report (roll-over), then one held over */
	uint8_t two[8] = { 0, 0, 0x1f, 0x20 }, held[8] = { 0, 0, 0x20, 0x28 };
	assert_int_equal(hid_kbd_feed(&k, 0, two, 8, &v, &err), 0);
	assert_int_equal(hid_kbd_feed(&k, 0, held, 8, &v, &err), 1);
	assert_true(v == 23);
	/* refusals, each starting afresh */
	uint8_t letter[8] = { 0, 0, 0x14 }, over[8] = { 0, 0, 0x01, 0x01, 0x01 };
	assert_int_equal(hid_kbd_feed(&k, 0, letter, 8, &v, &err), -EPROTO);
	assert_non_null(strstr(err.message, "key 0x14"));
	assert_int_equal(hid_kbd_feed(&k, 0, over, 8, &v, &err), -EPROTO);
	assert_non_null(strstr(err.message, "roll-over"));
	assert_int_equal(hid_kbd_feed(&k, 0, over, 7, &v, &err), -EPROTO);
	assert_int_equal(hid_kbd_feed(&k, 3, over, 8, &v, &err), -EPROTO);
	type(&kb, "1.2.3\n", false, false);
	int r = 0;
	while (kb.head != kb.tail && r == 0)
		r = hid_kbd_feed(&k, 0, kb.queue[kb.head++ % 64], 8, &v, &err);
	assert_int_equal(r, -EPROTO);
	assert_non_null(strstr(err.message, "'1.2.3', which is not a number"));
	pthread_mutex_destroy(&kb.lock);
}

struct typist {
	struct keyboard *kb;
	const char *text;
	bool keypad;
	unsigned empty_reads;           /* kb's count when the read was asked */
};

/* The operator, once the driver is waiting: after it has drained what was
 * queued before (a read finding nothing), so that the reading is not taken
 * for a stale one however slowly the driver runs (under valgrind). */
static void *type_later(void *data)
{
	struct typist *t = data;
	struct timespec ts = { 0, 1000000 };

	for (unsigned waited = 0; waited < READ_OK_MS; waited++) {
		pthread_mutex_lock(&t->kb->lock);
		bool drained = t->kb->empty_reads != t->empty_reads;
		pthread_mutex_unlock(&t->kb->lock);
		if (drained)
			break;
		nanosleep(&ts, NULL);
	}
	type(t->kb, t->text, t->keypad, false);
	return NULL;
}

static int read_typed(struct env *e, struct asph_device *d, struct keyboard *kb, const char *text,
		      bool keypad, struct asph_reading *rd, struct asph_error *err)
{
	const unsigned timeout_ms = READ_OK_MS;
	struct typist t = { kb, text, keypad, 0 };
	pthread_t th;

	pthread_mutex_lock(&kb->lock);
	t.empty_reads = kb->empty_reads;
	pthread_mutex_unlock(&kb->lock);

	assert_int_equal(pthread_create(&th, NULL, type_later, &t), 0);
	int r = read_once(e, d, rd, timeout_ms, err);
	pthread_join(th, NULL);
	return r;
}

/* Opening grabs the evdev node; readings asked for by the request report
 * and typed by the operator (within the timeout); a reading split over
 * reports, shifted and keypad digits. */
static void test_keyboard_device(void **state)
{
	struct keyboard kb;
	UMockdevTestbed *tb = keyboard_add(&kb);
	struct env e = { .tb = tb };
	struct asph_device *d;
	struct asph_reading rd;
	struct asph_error err;

	assert_int_equal(asph_registry_new(&e.reg, NULL), 0);
	e.hid = asph_registry_find(e.reg, "hid");
	if (open_hid(&e, "path=/dev/hidraw4,profile=keyboard,probe=optical,standoff=0,range=100", &d,
		     &err) < 0)
		fail_msg("open: %s", err.message);
	assert_int_equal(kb.grabs, 1);
	/* what was typed before the reading is stale */
	type(&kb, "7.5\n", false, false);
	/* the operator presses the data button: typed with the keypad */
	if (read_typed(&e, d, &kb, "-12.0875\n", true, &rd, &err) < 0)
		fail_msg("read: %s", err.message);
	assert_true(fabs(rd.value + 12.0875) < 1e-12);
	assert_false(rd.flags & ASPH_READING_OUT_OF_RANGE);
	/* nobody presses: the reading times out, saying what to do */
	assert_int_equal(read_once(&e, d, &rd, 80, &err), -ETIMEDOUT);
	assert_non_null(strstr(err.message, "press the gauge's data button or foot switch"));
	/* a key that has no place in a reading */
	assert_int_equal(read_typed(&e, d, &kb, "1q\n", false, &rd, &err), -EPROTO);
	assert_non_null(strstr(err.message, "key 0x14"));
	e.hid->probe->close(d);

	/* with a data request (an output report) and shifted digits */
	kb.on_request = "3,141\n";
	if (open_hid(&e, "path=/dev/hidraw4,profile=keyboard,cmd_request=output:02,grab=false,"
		     "probe=optical,standoff=0,range=100,unit_scale=0.0254", &d, &err) < 0)
		fail_msg("open: %s", err.message);
	assert_int_equal(kb.grabs, 1);
	if (read_once(&e, d, &rd, READ_OK_MS, &err) < 0)
		fail_msg("read: %s", err.message);
	assert_int_equal(kb.requests, 1);
	assert_true(fabs(rd.value - 3.141 * 0.0254) < 1e-12);
	e.hid->probe->close(d);
	asph_registry_free(e.reg);
	g_object_unref(tb);
	pthread_mutex_destroy(&kb.lock);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_decode),
		cmocka_unit_test(test_decode_errors),
		cmocka_unit_test(test_decode_profile_widths),
		cmocka_unit_test(test_command_parse),
		cmocka_unit_test_setup_teardown(test_open, setup, teardown),
		cmocka_unit_test_setup_teardown(test_readings, setup, teardown),
		cmocka_unit_test_setup_teardown(test_zero_hold, setup, teardown),
		cmocka_unit_test_setup_teardown(test_faults, setup, teardown),
		cmocka_unit_test_setup_teardown(test_stop, setup, teardown),
		cmocka_unit_test_setup_teardown(test_strong_end_to_end, setup, teardown),
		cmocka_unit_test(test_keyboard_decode),
		cmocka_unit_test(test_keyboard_device),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
