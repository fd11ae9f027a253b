/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The Modbus driver as it runs against a device: its probe (a sensor of a
 * built-in map or of the configured one) and its stage (the AZ map, or
 * the configured word size, word order and start), through the driver
 * table, libmodbus and the bus's retries, over Modbus RTU on a
 * pseudo-terminal whose other end is a peer answering each request as the
 * input says.
 *
 * The input: byte 0 chooses the sensor (bits 0-1: custom, custom with a
 * validity register, orbit-acs, rf60x; bits 2-4: the value's type; bit 5:
 * low word first; bit 6: holding registers; bit 7: the stage runs too);
 * byte 1 the stage (bit 0: 16-bit values; bit 1: low word first; bit 2:
 * the START handshake; bit 3: r-theta-z; bit 4: one retry; bit 5: reset
 * alarms). The rest is the peer's script, an answer per request, each a
 * tag and what it needs:
 *   tag % 4 == 0  the answer that fits: the registers read, from the next
 *                 bytes (zeros past the end), or a write's echo
 *   tag % 4 == 1  an exception, its code the next byte
 *   tag % 4 == 2  raw bytes: a length, then that many, with the CRC
 *                 appended when tag & 4 (so a frame can be almost right)
 *   tag % 4 == 3  no answer (once per input; later ones answer as 0)
 * The peer hangs up when the script ends. The probe opens and reads
 * twice; the stage opens, reports its status, homes, reads its position
 * and moves. Every refusal has a code and a reason; a reading is finite
 * or flagged out of range; a position is finite.
 */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph-driver/instrument.h"
#include "fuzz.h"
#include "modbus-frame.h"

/* The response timeout of a request (ms), and of a whole operation. */
#define REQUEST_MS "50"
#define OPERATION_MS 200

struct peer {
	int master;             /* the pseudo-terminal's master, -1 once hung up */
	int quit[2];            /* a pipe: the harness is done */
	const uint8_t *p, *end; /* the script left */
	bool silent;            /* the one silence is spent */
	pthread_t thread;
};

static uint8_t next_byte(struct peer *pe)
{
	return pe->p < pe->end ? *pe->p++ : 0;
}

static void send_frame(struct peer *pe, uint8_t *f, size_t n, bool crc)
{
	if (crc) {
		uint16_t c = mbsim_crc16(f, n);
		f[n++] = (uint8_t)c;
		f[n++] = (uint8_t)(c >> 8);
	}
	/* what the driver never reads is dropped once the line is full */
	if (write(pe->master, f, n) < 0 && errno != EAGAIN)
		fuzz_die("peer: %s", strerror(errno));
}

/* The answer to the request req (len bytes, whole and checked) the script
 * says; false when it is over. */
static bool answer(struct peer *pe, const uint8_t *req)
{
	uint8_t f[512];
	size_t n = 0;

	if (pe->p == pe->end)
		return false;
	uint8_t tag = next_byte(pe);
	if (tag % 4 == 3 && !pe->silent) {
		pe->silent = true;
		return true;
	}
	f[n++] = req[0];
	switch (tag % 4) {
	case 1:
		f[n++] = req[1] | 0x80;
		f[n++] = next_byte(pe);
		break;
	case 2: {
		size_t len = next_byte(pe);
		n = 0;
		while (n < len && pe->p < pe->end)
			f[n++] = next_byte(pe);
		send_frame(pe, f, n, tag & 4);
		return true;
	}
	default:
		f[n++] = req[1];
		if (req[1] == 3 || req[1] == 4) {
			size_t count = (size_t)(req[4] << 8 | req[5]);
			count = count > 125 ? 125 : count;
			f[n++] = (uint8_t)(2 * count);
			for (size_t k = 0; k < 2 * count; k++)
				f[n++] = next_byte(pe);
		} else {
			memcpy(f + n, req + 2, 4);
			n += 4;
		}
	}
	send_frame(pe, f, n, true);
	return true;
}

