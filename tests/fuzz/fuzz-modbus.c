/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The Modbus driver as it runs against a device: its probe (a sensor of a
 * built-in map or of the configured one) and its stage (the AZ map, or
 * the configured word size, word order and start), through the driver
 * table, libmodbus and the bus's retries, against a peer that answers
 * each request as the input says: over Modbus TCP on 127.0.0.1, or over
 * RTU on a pseudo-terminal.
 *
 * The input: byte 0 chooses the sensor (bits 0-1: custom, custom with a
 * validity register, orbit-acs, rf60x; bits 2-4: the value's type; bit 5:
 * low word first; bit 6: holding registers; bit 7: the stage runs too);
 * byte 1 the stage (bit 0: 16-bit values; bit 1: low word first; bit 2:
 * the START handshake; bit 3: r-theta-z; bit 4: one retry; bit 5: reset
 * alarms) and the line (bit 7: RTU, else TCP). The rest is the peer's
 * script, an answer per request, each a tag and what it needs:
 *   tag % 4 == 0  the answer that fits: the registers read, from the next
 *                 bytes (zeros past the end), or a write's echo
 *   tag % 4 == 1  an exception, its code the next byte
 *   tag % 4 == 2  raw bytes (unit and PDU): a length, then that many,
 *                 framed when tag & 4 (RTU: the CRC after them; TCP: the
 *                 request's MBAP header before), so a frame can be almost
 *                 right
 *   tag % 4 == 3  no answer (once per input; later ones answer as 0)
 * The peer hangs up when the script ends. The probe opens and reads
 * twice; the stage opens, reports its status, homes, reads its position
 * and moves. Every refusal has a code and a reason; a reading is finite
 * or flagged out of range; a position is finite; a status is one of the
 * states.
 */
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "asph-driver/instrument.h"
#include "fuzz.h"
#include "modbus-frame.h"

/* The response timeout of a request (ms), and of a whole operation. */
#define REQUEST_MS "10"
#define OPERATION_MS 200

struct peer {
	bool tcp;
	int line;               /* RTU: the pseudo-terminal's master; TCP: the
				 * connection; -1 none (hung up) */
	int listener;           /* TCP: where the driver connects, -1 hung up */
	int quit[2];            /* a pipe: the harness is done */
	const uint8_t *p, *end; /* the script left */
	bool silent;            /* the one silence is spent */
	pthread_t thread;
};

static uint8_t next_byte(struct peer *pe)
{
	return pe->p < pe->end ? *pe->p++ : 0;
}

/* The request of req's got bytes whole: its length, or 0. */
static size_t request_length(const struct peer *pe, const uint8_t *req, size_t got)
{
	if (!pe->tcp)
		return (size_t)mbsim_rtu_request_length(req, (int)got);
	if (got < 6)
		return 0;
	size_t len = 6u + (size_t)(req[4] << 8 | req[5]);
	return got >= len ? len : 0;
}

/* Sends unit and the PDU (n bytes at f + 1), framed (RTU: the CRC after
 * them; TCP: the MBAP header of the request's transaction before), or as
 * they are. What the driver never reads is dropped once the line is full. */
static void send_frame(struct peer *pe, const uint8_t *req, uint8_t *f, size_t n, bool framed)
{
	uint8_t out[600];
	size_t k = 0;

	if (pe->tcp && framed) {
		memcpy(out, req, 4);    /* transaction and protocol ids */
		out[4] = (uint8_t)(n >> 8);
		out[5] = (uint8_t)n;
		k = 6;
	}
	memcpy(out + k, f, n);
	k += n;
	if (!pe->tcp && framed) {
		uint16_t c = mbsim_crc16(out, k);
		out[k++] = (uint8_t)c;
		out[k++] = (uint8_t)(c >> 8);
	}
	ssize_t r = pe->tcp ? send(pe->line, out, k, MSG_NOSIGNAL | MSG_DONTWAIT)
			    : write(pe->line, out, k);
	if (r < 0 && errno != EAGAIN && errno != EPIPE && errno != ECONNRESET && errno != EIO)
		fuzz_die("peer: %s", strerror(errno));
}

/* The answer to the request req (whole) the script says; false when it is
 * over. */
static bool answer(struct peer *pe, const uint8_t *req)
{
	const uint8_t *pdu = req + (pe->tcp ? 7 : 1);
	uint8_t f[512];
	size_t n = 0;

	if (pe->p == pe->end)
		return false;
	uint8_t tag = next_byte(pe);
	if (tag % 4 == 3 && !pe->silent) {
		pe->silent = true;
		return true;
	}
	f[n++] = pdu[-1];       /* the unit */
	switch (tag % 4) {
	case 1:
		f[n++] = pdu[0] | 0x80;
		f[n++] = next_byte(pe);
		break;
	case 2: {
		size_t len = next_byte(pe);
		n = 0;
		while (n < len && pe->p < pe->end)
			f[n++] = next_byte(pe);
		send_frame(pe, req, f, n, tag & 4);
		return true;
	}
	default:
		f[n++] = pdu[0];
		if (pdu[0] == 3 || pdu[0] == 4) {
			size_t count = (size_t)(pdu[3] << 8 | pdu[4]);
			count = count > 125 ? 125 : count;
			f[n++] = (uint8_t)(2 * count);
			for (size_t k = 0; k < 2 * count; k++)
				f[n++] = next_byte(pe);
		} else {
			memcpy(f + n, pdu + 1, 4);
			n += 4;
		}
	}
	send_frame(pe, req, f, n, true);
	return true;
}

static void hang_up(struct peer *pe)
{
	if (pe->line >= 0)
		close(pe->line);
	if (pe->listener >= 0)
		close(pe->listener);
	pe->line = pe->listener = -1;
}

static void *peer_main(void *data)
{
	struct peer *pe = data;
	uint8_t req[512];
	size_t got = 0;

	for (;;) {
		struct pollfd p[3] = {
			{ .fd = pe->quit[0], .events = POLLIN },
			{ .fd = pe->line, .events = POLLIN },
			{ .fd = pe->listener, .events = POLLIN },
		};
		if (poll(p, 3, -1) < 0 && errno != EINTR)
			fuzz_die("peer: poll: %s", strerror(errno));
		if (p[0].revents)
			return NULL;
		if (p[2].revents & POLLIN) {
			/* a connection of the driver's, or its new one */
			int c = accept(pe->listener, NULL, NULL);
			if (c >= 0) {
				if (pe->line >= 0)
					close(pe->line);
				pe->line = c;
				got = 0;
			}
			continue;
		}
		if (!(p[1].revents & (POLLIN | POLLHUP)))
			continue;
		ssize_t r = read(pe->line, req + got, sizeof(req) - got);
		if (r <= 0 && pe->tcp) {
			/* the driver closed it */
			close(pe->line);
			pe->line = -1;
			got = 0;
			continue;
		}
		if (r <= 0)
			continue;
		got += (size_t)r;
		size_t len;
		while ((len = request_length(pe, req, got)) > 0) {
			if (!answer(pe, req)) {
				/* the script is over: the line goes dead */
				hang_up(pe);
				return NULL;
			}
			memmove(req, req + len, got - len);
			got -= len;
		}
		if (got == sizeof(req))
			got = 0;
	}
}

/* ------------------------------------------------------------ driver */

static void check_result(int r, const struct asph_error *err)
{
	if (r > 0)
		fuzz_die("an operation returned %d", r);
	if (r < 0)
		fuzz_check_error(err);
}

static void set_options(struct asph_options *o, const char *const *kv)
{
	struct asph_error err;

	for (; *kv; kv += 2)
		if (asph_options_set(o, kv[0], kv[1], &err) < 0)
			fuzz_die("option %s=%s: %s", kv[0], kv[1], err.message);
}

/* The driver's options: where the peer is (bus), then kv. */
static struct asph_options *options(const struct asph_driver *drv, const char *const *bus,
				    const char *const *kv)
{
	static const char *const timing[] = { "timeout", REQUEST_MS, "poll", "0", NULL };
	struct asph_options *o;
	struct asph_error err;

	if (asph_options_new(drv, &o, &err) < 0)
		fuzz_die("options: %s", err.message);
	set_options(o, timing);
	set_options(o, bus);
	set_options(o, kv);
	return o;
}

static void run_probe(const struct asph_driver *drv, const char *const *bus, uint8_t b)
{
	static const char *const types[] = { "s32", "u32", "s16", "u16", "f32" };
	static const char *const profiles[][12] = {
		{ "sensor_profile", "custom", "register", "0", NULL },
		{ "sensor_profile", "custom", "register", "16", "valid_register", "18",
		  "valid_bit", "3", NULL },
		{ "sensor_profile", "orbit-acs", "register", "100", "status_register", "110", NULL },
		{ "sensor_profile", "rf60x", NULL },
	};
	const char *format[] = {
		"type", types[((b >> 2) & 7) % 5],
		"word_order", b & 0x20 ? "low-first" : "high-first",
		"table", b & 0x40 ? "holding" : "input", NULL,
	};
	struct asph_options *o = options(drv, bus, profiles[b & 3]);
	struct asph_device *dev = NULL;
	struct asph_error err;

	if ((b & 3) != 3)
		set_options(o, format);
	asph_error_clear(&err);
	int r = drv->probe->open(drv, asph_options_values(o), OPERATION_MS, &dev, &err);
	check_result(r, &err);
	for (int k = 0; k < 2 && r == 0; k++) {
		struct asph_probe_context ctx = { .plan_index = (uint64_t)k };
		struct asph_reading rd;
		asph_error_clear(&err);
		r = drv->probe->read(dev, &ctx, &rd, OPERATION_MS, &err);
		check_result(r, &err);
		if (r == 0 && !(rd.flags & ASPH_READING_OUT_OF_RANGE) && !isfinite(rd.value))
			fuzz_die("a reading of %g not flagged out of range", rd.value);
	}
	if (dev)
		drv->probe->close(dev);
	asph_options_free(o);
}

static void run_stage(const struct asph_driver *drv, const char *const *bus, uint8_t b)
{
	const char *kv[] = {
		"word_size", b & 1 ? "16" : "32",
		"word_order", b & 2 ? "low-first" : "high-first",
		"start", b & 4 ? "start-bit" : "trigger",
		"kinematics", b & 8 ? "r-theta-z" : "xyz",
		"retries", b & 16 ? "1" : "0",
		"reset_alarm", b & 32 ? "true" : "false",
		/* 16-bit registers take the default speed only at a coarser scale */
		"counts_per_mm", "100", "counts_per_rad", "100", NULL,
	};
	struct asph_options *o = options(drv, bus, kv);
	const struct asph_stage_ops *ops = drv->stage;
	struct asph_device *dev = NULL;
	struct asph_stage_status st;
	struct asph_error err;
	double pos[3], to[3] = { 1, 0.5, -1 };

	asph_error_clear(&err);
	int r = ops->open(drv, asph_options_values(o), OPERATION_MS, &dev, &err);
	check_result(r, &err);
	if (r == 0) {
		r = ops->status(dev, &st, OPERATION_MS, &err);
		check_result(r, &err);
		if (r == 0 && (unsigned)st.state > ASPH_STAGE_DISCONNECTED)
			fuzz_die("stage state %d", (int)st.state);
		asph_error_clear(&err);
		check_result(ops->home(dev, OPERATION_MS, &err), &err);
		asph_error_clear(&err);
		r = ops->position(dev, pos, OPERATION_MS, &err);
		check_result(r, &err);
		if (r == 0 && !(isfinite(pos[0]) && isfinite(pos[1]) && isfinite(pos[2])))
			fuzz_die("a position not finite");
		asph_error_clear(&err);
		check_result(ops->move_to(dev, to, OPERATION_MS, &err), &err);
		ops->close(dev);
	}
	asph_options_free(o);
}

/* RTU: a pseudo-terminal, whose line the harness keeps open between the
 * probe and the stage (*line). */
static void open_rtu(struct peer *pe, char *device, size_t size, int *line)
{
	pe->line = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
	if (pe->line < 0 || grantpt(pe->line) < 0 || unlockpt(pe->line) < 0 ||
	    ptsname_r(pe->line, device, size) != 0 ||
	    (*line = open(device, O_RDWR | O_NOCTTY)) < 0)
		fuzz_die("no pseudo-terminal: %s", strerror(errno));
}

/* TCP: a listener on 127.0.0.1, its port into port. */
static void open_tcp(struct peer *pe, char *port, size_t size)
{
	struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
	socklen_t len = sizeof(a);

	pe->listener = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
	if (pe->listener < 0 || bind(pe->listener, (struct sockaddr *)&a, sizeof(a)) < 0 ||
	    listen(pe->listener, 4) < 0 ||
	    getsockname(pe->listener, (struct sockaddr *)&a, &len) < 0)
		fuzz_die("no listener: %s", strerror(errno));
	snprintf(port, size, "%u", (unsigned)ntohs(a.sin_port));
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	static struct asph_registry *reg;
	struct peer pe = { .line = -1, .listener = -1, .p = data + 2, .end = data + size };
	char where[64];
	int line = -1;

	if (size < 2)
		return 0;
	if (!reg && asph_registry_new(&reg, NULL) < 0)
		fuzz_die("no registry");
	const struct asph_driver *drv = asph_registry_find(reg, "modbus");
	pe.tcp = !(data[1] & 0x80);
	if (pe.tcp)
		open_tcp(&pe, where, sizeof(where));
	else
		open_rtu(&pe, where, sizeof(where), &line);
	const char *const tcp[] = { "transport", "tcp", "host", "127.0.0.1", "port", where, NULL };
	const char *const rtu[] = { "transport", "rtu", "device", where, NULL };
	if (pipe(pe.quit) < 0 || pthread_create(&pe.thread, NULL, peer_main, &pe) != 0)
		fuzz_die("no peer: %s", strerror(errno));
	run_probe(drv, pe.tcp ? tcp : rtu, data[0]);
	if (data[0] & 0x80)
		run_stage(drv, pe.tcp ? tcp : rtu, data[1]);
	if (write(pe.quit[1], "", 1) != 1)
		fuzz_die("peer: %s", strerror(errno));
	pthread_join(pe.thread, NULL);
	hang_up(&pe);
	if (line >= 0)
		close(line);
	close(pe.quit[0]);
	close(pe.quit[1]);
	return 0;
}
