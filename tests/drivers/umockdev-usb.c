/* SPDX-License-Identifier: GPL-3.0-or-later */
/* An emulated USB device: sysfs, device node and usbdevfs URBs. */
#include <errno.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include <linux/usbdevice_fs.h>
#include <sys/ioctl.h>

#include "umockdev-usb.h"

/* One URB the program submitted: the resolved struct and buffer. */
struct urb {
	UMockdevIoctlData *data;        /* struct usbdevfs_urb */
	UMockdevIoctlData *buf;         /* NULL for a 0-length buffer */
	int status, actual;
	bool done;
};

struct umu_usb {
	GMutex lock;
	UMockdevTestbed *tb;
	UMockdevIoctlBase *handler;
	struct umu_usb_desc desc;
	char *syspath, *devnode, *description;
	const struct umu_usb_ops *ops;
	void *model;
	GQueue urbs;                    /* struct urb *, in submit order */
	bool plugged;
	bool remove;                    /* unplugged by a callback: leave sysfs */
	char driver[64];                /* bound kernel driver, "" none */
	struct umu_usb_counts counts;
	FILE *record;
};

/* ------------------------------------------------------ descriptors */

static void put(GByteArray *a, const uint8_t *b, size_t n)
{
	g_byte_array_append(a, b, (guint)n);
}

static void endpoint(GByteArray *a, uint8_t addr, uint8_t type, uint16_t packet)
{
	uint8_t e[7] = { 7, 5, addr, type, (uint8_t)packet, (uint8_t)(packet >> 8),
			 type == 3 ? 8 : 0 };
	put(a, e, sizeof(e));
}

/* The device descriptor and the configuration, as sysfs' descriptors. */
static GByteArray *descriptors(const struct umu_usb_desc *d)
{
	GByteArray *a = g_byte_array_new();
	uint8_t n_ep = (uint8_t)(!!d->ep_in + !!d->ep_out + !!d->ep_intr);
	uint16_t total = (uint16_t)(9 + 9 + 7 * n_ep);
	uint8_t dev[18] = { 18, 1, 0x00, 0x02, 0, 0, 0, 64,
			    (uint8_t)d->vendor, (uint8_t)(d->vendor >> 8),
			    (uint8_t)d->product, (uint8_t)(d->product >> 8), 0x00, 0x01,
			    d->manufacturer ? 1 : 0, d->product_name ? 2 : 0, d->serial ? 3 : 0, 1 };
	uint8_t cfg[9] = { 9, 2, (uint8_t)total, (uint8_t)(total >> 8), 1, 1, 0, 0x80, 50 };
	uint8_t itf[9] = { 9, 4, 0, 0, n_ep, d->if_class, d->if_subclass, d->if_protocol, 0 };

	put(a, dev, sizeof(dev));
	put(a, cfg, sizeof(cfg));
	put(a, itf, sizeof(itf));
	if (d->ep_out)
		endpoint(a, d->ep_out, 2, d->max_packet);
	if (d->ep_in)
		endpoint(a, d->ep_in, 2, d->max_packet);
	if (d->ep_intr)
		endpoint(a, d->ep_intr, 3, 8);
	return a;
}

char *umu_usb_description(const struct umu_usb_desc *d)
{
	GByteArray *a = descriptors(d);
	GString *s = g_string_new(NULL);

	g_string_append_printf(s, "P: /devices/pci0000:00/0000:00:14.0/usb%u/%s\n"
			       "N: bus/usb/%03u/%03u\n"
			       "E: SUBSYSTEM=usb\nE: DEVTYPE=usb_device\nE: DRIVER=usb\n"
			       "E: DEVNAME=/dev/bus/usb/%03u/%03u\n"
			       "E: BUSNUM=%03u\nE: DEVNUM=%03u\n"
			       "E: PRODUCT=%x/%x/100\n"
			       "A: busnum=%u\\n\nA: devnum=%u\\n\nA: speed=480\\n\n"
			       "A: bConfigurationValue=1\\n\nA: bNumConfigurations=1\\n\n"
			       "A: idVendor=%04x\\n\nA: idProduct=%04x\\n\n",
			       d->busnum, d->sysname, d->busnum, d->devnum, d->busnum, d->devnum,
			       d->busnum, d->devnum, d->vendor, d->product, d->busnum, d->devnum,
			       d->vendor, d->product);
	if (d->serial)
		g_string_append_printf(s, "A: serial=%s\\n\n", d->serial);
	g_string_append(s, "H: descriptors=");
	for (guint i = 0; i < a->len; i++)
		g_string_append_printf(s, "%02X", a->data[i]);
	g_string_append(s, "\n");
	g_byte_array_unref(a);
	return g_string_free(s, FALSE);
}