static void *peer_main(void *data)
{
	struct peer *pe = data;
	uint8_t req[512];
	int got = 0;

	for (;;) {
		struct pollfd p[2] = {
			{ .fd = pe->quit[0], .events = POLLIN },
			{ .fd = pe->master, .events = POLLIN },
		};
		if (poll(p, 2, -1) < 0 && errno != EINTR)
			fuzz_die("peer: poll: %s", strerror(errno));
		if (p[0].revents)
			return NULL;
		if (!(p[1].revents & POLLIN))
			continue;
		ssize_t r = read(pe->master, req + got, sizeof(req) - (size_t)got);
		if (r <= 0)
			continue;
		got += (int)r;
		int len;
		while ((len = mbsim_rtu_request_length(req, got)) > 0) {
			if (!answer(pe, req)) {
				/* the script is over: the line goes dead */
				close(pe->master);
				pe->master = -1;
				return NULL;
			}
			memmove(req, req + len, (size_t)(got - len));
			got -= len;
		}
		if (got == (int)sizeof(req))
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

static struct asph_options *options(const struct asph_driver *drv, const char *device,
				    const char *const *kv)
{
	struct asph_options *o;
	struct asph_error err;

	if (asph_options_new(drv, &o, &err) < 0)
		fuzz_die("options: %s", err.message);
	static const char *const bus[] = {
		"transport", "rtu", "timeout", REQUEST_MS, "poll", "0", NULL,
	};
	for (const char *const *p = bus; *p; p += 2)
		if (asph_options_set(o, p[0], p[1], &err) < 0)
			fuzz_die("option %s: %s", p[0], err.message);
	if (asph_options_set(o, "device", device, &err) < 0)
		fuzz_die("option device: %s", err.message);
	for (; *kv; kv += 2)
		if (asph_options_set(o, kv[0], kv[1], &err) < 0)
			fuzz_die("option %s=%s: %s", kv[0], kv[1], err.message);
	return o;
}

static void run_probe(const struct asph_driver *drv, const char *device, uint8_t b)
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
	struct asph_options *o = options(drv, device, profiles[b & 3]);
	struct asph_device *dev = NULL;
	struct asph_error err;

	for (const char *const *p = format; *p && (b & 3) != 3; p += 2)
		if (asph_options_set(o, p[0], p[1], &err) < 0)
			fuzz_die("option %s: %s", p[0], err.message);
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

static void run_stage(const struct asph_driver *drv, const char *device, uint8_t b)
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
	struct asph_options *o = options(drv, device, kv);
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

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	static struct asph_registry *reg;
	struct peer pe = { .p = data + 2, .end = data + size };
	char device[64];

	if (size < 2)
		return 0;
	if (!reg && asph_registry_new(&reg, NULL) < 0)
		fuzz_die("no registry");
	const struct asph_driver *drv = asph_registry_find(reg, "modbus");
	pe.master = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
	if (pe.master < 0 || grantpt(pe.master) < 0 || unlockpt(pe.master) < 0 ||
	    ptsname_r(pe.master, device, sizeof(device)) != 0 || pipe(pe.quit) < 0)
		fuzz_die("no pseudo-terminal: %s", strerror(errno));
	/* the line stays open between the probe and the stage */
	int line = open(device, O_RDWR | O_NOCTTY);
	if (line < 0 || pthread_create(&pe.thread, NULL, peer_main, &pe) != 0)
		fuzz_die("no peer: %s", strerror(errno));
	run_probe(drv, device, data[0]);
	if (data[0] & 0x80)
		run_stage(drv, device, data[1]);
	if (write(pe.quit[1], "", 1) != 1)
		fuzz_die("peer: %s", strerror(errno));
	pthread_join(pe.thread, NULL);
	if (pe.master >= 0)
		close(pe.master);
	close(line);
	close(pe.quit[0]);
	close(pe.quit[1]);
	return 0;
}
