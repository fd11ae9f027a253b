/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The CANopen subset a CiA 402 drive needs, as frames: NMT, heartbeat and
 * boot-up, EMCY, expedited SDO, SocketCAN error frames, and the CiA 402
 * statusword/controlword. Pure functions without I/O: the driver, the
 * simulated drive of the tests and a fuzz target share them. Internal.
 */
#ifndef ASPH_CAN_PROTOCOL_H
#define ASPH_CAN_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <linux/can.h>

/* COB-IDs of the predefined connection set (CiA 301), plus the node id */
#define CANOPEN_COB_NMT 0x000u
#define CANOPEN_COB_EMCY 0x080u
#define CANOPEN_COB_SDO_TX 0x580u       /* server (drive) to client */
#define CANOPEN_COB_SDO_RX 0x600u       /* client to server (drive) */
#define CANOPEN_COB_HEARTBEAT 0x700u
#define CANOPEN_NODE_MAX 127

enum canopen_nmt_command {
	CANOPEN_NMT_START = 0x01,
	CANOPEN_NMT_STOP = 0x02,
	CANOPEN_NMT_PRE_OPERATIONAL = 0x80,
	CANOPEN_NMT_RESET_NODE = 0x81,
	CANOPEN_NMT_RESET_COMMUNICATION = 0x82,
};

/* The state a heartbeat carries (0 is the boot-up message). */
enum canopen_nmt_state {
	CANOPEN_STATE_BOOTUP = 0x00,
	CANOPEN_STATE_STOPPED = 0x04,
	CANOPEN_STATE_OPERATIONAL = 0x05,
	CANOPEN_STATE_PRE_OPERATIONAL = 0x7f,
};

enum can_event_type {
	CAN_EV_OTHER = 0,       /* a valid frame this subset does not use */
	CAN_EV_NMT,             /* an NMT command (master to nodes) */
	CAN_EV_SDO_REQUEST,     /* client to server */
	CAN_EV_SDO_RESPONSE,    /* server to client */
	CAN_EV_EMCY,
	CAN_EV_HEARTBEAT,       /* state CANOPEN_STATE_BOOTUP: boot-up */
	CAN_EV_BUS_ERROR,       /* a SocketCAN error frame */
};

enum canopen_sdo_kind {
	SDO_UPLOAD,             /* request: read; response: the value */
	SDO_DOWNLOAD,           /* request: write the value; response: done */
	SDO_ABORT,
	SDO_UNSUPPORTED,        /* segmented or block transfer */
};

struct canopen_sdo {
	enum canopen_sdo_kind kind;
	uint16_t index;
	uint8_t subindex;
	uint8_t size;           /* bytes of value; 0 = not indicated */
	uint32_t value;         /* little-endian payload, zero-extended */
	uint32_t abort_code;    /* SDO_ABORT */
};

struct can_event {
	enum can_event_type type;
	uint8_t node;           /* 0 for NMT, bus errors and OTHER */
	union {
		struct {
			uint8_t command;        /* enum canopen_nmt_command */
			uint8_t node;           /* 0 = all */
		} nmt;
		struct canopen_sdo sdo;
		struct {
			uint16_t code;          /* 0 = error reset */
			uint8_t reg;            /* error register 0x1001 */
		} emcy;
		uint8_t state;                  /* heartbeat: enum canopen_nmt_state */
		struct {
			uint32_t class;         /* CAN_ERR_* of the id */
			uint8_t data[8];
		} bus;
	} u;
};

/*
 * Decodes one frame. -EPROTO for a frame that cannot be what its id says
 * (bad length, a remote frame where data is due, an SDO command specifier
 * that does not exist); ev is then undefined. Never reads past can_dlc,
 * which must be <= 8 (else -EPROTO).
 */
int canopen_decode(const struct can_frame *f, struct can_event *ev);

/* Encoders: each fills a whole frame. */
void canopen_nmt_frame(struct can_frame *f, uint8_t command, uint8_t node);
void canopen_heartbeat_frame(struct can_frame *f, uint8_t node, uint8_t state);
void canopen_emcy_frame(struct can_frame *f, uint8_t node, uint16_t code, uint8_t reg);
/* request: client to server; else server to client. size 1..4 for the
 * value of a download request or an upload response, else 0. */
void canopen_sdo_frame(struct can_frame *f, uint8_t node, bool request,
		       enum canopen_sdo_kind kind, uint16_t index, uint8_t subindex,
		       uint32_t value, uint8_t size);
void canopen_sdo_abort_frame(struct can_frame *f, uint8_t node, bool request,
			     uint16_t index, uint8_t subindex, uint32_t code);

/* The CiA 301 text of an SDO abort code ("object does not exist in the
 * object dictionary"), or NULL for a code outside the table. */
const char *canopen_abort_text(uint32_t code);
/* The CiA 301 / 402 meaning of an error code (0x603F, EMCY): a specific
 * text when known, else its class ("voltage", "temperature"). */
const char *canopen_error_text(uint16_t code);
const char *canopen_nmt_state_name(uint8_t state);
/* A readable account of an error frame into buf; returns buf. *fatal says
 * whether the bus is unusable (bus-off, error passive). */
const char *canopen_bus_error_text(const struct can_event *ev, bool *fatal,
				   char *buf, size_t size);

/* ------------------------------------------------------- CiA 402 */

