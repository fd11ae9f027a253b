/* SPDX-License-Identifier: GPL-3.0-or-later */
/* CANopen frames and the CiA 402 state machine, without I/O. */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include <linux/can/error.h>

#include "protocol.h"

static uint32_t le32(const uint8_t *p)
{
	return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static void put_le32(uint8_t *p, uint32_t v)
{
	for (int i = 0; i < 4; i++)
		p[i] = (uint8_t)(v >> (8 * i));
}

/* Byte 0 of an SDO frame: the command specifier in bits 7..5; for an
 * initiate transfer, n (bytes not used) in 3..2, expedited 1, size 0. */
static int decode_sdo(const struct can_frame *f, bool request, struct canopen_sdo *s)
{
	uint8_t cmd = f->data[0], cs = cmd >> 5;

	if (f->can_dlc != 8)
		return -EPROTO;
	memset(s, 0, sizeof(*s));
	s->index = (uint16_t)(f->data[1] | f->data[2] << 8);
	s->subindex = f->data[3];
	if (cs == 4) {
		s->kind = SDO_ABORT;
		s->abort_code = le32(f->data + 4);
		return 0;
	}
	/* request: 1 initiate download, 2 initiate upload; response: 2
	 * initiate upload, 3 initiate download; the rest are segments and
	 * block transfers, which an expedited client never starts */
	if ((request && cs == 1) || (!request && cs == 2)) {
		s->kind = request ? SDO_DOWNLOAD : SDO_UPLOAD;
		if (!(cmd & 0x02)) {
			s->kind = SDO_UNSUPPORTED;
			return 0;
		}
		s->size = (cmd & 0x01) ? (uint8_t)(4 - ((cmd >> 2) & 3)) : 0;
		uint32_t v = le32(f->data + 4);
		s->value = s->size && s->size < 4 ? v & ((1u << (8 * s->size)) - 1) : v;
		return 0;
	}
	if ((request && cs == 2) || (!request && cs == 3)) {
		s->kind = request ? SDO_UPLOAD : SDO_DOWNLOAD;
		return 0;
	}
	if (cs <= 6) {
		s->kind = SDO_UNSUPPORTED;
		return 0;
	}
	return -EPROTO;
}

int canopen_decode(const struct can_frame *f, struct can_event *ev)
{
	memset(ev, 0, sizeof(*ev));
	if (f->can_dlc > 8)
		return -EPROTO;
	if (f->can_id & CAN_ERR_FLAG) {
		ev->type = CAN_EV_BUS_ERROR;
		ev->u.bus.class = f->can_id & CAN_ERR_MASK;
		memcpy(ev->u.bus.data, f->data, f->can_dlc);
		return 0;
	}
	/* extended ids and remote frames are not part of this subset */
	if (f->can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG))
		return 0;
	uint32_t id = f->can_id & CAN_SFF_MASK, fn = id & 0x780u;
	uint8_t node = (uint8_t)(id & 0x7fu);

	if (id == CANOPEN_COB_NMT) {
		if (f->can_dlc != 2 || f->data[1] > CANOPEN_NODE_MAX)
			return -EPROTO;
		ev->type = CAN_EV_NMT;
		ev->u.nmt.command = f->data[0];
		ev->u.nmt.node = f->data[1];
		return 0;
	}
	if (node == 0)
		return 0;       /* SYNC (0x080), TIME (0x100), ... */
	ev->node = node;
	switch (fn) {
	case CANOPEN_COB_EMCY:
		if (f->can_dlc != 8)
			return -EPROTO;
		ev->type = CAN_EV_EMCY;
		ev->u.emcy.code = (uint16_t)(f->data[0] | f->data[1] << 8);
		ev->u.emcy.reg = f->data[2];
		return 0;
	case CANOPEN_COB_SDO_TX:
	case CANOPEN_COB_SDO_RX:
		ev->type = fn == CANOPEN_COB_SDO_RX ? CAN_EV_SDO_REQUEST : CAN_EV_SDO_RESPONSE;
		return decode_sdo(f, fn == CANOPEN_COB_SDO_RX, &ev->u.sdo);
	case CANOPEN_COB_HEARTBEAT:
		if (f->can_dlc != 1)
			return -EPROTO;
		ev->type = CAN_EV_HEARTBEAT;
		ev->u.state = f->data[0] & 0x7f;        /* bit 7: node guarding toggle */
		return 0;
	default:
		ev->node = 0;
		return 0;       /* PDOs */
	}
}

