/* SPDX-License-Identifier: GPL-3.0-or-later */
/* USBTMC over libusb: bulk messages, class requests, recovery. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <libusb.h>

#include "protocol.h"
#include "transport.h"
#include "util-mem.h"
#include "util-time.h"

#define USBTMC_CLASS 0xfe
#define USBTMC_SUBCLASS 0x03
/* Longest the event loop sleeps before it looks at the stop flag again
 * (usbtmc_wake() cuts it short). */
#define SLICE_MS 20
/* Status polls and drained transfers a recovery makes at most. */
#define MAX_POLLS 64

/*
 * What must happen before the next message: the previous one failed and
 * left the device mid-transfer. Run at the start of the next call, within
 * that call's timeout, so that no call blocks longer than its own.
 */
enum recovery {
	RECOVER_NONE = 0,
	RECOVER_ABORT_IN,       /* INITIATE_ABORT_BULK_IN of tag */
	RECOVER_ABORT_OUT,      /* INITIATE_ABORT_BULK_OUT of tag */
	RECOVER_CLEAR,          /* INITIATE_CLEAR (after halts cleared) */
};

struct usbtmc {
	libusb_context *ctx;
	libusb_device_handle *h;
	int iface;
	uint8_t ep_in, ep_out;
	uint16_t packet_in;
	bool reattach;
	uint8_t tag;            /* last bTag sent */
	size_t chunk;
	uint8_t *in;            /* one bulk-IN transfer */
	size_t in_size;
	enum recovery recover;
	uint8_t recover_tag;
	uint8_t halted;         /* endpoint whose halt must be cleared, or 0 */
	char name[96];
	char serial[64];
};

void usbtmc_header(uint8_t *h, uint8_t id, uint8_t tag, uint32_t size,
		   uint8_t attributes, uint8_t term_char)
{
	memset(h, 0, USBTMC_HEADER_SIZE);
	h[0] = id;
	h[1] = tag;
	h[2] = (uint8_t)~tag;
	for (int i = 0; i < 4; i++)
		h[4 + i] = (uint8_t)(size >> (8 * i));
	h[8] = attributes;
	h[9] = term_char;
}

size_t usbtmc_padded(size_t n)
{
	return (USBTMC_HEADER_SIZE + n + 3) & ~(size_t)3;
}

