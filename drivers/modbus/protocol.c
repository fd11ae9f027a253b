/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Modbus exceptions, register words and the libmodbus bus with the driver
 * ABI's timeouts and reasons. */
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <modbus.h>

#include "protocol.h"
#include "transport.h"

/* -------------------------------------------------------- exceptions */

const char *mb_exception_text(unsigned code)
{
	static const char *const text[] = {
		[1] = "illegal function",
		[2] = "illegal data address",
		[3] = "illegal data value",
		[4] = "server device failure",
		[5] = "acknowledge (request accepted, still processing)",
		[6] = "server device busy",
		[7] = "negative acknowledge",
		[8] = "memory parity error",
		[10] = "gateway path unavailable",
		[11] = "gateway target device failed to respond",
	};
	if (code < sizeof(text) / sizeof(text[0]) && text[code])
		return text[code];
	return "unknown exception";
}

/* ------------------------------------------------------------- words */

uint32_t mb_get32(const uint16_t *w, enum mb_word_order order)
{
	if (order == MB_HIGH_WORD_FIRST)
		return (uint32_t)w[0] << 16 | w[1];
	return (uint32_t)w[1] << 16 | w[0];
}

void mb_put32(uint16_t *w, uint32_t v, enum mb_word_order order)
{
	uint16_t hi = (uint16_t)(v >> 16), lo = (uint16_t)v;

	w[0] = order == MB_HIGH_WORD_FIRST ? hi : lo;
	w[1] = order == MB_HIGH_WORD_FIRST ? lo : hi;
}

/* -------------------------------------------------------------- bus */

/*
 * A connection. A serial line is shared by everything on it in this
 * process (a stage's drives and a sensor on one RS-485 line): one open
 * port, one transaction at a time. TCP users each have their own.
 */
struct mb_link {
	modbus_t *ctx;
	pthread_mutex_t lock;
	unsigned refs;
	struct mb_bus_params p;         /* strings point into device, host */
	char device[256], host[256];
	char name[300];                 /* prefixes reasons */
	/* A try went without a fitting answer, so one may still be on its
	 * way: TCP has closed the connection and connects again before the
	 * next request; a serial line is drained before it, waiting for a
	 * late answer to start until late_until (CLOCK_MONOTONIC ns). */
	bool unsettled;
	uint64_t late_until;
	struct mb_link *next;
};

/* Per user: the link and the user's own timeouts. */
struct mb_bus {
	struct mb_link *link;
	unsigned timeout_ms, retries;
};

static pthread_mutex_t serial_lock = PTHREAD_MUTEX_INITIALIZER;
static struct mb_link *serial_links;

static int connect_error(struct mb_link *l, int e, struct asph_error *err)
{
	if (l->p.framing == MB_FRAMING_RTU && (e == EACCES || e == EPERM))
		return asph_error_set(err, -ENODEV,
				      "%s: permission denied (the user needs the serial group, "
				      "usually dialout: see docs/driver-modbus.md)", l->name);
	if (l->p.framing == MB_FRAMING_RTU && e == ENOENT)
		return asph_error_set(err, -ENODEV, "%s: no such serial port", l->name);
	return asph_error_set(err, -ENODEV, "%s: cannot connect: %s", l->name,
			      modbus_strerror(e));
}

static int link_new(const struct mb_bus_params *p, struct mb_link **out,
		    struct asph_error *err)
{
	struct mb_link *l = calloc(1, sizeof(*l));
	char port[16];

	if (!l)
		return asph_error_set(err, -ENOMEM, "out of memory");
	l->p = *p;
	snprintf(l->device, sizeof(l->device), "%s", p->device ? p->device : "");
	snprintf(l->host, sizeof(l->host), "%s", p->host ? p->host : "");
	l->p.device = l->device;
	l->p.host = l->host;
	l->refs = 1;
	pthread_mutex_init(&l->lock, NULL);
	snprintf(port, sizeof(port), "%d", p->port);
	if (p->framing == MB_FRAMING_RTU) {
		snprintf(l->name, sizeof(l->name), "%s", l->device);
		l->ctx = modbus_new_rtu(l->device, p->baud, p->parity, p->data_bits, p->stop_bits);
	} else {
		snprintf(l->name, sizeof(l->name), "%s:%d", l->host, p->port);
		l->ctx = modbus_new_tcp_pi(l->host, port);
	}
	int r = 0;
	if (!l->ctx) {
		r = asph_error_set(err, -EINVAL, "%s: cannot set up the connection: %s",
				   l->name, modbus_strerror(errno));
	} else {
		/* retries and reconnects are ours, bounded by the timeouts */
		modbus_set_error_recovery(l->ctx, MODBUS_ERROR_RECOVERY_NONE);
		if (modbus_connect(l->ctx) < 0)
			r = connect_error(l, errno, err);
	}
	if (r < 0) {
		if (l->ctx)
			modbus_free(l->ctx);
		pthread_mutex_destroy(&l->lock);
		free(l);
		return r;
	}
	*out = l;
	return 0;
}