static void frame(struct can_frame *f, uint32_t id, uint8_t dlc)
{
	memset(f, 0, sizeof(*f));
	f->can_id = id;
	f->can_dlc = dlc;
}

void canopen_nmt_frame(struct can_frame *f, uint8_t command, uint8_t node)
{
	frame(f, CANOPEN_COB_NMT, 2);
	f->data[0] = command;
	f->data[1] = node;
}

void canopen_heartbeat_frame(struct can_frame *f, uint8_t node, uint8_t state)
{
	frame(f, CANOPEN_COB_HEARTBEAT + node, 1);
	f->data[0] = state;
}

void canopen_emcy_frame(struct can_frame *f, uint8_t node, uint16_t code, uint8_t reg)
{
	frame(f, CANOPEN_COB_EMCY + node, 8);
	f->data[0] = (uint8_t)code;
	f->data[1] = (uint8_t)(code >> 8);
	f->data[2] = reg;
}

void canopen_sdo_frame(struct can_frame *f, uint8_t node, bool request,
		       enum canopen_sdo_kind kind, uint16_t index, uint8_t subindex,
		       uint32_t value, uint8_t size)
{
	bool carries = request ? kind == SDO_DOWNLOAD : kind == SDO_UPLOAD;
	uint8_t cs;

	frame(f, (request ? CANOPEN_COB_SDO_RX : CANOPEN_COB_SDO_TX) + node, 8);
	if (request)
		cs = kind == SDO_DOWNLOAD ? 1 : 2;
	else
		cs = kind == SDO_UPLOAD ? 2 : 3;
	f->data[0] = (uint8_t)(cs << 5);
	if (carries && size >= 1 && size <= 4) {
		f->data[0] |= (uint8_t)((4 - size) << 2 | 0x03);
		put_le32(f->data + 4, size < 4 ? value & ((1u << (8 * size)) - 1) : value);
	}
	f->data[1] = (uint8_t)index;
	f->data[2] = (uint8_t)(index >> 8);
	f->data[3] = subindex;
}

void canopen_sdo_abort_frame(struct can_frame *f, uint8_t node, bool request,
			     uint16_t index, uint8_t subindex, uint32_t code)
{
	frame(f, (request ? CANOPEN_COB_SDO_RX : CANOPEN_COB_SDO_TX) + node, 8);
	f->data[0] = 0x80;
	f->data[1] = (uint8_t)index;
	f->data[2] = (uint8_t)(index >> 8);
	f->data[3] = subindex;
	put_le32(f->data + 4, code);
}

/* ------------------------------------------------------------ texts */

static const struct {
	uint32_t code;
	const char *text;
} abort_codes[] = {
	{ 0x05030000, "toggle bit not alternated" },
	{ 0x05040000, "SDO protocol timed out" },
	{ 0x05040001, "client/server command specifier not valid or unknown" },
	{ 0x05040002, "invalid block size" },
	{ 0x05040003, "invalid sequence number" },
	{ 0x05040004, "CRC error" },
	{ 0x05040005, "out of memory" },
	{ 0x06010000, "unsupported access to an object" },
	{ 0x06010001, "attempt to read a write-only object" },
	{ 0x06010002, "attempt to write a read-only object" },
	{ 0x06020000, "object does not exist in the object dictionary" },
	{ 0x06040041, "object cannot be mapped to the PDO" },
	{ 0x06040042, "the objects to be mapped would exceed the PDO length" },
	{ 0x06040043, "general parameter incompatibility" },
	{ 0x06040047, "general internal incompatibility in the device" },
	{ 0x06060000, "access failed due to a hardware error" },
	{ 0x06070010, "data type does not match: length of service parameter does not match" },
	{ 0x06070012, "data type does not match: length of service parameter too high" },
	{ 0x06070013, "data type does not match: length of service parameter too low" },
	{ 0x06090011, "sub-index does not exist" },
	{ 0x06090030, "invalid value for parameter" },
	{ 0x06090031, "value of parameter written too high" },
	{ 0x06090032, "value of parameter written too low" },
	{ 0x06090036, "maximum value is less than minimum value" },
	{ 0x060a0023, "resource not available: SDO connection" },
	{ 0x08000000, "general error" },
	{ 0x08000020, "data cannot be transferred or stored to the application" },
	{ 0x08000021, "data cannot be transferred or stored to the application because of local control" },
	{ 0x08000022, "data cannot be transferred or stored to the application because of the present device state" },
	{ 0x08000023, "object dictionary dynamic generation failed or no object dictionary is present" },
	{ 0x08000024, "no data available" },
};

