/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Modbus frames on the test side: the RTU CRC-16 and the length of an RTU
 * request, with which the simulator (modbus-sim.c) and the peer of the
 * Modbus fuzz target (tests/fuzz/fuzz-modbus.c) frame their serial
 * traffic, and a pure decoder of response frames, which the tests check
 * against the Modbus specifications' examples. The driver itself leaves
 * the frames to libmodbus.
 */
#ifndef ASPH_TEST_MODBUS_FRAME_H
#define ASPH_TEST_MODBUS_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "modbus/protocol.h"

/* A decoded response ADU. data points into the decoded buffer. */
struct mbsim_frame {
	uint16_t transaction;   /* TCP only */
	uint8_t unit;
	uint8_t function;       /* without the exception flag 0x80 */
	uint8_t exception;      /* exception code; 0 for a normal answer */
	const uint8_t *data;    /* register bytes (reads) or the echoed
				 * address and value/quantity (writes) */
	size_t len;
	size_t size;            /* bytes of buf the frame takes */
};

/*
 * Decodes a response frame without I/O. -EBADMSG for a frame that is too
 * short, has a bad CRC (RTU) or an MBAP header that does not fit (TCP),
 * -EPROTO for a PDU whose length does not match its function, -ENOTSUP for
 * a function code it does not know. On failure *out is left zeroed.
 */
int mbsim_frame_decode(const uint8_t *buf, size_t len, enum mb_framing framing,
		       struct mbsim_frame *out);

/* The Modbus RTU CRC-16 (polynomial 0xA001, initial 0xFFFF). */
uint16_t mbsim_crc16(const uint8_t *buf, size_t len);

/* The length of the RTU request that starts buf, of which got bytes are
 * there; 0 while it is not whole. */
int mbsim_rtu_request_length(const uint8_t *buf, int got);

#endif
