/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * An emulated USB device for the driver tests, on umockdev-util.h: its
 * sysfs node with the descriptors libusb reads (device, one configuration,
 * one interface with its endpoints), its device node, and a usbdevfs
 * handler that answers SUBMITURB / REAPURB(NDELAY) / DISCARDURB and the
 * interface ioctls the way the kernel does, passing every transfer to the
 * device model's callbacks. GLib inside tests only.
 *
 * The callbacks run on umockdev's worker thread with the device's lock
 * held; the test changes the model's state under umu_usb_lock().
 */
#ifndef ASPH_TEST_UMOCKDEV_USB_H
#define ASPH_TEST_UMOCKDEV_USB_H

#include <limits.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "umockdev-util.h"

struct umu_usb_desc {
	unsigned busnum, devnum;        /* /dev/bus/usb/BBB/DDD */
	const char *sysname;            /* "1-2" */
	uint16_t vendor, product;
	const char *manufacturer, *product_name, *serial; /* NULL: no string */
	uint8_t if_class, if_subclass, if_protocol;
	uint8_t ep_in, ep_out, ep_intr; /* 0: none */
	uint16_t max_packet;            /* of the bulk endpoints */
};

/* A callback's answer when the transfer cannot complete yet: the URB
 * stays in flight (retried at each reap) until it can or is discarded. */
#define UMU_PENDING INT_MIN
/* A callback's answer when the device is pulled out during the transfer:
 * as umu_usb_unplug(). */
#define UMU_UNPLUGGED (INT_MIN + 1)

struct umu_usb_ops {
	/* setup is the 8-byte SETUP packet; data holds the OUT stage, or
	 * receives up to wLength bytes of the IN stage. Returns the bytes of
	 * the data stage, or a negative URB status (-EPIPE: stall). */
	int (*control)(void *model, const uint8_t *setup, uint8_t *data, size_t len);
	/* Returns 0, UMU_PENDING, UMU_UNPLUGGED or a negative URB status. */
	int (*bulk_out)(void *model, uint8_t ep, const uint8_t *buf, size_t len);
	/* Fills at most len bytes; returns their number, UMU_PENDING,
	 * UMU_UNPLUGGED or a negative URB status. */
	int (*bulk_in)(void *model, uint8_t ep, uint8_t *buf, size_t len);
	/* Optional: a program claimed the interface (a new session). */
	void (*claimed)(void *model);
};

struct umu_usb;

/*
 * Adds the device to the testbed (handler attached first, so libusb can
 * open it as soon as it appears) and returns it. The model's callbacks
 * get model.
 */
struct umu_usb *umu_usb_new(UMockdevTestbed *tb, const struct umu_usb_desc *d,
			    const struct umu_usb_ops *ops, void *model);
/* Removes the device if still plugged, detaches the handler and frees. */
void umu_usb_free(struct umu_usb *u);

/* The sysfs path of the usb_device (a parent for more nodes). */
const char *umu_usb_syspath(const struct umu_usb *u);
const char *umu_usb_devnode(const struct umu_usb *u);

/* The text umockdev_testbed_add_from_string() takes for d (g_free), as a
 * .umockdev file for umockdev-run holds it. */
char *umu_usb_description(const struct umu_usb_desc *d);

/*
 * Unplug: URBs in flight complete with -ENODEV, every later ioctl fails
 * with ENODEV and the device leaves sysfs. Plug brings it back (a new
 * enumeration finds it).
 */
void umu_usb_unplug(struct umu_usb *u);
void umu_usb_plug(struct umu_usb *u);

/* Emulates a kernel driver bound to the interface (GETDRIVER answers its
 * name until USBDEVFS_DISCONNECT; USBDEVFS_CONNECT binds it again). */
void umu_usb_bind_driver(struct umu_usb *u, const char *name);

struct umu_usb_counts {
	unsigned claims, releases, detaches, attaches;
	unsigned halts_cleared[32];     /* by endpoint number | 16 for IN */
	unsigned discarded;
	unsigned in_flight;             /* URBs submitted, not reaped */
};
void umu_usb_counts(struct umu_usb *u, struct umu_usb_counts *out);

/* Writes every reaped URB and the capabilities to f in umockdev's ioctl
 * record format (a trace for umockdev-run --ioctl); NULL stops. */
void umu_usb_record(struct umu_usb *u, FILE *f);

void umu_usb_lock(struct umu_usb *u);
void umu_usb_unlock(struct umu_usb *u);

#endif
