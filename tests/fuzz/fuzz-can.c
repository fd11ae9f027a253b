/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * CANopen frame decoder of the CAN driver. The input is a sequence of
 * frames of 13 bytes each: the 32-bit CAN id (flags included), the DLC
 * (any value: the decoder must refuse more than 8) and 8 data bytes. Every
 * 16-bit word is also read as a CiA 402 statusword.
 */
#include <stdint.h>
#include <string.h>

#include "fuzz.h"
#include "protocol.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	for (size_t off = 0; off + 13 <= size; off += 13) {
		struct can_frame f;
		struct can_event ev;
		uint32_t id;

		memset(&f, 0, sizeof(f));
		memcpy(&id, data + off, 4);
		f.can_id = id;
		f.can_dlc = data[off + 4];
		memcpy(f.data, data + off + 5, 8);
		if (canopen_decode(&f, &ev) == 0) {
			if (f.can_dlc > 8)
				fuzz_die("decoded a frame with DLC %u", f.can_dlc);
			if (ev.node > CANOPEN_NODE_MAX)
				fuzz_die("decoded node %u", ev.node);
			if ((ev.type == CAN_EV_SDO_REQUEST || ev.type == CAN_EV_SDO_RESPONSE) &&
			    ev.u.sdo.kind == SDO_ABORT)
				(void)canopen_abort_text(ev.u.sdo.abort_code);
		}
	}
	for (size_t off = 0; off + 2 <= size; off += 2)
		(void)cia402_decode_statusword((uint16_t)(data[off] | data[off + 1] << 8));
	return 0;
}