/* ---------------------------------------------------------- urbs */

static void urb_free(struct urb *u)
{
	if (u->buf)
		umockdev_ioctl_data_unref(u->buf);
	umockdev_ioctl_data_unref(u->data);
	g_free(u);
}

static struct usbdevfs_urb *urb_struct(struct urb *u)
{
	return (struct usbdevfs_urb *)u->data->data;
}

/* A GET_DESCRIPTOR of a string, answered from the description. */
static int string_descriptor(struct umu_usb *u, const uint8_t *setup, uint8_t *data, size_t len)
{
	const char *strings[] = { NULL, u->desc.manufacturer, u->desc.product_name, u->desc.serial };
	unsigned index = setup[2];
	uint8_t d[255];
	size_t n;

	if (index == 0) {
		d[0] = 4;
		d[1] = 3;
		d[2] = 0x09;    /* English (US) */
		d[3] = 0x04;
		n = 4;
	} else if (index < 4 && strings[index]) {
		n = 2;
		for (const char *c = strings[index]; *c && n + 2 <= sizeof(d); c++) {
			d[n++] = (uint8_t)*c;
			d[n++] = 0;
		}
		d[0] = (uint8_t)n;
		d[1] = 3;
	} else {
		return -EPIPE;
	}
	n = n < len ? n : len;
	memcpy(data, d, n);
	return (int)n;
}

static int control(struct umu_usb *u, uint8_t *buf, size_t len)
{
	if (len < 8)
		return -EINVAL;
	uint16_t wlength = (uint16_t)(buf[6] | buf[7] << 8);
	size_t n = wlength < len - 8 ? wlength : len - 8;
	if (buf[0] == 0x80 && buf[1] == 6 && buf[3] == 3)
		return string_descriptor(u, buf, buf + 8, n);
	return u->ops->control ? u->ops->control(u->model, buf, buf + 8, n) : -EPIPE;
}

/* The device is gone: what is in flight completes with -ENODEV. Lock held. */
static void pull(struct umu_usb *u)
{
	u->plugged = false;
	for (GList *l = u->urbs.head; l; l = l->next) {
		struct urb *x = l->data;
		if (!x->done) {
			x->status = -ENODEV;
			x->actual = 0;
			x->done = true;
		}
	}
}

/* Runs the URB on the model; false while the model has no answer yet. */
static bool attempt(struct umu_usb *u, struct urb *x)
{
	struct usbdevfs_urb *s = urb_struct(x);
	uint8_t *buf = x->buf ? x->buf->data : NULL;
	size_t len = x->buf ? (size_t)x->buf->data_len : 0;
	int r;

	if (!u->plugged) {
		r = -ENODEV;
	} else if (s->type == USBDEVFS_URB_TYPE_CONTROL) {
		r = control(u, buf, len);
	} else if (s->type == USBDEVFS_URB_TYPE_BULK && (s->endpoint & 0x80)) {
		r = u->ops->bulk_in ? u->ops->bulk_in(u->model, s->endpoint, buf, len) : -EPIPE;
	} else if (s->type == USBDEVFS_URB_TYPE_BULK) {
		r = u->ops->bulk_out ? u->ops->bulk_out(u->model, s->endpoint, buf, len) : -EPIPE;
		if (r == 0)
			r = (int)len;
	} else {
		r = -EPIPE;
	}
	if (r == UMU_PENDING)
		return false;
	if (r == UMU_UNPLUGGED) {
		pull(u);
		u->remove = true;
		r = -ENODEV;
	}
	x->status = r < 0 ? r : 0;
	x->actual = r < 0 ? 0 : r;
	x->done = true;
	return true;
}

