/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Simulated CiA 402 drives (and a CiA 404 sensor) on the far end of a
 * descriptor carrying one struct can_frame per message: each node has its
 * NMT state and heartbeat producer, an expedited SDO server with the CiA 301
 * abort codes, the CiA 402 state machine, profile position motion following
 * the set-point handshake (bits 4 and 12, target reached on bit 10, one
 * buffered set point), homing, the touch probe (0x60B8..0x60BB, 0x60D5,
 * 0x60D6) latching the encoder on the edges of a trigger line, and the
 * digital outputs (0x60FE) of which one may drive that line; with faults
 * to inject. can_sim_feed() handles one frame without a
 * thread (for fuzzing); can_sim_run() serves the descriptor on a thread.
 */
#ifndef ASPH_TEST_CAN_SIM_H
#define ASPH_TEST_CAN_SIM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "can/protocol.h"

#define CAN_SIM_MAX_NODES 4

struct can_sim;

struct can_sim_config {
	unsigned n_nodes;
	uint8_t nodes[CAN_SIM_MAX_NODES];
	uint32_t device_type[CAN_SIM_MAX_NODES];        /* 0: a CiA 402 drive */
	unsigned heartbeat_ms;          /* 0x1017 after a reset */
	/* motion runs at the profile velocity times this; 0: a set point is
	 * reached the moment it is accepted */
	double speed_factor;
	/* the bus's bit rate (bit/s): a request is taken, and answered, once
	 * it and its answer would have crossed a bus of this rate, each frame
	 * with its stuff bits (ISO 11898-1); 0: at once */
	double bitrate;
	int32_t home_switch[CAN_SIM_MAX_NODES];         /* counts, for methods != 35/37 */
	/* what each drive has of the touch probe (enum can_sim_touch_probe) */
	uint8_t touch_probe[CAN_SIM_MAX_NODES];
	/* the trigger line, wired to every drive's touch probe 1 input (and to
	 * the probe's trigger input), is driven by output trigger_bit of
	 * 0x60FE:01 of node trigger_node (0: by no output, only by
	 * can_sim_trigger()) */
	uint8_t trigger_node, trigger_bit;
};

enum can_sim_touch_probe {
	CAN_SIM_TP_FULL = 0,            /* 0x60B8..0x60BB and the edge counters */
	CAN_SIM_TP_NO_COUNTER,          /* without 0x60D5 / 0x60D6 */
	CAN_SIM_TP_NONE,                /* no touch probe: 0x60B8.. do not exist */
};

/* The sim owns fd. */
int can_sim_new(int fd, const struct can_sim_config *c, struct can_sim **out);
/* Serves fd on a thread until can_sim_free(). */
int can_sim_run(struct can_sim *s);
void can_sim_free(struct can_sim *s);
/* Handles one frame from the client (answers are written to fd). */
void can_sim_feed(struct can_sim *s, const struct can_frame *f);

/* ---- faults, from any thread */
/* The drive goes to fault with code (0x603F, and an EMCY); persistent: a
 * fault reset does not clear it. */
void can_sim_fault(struct can_sim *s, uint8_t node, uint16_t code, bool persistent);
/* The drive faults with code shortly after accepting its next set point. */
void can_sim_fault_on_move(struct can_sim *s, uint8_t node, uint16_t code);
/* No answers and no heartbeat at all. */
void can_sim_silence(struct can_sim *s, uint8_t node, bool silent);
void can_sim_heartbeat(struct can_sim *s, uint8_t node, bool on);
/* Every access to index:sub answers this abort code (0: normal again). */
void can_sim_abort(struct can_sim *s, uint8_t node, uint16_t index, uint8_t sub, uint32_t code);
enum can_sim_garble {
	CAN_SIM_GARBLE_NONE, CAN_SIM_SHORT, CAN_SIM_SEGMENTED, CAN_SIM_OTHER_INDEX,
	CAN_SIM_LONG,           /* the answer with 8 bytes more in its datagram */
};
/* The next SDO answer of node is malformed so. */
void can_sim_garble(struct can_sim *s, uint8_t node, enum can_sim_garble g);
/* The drive restarts by itself (power glitch, watchdog): boot-up message,
 * pre-operational, switch on disabled, home lost. */
void can_sim_reboot(struct can_sim *s, uint8_t node);
void can_sim_homing_error(struct can_sim *s, uint8_t node, bool on);
/* Sends an error frame (CAN_ERR_* class, data[1] controller status). */
void can_sim_error_frame(struct can_sim *s, uint32_t class, uint8_t ctrl);
/* The value of the probe object 0x7130:01. */
void can_sim_set_probe(struct can_sim *s, uint8_t node, int16_t value);
/* The link to the client is gone: each drive in operation enabled reacts as
 * to a lost master (abort connection option 0x6007 = quick stop). */
void can_sim_link_lost(struct can_sim *s);
/* Ends the injected faults: a drive in fault can be reset again, silent
 * nodes answer, no aborts, garbling, homing errors or pending faults. */
void can_sim_heal(struct can_sim *s);

/* Drives the trigger line from outside (the probe's own trigger). */
void can_sim_trigger(struct can_sim *s, bool level);
/* Each rise the trigger output gives bounces once (rise, fall, rise). */
void can_sim_bounce(struct can_sim *s, bool on);

/* An edge of the trigger line: its instant, and every drive's encoder
 * (position actual value) and set-point target at that instant. */
struct can_sim_edge {
	uint64_t t_ns;
	bool rising;
	int32_t encoder[CAN_SIM_MAX_NODES];     /* in the order of the config's nodes */
	int32_t goal[CAN_SIM_MAX_NODES];
};
/* The edges since the start (the first 8192 are kept; at most max into
 * out); returns how many there were in all. */
size_t can_sim_edges(struct can_sim *s, struct can_sim_edge *out, size_t max);

struct can_sim_node {
	enum cia402_state state;
	uint8_t nmt;
	int8_t mode;
	uint16_t controlword;
	int32_t position, target;
	uint32_t velocity;
	int8_t homing_method;
	unsigned quick_stops, fault_resets, set_points, homings, resets;
	unsigned disable_ops;   /* disable operation (0x07) while enabled */
	unsigned link_stops;    /* quick stops of can_sim_link_lost() */
	bool homed;
	bool moving;            /* a motion or homing under way */
	uint16_t tp_function, tp_status;        /* 0x60B8, 0x60B9 */
	int32_t tp_positive, tp_negative;       /* 0x60BA, 0x60BB */
	uint16_t tp_positive_count;             /* 0x60D5 */
	unsigned buffered_set_points;           /* set points taken into the buffer */
	/* CLOCK_MONOTONIC when it took its first set point in profile
	 * position mode (the first move after homing); 0: none yet */
	uint64_t first_set_point_ns;
	unsigned sdo_requests;                  /* SDO requests it answered */
};
/* A snapshot of node. */
void can_sim_get(struct can_sim *s, uint8_t node, struct can_sim_node *out);

#endif