static uint32_t le32(const uint8_t *p)
{
	return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

uint8_t usbtmc_next_tag(const struct usbtmc *t)
{
	return (uint8_t)(t->tag % 255 + 1);
}

static uint8_t take_tag(struct usbtmc *t)
{
	t->tag = usbtmc_next_tag(t);
	return t->tag;
}

const char *usbtmc_name(const struct usbtmc *t)
{
	return t->name;
}

const char *usbtmc_serial(const struct usbtmc *t)
{
	return t->serial;
}

void usbtmc_wake(struct usbtmc *t)
{
	libusb_interrupt_event_handler(t->ctx);
}

static int gone(const struct usbtmc *t, struct asph_error *err)
{
	return asph_error_set(err, -ENODEV, "%s: device unplugged", t->name);
}

/* ------------------------------------------------------- transfers */

static void LIBUSB_CALL transfer_done(struct libusb_transfer *x)
{
	*(int *)x->user_data = 1;
}

/* A transfer whose cancellation never came back completes here, if ever. */
static void LIBUSB_CALL transfer_orphaned(struct libusb_transfer *x)
{
	libusb_free_transfer(x);
}

/* run(): the transfer is still in flight and now frees itself. */
#define ORPHANED (-EDEADLK)

static bool stopped(atomic_bool *stop)
{
	return stop && atomic_load_explicit(stop, memory_order_relaxed);
}

/*
 * Submits x and handles events until it completes. A stop, the deadline or
 * a failing event loop cancels it, and the cancellation is waited for
 * (libusb owns the buffers until then) for at most a second more. Returns
 * 0 with *actual, or the ABI's code without a reason (the caller knows
 * what the transfer was); ORPHANED when x could not be taken back.
 */
static int run(struct usbtmc *t, struct libusb_transfer *x, atomic_bool *stop,
	       uint64_t deadline, int *actual)
{
	int completed = 0, why = 0;
	bool cancelled = false;

	*actual = 0;
	/* run() waits for the completion, or hands x to transfer_orphaned
	 * and clears this before returning */
	// cppcheck-suppress autoVariables
	x->user_data = &completed;
	x->callback = transfer_done;
	x->timeout = 0;
	int r = libusb_submit_transfer(x);
	if (r < 0)
		return r == LIBUSB_ERROR_NO_DEVICE ? -ENODEV : -EIO;
	while (!completed) {
		unsigned left = transport_ms_left(deadline);
		struct timeval tv = { 0, 1000 * (long)(left < SLICE_MS ? left : SLICE_MS) };
		r = libusb_handle_events_timeout_completed(t->ctx, &tv, &completed);
		if (completed)
			break;
		if (!why && r < 0 && r != LIBUSB_ERROR_INTERRUPTED)
			why = r == LIBUSB_ERROR_NO_DEVICE ? -ENODEV : -EIO;
		if (!why && stopped(stop))
			why = -ECANCELED;
		if (!why && transport_ms_left(deadline) == 0)
			why = -ETIMEDOUT;
		if (why && !cancelled) {
			cancelled = true;
			deadline = transport_deadline(1000);
			if (libusb_cancel_transfer(x) == LIBUSB_ERROR_NO_DEVICE)
				why = -ENODEV;
		} else if (cancelled && transport_ms_left(deadline) == 0) {
			x->callback = transfer_orphaned;
			x->user_data = NULL;
			return ORPHANED;
		}
	}
	*actual = x->actual_length;
	switch (x->status) {
	case LIBUSB_TRANSFER_COMPLETED:
		return why == -ENODEV ? why : 0;
	case LIBUSB_TRANSFER_CANCELLED:
	case LIBUSB_TRANSFER_TIMED_OUT:
		return why ? why : -ETIMEDOUT;
	case LIBUSB_TRANSFER_STALL:
		return -EPIPE;
	case LIBUSB_TRANSFER_NO_DEVICE:
		return -ENODEV;
	case LIBUSB_TRANSFER_OVERFLOW:
		return -EOVERFLOW;
	default:
		return why ? why : -EIO;
	}
}

static int bulk(struct usbtmc *t, uint8_t ep, uint8_t *buf, size_t len,
		atomic_bool *stop, uint64_t deadline, int *actual)
{
	struct libusb_transfer *x = libusb_alloc_transfer(0);

	if (!x)
		return -ENOMEM;
	libusb_fill_bulk_transfer(x, t->h, ep, buf, (int)len, NULL, NULL, 0);
	int r = run(t, x, stop, deadline, actual);
	if (r != ORPHANED)
		libusb_free_transfer(x);
	return r;
}

/* A control request; IN requests return the bytes in data. */
static int control(struct usbtmc *t, uint8_t type, uint8_t request, uint16_t value,
		   uint16_t index, uint8_t *data, uint16_t len, atomic_bool *stop,
		   uint64_t deadline, int *actual)
{
	uint8_t *buf = calloc(1, LIBUSB_CONTROL_SETUP_SIZE + len);
	struct libusb_transfer *x = libusb_alloc_transfer(0);

	if (!buf || !x) {
		free(buf);
		libusb_free_transfer(x);
		return -ENOMEM;
	}
	libusb_fill_control_setup(buf, type, request, value, index, len);
	if (!(type & LIBUSB_ENDPOINT_IN))
		memcpy(buf + LIBUSB_CONTROL_SETUP_SIZE, data, len);
	libusb_fill_control_transfer(x, t->h, buf, NULL, NULL, 0);
	x->flags = LIBUSB_TRANSFER_FREE_BUFFER;
	int r = run(t, x, stop, deadline, actual);
	if (r == ORPHANED)
		return r;
	if (r == 0 && (type & LIBUSB_ENDPOINT_IN))
		memcpy(data, buf + LIBUSB_CONTROL_SETUP_SIZE, (size_t)*actual);
	libusb_free_transfer(x);
	return r;
}

/* The reason for a failed transfer of what. */
static int transfer_error(struct usbtmc *t, int r, const char *what, uint8_t ep,
			  unsigned timeout_ms, struct asph_error *err)
{
	switch (r) {
	case -ENODEV:
		return gone(t, err);
	case -ECANCELED:
		return asph_error_set(err, r, "%s: %s stopped", t->name, what);
	case -ETIMEDOUT:
		return asph_error_set(err, r, "%s: %s: no answer within %u ms", t->name, what,
				      timeout_ms);
	case -EPIPE:
		return asph_error_set(err, -EIO, "%s: %s: endpoint 0x%02x stalled", t->name, what, ep);
	case -EOVERFLOW:
		return asph_error_set(err, -EPROTO, "%s: %s: the device sent more than was asked",
				      t->name, what);
	case -ENOMEM:
		return asph_error_set(err, r, "out of memory");
	case ORPHANED:
		return asph_error_set(err, -EIO, "%s: %s: the transfer could not be cancelled",
				      t->name, what);
	default:
		return asph_error_set(err, -EIO, "%s: %s failed", t->name, what);
	}
}

/* ------------------------------------------------------ recovery */

#define REQ_IFACE (LIBUSB_ENDPOINT_IN | LIBUSB_REQUEST_TYPE_CLASS | LIBUSB_RECIPIENT_INTERFACE)
#define REQ_EP (LIBUSB_ENDPOINT_IN | LIBUSB_REQUEST_TYPE_CLASS | LIBUSB_RECIPIENT_ENDPOINT)

/* Reads and drops what the device has queued on bulk-IN, up to a short
 * packet. */
static int drain_in(struct usbtmc *t, atomic_bool *stop, uint64_t deadline)
{
	for (int i = 0; i < MAX_POLLS; i++) {
		int got = 0;
		int r = bulk(t, t->ep_in, t->in, t->in_size, stop, deadline, &got);
		if (r < 0)
			return r;
		/* a short (or zero-length) packet ended the device's transfer */
		if ((size_t)got < t->in_size)
			return 0;
	}
	return -EPROTO;
}

static int clear_halt(struct usbtmc *t, uint8_t ep)
{
	int r = libusb_clear_halt(t->h, ep);
	return r == LIBUSB_ERROR_NO_DEVICE ? -ENODEV : r < 0 ? -EIO : 0;
}

/* Polls a CHECK_*_STATUS request while the device says PENDING. */
static int poll_status(struct usbtmc *t, uint8_t type, uint8_t request, uint16_t index,
		       uint16_t len, bool drain, atomic_bool *stop, uint64_t deadline)
{
	uint8_t st[8] = { 0 };

	for (int i = 0; i < MAX_POLLS; i++) {
		int got = 0;
		int r = control(t, type, request, 0, index, st, len, stop, deadline, &got);
		if (r < 0)
			return r;
		if (got < 1)
			return -EPROTO;
		if (st[0] == USBTMC_STATUS_SUCCESS)
			return 0;
		if (st[0] != USBTMC_STATUS_PENDING)
			return -EPROTO;
		/* bit 0 of the second byte: bulk-IN still holds data */
		if (drain && got > 1 && (st[1] & 1)) {
			r = drain_in(t, stop, deadline);
			if (r < 0)
				return r;
		} else {
			msleep(1);
		}
		if (transport_ms_left(deadline) == 0)
			return -ETIMEDOUT;
	}
	return -EPROTO;
}

/* INITIATE_ABORT_BULK_IN or _OUT of the transfer tagged tag on ep: 1 when
 * the device is aborting it, 0 when there was none to abort (FAILED, or no
 * transfer in progress), else an error. */
static int initiate_abort(struct usbtmc *t, uint8_t request, uint8_t tag, uint8_t ep,
			  atomic_bool *stop, uint64_t deadline)
{
	uint8_t st[2] = { 0 };
	int got = 0;
	int r = control(t, REQ_EP, request, tag, ep, st, 2, stop, deadline, &got);

	if (r < 0)
		return r;
	if (got < 1)
		return -EPROTO;
	if (st[0] == USBTMC_STATUS_SUCCESS)
		return 1;
	return st[0] == USBTMC_STATUS_FAILED ||
	       st[0] == USBTMC_STATUS_TRANSFER_NOT_IN_PROGRESS ? 0 : -EPROTO;
}

static int abort_in(struct usbtmc *t, uint8_t tag, atomic_bool *stop, uint64_t deadline)
{
	int r = initiate_abort(t, USBTMC_INITIATE_ABORT_BULK_IN, tag, t->ep_in, stop, deadline);

	if (r <= 0)
		return r;
	r = drain_in(t, stop, deadline);
	if (r < 0)
		return r;
	return poll_status(t, REQ_EP, USBTMC_CHECK_ABORT_BULK_IN_STATUS, t->ep_in, 8, true,
			   stop, deadline);
}

static int abort_out(struct usbtmc *t, uint8_t tag, atomic_bool *stop, uint64_t deadline)
{
	int r = initiate_abort(t, USBTMC_INITIATE_ABORT_BULK_OUT, tag, t->ep_out, stop, deadline);

	if (r <= 0)
		return r;
	r = poll_status(t, REQ_EP, USBTMC_CHECK_ABORT_BULK_OUT_STATUS, t->ep_out, 8, false,
			stop, deadline);
	return r < 0 ? r : clear_halt(t, t->ep_out);
}

static int clear_at(struct usbtmc *t, atomic_bool *stop, uint64_t deadline)
{
	uint8_t st[1] = { 0 };
	int got = 0;
	int r = control(t, REQ_IFACE, USBTMC_INITIATE_CLEAR, 0, (uint16_t)t->iface, st, 1,
			stop, deadline, &got);

	if (r < 0)
		return r;
	if (got < 1 || st[0] != USBTMC_STATUS_SUCCESS)
		return -EPROTO;
	r = poll_status(t, REQ_IFACE, USBTMC_CHECK_CLEAR_STATUS, (uint16_t)t->iface, 2, true,
			stop, deadline);
	return r < 0 ? r : clear_halt(t, t->ep_out);
}

int usbtmc_clear(struct usbtmc *t, atomic_bool *stop, unsigned timeout_ms,
		 struct asph_error *err)
{
	int r = clear_at(t, stop, transport_deadline(timeout_ms));

	if (r == 0)
		return 0;
	if (r == -EPROTO)
		return asph_error_set(err, r, "%s: device clear (INITIATE_CLEAR) refused", t->name);
	return transfer_error(t, r, "device clear", 0, timeout_ms, err);
}

static void need(struct usbtmc *t, enum recovery what, uint8_t tag)
{
	/* a clear covers an abort; never downgrade */
	if (t->recover != RECOVER_CLEAR)
		t->recover = what;
	t->recover_tag = tag;
}

/* The state machine of recovery, one step per pending state. */
static int recover(struct usbtmc *t, atomic_bool *stop, uint64_t deadline,
		   unsigned timeout_ms, struct asph_error *err)
{
	int r = 0;

	if (t->halted) {
		r = clear_halt(t, t->halted);
		if (r < 0)
			return transfer_error(t, r, "clearing a halt", t->halted, timeout_ms, err);
		t->halted = 0;
	}
	switch (t->recover) {
	case RECOVER_NONE:
		return 0;
	case RECOVER_ABORT_IN:
		r = abort_in(t, t->recover_tag, stop, deadline);
		break;
	case RECOVER_ABORT_OUT:
		r = abort_out(t, t->recover_tag, stop, deadline);
		break;
	case RECOVER_CLEAR:
		r = clear_at(t, stop, deadline);
		break;
	}
	if (r == -EPROTO)
		return asph_error_set(err, r, "%s: the device refused to recover from the last "
				      "failed transfer (abort/clear)", t->name);
	if (r < 0)
		return transfer_error(t, r, "recovery from the last failed transfer", 0,
				      timeout_ms, err);
	t->recover = RECOVER_NONE;
	return 0;
}

/* After a failed transfer of tag on ep: what the next call must do. */
static void after_failure(struct usbtmc *t, int r, uint8_t ep, uint8_t tag)
{
	if (r == -ETIMEDOUT || r == -ECANCELED)
		need(t, ep == t->ep_in ? RECOVER_ABORT_IN : RECOVER_ABORT_OUT, tag);
	else if (r == -EPIPE) {
		t->halted = ep;
		need(t, RECOVER_CLEAR, tag);
	} else if (r != -ENODEV)
		need(t, RECOVER_CLEAR, tag);
}

/* ----------------------------------------------------- messages */

static int send_transfer(struct usbtmc *t, uint8_t *buf, size_t len, atomic_bool *stop,
			 uint64_t deadline, unsigned timeout_ms, const char *what,
			 struct asph_error *err)
{
	int got = 0;
	int r = bulk(t, t->ep_out, buf, len, stop, deadline, &got);

	if (r == 0 && (size_t)got != len)
		r = -EIO;
	if (r < 0) {
		after_failure(t, r, t->ep_out, buf[1]);
		return transfer_error(t, r, what, t->ep_out, timeout_ms, err);
	}
	return 0;
}

int usbtmc_write(struct usbtmc *t, const char *msg, size_t len, atomic_bool *stop,
		 unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = recover(t, stop, deadline, timeout_ms, err);
	size_t done = 0;

	if (r < 0)
		return r;
	do {
		size_t n = len - done < t->chunk ? len - done : t->chunk;
		bool last = done + n == len;
		size_t total = usbtmc_padded(n);
		_cleanup_free_ uint8_t *buf = calloc(1, total);
		if (!buf)
			return asph_error_set(err, -ENOMEM, "out of memory");
		usbtmc_header(buf, USBTMC_DEV_DEP_MSG_OUT, take_tag(t), (uint32_t)n,
			      last ? USBTMC_EOM : 0, 0);
		memcpy(buf + USBTMC_HEADER_SIZE, msg + done, n);
		r = send_transfer(t, buf, total, stop, deadline, timeout_ms, "sending a message", err);
		if (r < 0)
			return r;
		done += n;
	} while (done < len);
	return 0;
}

/* Checks a DEV_DEP_MSG_IN header against the request of tag; returns the
 * message bytes it carries, or -EPROTO. */
static int check_reply(struct usbtmc *t, const uint8_t *h, int got, uint8_t tag, size_t asked,
		       struct asph_error *err)
{
	if (got < USBTMC_HEADER_SIZE)
		return asph_error_set(err, -EPROTO,
				      "%s: short read: %d bytes, a reply header has %d",
				      t->name, got, USBTMC_HEADER_SIZE);
	if (h[0] != USBTMC_DEV_DEP_MSG_IN || h[1] != tag || h[1] + h[2] != 0xff)
		return asph_error_set(err, -EPROTO,
				      "%s: reply header (MsgID %u, bTag %u, bTagInverse %u) does not "
				      "answer request bTag %u", t->name, h[0], h[1], h[2], tag);
	uint32_t n = le32(h + 4);
	if (n > asked)
		return asph_error_set(err, -EPROTO, "%s: reply announces %u bytes, %zu were asked",
				      t->name, n, asked);
	if ((size_t)got < USBTMC_HEADER_SIZE + (size_t)n)
		return asph_error_set(err, -EPROTO,
				      "%s: short read: reply announces %u bytes, %d arrived",
				      t->name, n, got - USBTMC_HEADER_SIZE);
	return (int)n;
}

int usbtmc_read(struct usbtmc *t, char *buf, size_t size, size_t *len, atomic_bool *stop,
		unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = recover(t, stop, deadline, timeout_ms, err);

	*len = 0;
	if (r < 0)
		return r;
	for (;;) {
		uint8_t req[USBTMC_HEADER_SIZE];
		uint8_t tag = take_tag(t);
		int got = 0;

		usbtmc_header(req, USBTMC_REQUEST_DEV_DEP_MSG_IN, tag, (uint32_t)t->chunk, 0, 0);
		r = send_transfer(t, req, sizeof(req), stop, deadline, timeout_ms,
				  "requesting a reply", err);
		if (r < 0)
			return r;
		r = bulk(t, t->ep_in, t->in, t->in_size, stop, deadline, &got);
		if (r < 0) {
			after_failure(t, r, t->ep_in, tag);
			return transfer_error(t, r, "reading a reply", t->ep_in, timeout_ms, err);
		}
		int n = check_reply(t, t->in, got, tag, t->chunk, err);
		if (n >= 0 && *len + (size_t)n >= size)
			n = asph_error_set(err, -EPROTO, "%s: reply longer than %zu bytes", t->name,
					   size - 1);
		if (n < 0) {
			need(t, RECOVER_CLEAR, tag);
			return n;
		}
		memcpy(buf + *len, t->in + USBTMC_HEADER_SIZE, (size_t)n);
		*len += (size_t)n;
		buf[*len] = '\0';
		if (t->in[8] & USBTMC_EOM)
			return 0;
	}
}

/* -------------------------------------------------------- opening */

struct found {
	int iface;
	uint8_t ep_in, ep_out;
	uint16_t packet_in;
};

/* The first USBTMC interface of the active configuration with a bulk pair. */
static bool find_interface(libusb_device *dev, struct found *f)
{
	struct libusb_config_descriptor *cfg;
	bool ok = false;

	if (libusb_get_active_config_descriptor(dev, &cfg) < 0 &&
	    libusb_get_config_descriptor(dev, 0, &cfg) < 0)
		return false;
	for (int i = 0; i < cfg->bNumInterfaces && !ok; i++) {
		for (int a = 0; a < cfg->interface[i].num_altsetting && !ok; a++) {
			const struct libusb_interface_descriptor *id = &cfg->interface[i].altsetting[a];
			if (id->bInterfaceClass != USBTMC_CLASS || id->bInterfaceSubClass != USBTMC_SUBCLASS)
				continue;
			*f = (struct found){ .iface = id->bInterfaceNumber };
			for (int e = 0; e < id->bNumEndpoints; e++) {
				const struct libusb_endpoint_descriptor *ep = &id->endpoint[e];
				if ((ep->bmAttributes & 3) != LIBUSB_TRANSFER_TYPE_BULK)
					continue;
				if (ep->bEndpointAddress & LIBUSB_ENDPOINT_IN) {
					f->ep_in = ep->bEndpointAddress;
					f->packet_in = ep->wMaxPacketSize;
				} else {
					f->ep_out = ep->bEndpointAddress;
				}
			}
			ok = f->ep_in && f->ep_out && f->packet_in;
		}
	}
	libusb_free_config_descriptor(cfg);
	return ok;
}

/* A string descriptor in ASCII ('?' for anything else). */
static int read_string(struct usbtmc *t, uint8_t index, char *out, size_t size,
		       atomic_bool *stop, uint64_t deadline)
{
	uint8_t d[255] = { 0 };
	int got = 0;
	uint8_t type = LIBUSB_ENDPOINT_IN | LIBUSB_REQUEST_TYPE_STANDARD | LIBUSB_RECIPIENT_DEVICE;
	int r = control(t, type, LIBUSB_REQUEST_GET_DESCRIPTOR, LIBUSB_DT_STRING << 8, 0, d,
			sizeof(d), stop, deadline, &got);

	if (r < 0)
		return r;
	if (got < 4 || d[1] != LIBUSB_DT_STRING)
		return -EPROTO;
	uint16_t lang = (uint16_t)(d[2] | d[3] << 8);
	r = control(t, type, LIBUSB_REQUEST_GET_DESCRIPTOR, (uint16_t)(LIBUSB_DT_STRING << 8 | index),
		    lang, d, sizeof(d), stop, deadline, &got);
	if (r < 0)
		return r;
	if (got < 2 || d[1] != LIBUSB_DT_STRING || d[0] > got)
		return -EPROTO;
	size_t n = 0;
	for (int i = 2; i + 1 < d[0] && n + 1 < size; i += 2)
		out[n++] = d[i + 1] == 0 && d[i] >= 0x20 && d[i] < 0x7f ? (char)d[i] : '?';
	out[n] = '\0';
	return 0;
}

void usbtmc_close(struct usbtmc *t)
{
	if (!t)
		return;
	if (t->h) {
		libusb_release_interface(t->h, t->iface);
		if (t->reattach)
			libusb_attach_kernel_driver(t->h, t->iface);
		libusb_close(t->h);
	}
	if (t->ctx)
		libusb_exit(t->ctx);
	free(t->in);
	free(t);
}

/* Opens dev if it matches p (serial included); 1 when taken, 0 to go on. */
static int try_device(struct usbtmc *t, libusb_device *dev, const struct usbtmc_params *p,
		      atomic_bool *stop, uint64_t deadline, struct asph_error *err)
{
	struct libusb_device_descriptor dd;
	struct found f;

	if (libusb_get_device_descriptor(dev, &dd) < 0 ||
	    (p->vendor && dd.idVendor != p->vendor) || (p->product && dd.idProduct != p->product) ||
	    !find_interface(dev, &f))
		return 0;
	snprintf(t->name, sizeof(t->name), "USBTMC %04x:%04x at %03u/%03u", dd.idVendor,
		 dd.idProduct, libusb_get_bus_number(dev), libusb_get_device_address(dev));
	int r = libusb_open(dev, &t->h);
	if (r == LIBUSB_ERROR_ACCESS)
		return asph_error_set(err, -EACCES, "%s: no permission to open /dev/bus/usb/%03u/%03u "
				      "(udev rules: docs/driver-usb.md)", t->name,
				      libusb_get_bus_number(dev), libusb_get_device_address(dev));
	if (r < 0)
		return r == LIBUSB_ERROR_NO_DEVICE ? gone(t, err)
						   : asph_error_set(err, -EIO, "%s: cannot open it: %s",
								    t->name, libusb_strerror(r));
	t->serial[0] = '\0';
	if (dd.iSerialNumber && read_string(t, dd.iSerialNumber, t->serial, sizeof(t->serial),
					    stop, deadline) == -ENODEV)
		return gone(t, err);
	if (p->serial && *p->serial && strcmp(p->serial, t->serial)) {
		libusb_close(t->h);
		t->h = NULL;
		return 0;
	}
	t->iface = f.iface;
	t->ep_in = f.ep_in;
	t->ep_out = f.ep_out;
	t->packet_in = f.packet_in;
	return 1;
}

static int claim(struct usbtmc *t, struct asph_error *err)
{
	if (libusb_kernel_driver_active(t->h, t->iface) == 1) {
		int r = libusb_detach_kernel_driver(t->h, t->iface);
		if (r < 0 && r != LIBUSB_ERROR_NOT_FOUND)
			return asph_error_set(err, r == LIBUSB_ERROR_NO_DEVICE ? -ENODEV : -EBUSY,
					      "%s: cannot detach the kernel driver of interface %d: %s",
					      t->name, t->iface, libusb_strerror(r));
		t->reattach = r == 0;
	}
	int r = libusb_claim_interface(t->h, t->iface);
	if (r == LIBUSB_ERROR_BUSY)
		return asph_error_set(err, -EBUSY, "%s: interface %d is claimed by another program",
				      t->name, t->iface);
	if (r < 0)
		return r == LIBUSB_ERROR_NO_DEVICE ? gone(t, err)
						   : asph_error_set(err, -EIO, "%s: cannot claim interface %d: %s",
								    t->name, t->iface, libusb_strerror(r));
	return 0;
}

static int find(struct usbtmc *t, const struct usbtmc_params *p, atomic_bool *stop,
		uint64_t deadline, struct asph_error *err)
{
	libusb_device **list;
	ssize_t n = libusb_get_device_list(t->ctx, &list);
	int r = 0;

	if (n < 0)
		return asph_error_set(err, -EIO, "cannot list USB devices: %s",
				      libusb_strerror((int)n));
	for (ssize_t i = 0; i < n && r == 0; i++)
		r = try_device(t, list[i], p, stop, deadline, err);
	libusb_free_device_list(list, 1);
	if (r == 0) {
		char what[64] = "";
		if (p->vendor || p->product)
			snprintf(what, sizeof(what), " %04x:%04x", p->vendor, p->product);
		return asph_error_set(err, -ENODEV, "no USBTMC device%s%s%s found (is it plugged in?)",
				      what, p->serial && *p->serial ? " with serial " : "",
				      p->serial ? p->serial : "");
	}
	return r < 0 ? r : 0;
}

int usbtmc_open(const struct usbtmc_params *p, atomic_bool *stop, unsigned timeout_ms,
		struct usbtmc **out, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	struct usbtmc *t = calloc(1, sizeof(*t));
	int r;

	if (!t)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (libusb_init(&t->ctx) < 0) {
		t->ctx = NULL;
		usbtmc_close(t);
		return asph_error_set(err, -EIO, "cannot initialize libusb");
	}
	r = find(t, p, stop, deadline, err);
	if (r == 0)
		r = claim(t, err);
	if (r == 0) {
		t->chunk = p->read_chunk;
		/* the whole reply of one request in one transfer, in whole
		 * packets */
		t->in_size = (usbtmc_padded(t->chunk) + t->packet_in - 1) / t->packet_in * t->packet_in;
		t->in = calloc(1, t->in_size);
		if (!t->in)
			r = asph_error_set(err, -ENOMEM, "out of memory");
	}
	if (r == 0 && p->clear)
		r = usbtmc_clear(t, stop, transport_ms_left(deadline), err);
	if (r < 0) {
		usbtmc_close(t);
		return r;
	}
	*out = t;
	return 0;
}