#define CIA402_CONTROLWORD 0x6040
#define CIA402_STATUSWORD 0x6041
#define CIA402_ERROR_CODE 0x603f
#define CIA402_MODE 0x6060
#define CIA402_MODE_DISPLAY 0x6061
#define CIA402_POSITION_ACTUAL 0x6064
#define CIA402_TARGET_POSITION 0x607a
#define CIA402_PROFILE_VELOCITY 0x6081
#define CIA402_PROFILE_ACCELERATION 0x6083
#define CIA402_PROFILE_DECELERATION 0x6084
#define CIA402_HOMING_METHOD 0x6098
#define CIA402_HOMING_SPEEDS 0x6099     /* :01 switch search, :02 zero search */
#define CIA402_HOMING_ACCELERATION 0x609a
/* touch probe (CiA 402-2, IEC 61800-7-201): the drive latches its
 * position actual value on an edge of its touch probe input */
#define CIA402_TOUCH_PROBE_FUNCTION 0x60b8
#define CIA402_TOUCH_PROBE_STATUS 0x60b9
#define CIA402_TOUCH_PROBE1_POSITIVE 0x60ba     /* position at the rising edge */
#define CIA402_TOUCH_PROBE1_NEGATIVE 0x60bb     /* position at the falling edge */
#define CIA402_TOUCH_PROBE1_POS_COUNT 0x60d5    /* rising edges latched, modulo 2^16 */
#define CIA402_TOUCH_PROBE1_NEG_COUNT 0x60d6
#define CIA402_DIGITAL_OUTPUTS 0x60fe           /* :01 physical outputs, :02 bit mask */
#define CANOPEN_DEVICE_TYPE 0x1000
#define CANOPEN_HEARTBEAT_TIME 0x1017

#define CIA402_MODE_PROFILE_POSITION 1
#define CIA402_MODE_HOMING 6

/* controlword commands (CiA 402 table "device control commands") */
#define CIA402_CW_SHUTDOWN 0x0006
#define CIA402_CW_SWITCH_ON 0x0007
#define CIA402_CW_DISABLE_VOLTAGE 0x0000
#define CIA402_CW_QUICK_STOP 0x0002
#define CIA402_CW_ENABLE_OPERATION 0x000f
#define CIA402_CW_FAULT_RESET 0x0080
#define CIA402_CW_NEW_SET_POINT 0x0010  /* pp: bit 4; homing: start */
#define CIA402_CW_RELATIVE 0x0040       /* pp: bit 6 */
#define CIA402_CW_CHANGE_IMMEDIATELY 0x0020     /* pp: bit 5; 0: the set point is buffered */
#define CIA402_CW_CHANGE_ON_SET_POINT 0x0200    /* pp: bit 9; pass a buffered set point's
						 * target without stopping */

/* 0x60B8 touch probe function, touch probe 1 (bits 8..15: touch probe 2) */
#define CIA402_TP_ENABLE 0x0001                 /* bit 0: switched on */
#define CIA402_TP_CONTINUOUS 0x0002             /* bit 1: 0 first event only, 1 every event */
#define CIA402_TP_SOURCE_MASK 0x000c            /* bits 2-3: 00 touch probe 1 input,
						 * 01 encoder zero impulse, 10 per 0x60D0,
						 * 11 reserved */
#define CIA402_TP_POSITIVE_EDGE 0x0010          /* bit 4: latch on the rising edge */
#define CIA402_TP_NEGATIVE_EDGE 0x0020          /* bit 5: latch on the falling edge */
/* 0x60B9 touch probe status, touch probe 1 */
#define CIA402_TPS_ENABLED 0x0001               /* bit 0 */
#define CIA402_TPS_POSITIVE_STORED 0x0002       /* bit 1: 0x60BA holds a latch */
#define CIA402_TPS_NEGATIVE_STORED 0x0004       /* bit 2: 0x60BB holds a latch */

/* statusword bits beyond the state */
#define CIA402_SW_WARNING 0x0080
#define CIA402_SW_TARGET_REACHED 0x0400
#define CIA402_SW_INTERNAL_LIMIT 0x0800
#define CIA402_SW_BIT12 0x1000          /* pp: set-point acknowledge; homing: attained */
#define CIA402_SW_BIT13 0x2000          /* pp: following error; homing: error */

enum cia402_state {
	CIA402_NOT_READY_TO_SWITCH_ON = 0,
	CIA402_SWITCH_ON_DISABLED,
	CIA402_READY_TO_SWITCH_ON,
	CIA402_SWITCHED_ON,
	CIA402_OPERATION_ENABLED,
	CIA402_QUICK_STOP_ACTIVE,
	CIA402_FAULT_REACTION_ACTIVE,
	CIA402_FAULT,
	CIA402_UNKNOWN,         /* a bit pattern the profile does not define */
};

enum cia402_state cia402_decode_statusword(uint16_t sw);
/* The state bits of a state (for a drive that produces a statusword). */
uint16_t cia402_statusword_bits(enum cia402_state s);
const char *cia402_state_name(enum cia402_state s);

/* The state a controlword written in state s leads to (the transitions of
 * the CiA 402 state machine); prev is the controlword before (the fault
 * reset acts on the rising edge of bit 7). FAULT stays FAULT unless the
 * reset is allowed (fault_cleared). */
enum cia402_state cia402_next_state(enum cia402_state s, uint16_t prev, uint16_t cw,
				    bool fault_cleared);

#endif
