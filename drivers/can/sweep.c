/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Sweeps of the CAN stage (device.h). A sweep is profile position mode
 * with buffered set points: each axis gets the next target while it runs
 * to the one before (controlword bit 5 low: after the one in process; bit
 * 9: through its target without stopping). Statusword bit 12 stays up while a set point waits in the
 * buffer, so its fall says the axis passed the target before. Once every
 * axis passed point k, the trigger line fires (a digital output of one
 * drive, 0x60FE, wired to the probe's trigger input and every axis' touch
 * probe 1 input): each drive latches its encoder at that edge, and the
 * probe takes reading k there. docs/driver-can.md.
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "device.h"
#include "transport.h"
#include "util-time.h"

#define SWEEP_CW (CIA402_CW_ENABLE_OPERATION | CIA402_CW_CHANGE_ON_SET_POINT)

/* Waits until a's set-point buffer is free: the targets sent before the
 * last one are passed. */
static int buffer_free(struct asph_device *d, const struct axis *a, uint64_t deadline,
		       struct asph_error *err)
{
	for (;;) {
		uint16_t sw;
		int r = can_motion_sw(d, a, &sw, deadline, err);
		if (r < 0 || !(sw & CIA402_SW_BIT12))
			return r;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s: the sweep did not pass its set "
					      "points in time", can_drive_name(d, a));
		r = can_bus_idle(d->bus, POLL_MS, err);
		if (r < 0)
			return r;
	}
}

/* The set-point handshake of a buffered target. */
static int queue_set_point(struct asph_device *d, struct axis *a, int32_t target,
			   uint64_t deadline, struct asph_error *err)
{
	uint16_t sw;
	int r = can_write_obj(d, a->node, CIA402_TARGET_POSITION, 0, (uint32_t)target, 4, deadline, err);

	a->target_valid = false;
	if (r == 0)
		r = can_write_cw(d, a, SWEEP_CW | CIA402_CW_NEW_SET_POINT, deadline, err);
	while (r == 0) {
		r = can_motion_sw(d, a, &sw, deadline, err);
		if (r < 0 || (sw & CIA402_SW_BIT12))
			break;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s did not acknowledge the new set point "
					      "in time", can_drive_name(d, a));
		r = can_bus_idle(d->bus, POLL_MS, err);
	}
	if (r == 0)
		r = can_write_cw(d, a, SWEEP_CW, deadline, err);
	a->target = target;
	return r;
}

static int write_outputs(struct asph_device *d, uint32_t v, uint64_t deadline,
			 struct asph_error *err)
{
	int r = can_write_obj(d, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 1, v, 4, deadline, err);
	if (r == 0)
		d->outputs = v;
	return r;
}

/* Every axis in profile position mode; the touch probes armed; the
 * trigger output enabled (0x60FE:02) and low, the other outputs kept. */
static int sweep_prepare(struct asph_device *d, uint64_t deadline, struct asph_error *err)
{
	uint32_t mask, bit = 1u << d->trigger_bit;
	int r = 0;

	for (int k = 0; k < 3 && r == 0; k++)
		if (d->ax[k].node)
			r = can_axis_pp(d, &d->ax[k], deadline, err);
	for (int k = 0; k < 3 && r == 0 && can_latching(d); k++)
		if (d->ax[k].node)
			r = can_arm_touch_probe(d, &d->ax[k], deadline, err);
	if (r < 0 || !d->trigger_bit)
		return r;
	r = can_bus_sdo_upload(d->bus, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 2, &mask,
			       can_sdo_time(d, deadline), err);
	if (r == 0 && !(mask & bit))
		r = can_write_obj(d, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 2, mask | bit, 4, deadline,
				  err);
	if (r == 0)
		r = can_bus_sdo_upload(d->bus, d->trigger_node, CIA402_DIGITAL_OUTPUTS, 1,
				       &d->outputs, can_sdo_time(d, deadline), err);
	if (r == 0 && (d->outputs & bit))
		r = write_outputs(d, d->outputs & ~bit, deadline, err);
	return r;
}

/* Fires the trigger for point k and records where the axes were: latched
 * by the drives, else read back right after (at the instant of the reads). */