static void link_free(struct mb_link *l)
{
	modbus_close(l->ctx);
	modbus_free(l->ctx);
	pthread_mutex_destroy(&l->lock);
	free(l);
}

static bool same_line(const struct mb_bus_params *a, const struct mb_bus_params *b)
{
	return a->baud == b->baud && a->parity == b->parity && a->data_bits == b->data_bits &&
	       a->stop_bits == b->stop_bits;
}

static int serial_link(const struct mb_bus_params *p, struct mb_link **out,
		       struct asph_error *err)
{
	int r = 0;

	pthread_mutex_lock(&serial_lock);
	struct mb_link *l = serial_links;
	while (l && strcmp(l->device, p->device) != 0)
		l = l->next;
	if (l && !same_line(&l->p, p)) {
		r = asph_error_set(err, -EINVAL, "%s: already open at %d baud, parity %c, %d data "
				   "and %d stop bits: every device on a line needs the same settings",
				   l->name, l->p.baud, l->p.parity, l->p.data_bits, l->p.stop_bits);
	} else if (l) {
		l->refs++;
	} else {
		struct mb_link *fresh = NULL;
		r = link_new(p, &fresh, err);
		if (r == 0 && fresh) {
			fresh->next = serial_links;
			serial_links = l = fresh;
		}
	}
	pthread_mutex_unlock(&serial_lock);
	if (r == 0)
		*out = l;
	return r;
}

static void serial_unlink(struct mb_link *l)
{
	pthread_mutex_lock(&serial_lock);
	bool last = --l->refs == 0;
	for (struct mb_link **pp = &serial_links; last && *pp; pp = &(*pp)->next)
		if (*pp == l) {
			*pp = l->next;
			break;
		}
	pthread_mutex_unlock(&serial_lock);
	if (last)
		link_free(l);
}

int mb_bus_open(const struct mb_bus_params *p, struct mb_bus **out,
		struct asph_error *err)
{
	struct mb_bus *b = calloc(1, sizeof(*b));

	if (!b)
		return asph_error_set(err, -ENOMEM, "out of memory");
	b->timeout_ms = p->timeout_ms;
	b->retries = p->retries;
	int r = p->framing == MB_FRAMING_RTU ? serial_link(p, &b->link, err)
					     : link_new(p, &b->link, err);
	if (r < 0) {
		free(b);
		return r;
	}
	*out = b;
	return 0;
}

void mb_bus_free(struct mb_bus *b)
{
	if (!b)
		return;
	if (b->link->p.framing == MB_FRAMING_RTU)
		serial_unlink(b->link);
	else
		link_free(b->link);
	free(b);
}

static void set_timeouts(modbus_t *ctx, unsigned ms)
{
	if (ms == 0)
		ms = 1;
	modbus_set_response_timeout(ctx, ms / 1000, (ms % 1000) * 1000);
	modbus_set_byte_timeout(ctx, ms / 1000, (ms % 1000) * 1000);
}

static bool worth_retrying(int e)
{
	return e == ETIMEDOUT || e == EMBBADCRC || e == EMBBADDATA || e == EMBBADSLAVE ||
	       e == EMBMDATA || e == EMBBADEXC || e == EINTR;
}

/* An answer that belongs to another request, e.g. a late one to an
 * earlier try. */
static bool out_of_step(int e)
{
	return e == EMBBADDATA || e == EMBBADSLAVE || e == EMBMDATA;
}

static bool link_lost(int e)
{
	return e == ECONNRESET || e == EPIPE || e == EBADF || e == ENOTCONN ||
	       e == ECONNREFUSED || e == EIO || e == ENXIO || e == ENODEV;
}

/* The reason of a failed transaction, errno e, after tries attempts. */
/* op_ms: the operation's timeout when it, not the response timeout, cut
 * the tries short. */
