/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A CiA 402 drive of the CAN stage over SDO: its objects read and written
 * within an operation's deadline, its faults and their error codes, the
 * quick stop of every axis after one, and the state machine driven to
 * "operation enabled" (device.h).
 */
#include <errno.h>
#include <stdatomic.h>

#include "device.h"
#include "transport.h"

const char *const can_axis_names[3] = { "x", "y", "z" };

unsigned can_sdo_time(const struct asph_device *d, uint64_t deadline)
{
	unsigned left = transport_ms_left(deadline);
	return left < d->sdo_ms ? left : d->sdo_ms;
}

const char *can_drive_name(const struct asph_device *d, const struct axis *a)
{
	return can_bus_node_name(d->bus, a->node);
}

int can_read_u16(struct asph_device *d, uint8_t node, uint16_t index, uint16_t *v,
		 uint64_t deadline, struct asph_error *err)
{
	uint32_t x;
	int r = can_bus_sdo_upload(d->bus, node, index, 0, &x, can_sdo_time(d, deadline), err);
	*v = (uint16_t)x;
	return r;
}

int can_write_obj(struct asph_device *d, uint8_t node, uint16_t index, uint8_t sub,
		  uint32_t v, uint8_t size, uint64_t deadline, struct asph_error *err)
{
	return can_bus_sdo_download(d->bus, node, index, sub, v, size, can_sdo_time(d, deadline), err);
}

int can_write_cw(struct asph_device *d, const struct axis *a, uint16_t cw, uint64_t deadline,
		 struct asph_error *err)
{
	return can_write_obj(d, a->node, CIA402_CONTROLWORD, 0, cw, 2, deadline, err);
}

/* -EPROTO naming the drive's error code (0x603F, else its last EMCY). */
int can_drive_fault(struct asph_device *d, const struct axis *a, const char *why,
		    struct asph_error *err)
{
	uint16_t code = 0;

	if (can_read_u16(d, a->node, CIA402_ERROR_CODE, &code, transport_deadline(d->sdo_ms),
			 NULL) < 0 || code == 0)
		code = can_bus_last_emcy(d->bus, a->node);
	return asph_error_set(err, -EPROTO, "%s: drive fault, error code 0x%04x (%s)%s",
			      can_drive_name(d, a), code, canopen_error_text(code), why);
}

/* Quick stop to every drive still answering, after a fault. */
static void quick_stop_all(struct asph_device *d)
{
	uint8_t nodes[3];
	unsigned n = 0;

	for (int k = 0; k < 3; k++) {
		d->ax[k].target_valid = false;
		if (d->ax[k].node && !can_bus_node_lost(d->bus, d->ax[k].node))
			nodes[n++] = d->ax[k].node;
	}
	can_bus_sdo_download_all(d->bus, nodes, n, CIA402_CONTROLWORD, 0, CIA402_CW_QUICK_STOP, 2,
				 d->sdo_ms);
}

/* Ends a stage operation: a fault stops every axis; a stop keeps its
 * reason simple. */
int can_finish(struct asph_device *d, int r, const char *what, struct asph_error *err)
{
	if (r == -ECANCELED || atomic_load(&d->stopped))
		return asph_error_set(err, -ECANCELED, "%s stopped", what);
	if (r < 0)
		quick_stop_all(d);
	return r;
}

int can_check_stopped(struct asph_device *d, struct asph_error *err)
{
	if (atomic_load(&d->stopped))
		return asph_error_set(err, -ECANCELED, "stopped: close and reopen the instrument");
	return 0;
}

/* ------------------------------------------- the CiA 402 state machine */

/* The CiA 402 state machine driven to "operation enabled", one transition
 * per statusword read. */
int can_axis_enable(struct asph_device *d, struct axis *a, uint64_t deadline,
		    struct asph_error *err)
{
	bool reset_sent = false;

	for (;;) {
		uint16_t sw, cw = 0;
		bool wait = false;
		int r = can_read_u16(d, a->node, CIA402_STATUSWORD, &sw, deadline, err);
		if (r < 0)
			return r;
		enum cia402_state s = cia402_decode_statusword(sw);
		switch (s) {
		case CIA402_OPERATION_ENABLED:
			return 0;
		case CIA402_FAULT:
			if (!d->fault_reset)
				return can_drive_fault(d, a, "; fault_reset is off: clear it at the drive", err);
			if (reset_sent)
				return can_drive_fault(d, a, "; a fault reset did not clear it", err);
			reset_sent = true;
			/* the reset acts on the rising edge of bit 7 */
			r = can_write_cw(d, a, CIA402_CW_DISABLE_VOLTAGE, deadline, err);
			cw = CIA402_CW_FAULT_RESET;
			break;
		case CIA402_NOT_READY_TO_SWITCH_ON:
		case CIA402_FAULT_REACTION_ACTIVE:
			wait = true;
			break;
		case CIA402_SWITCH_ON_DISABLED:
			cw = CIA402_CW_SHUTDOWN;
			break;
		case CIA402_READY_TO_SWITCH_ON:
			cw = CIA402_CW_SWITCH_ON;
			break;
		case CIA402_SWITCHED_ON:
			cw = CIA402_CW_ENABLE_OPERATION;
			break;
		case CIA402_QUICK_STOP_ACTIVE:
			cw = CIA402_CW_DISABLE_VOLTAGE;
			break;
		default:
			return asph_error_set(err, -EPROTO, "%s: statusword 0x%04x is no CiA 402 state",
					      can_drive_name(d, a), sw);
		}
		if (r == 0)
			r = wait ? can_bus_idle(d->bus, 2, err) : can_write_cw(d, a, cw, deadline, err);
		if (r < 0)
			return r;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT,
					      "%s did not become ready for operation in time (stuck in "
					      "'%s')", can_drive_name(d, a), cia402_state_name(s));
	}
}

/* Reads the statusword of a drive that must stay enabled. */
int can_enabled_sw(struct asph_device *d, const struct axis *a, uint16_t *sw, uint64_t deadline,
		   struct asph_error *err)
{
	int r = can_read_u16(d, a->node, CIA402_STATUSWORD, sw, deadline, err);
	if (r < 0)
		return r;
	enum cia402_state s = cia402_decode_statusword(*sw);
	if (s == CIA402_FAULT || s == CIA402_FAULT_REACTION_ACTIVE)
		return can_drive_fault(d, a, "", err);
	if (s != CIA402_OPERATION_ENABLED)
		return asph_error_set(err, -EPROTO, "%s left operation enabled: it is in '%s'",
				      can_drive_name(d, a), cia402_state_name(s));
	return 0;
}