static void write_hex(FILE *f, const uint8_t *b, size_t n)
{
	for (size_t i = 0; i < n; i++)
		fprintf(f, "%02X", b[i]);
}

/* umockdev's record format of a reaped URB, under the request that reaped
 * it: IN transfers are children of the OUT transfer before them. */
static void record(struct umu_usb *u, struct urb *x, bool ndelay)
{
	struct usbdevfs_urb *s = urb_struct(x);
	bool in = s->endpoint & 0x80;

	if (!u->record)
		return;
	fprintf(u->record, "%sUSBDEVFS_REAPURB%s 0 %u %u %d %u %d %d 0 ", in ? " " : "",
		ndelay ? "NDELAY" : "", s->type, s->endpoint, x->status, s->flags, s->buffer_length, x->actual);
	write_hex(u->record, x->buf ? x->buf->data : NULL, in ? (size_t)x->actual
				 : (size_t)s->buffer_length);
	fputc('\n', u->record);
}

static void complete_errno(UMockdevIoctlClient *c, int e)
{
	umockdev_ioctl_client_complete(c, e ? -1 : 0, e);
}

static void submit(struct umu_usb *u, UMockdevIoctlClient *c)
{
	struct urb *x = g_new0(struct urb, 1);

	if (!u->plugged) {
		g_free(x);
		complete_errno(c, ENODEV);
		return;
	}
	x->data = umt_arg_resolve(c, 0, sizeof(struct usbdevfs_urb));
	struct usbdevfs_urb *s = urb_struct(x);
	if (s->buffer_length > 0) {
		GError *e = NULL;
		x->buf = umockdev_ioctl_data_resolve(x->data, offsetof(struct usbdevfs_urb, buffer),
						     (gsize)s->buffer_length, &e);
		g_assert_no_error(e);
	}
	g_queue_push_tail(&u->urbs, x);
	u->counts.in_flight++;
	complete_errno(c, 0);
}

/* Hands the first finished URB back, as the kernel's reap does. */
static void reap(struct umu_usb *u, UMockdevIoctlClient *c, bool ndelay)
{
	struct urb *x = NULL;

	for (GList *l = u->urbs.head; l; l = l->next) {
		struct urb *y = l->data;
		if (y->done || attempt(u, y)) {
			x = y;
			g_queue_delete_link(&u->urbs, l);
			break;
		}
		/* a bulk endpoint answers in order */
		if (!(urb_struct(y)->endpoint & 0x80))
			break;
	}
	if (!x) {
		complete_errno(c, u->plugged ? EAGAIN : ENODEV);
		return;
	}
	struct usbdevfs_urb *s = urb_struct(x);
	umockdev_ioctl_data_update(x->data, offsetof(struct usbdevfs_urb, status),
				   (guint8 *)&x->status, sizeof(x->status));
	umockdev_ioctl_data_update(x->data, offsetof(struct usbdevfs_urb, actual_length),
				   (guint8 *)&x->actual, sizeof(x->actual));
	if (x->buf && (s->type == USBDEVFS_URB_TYPE_CONTROL || (s->endpoint & 0x80))) {
		/* marks the buffer for copying back to the program */
		guint8 *copy = g_memdup2(x->buf->data, (gsize)x->buf->data_len);
		umockdev_ioctl_data_update(x->buf, 0, copy, x->buf->data_len);
		g_free(copy);
	}
	record(u, x, ndelay);
	UMockdevIoctlData *ptr = umt_arg_resolve(c, 0, sizeof(void *));
	umockdev_ioctl_data_set_ptr(ptr, 0, x->data);
	umockdev_ioctl_data_unref(ptr);
	u->counts.in_flight--;
	complete_errno(c, 0);
	urb_free(x);
}

static void discard(struct umu_usb *u, UMockdevIoctlClient *c)
{
	size_t len;
	uint8_t *arg = umt_arg(c, &len);
	gulong addr;

	memcpy(&addr, arg, sizeof(addr));
	for (GList *l = u->urbs.head; l; l = l->next) {
		struct urb *x = l->data;
		if (x->data->client_addr == addr && !x->done) {
			x->status = -ENOENT;
			x->actual = 0;
			x->done = true;
			u->counts.discarded++;
			complete_errno(c, 0);
			return;
		}
	}
	complete_errno(c, EINVAL);
}