static int fail(const struct mb_link *l, int unit, const char *what, int addr, int e,
		unsigned tries, unsigned attempt_ms, unsigned op_ms, struct asph_error *err)
{
	const char *n = l->name;

	if (e > MODBUS_ENOBASE && e <= EMBXGTAR) {
		unsigned code = (unsigned)(e - MODBUS_ENOBASE);
		return asph_error_set(err, -EPROTO, "%s: unit %d refused %s register %d (0x%04x): "
				      "exception %u, %s", n, unit, what, addr, (unsigned)addr,
				      code, mb_exception_text(code));
	}
	if (e == ETIMEDOUT && op_ms)
		return asph_error_set(err, -ETIMEDOUT, "%s: unit %d did not answer (%s register %d, "
				      "%u %s within the operation's %u ms)", n, unit, what, addr,
				      tries, tries == 1 ? "try" : "tries", op_ms);
	if (e == ETIMEDOUT)
		return asph_error_set(err, -ETIMEDOUT, "%s: unit %d did not answer (%s register %d, "
				      "%u %s of %u ms)", n, unit, what, addr, tries,
				      tries == 1 ? "try" : "tries", attempt_ms);
	if (e == EMBBADCRC)
		return asph_error_set(err, -EIO, "%s: unit %d: answers with a bad CRC (%u %s): "
				      "check the wiring, termination and baud rate", n, unit, tries,
				      tries == 1 ? "try" : "tries");
	if (e == EMBBADDATA || e == EMBBADSLAVE || e == EMBMDATA || e == EMBBADEXC)
		return asph_error_set(err, -EPROTO, "%s: unit %d: answer does not fit the request "
				      "(%s register %d): %s", n, unit, what, addr, modbus_strerror(e));
	if (link_lost(e))
		return asph_error_set(err, -ENODEV, "%s: connection lost: %s", n, modbus_strerror(e));
	return asph_error_set(err, -EIO, "%s: unit %d: %s", n, unit, modbus_strerror(e));
}

/* The connection could not be made again after a try without a fitting
 * answer (e, 0 when that was in an earlier transaction). */
static int reconnect_failed(const struct mb_link *l, int unit, const char *what, int addr, int e,
			    int ce, struct asph_error *err)
{
	if (!e)
		return asph_error_set(err, -ENODEV, "%s: connection lost: cannot connect again: %s",
				      l->name, modbus_strerror(ce));
	return asph_error_set(err, -ENODEV, "%s: connection lost: unit %d %s (%s register %d), "
			      "then connecting again failed: %s", l->name, unit,
			      e == ETIMEDOUT ? "did not answer" : "answered out of step", what, addr,
			      modbus_strerror(ce));
}

/* Silence that ends a frame on a serial line. USB adapters hand on what
 * they received in chunks (an FTDI chip every 16 ms by default), so one
 * frame can pause that long. */
enum { RTU_QUIET_MS = 20 };

/* A serial line after a try without a fitting answer: the device may still
 * send one (late, or the rest of a garbled frame), which the next request
 * would take for its own (RTU has no transaction ids). Waits until
 * late_until for it to start, then until the line has been quiet for
 * RTU_QUIET_MS, all before `until`, and drops it. */
static void rtu_drain(struct mb_link *l, uint64_t until)
{
	struct pollfd p = { .fd = modbus_get_socket(l->ctx), .events = POLLIN };
	unsigned wait = transport_ms_left(l->late_until);
	uint8_t sink[MODBUS_RTU_MAX_ADU_LENGTH];

	for (;;) {
		unsigned left = transport_ms_left(until);
		if (wait > left)
			wait = left;
		if (wait == 0 || poll(&p, 1, (int)wait) <= 0 || read(p.fd, sink, sizeof(sink)) <= 0)
			break;
		wait = RTU_QUIET_MS;
	}
	modbus_flush(l->ctx);
}

/* Before a request: an unsettled link gets a new connection (TCP; an
 * answer still on its way to the old one cannot arrive on it) or is
 * drained, until `until` at most (a serial line, which stays unsettled
 * until a first try gets its answer). 0, or the errno of the connect. */
static int settle(struct mb_link *l, uint64_t until)
{
	if (!l->unsettled)
		return 0;
	if (l->p.framing == MB_FRAMING_RTU) {
		rtu_drain(l, until);
		return 0;
	}
	modbus_close(l->ctx);
	errno = 0;
	if (modbus_connect(l->ctx) < 0)
		return errno ? errno : ETIMEDOUT;   /* libmodbus's connect timeout sets none */
	l->unsettled = false;
	return 0;
}

/* After a try without a fitting answer (errno e). A late answer may
 * start within one more response timeout; the rest of a garbled one at
 * once. */
static void unsettle(struct mb_link *l, int e, unsigned timeout_ms)
{
	l->unsettled = true;
	if (l->p.framing == MB_FRAMING_TCP)
		modbus_close(l->ctx);
	else
		l->late_until = transport_deadline(e == EMBBADCRC && timeout_ms > RTU_QUIET_MS
						   ? RTU_QUIET_MS : timeout_ms);
}

/* Until when getting in step may last before a try: an operation's first
 * try keeps its own response time (ms). */
static uint64_t settle_until(uint64_t deadline, unsigned tries, unsigned ms)
{
	uint64_t keep = tries ? 0 : (uint64_t)ms * 1000000u;

	return deadline > keep ? deadline - keep : 0;
}

