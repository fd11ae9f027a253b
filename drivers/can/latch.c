/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The drives' touch probes (0x60B8): whether each axis' drive has one, armed
 * before a sweep, and the position each latched on the probe's trigger
 * (device.h).
 */
#include <errno.h>

#include "device.h"

#define ABORT_NO_OBJECT 0x06020000u

/* Whether a's drive has a touch probe (0x60B8), and its edge counter
 * (0x60D5) for the continuous mode: an SDO abort "object does not exist"
 * says it has not. */
int can_detect_touch_probe(struct asph_device *d, struct axis *a, uint64_t deadline,
			   struct asph_error *err)
{
	uint32_t v;

	a->tp = TP_NONE;
	if (d->touch_probe == TOUCH_PROBE_OFF || !d->trigger_bit)
		return 0;
	int r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE_FUNCTION, 0, &v,
				   can_sdo_time(d, deadline), err);
	if (r == -EPROTO && can_bus_last_abort(d->bus) == ABORT_NO_OBJECT) {
		if (d->touch_probe == TOUCH_PROBE_ON)
			return asph_error_set(err, -EPROTO, "%s has no touch probe (0x60B8 does not "
					      "exist): touch_probe=on needs one in every axis' drive",
					      can_drive_name(d, a));
		return 0;
	}
	if (r < 0)
		return r;
	r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POS_COUNT, 0, &v,
			       can_sdo_time(d, deadline), err);
	if (r == -EPROTO && can_bus_last_abort(d->bus) == ABORT_NO_OBJECT) {
		a->tp = TP_SINGLE;
		return 0;
	}
	a->tp = TP_CONTINUOUS;
	return r;
}

/* Every axis latches: positions during sweeps are the drives' own. */
bool can_latching(const struct asph_device *d)
{
	for (int k = 0; k < 3; k++)
		if (d->ax[k].node && d->ax[k].tp == TP_NONE)
			return false;
	return d->trigger_bit != 0;
}

int can_write_tp(struct asph_device *d, const struct axis *a, uint16_t f, uint64_t deadline,
		 struct asph_error *err)
{
	return can_write_obj(d, a->node, CIA402_TOUCH_PROBE_FUNCTION, 0, f, 2, deadline, err);
}

/* Touch probe 1 on the rising edge of its input, switched off first (a
 * drive refuses a change of mode while it is on); every edge in the
 * continuous mode, else the first one after each arming. */
int can_arm_touch_probe(struct asph_device *d, struct axis *a, uint64_t deadline,
			struct asph_error *err)
{
	uint16_t f = CIA402_TP_ENABLE | CIA402_TP_POSITIVE_EDGE, st = 0;
	uint32_t count;

	if (a->tp == TP_CONTINUOUS)
		f |= CIA402_TP_CONTINUOUS;
	int r = can_write_tp(d, a, 0, deadline, err);
	if (r == 0)
		r = can_write_tp(d, a, f, deadline, err);
	if (r == 0)
		r = can_read_u16(d, a->node, CIA402_TOUCH_PROBE_STATUS, &st, deadline, err);
	if (r == 0 && (!(st & CIA402_TPS_ENABLED) || (st & CIA402_TPS_POSITIVE_STORED)))
		return asph_error_set(err, -EPROTO, "%s: the touch probe did not arm (0x60B9 = "
				      "0x%04x after 0x60B8 = 0x%04x)", can_drive_name(d, a), st, f);
	if (r == 0 && a->tp == TP_CONTINUOUS) {
		r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POS_COUNT, 0, &count,
				       can_sdo_time(d, deadline), err);
		a->tp_count = (uint16_t)count;
	}
	return r;
}

/* The position a's drive latched on the trigger just fired, counts. */
int can_read_latch(struct asph_device *d, struct axis *a, int32_t *at, uint64_t deadline,
		   struct asph_error *err)
{
	uint32_t v;
	uint16_t st, edges = 1;
	int r;

	if (a->tp == TP_CONTINUOUS) {
		r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POS_COUNT, 0, &v,
				       can_sdo_time(d, deadline), err);
		if (r < 0)
			return r;
		edges = (uint16_t)(v - a->tp_count);
		a->tp_count = (uint16_t)v;
	} else {
		r = can_read_u16(d, a->node, CIA402_TOUCH_PROBE_STATUS, &st, deadline, err);
		if (r < 0)
			return r;
		edges = (st & CIA402_TPS_POSITIVE_STORED) != 0;
	}
	if (edges == 0)
		return asph_error_set(err, -EPROTO, "%s: the touch probe latched no edge of the "
				      "trigger: check the wiring of output %u of node %u to its touch "
				      "probe 1 input", can_drive_name(d, a), d->trigger_bit, d->trigger_node);
	if (edges > 1)
		return asph_error_set(err, -EPROTO, "%s: the touch probe latched %u edges for one "
				      "trigger (a bouncing or noisy trigger line)", can_drive_name(d, a), edges);
	r = can_bus_sdo_upload(d->bus, a->node, CIA402_TOUCH_PROBE1_POSITIVE, 0, &v,
			       can_sdo_time(d, deadline), err);
	*at = (int32_t)v;
	/* first-event mode: a rising edge of bit 4 arms it again */
	if (r == 0 && a->tp == TP_SINGLE)
		r = can_write_tp(d, a, CIA402_TP_ENABLE, deadline, err);
	if (r == 0 && a->tp == TP_SINGLE)
		r = can_write_tp(d, a, CIA402_TP_ENABLE | CIA402_TP_POSITIVE_EDGE, deadline, err);
	return r;
}