static int fire(struct asph_device *d, size_t k, uint64_t deadline, struct asph_error *err)
{
	struct asph_position_sample *s = &d->trace[d->trace_n];
	uint32_t bit = 1u << d->trigger_bit;
	bool latch = can_latching(d);
	int r = 0;

	memset(s, 0, sizeof(*s));
	s->trigger = (uint32_t)k;
	uint64_t t0 = now_monotonic_ns();
	if (d->trigger_bit) {
		r = write_outputs(d, d->outputs | bit, deadline, err);
		/* the edge is somewhere within the write's exchange */
		s->t_ns = t0 + (now_monotonic_ns() - t0) / 2;
		if (r == 0)
			r = write_outputs(d, d->outputs & ~bit, deadline, err);
		t0 = now_monotonic_ns();
	}
	for (int a = 0; a < 3 && r == 0; a++) {
		struct axis *ax = &d->ax[a];
		int32_t c = 0;
		uint32_t v;
		if (!ax->node)
			continue;
		if (latch) {
			r = can_read_latch(d, ax, &c, deadline, err);
		} else {
			r = can_bus_sdo_upload(d->bus, ax->node, CIA402_POSITION_ACTUAL, 0, &v,
					       can_sdo_time(d, deadline), err);
			c = (int32_t)v;
		}
		s->position[a] = c / ax->counts_per_mm;
	}
	if (r < 0)
		return r;
	s->source = latch ? ASPH_POSITION_LATCHED : ASPH_POSITION_READ_BACK;
	if (!latch)
		s->t_ns = t0 + (now_monotonic_ns() - t0) / 2;
	d->trace_n++;
	return 0;
}

static int sweep_run(struct asph_device *d, const double *p, size_t n, uint64_t deadline,
		     struct asph_error *err)
{
	int r = 0;

	for (size_t k = 0; k < n && r == 0; k++) {
		for (int a = 0; a < 3 && r == 0; a++) {
			struct axis *ax = &d->ax[a];
			if (!ax->node)
				continue;
			if (k == 0)
				r = buffer_free(d, ax, deadline, err);
			if (r == 0)
				r = queue_set_point(d, ax, counts(ax, p[3 * k + a]), deadline, err);
		}
		/* point k - 1 is passed once every buffer took point k */
		for (int a = 0; a < 3 && r == 0 && k > 0; a++)
			if (d->ax[a].node)
				r = buffer_free(d, &d->ax[a], deadline, err);
		if (r == 0 && k > 0)
			r = fire(d, k - 1, deadline, err);
	}
	for (int a = 0; a < 3 && r == 0; a++) {
		struct axis *ax = &d->ax[a];
		int there = 0;
		while (ax->node && r == 0 && there == 0) {
			there = can_axis_arrived(d, ax, deadline, err);
			r = there < 0 ? there : 0;
			if (r == 0 && there == 0)
				r = transport_ms_left(deadline) ? can_bus_idle(d->bus, POLL_MS, err)
					: asph_error_set(err, -ETIMEDOUT, "%s: the sweep did not "
							 "end in time", can_drive_name(d, ax));
		}
	}
	if (r == 0)
		r = fire(d, n - 1, deadline, err);
	return r;
}

int can_stage_sweep(struct asph_device *d, const double *p, size_t n, unsigned timeout_ms,
		    struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = can_check_stopped(d, err);

	d->trace_n = d->trace_read = 0;
	for (size_t k = 0; k < n && r == 0; k++)
		r = can_check_target(d, p + 3 * k, err);
	if (r < 0 || n == 0)
		return r;
	if (n > d->trace_cap) {
		struct asph_position_sample *t = realloc(d->trace, n * sizeof(*t));
		if (!t)
			return asph_error_set(err, -ENOMEM, "out of memory");
		d->trace = t;
		d->trace_cap = n;
	}
	r = sweep_prepare(d, deadline, err);
	if (r == 0)
		r = sweep_run(d, p, n, deadline, err);
	for (int a = 0; a < 3 && r == 0; a++) {
		struct axis *ax = &d->ax[a];
		ax->target_valid = ax->node != 0;
		if (ax->node && can_latching(d))
			r = can_write_tp(d, ax, 0, deadline, err);
	}
	return can_finish(d, r, "sweep", err);
}

/* The positions of the last sweep, one per trigger, each handed out once. */
int can_stage_trace(struct asph_device *d, struct asph_position_sample *out, size_t max,
		    size_t *n, unsigned timeout_ms, struct asph_error *err)
{
	size_t k = d->trace_n - d->trace_read;

	if (k > max)
		k = max;
	memcpy(out, d->trace + d->trace_read, k * sizeof(*out));
	d->trace_read += k;
	*n = k;
	return 0;
}