const char *canopen_abort_text(uint32_t code)
{
	for (size_t i = 0; i < sizeof(abort_codes) / sizeof(abort_codes[0]); i++)
		if (abort_codes[i].code == code)
			return abort_codes[i].text;
	return NULL;
}

const char *canopen_error_text(uint16_t code)
{
	static const struct {
		uint16_t code;
		const char *text;
	} known[] = {
		{ 0x0000, "no error" },
		{ 0x2310, "continuous over-current" },
		{ 0x2320, "short circuit at the outputs" },
		{ 0x3210, "DC link over-voltage" },
		{ 0x3220, "DC link under-voltage" },
		{ 0x4210, "excess temperature of the device" },
		{ 0x4310, "excess temperature of the drive" },
		{ 0x5441, "enable input inactive" },
		{ 0x7121, "motor blocked" },
		{ 0x7305, "incremental sensor fault" },
		{ 0x8110, "CAN overrun, objects lost" },
		{ 0x8120, "CAN in error passive mode" },
		{ 0x8130, "life guard or heartbeat error" },
		{ 0x8140, "recovered from bus-off" },
		{ 0x8611, "following error" },
		{ 0x8612, "reference limit" },
		{ 0xff00, "device specific" },
	};
	static const char *const classes[16] = {
		"error reset or no error", "generic error", "current", "voltage", "temperature",
		"device hardware", "device software", "additional modules", "monitoring",
		"external error", NULL, NULL, NULL, NULL, NULL, "additional functions",
	};

	for (size_t i = 0; i < sizeof(known) / sizeof(known[0]); i++)
		if (known[i].code == code)
			return known[i].text;
	if ((code & 0xff00) == 0xff00)
		return "device specific";
	const char *c = classes[code >> 12];
	return c ? c : "unknown error class";
}

const char *canopen_nmt_state_name(uint8_t state)
{
	switch (state) {
	case CANOPEN_STATE_BOOTUP: return "boot-up";
	case CANOPEN_STATE_STOPPED: return "stopped";
	case CANOPEN_STATE_OPERATIONAL: return "operational";
	case CANOPEN_STATE_PRE_OPERATIONAL: return "pre-operational";
	default: return "unknown";
	}
}

const char *canopen_bus_error_text(const struct can_event *ev, bool *fatal, char *buf,
				   size_t size)
{
	uint32_t c = ev->u.bus.class;
	uint8_t ctrl = ev->u.bus.data[1];

	*fatal = true;
	if (c & CAN_ERR_BUSOFF)
		snprintf(buf, size, "bus-off: the CAN controller left the bus after too many "
			 "errors (wiring, termination or bit rate)");
	else if ((c & CAN_ERR_CRTL) && (ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE)))
		snprintf(buf, size, "error passive: the CAN controller sees too many bus errors "
			 "(wiring, termination or bit rate)");
	else {
		*fatal = false;
		if (c & CAN_ERR_ACK)
			snprintf(buf, size, "no node acknowledges the frames (nothing connected, "
				 "powered off, or another bit rate)");
		else if (c & CAN_ERR_TX_TIMEOUT)
			snprintf(buf, size, "transmission timed out");
		else if (c & CAN_ERR_RESTARTED)
			snprintf(buf, size, "the CAN controller restarted");
		else if ((c & CAN_ERR_CRTL) && (ctrl & (CAN_ERR_CRTL_RX_OVERFLOW | CAN_ERR_CRTL_TX_OVERFLOW)))
			snprintf(buf, size, "the CAN controller's buffer overflowed");
		else
			snprintf(buf, size, "bus error (class 0x%03x)", (unsigned)c);
	}
	return buf;
}

/* ------------------------------------------------------- CiA 402 */

