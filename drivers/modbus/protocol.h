/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Modbus on the wire: a bus (libmodbus, RTU or TCP) with timeouts, retries
 * and failures turned into the driver ABI's codes with a readable reason;
 * 16/32-bit register words. libmodbus frames the requests and checks the
 * answers. Internal to drivers/.
 */
#ifndef ASPH_MODBUS_PROTOCOL_H
#define ASPH_MODBUS_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

/* ------------------------------------------------------------ framing */

enum mb_framing {
	MB_FRAMING_RTU = 0,     /* unit, PDU, CRC-16 (low byte first) */
	MB_FRAMING_TCP,         /* MBAP header (7 bytes), PDU */
};

/* "illegal data address", ...; a generic text for unknown codes. */
const char *mb_exception_text(unsigned code);

/* ------------------------------------------------------------- words */

enum mb_word_order {
	MB_HIGH_WORD_FIRST = 0, /* the upper 16 bits at the lower address */
	MB_LOW_WORD_FIRST,
};

uint32_t mb_get32(const uint16_t *w, enum mb_word_order order);
void mb_put32(uint16_t *w, uint32_t v, enum mb_word_order order);

/* -------------------------------------------------------------- bus */

struct mb_bus_params {
	enum mb_framing framing;
	const char *device;     /* RTU: serial port */
	int baud;
	char parity;            /* 'N', 'E', 'O' */
	int data_bits, stop_bits;
	const char *host;       /* TCP */
	int port;
	unsigned timeout_ms;    /* response timeout of one attempt */
	unsigned retries;       /* further attempts after a timeout or a
				 * garbled answer; never after an exception.
				 * Before each, a late answer to the last is
				 * kept out: TCP connects again, RTU drains */
};

struct mb_bus;

/*
 * Connects. -ENODEV (with the reason: no such port, permission, refused)
 * when the device cannot be reached. Users of one serial port in a process
 * share it (one transaction at a time); a port already open at other line
 * settings is refused with -EINVAL.
 */
int mb_bus_open(const struct mb_bus_params *p, struct mb_bus **out,
		struct asph_error *err);
void mb_bus_free(struct mb_bus *b);

/*
 * One transaction with unit. No call waits longer than timeout_ms in all
 * (0: one attempt with the response timeout). Errors: -ETIMEDOUT (no
 * answer in time, also when answers came late), -EPROTO (an exception
 * response, decoded, or an answer that does not fit the request), -EIO
 * (bad CRC or another transport error), -ENODEV (the connection or the
 * port went away, or TCP could not connect again after a try without an
 * answer).
 */
int mb_read_registers(struct mb_bus *b, int unit, bool input, int addr,
		      int n, uint16_t *dst, unsigned timeout_ms,
		      struct asph_error *err);
int mb_write_registers(struct mb_bus *b, int unit, int addr, int n,
		       const uint16_t *src, unsigned timeout_ms,
		       struct asph_error *err);

#endif