static void getdriver(struct umu_usb *u, UMockdevIoctlClient *c)
{
	if (!u->driver[0]) {
		complete_errno(c, ENODATA);
		return;
	}
	UMockdevIoctlData *d = umt_arg_resolve(c, 0, sizeof(struct usbdevfs_getdriver));
	struct usbdevfs_getdriver gd = { 0 };
	memcpy(&gd, d->data, sizeof(gd));
	snprintf(gd.driver, sizeof(gd.driver), "%s", u->driver);
	umockdev_ioctl_data_update(d, 0, (guint8 *)&gd, sizeof(gd));
	umockdev_ioctl_data_unref(d);
	complete_errno(c, 0);
}

/* USBDEVFS_IOCTL: the kernel driver's DISCONNECT and CONNECT. */
static void driver_ioctl(struct umu_usb *u, UMockdevIoctlClient *c)
{
	UMockdevIoctlData *d = umt_arg_resolve(c, 0, sizeof(struct usbdevfs_ioctl));
	struct usbdevfs_ioctl io;
	int e = 0;

	memcpy(&io, d->data, sizeof(io));
	umockdev_ioctl_data_unref(d);
	if (io.ioctl_code == (int)USBDEVFS_DISCONNECT) {
		u->counts.detaches++;
		if (u->driver[0] && strcmp(u->driver, "usbfs"))
			snprintf(u->driver, sizeof(u->driver), "%s", "");
		else
			e = ENODATA;
	} else if (io.ioctl_code == (int)USBDEVFS_CONNECT) {
		u->counts.attaches++;
	} else {
		e = ENOTTY;
	}
	complete_errno(c, e);
}

static void clear_halt(struct umu_usb *u, UMockdevIoctlClient *c)
{
	UMockdevIoctlData *d = umt_arg_resolve(c, 0, sizeof(unsigned int));
	unsigned int ep;

	memcpy(&ep, d->data, sizeof(ep));
	umockdev_ioctl_data_unref(d);
	u->counts.halts_cleared[(ep & 0x0f) | (ep & 0x80 ? 16 : 0)]++;
	complete_errno(c, 0);
}

static void capabilities(struct umu_usb *u, UMockdevIoctlClient *c)
{
	uint32_t caps = USBDEVFS_CAP_BULK_CONTINUATION | USBDEVFS_CAP_NO_PACKET_SIZE_LIM |
			USBDEVFS_CAP_REAP_AFTER_DISCONNECT | USBDEVFS_CAP_ZERO_PACKET;
	UMockdevIoctlData *d = umt_arg_resolve(c, 0, sizeof(caps));

	umockdev_ioctl_data_update(d, 0, (guint8 *)&caps, sizeof(caps));
	umockdev_ioctl_data_unref(d);
	if (u->record) {
		fprintf(u->record, "USBDEVFS_GET_CAPABILITIES 0 ");
		write_hex(u->record, (const uint8_t *)&caps, sizeof(caps));
		fputc('\n', u->record);
	}
	complete_errno(c, 0);
}

static gboolean handle_ioctl(UMockdevIoctlBase *h, UMockdevIoctlClient *c, struct umu_usb *u)
{
	gulong request = umockdev_ioctl_client_get_request(c);

	(void)h;
	g_mutex_lock(&u->lock);
	if (request == USBDEVFS_SUBMITURB)
		submit(u, c);
	else if (request == USBDEVFS_REAPURB || request == USBDEVFS_REAPURBNDELAY)
		reap(u, c, request == USBDEVFS_REAPURBNDELAY);
	else if (!u->plugged)
		complete_errno(c, ENODEV);
	else if (request == USBDEVFS_DISCARDURB)
		discard(u, c);
	else if (request == USBDEVFS_GET_CAPABILITIES)
		capabilities(u, c);
	else if (request == USBDEVFS_GETDRIVER)
		getdriver(u, c);
	else if (request == USBDEVFS_IOCTL)
		driver_ioctl(u, c);
	else if (request == USBDEVFS_CLEAR_HALT)
		clear_halt(u, c);
	else if (request == USBDEVFS_CLAIMINTERFACE) {
		u->counts.claims++;
		if (!u->driver[0] && u->ops->claimed)
			u->ops->claimed(u->model);
		complete_errno(c, u->driver[0] ? EBUSY : 0);
	} else if (request == USBDEVFS_RELEASEINTERFACE) {
		u->counts.releases++;
		complete_errno(c, 0);
	} else {
		complete_errno(c, request == USBDEVFS_RESET || request == USBDEVFS_RESETEP ? 0 : ENOTTY);
	}
	bool remove = u->remove;
	u->remove = false;
	g_mutex_unlock(&u->lock);
	if (remove)
		umockdev_testbed_remove_device(u->tb, u->syspath);
	return TRUE;
}

