/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A simulated USBTMC instrument for the USB driver's tests: the device
 * side of USBTMC (bulk headers with their bTag checks, the class requests
 * that abort and clear) and a small SCPI instrument behind it, the
 * driver's default profile: a stage (MOVE:ABS, HOME, POS?, STAT?) and a
 * probe whose MEAS:DIST? is the height of the simulated part (the mock
 * driver's, drivers/mock/protocol.h) under the stage, above the stage's z.
 * Where the stage is comes from the instrument's own moves, or from
 * world_xyz when another driver's stage carries the probe.
 */
#ifndef ASPH_TEST_USBTMC_SIM_H
#define ASPH_TEST_USBTMC_SIM_H

#include <stdbool.h>
#include <stdint.h>

#include "umockdev-usb.h"

struct mock_part;

enum usbtmc_sim_fault {
	SIM_FAULT_NONE = 0,
	SIM_FAULT_STALL_IN,     /* the reply's bulk-IN stalls (EPIPE) */
	SIM_FAULT_SHORT_READ,   /* the reply is cut to half of what it announces */
	SIM_FAULT_WRONG_TAG,    /* the reply carries another bTag */
	SIM_FAULT_UNPLUG,       /* the device is unplugged while the reply is read */
	SIM_FAULT_SILENT,       /* the reply never comes */
	SIM_FAULT_STUCK_OUT,    /* the n-th bulk-OUT transfer never completes */
};

struct usbtmc_sim {
	struct umu_usb *usb;
	struct mock_part *part;         /* NULL: MEAS:DIST? is unknown */
	const volatile double *world_xyz; /* NULL: the instrument's own stage */
	/* faults: the reply to the fault_at-th query from now on (1 = next) */
	enum usbtmc_sim_fault fault;
	unsigned fault_at;
	unsigned max_chunk;             /* a reply is split into IN transfers
					 * of at most this (0: as asked) */
	/* state */
	uint8_t last_tag;
	char msg[4096];
	size_t msg_len;
	char reply[4096];
	size_t reply_len, reply_sent;
	bool has_reply;
	bool request;                   /* a REQUEST_DEV_DEP_MSG_IN waits */
	uint8_t request_tag;
	uint32_t request_size;
	bool zlp;                       /* a short packet ends an abort */
	bool out_stuck;                 /* a bulk-OUT transfer hangs */
	uint8_t out_stuck_tag;
	int errors[8];
	unsigned n_errors;
	double pos[3];
	bool homed;
	int moving;                     /* status polls until it stands */
	/* what the host did */
	unsigned n_commands, n_queries, n_tag_errors, n_align_errors;
	unsigned n_clear, n_abort_in, n_abort_out, n_transfers_in;
};

extern const struct umu_usb_ops usbtmc_sim_ops;

/* The device of the tests: 1234:5678 serial SN4711 at /dev/bus/usb/001/005. */
extern const struct umu_usb_desc usbtmc_sim_desc;

/* Arms a fault for the n-th query from now (under umu_usb_lock). */
void usbtmc_sim_fault(struct usbtmc_sim *s, enum usbtmc_sim_fault f, unsigned n);

#endif
