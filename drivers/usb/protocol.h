/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * USB Test and Measurement Class (USBTMC, USB-IF class 0xFE subclass 0x03)
 * over libusb: device-dependent messages on the bulk endpoints with their
 * 12-byte headers and bTag sequence, and the class requests on the control
 * endpoint that bring a stuck transfer back (INITIATE_ABORT_BULK_IN/OUT,
 * INITIATE_CLEAR with their CHECK_*_STATUS polls). Every call has a
 * timeout; a stop flag raised on another thread (usbtmc_wake() makes the
 * waiting call see it at once) makes it return -ECANCELED. Internal.
 */
#ifndef ASPH_USB_PROTOCOL_H
#define ASPH_USB_PROTOCOL_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

/* Message ids of the bulk headers (USBTMC 1.0, table 2). */
enum {
	USBTMC_DEV_DEP_MSG_OUT = 1,
	USBTMC_REQUEST_DEV_DEP_MSG_IN = 2,
	USBTMC_DEV_DEP_MSG_IN = 2,
};

/* Class requests (USBTMC 1.0, table 15) and their status values. */
enum {
	USBTMC_INITIATE_ABORT_BULK_OUT = 1,
	USBTMC_CHECK_ABORT_BULK_OUT_STATUS = 2,
	USBTMC_INITIATE_ABORT_BULK_IN = 3,
	USBTMC_CHECK_ABORT_BULK_IN_STATUS = 4,
	USBTMC_INITIATE_CLEAR = 5,
	USBTMC_CHECK_CLEAR_STATUS = 6,
	USBTMC_GET_CAPABILITIES = 7,
};

enum {
	USBTMC_STATUS_SUCCESS = 0x01,
	USBTMC_STATUS_PENDING = 0x02,
	USBTMC_STATUS_FAILED = 0x80,
	USBTMC_STATUS_TRANSFER_NOT_IN_PROGRESS = 0x81,
};

#define USBTMC_HEADER_SIZE 12
#define USBTMC_EOM 0x01

struct usbtmc;

struct usbtmc_params {
	uint16_t vendor, product;       /* 0: any */
	const char *serial;             /* NULL or "": any */
	size_t read_chunk;              /* message bytes asked per bulk-IN */
	bool clear;                     /* INITIATE_CLEAR after claiming */
};

/*
 * Enumerates the bus (a fresh libusb context each time, so a device that
 * was unplugged and plugged back is found again), opens the first USBTMC
 * interface that matches, detaches a kernel driver bound to it (reattached
 * on close) and claims it. -ENODEV when no device matches, -EACCES when
 * the device node may not be opened.
 */
int usbtmc_open(const struct usbtmc_params *p, atomic_bool *stop,
		unsigned timeout_ms, struct usbtmc **out,
		struct asph_error *err);
void usbtmc_close(struct usbtmc *t);

/* "VVVV:PPPP serial S" as the reasons name the device. */
const char *usbtmc_name(const struct usbtmc *t);
const char *usbtmc_serial(const struct usbtmc *t);

/* Wakes a call waiting on the bus so it sees its stop flag. Any thread. */
void usbtmc_wake(struct usbtmc *t);

/*
 * One device-dependent message to the device (split into transfers of at
 * most the IN chunk size, EOM on the last). After a timeout the transfer
 * is aborted (INITIATE_ABORT_BULK_OUT) so the next message starts clean.
 */
int usbtmc_write(struct usbtmc *t, const char *msg, size_t len,
		 atomic_bool *stop, unsigned timeout_ms,
		 struct asph_error *err);

/*
 * One message from the device, over as many REQUEST_DEV_DEP_MSG_IN
 * transfers as it takes until EOM, into buf (NUL-terminated, *len bytes
 * without the NUL). A header that does not answer the request (message id,
 * bTag, bTagInverse), a short transfer, or a message longer than size is
 * -EPROTO, after which the device is cleared (INITIATE_CLEAR); a timeout
 * aborts the transfer (INITIATE_ABORT_BULK_IN).
 */
int usbtmc_read(struct usbtmc *t, char *buf, size_t size, size_t *len,
		atomic_bool *stop, unsigned timeout_ms,
		struct asph_error *err);

/* INITIATE_CLEAR, CHECK_CLEAR_STATUS until done, then clears the halt of
 * the bulk-OUT endpoint: the device's input and output buffers are empty. */
int usbtmc_clear(struct usbtmc *t, atomic_bool *stop, unsigned timeout_ms,
		 struct asph_error *err);

/* The bTag the next transfer will carry (1..255). */
uint8_t usbtmc_next_tag(const struct usbtmc *t);

/* Builds a bulk header: id, tag, ~tag, 0, size (LE), attributes, then
 * term_char for REQUEST_DEV_DEP_MSG_IN. */
void usbtmc_header(uint8_t *h, uint8_t id, uint8_t tag, uint32_t size,
		   uint8_t attributes, uint8_t term_char);

/* Bytes of a bulk-OUT transfer carrying n message bytes (a multiple of 4). */
size_t usbtmc_padded(size_t n);

#endif
