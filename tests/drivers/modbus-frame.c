/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Modbus frames of the simulator and the fuzz target's peer
 * (modbus-frame.h). */
#include <errno.h>
#include <string.h>

#include "modbus-frame.h"

uint16_t mbsim_crc16(const uint8_t *buf, size_t len)
{
	uint16_t crc = 0xffff;

	for (size_t i = 0; i < len; i++) {
		crc ^= buf[i];
		for (int b = 0; b < 8; b++)
			crc = (crc & 1) ? (uint16_t)((crc >> 1) ^ 0xa001) : (uint16_t)(crc >> 1);
	}
	return crc;
}

/* Bytes of the request in buf so far, 0 while incomplete. */
int mbsim_rtu_request_length(const uint8_t *buf, int got)
{
	if (got < 2)
		return 0;
	int len = buf[1] == 16 || buf[1] == 15 ? (got < 7 ? 0 : 9 + buf[6]) : 8;
	return len && got >= len ? len : 0;
}

/* Checks the PDU (function code onwards) of a response. */
static int decode_pdu(const uint8_t *pdu, size_t n, struct mbsim_frame *f)
{
	if (n < 2)
		return -EBADMSG;
	f->function = pdu[0] & 0x7f;
	if (pdu[0] & 0x80) {
		if (n != 2 || pdu[1] == 0)
			return -EPROTO;
		f->exception = pdu[1];
		f->data = pdu + 1;
		f->len = 1;
		return 0;
	}
	switch (f->function) {
	case 1: case 2: case 3: case 4: case 23:
		/* byte count, then that many bytes (whole registers for 3, 4, 23) */
		if (pdu[1] + 2u != n || pdu[1] == 0 ||
		    (f->function >= 3 && pdu[1] % 2))
			return -EPROTO;
		f->data = pdu + 2;
		f->len = pdu[1];
		return 0;
	case 5: case 6: case 15: case 16:
		/* the echoed address and value (or quantity) */
		if (n != 5)
			return -EPROTO;
		f->data = pdu + 1;
		f->len = 4;
		return 0;
	default:
		return -ENOTSUP;
	}
}

int mbsim_frame_decode(const uint8_t *buf, size_t len, enum mb_framing framing,
		       struct mbsim_frame *out)
{
	struct mbsim_frame f = { 0 };
	int r;

	memset(out, 0, sizeof(*out));
	if (!buf)
		return -EBADMSG;
	if (framing == MB_FRAMING_RTU) {
		if (len < 5 || len > 256)
			return -EBADMSG;
		uint16_t crc = (uint16_t)(buf[len - 2] | buf[len - 1] << 8);
		if (mbsim_crc16(buf, len - 2) != crc)
			return -EBADMSG;
		f.unit = buf[0];
		f.size = len;
		r = decode_pdu(buf + 1, len - 3, &f);
	} else {
		if (len < 9)
			return -EBADMSG;
		size_t follow = (size_t)(buf[4] << 8 | buf[5]);
		/* protocol id 0; the length counts the unit and the PDU */
		if ((buf[2] | buf[3]) != 0 || follow < 3 || follow > 254 || 6 + follow > len)
			return -EBADMSG;
		f.transaction = (uint16_t)(buf[0] << 8 | buf[1]);
		f.unit = buf[6];
		f.size = 6 + follow;
		r = decode_pdu(buf + 7, follow - 1, &f);
	}
	if (r == 0)
		*out = f;
	return r;
}