/* ------------------------------------------------------- lifetime */

static void add(struct umu_usb *u)
{
	umt_attach(u->tb, u->devnode, u->handler);
	umt_add(u->tb, u->description);
}

struct umu_usb *umu_usb_new(UMockdevTestbed *tb, const struct umu_usb_desc *d,
			    const struct umu_usb_ops *ops, void *model)
{
	struct umu_usb *u = g_new0(struct umu_usb, 1);

	g_mutex_init(&u->lock);
	g_queue_init(&u->urbs);
	u->tb = g_object_ref(tb);
	u->desc = *d;
	u->ops = ops;
	u->model = model;
	u->description = umu_usb_description(d);
	u->syspath = g_strdup_printf("/sys/devices/pci0000:00/0000:00:14.0/usb%u/%s", d->busnum,
				     d->sysname);
	u->devnode = g_strdup_printf("/dev/bus/usb/%03u/%03u", d->busnum, d->devnum);
	u->handler = umockdev_ioctl_base_new();
	g_signal_connect(u->handler, "handle-ioctl", G_CALLBACK(handle_ioctl), u);
	u->plugged = true;
	add(u);
	return u;
}

void umu_usb_unplug(struct umu_usb *u)
{
	g_mutex_lock(&u->lock);
	bool was = u->plugged;
	pull(u);
	g_mutex_unlock(&u->lock);
	if (was)
		umockdev_testbed_remove_device(u->tb, u->syspath);
}

void umu_usb_plug(struct umu_usb *u)
{
	g_mutex_lock(&u->lock);
	bool was = u->plugged;
	u->plugged = true;
	g_mutex_unlock(&u->lock);
	if (was)
		return;
	umockdev_testbed_detach_ioctl(u->tb, u->devnode, NULL);
	add(u);
}

void umu_usb_free(struct umu_usb *u)
{
	if (!u)
		return;
	if (u->plugged)
		umockdev_testbed_remove_device(u->tb, u->syspath);
	umockdev_testbed_detach_ioctl(u->tb, u->devnode, NULL);
	g_object_unref(u->handler);
	g_queue_clear_full(&u->urbs, (GDestroyNotify)urb_free);
	g_object_unref(u->tb);
	g_mutex_clear(&u->lock);
	g_free(u->description);
	g_free(u->syspath);
	g_free(u->devnode);
	g_free(u);
}

const char *umu_usb_syspath(const struct umu_usb *u)
{
	return u->syspath;
}

const char *umu_usb_devnode(const struct umu_usb *u)
{
	return u->devnode;
}

void umu_usb_bind_driver(struct umu_usb *u, const char *name)
{
	g_mutex_lock(&u->lock);
	snprintf(u->driver, sizeof(u->driver), "%s", name ? name : "");
	g_mutex_unlock(&u->lock);
}

void umu_usb_counts(struct umu_usb *u, struct umu_usb_counts *out)
{
	g_mutex_lock(&u->lock);
	*out = u->counts;
	g_mutex_unlock(&u->lock);
}

void umu_usb_record(struct umu_usb *u, FILE *f)
{
	g_mutex_lock(&u->lock);
	u->record = f;
	if (f)
		fprintf(f, "@DEV %s (usbdevfs)\n", u->devnode);
	g_mutex_unlock(&u->lock);
}

void umu_usb_lock(struct umu_usb *u)
{
	g_mutex_lock(&u->lock);
}

void umu_usb_unlock(struct umu_usb *u)
{
	g_mutex_unlock(&u->lock);
}