/* The response timeout of the next try: the option's, cut to what is left
 * of the operation; 0 when nothing is left after the first. */
static unsigned slice(const struct mb_bus *b, unsigned tries, uint64_t deadline)
{
	unsigned left = transport_ms_left(deadline);

	if (tries == 0 && left == 0)
		return b->timeout_ms;
	return left < b->timeout_ms ? left : b->timeout_ms;
}

enum op { OP_READ_HOLDING, OP_READ_INPUT, OP_WRITE };

/* One try: 0 or the errno. */
static int request(modbus_t *ctx, enum op op, int addr, int n, uint16_t *regs)
{
	int rc = op == OP_WRITE ? modbus_write_registers(ctx, addr, n, regs)
		 : op == OP_READ_INPUT ? modbus_read_input_registers(ctx, addr, n, regs)
		 : modbus_read_registers(ctx, addr, n, regs);

	return rc == n ? 0 : rc < 0 ? errno : EMBMDATA;
}

static int attempts(struct mb_bus *b, enum op op, int unit, int addr, int n, uint16_t *regs,
		    unsigned timeout_ms, struct asph_error *err)
{
	struct mb_link *l = b->link;
	const char *what = op == OP_WRITE ? "writing" : "reading";
	uint64_t deadline = transport_deadline(timeout_ms ? timeout_ms : b->timeout_ms);
	unsigned tries = 0, attempt_ms = b->timeout_ms;
	bool timed_out = false;
	int e = 0;

	if (modbus_set_slave(l->ctx, unit) < 0)
		return asph_error_set(err, -EINVAL, "%s: unit %d is not valid", l->name, unit);
	while (tries <= b->retries) {
		unsigned ms = slice(b, tries, deadline);
		if (ms == 0)
			break;
		set_timeouts(l->ctx, ms);
		int ce = settle(l, settle_until(deadline, tries, ms));
		if (ce)
			return reconnect_failed(l, unit, what, addr, e, ce, err);
		/* getting in step took its time */
		if ((ms = slice(b, tries, deadline)) == 0)
			break;
		attempt_ms = ms;
		set_timeouts(l->ctx, attempt_ms);
		tries++;
		e = request(l->ctx, op, addr, n, regs);
		if (e == 0) {
			/* after a retry on a serial line, the answer to an
			 * earlier try may still come */
			l->unsettled = tries > 1 && l->p.framing == MB_FRAMING_RTU;
			return 0;
		}
		timed_out = timed_out || e == ETIMEDOUT;
		if (link_lost(e) && l->p.framing == MB_FRAMING_TCP) {
			/* a gateway that dropped the connection: one reconnect */
			modbus_close(l->ctx);
			if (modbus_connect(l->ctx) < 0) {
				/* the next transaction tries once more */
				l->unsettled = true;
				return fail(l, unit, what, addr, e, tries, attempt_ms, 0, err);
			}
			continue;
		}
		if (!worth_retrying(e))
			break;
		unsettle(l, e, b->timeout_ms);
	}
	/* a device that was only slow: what answered out of step was late */
	if (timed_out && out_of_step(e))
		e = ETIMEDOUT;
	return fail(l, unit, what, addr, e ? e : ETIMEDOUT, tries, attempt_ms,
		    attempt_ms < b->timeout_ms || tries <= b->retries ? timeout_ms : 0, err);
}

static int transact(struct mb_bus *b, enum op op, int unit, int addr, int n, uint16_t *regs,
		    unsigned timeout_ms, struct asph_error *err)
{
	pthread_mutex_lock(&b->link->lock);
	int r = attempts(b, op, unit, addr, n, regs, timeout_ms, err);
	pthread_mutex_unlock(&b->link->lock);
	return r;
}

int mb_read_registers(struct mb_bus *b, int unit, bool input, int addr, int n,
		      uint16_t *dst, unsigned timeout_ms, struct asph_error *err)
{
	return transact(b, input ? OP_READ_INPUT : OP_READ_HOLDING, unit, addr, n, dst,
			timeout_ms, err);
}

int mb_write_registers(struct mb_bus *b, int unit, int addr, int n, const uint16_t *src,
		       unsigned timeout_ms, struct asph_error *err)
{
	uint16_t copy[MODBUS_MAX_WRITE_REGISTERS];

	if (n <= 0 || n > MODBUS_MAX_WRITE_REGISTERS)
		return asph_error_set(err, -EINVAL, "%s: %d registers cannot be written at once",
				      b->link->name, n);
	memcpy(copy, src, (size_t)n * sizeof(*src));
	return transact(b, OP_WRITE, unit, addr, n, copy, timeout_ms, err);
}