enum cia402_state cia402_decode_statusword(uint16_t sw)
{
	/* the state is bits 0-3, 5 and 6; which of them count depends on
	 * the state (CiA 402 table "statusword state coding") */
	switch (sw & 0x4f) {
	case 0x00: return CIA402_NOT_READY_TO_SWITCH_ON;
	case 0x40: return CIA402_SWITCH_ON_DISABLED;
	case 0x0f: return CIA402_FAULT_REACTION_ACTIVE;
	case 0x08: return CIA402_FAULT;
	default: break;
	}
	switch (sw & 0x6f) {
	case 0x21: return CIA402_READY_TO_SWITCH_ON;
	case 0x23: return CIA402_SWITCHED_ON;
	case 0x27: return CIA402_OPERATION_ENABLED;
	case 0x07: return CIA402_QUICK_STOP_ACTIVE;
	default: return CIA402_UNKNOWN;
	}
}

uint16_t cia402_statusword_bits(enum cia402_state s)
{
	/* with voltage enabled (bit 4) from ready to switch on on */
	switch (s) {
	case CIA402_NOT_READY_TO_SWITCH_ON: return 0x0000;
	case CIA402_SWITCH_ON_DISABLED: return 0x0040;
	case CIA402_READY_TO_SWITCH_ON: return 0x0031;
	case CIA402_SWITCHED_ON: return 0x0033;
	case CIA402_OPERATION_ENABLED: return 0x0037;
	case CIA402_QUICK_STOP_ACTIVE: return 0x0017;
	case CIA402_FAULT_REACTION_ACTIVE: return 0x001f;
	case CIA402_FAULT: return 0x0008;
	default: return 0x004f;
	}
}

const char *cia402_state_name(enum cia402_state s)
{
	switch (s) {
	case CIA402_NOT_READY_TO_SWITCH_ON: return "not ready to switch on";
	case CIA402_SWITCH_ON_DISABLED: return "switch on disabled";
	case CIA402_READY_TO_SWITCH_ON: return "ready to switch on";
	case CIA402_SWITCHED_ON: return "switched on";
	case CIA402_OPERATION_ENABLED: return "operation enabled";
	case CIA402_QUICK_STOP_ACTIVE: return "quick stop active";
	case CIA402_FAULT_REACTION_ACTIVE: return "fault reaction active";
	case CIA402_FAULT: return "fault";
	default: return "undefined state";
	}
}

enum cia402_state cia402_next_state(enum cia402_state s, uint16_t prev, uint16_t cw,
				    bool fault_cleared)
{
	bool disable_voltage = !(cw & 0x02);
	bool quick_stop = (cw & 0x06) == 0x02;
	bool shutdown = (cw & 0x87) == 0x06;
	bool switch_on = (cw & 0x8f) == 0x07;
	bool enable = (cw & 0x8f) == 0x0f;

	switch (s) {
	case CIA402_FAULT:
		/* transition 15 on the rising edge of bit 7 */
		if ((cw & 0x80) && !(prev & 0x80) && fault_cleared)
			return CIA402_SWITCH_ON_DISABLED;
		return s;
	case CIA402_SWITCH_ON_DISABLED:
		return shutdown ? CIA402_READY_TO_SWITCH_ON : s;
	case CIA402_READY_TO_SWITCH_ON:
		if (disable_voltage || quick_stop)
			return CIA402_SWITCH_ON_DISABLED;
		return switch_on ? CIA402_SWITCHED_ON : s;
	case CIA402_SWITCHED_ON:
		if (disable_voltage || quick_stop)
			return CIA402_SWITCH_ON_DISABLED;
		if (shutdown)
			return CIA402_READY_TO_SWITCH_ON;
		return enable ? CIA402_OPERATION_ENABLED : s;
	case CIA402_OPERATION_ENABLED:
		if (disable_voltage)
			return CIA402_SWITCH_ON_DISABLED;
		if (quick_stop)
			return CIA402_QUICK_STOP_ACTIVE;
		if (shutdown)
			return CIA402_READY_TO_SWITCH_ON;
		return switch_on ? CIA402_SWITCHED_ON : s;
	case CIA402_QUICK_STOP_ACTIVE:
		/* once stopped, only disable voltage leaves it (transition 12) */
		return disable_voltage ? CIA402_SWITCH_ON_DISABLED : s;
	default:
		return s;
	}
}
