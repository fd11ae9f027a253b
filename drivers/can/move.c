/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Moves of the CAN stage: profile position mode, one set point per axis
 * and its handshake, and the statusword of an axis under way (device.h). */
#include <errno.h>
#include <math.h>

#include "device.h"
#include "transport.h"

/* Profile position mode with the profile's speed and accelerations. */
int can_axis_pp(struct asph_device *d, struct axis *a, uint64_t deadline,
		struct asph_error *err)
{
	uint32_t v = (uint32_t)fmin(4294967295.0, fmax(1, round(d->speed * a->counts_per_mm)));
	uint32_t acc = (uint32_t)fmin(4294967295.0, fmax(1, round(d->acceleration * a->counts_per_mm)));

	if (a->pp)
		return 0;
	int r = can_write_obj(d, a->node, CIA402_MODE, 0, CIA402_MODE_PROFILE_POSITION, 1, deadline,
			      err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_PROFILE_VELOCITY, 0, v, 4, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_PROFILE_ACCELERATION, 0, acc, 4, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_PROFILE_DECELERATION, 0, acc, 4, deadline, err);
	a->pp = r == 0;
	return r;
}

int can_check_target(const struct asph_device *d, const double *t, struct asph_error *err)
{
	for (int k = 0; k < 3; k++) {
		const struct axis *a = &d->ax[k];
		if (!a->node && t[k] != 0)
			return asph_error_set(err, -ERANGE, "axis %s has no drive (%s_node=0): it stays at 0",
					      can_axis_names[k], can_axis_names[k]);
		if (a->node && !(t[k] >= a->min && t[k] <= a->max))
			return asph_error_set(err, -ERANGE, "axis %s: target %.6f mm is outside %.6g .. %.6g",
					      can_axis_names[k], t[k], a->min, a->max);
		if (a->node && !a->homed)
			return asph_error_set(err, -EPROTO, "axis %s is not homed", can_axis_names[k]);
	}
	return 0;
}

/*
 * The set-point handshake of profile position mode: the new target, bit 4
 * up; the drive acknowledges with bit 12; bit 4 down; the drive drops bit
 * 12 and raises bit 10 when it is there.
 */
static int send_set_point(struct asph_device *d, struct axis *a, int32_t target,
			  uint64_t deadline, struct asph_error *err)
{
	uint16_t sw;
	int r = can_axis_pp(d, a, deadline, err);

	a->target_valid = false;
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_TARGET_POSITION, 0, (uint32_t)target, 4, deadline, err);
	if (r == 0)
		r = can_write_cw(d, a, CIA402_CW_ENABLE_OPERATION | CIA402_CW_NEW_SET_POINT, deadline, err);
	if (r < 0)
		return r;
	for (;;) {
		r = can_enabled_sw(d, a, &sw, deadline, err);
		if (r < 0)
			return r;
		if (sw & CIA402_SW_BIT12)
			break;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s did not acknowledge the new set point "
					      "in time", can_drive_name(d, a));
		r = can_bus_idle(d->bus, POLL_MS, err);
		if (r < 0)
			return r;
	}
	a->target = target;
	a->target_valid = true;
	return can_write_cw(d, a, CIA402_CW_ENABLE_OPERATION, deadline, err);
}

/* The statusword of an axis in motion, which must not have a following
 * error or a limit. */
int can_motion_sw(struct asph_device *d, const struct axis *a, uint16_t *out,
		  uint64_t deadline, struct asph_error *err)
{
	uint16_t sw;
	int r = can_enabled_sw(d, a, &sw, deadline, err);

	*out = sw;
	if (r < 0)
		return r;
	if (sw & CIA402_SW_BIT13)
		return asph_error_set(err, -EPROTO, "%s: following error: the axis lags its profile "
				      "(blocked, or speed/acceleration too high)", can_drive_name(d, a));
	if (sw & CIA402_SW_INTERNAL_LIMIT)
		return asph_error_set(err, -ERANGE, "%s: internal limit active (a limit switch or the "
				      "drive's software limits)", can_drive_name(d, a));
	return 0;
}

/* 1 when the axis is at its target, 0 while it moves. */
int can_axis_arrived(struct asph_device *d, const struct axis *a, uint64_t deadline,
		     struct asph_error *err)
{
	uint16_t sw;
	int r = can_motion_sw(d, a, &sw, deadline, err);

	if (r < 0)
		return r;
	return (sw & CIA402_SW_TARGET_REACHED) && !(sw & CIA402_SW_BIT12);
}

int can_stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		   struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	bool moving[3] = { false };
	int r = can_check_stopped(d, err);

	if (r == 0)
		r = can_check_target(d, t, err);
	if (r < 0)
		return r;
	for (int k = 0; k < 3 && r == 0; k++) {
		struct axis *a = &d->ax[k];
		int32_t c = counts(a, t[k]);
		/* an axis already sent there keeps still */
		if (a->node && !(a->target_valid && a->target == c)) {
			moving[k] = true;
			r = send_set_point(d, a, c, deadline, err);
		}
	}
	while (r == 0) {
		bool all = true;
		for (int k = 0; k < 3 && r == 0; k++) {
			if (!moving[k])
				continue;
			int there = can_axis_arrived(d, &d->ax[k], deadline, err);
			r = there < 0 ? there : 0;
			moving[k] = there == 0;
			all = all && there == 1;
		}
		if (r < 0 || all)
			break;
		r = transport_ms_left(deadline) ? can_bus_idle(d->bus, POLL_MS, err)
			: asph_error_set(err, -ETIMEDOUT, "move did not finish within %u ms", timeout_ms);
	}
	return can_finish(d, r, "motion", err);
}
