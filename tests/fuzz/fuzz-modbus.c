/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Modbus response decoder of the Modbus driver. The first byte picks the
 * framing (bit 0: TCP) and, for RTU, whether the harness appends the right
 * CRC (bit 1) so that mutations reach the PDU decoding behind the check.
 * The rest is a stream of frames decoded one after the other, as a reply
 * buffer would be.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz.h"
#include "protocol.h"

static void check(const uint8_t *buf, size_t len, const struct mb_frame *f)
{
	if (f->size == 0 || f->size > len)
		fuzz_die("a frame of %zu bytes in %zu", f->size, len);
	if (f->len && (f->data < buf || f->data + f->len > buf + f->size))
		fuzz_die("frame data outside the frame");
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	if (size < 1)
		return 0;
	enum mb_framing framing = data[0] & 1 ? MB_FRAMING_TCP : MB_FRAMING_RTU;
	const uint8_t *p = data + 1;
	size_t n = size - 1;
	struct mb_frame f;

	if (framing == MB_FRAMING_RTU && (data[0] & 2) && n <= 254) {
		/* Exactly n + 2 bytes, so a read past the frame is caught. */
		uint8_t *frame = malloc(n + 2);
		if (!frame)
			return 0;
		memcpy(frame, p, n);
		uint16_t crc = mb_crc16(frame, n);
		frame[n] = (uint8_t)crc;
		frame[n + 1] = (uint8_t)(crc >> 8);
		if (mb_frame_decode(frame, n + 2, framing, &f) == 0) {
			check(frame, n + 2, &f);
			if (f.exception)
				(void)mb_exception_text(f.exception);
		}
		free(frame);
		return 0;
	}
	while (n > 0) {
		if (mb_frame_decode(p, n, framing, &f) < 0)
			break;
		check(p, n, &f);
		if (f.exception)
			(void)mb_exception_text(f.exception);
		p += f.size;
		n -= f.size;
	}
	return 0;
}
