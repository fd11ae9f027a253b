/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Homing of the CAN stage: each axis' drive in homing mode (0x6098),
 * z first (device.h). */
#include <errno.h>
#include <math.h>

#include "device.h"
#include "transport.h"

/* Homing order: z first, so the probe leaves the part before x and y move. */
static const int home_order[3] = { 2, 0, 1 };

static int axis_home(struct asph_device *d, struct axis *a, uint64_t deadline,
		     struct asph_error *err)
{
	uint32_t v = (uint32_t)fmax(1, llround(d->homing_speed * a->counts_per_mm));
	uint32_t acc = (uint32_t)fmin(4294967295.0, fmax(1, round(d->acceleration * a->counts_per_mm)));
	uint16_t sw = 0;

	a->homed = a->pp = a->target_valid = false;
	int r = can_axis_enable(d, a, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_MODE, 0, CIA402_MODE_HOMING, 1, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_HOMING_METHOD, 0, (uint32_t)d->homing_method & 0xff,
				  1, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_HOMING_SPEEDS, 1, v, 4, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_HOMING_SPEEDS, 2, v / 10 ? v / 10 : 1, 4, deadline, err);
	if (r == 0)
		r = can_write_obj(d, a->node, CIA402_HOMING_ACCELERATION, 0, acc, 4, deadline, err);
	/* homing starts on the rising edge of bit 4 */
	if (r == 0)
		r = can_write_cw(d, a, CIA402_CW_ENABLE_OPERATION, deadline, err);
	if (r == 0)
		r = can_write_cw(d, a, CIA402_CW_ENABLE_OPERATION | CIA402_CW_NEW_SET_POINT, deadline, err);
	while (r == 0) {
		r = can_enabled_sw(d, a, &sw, deadline, err);
		if (r < 0)
			break;
		if (sw & CIA402_SW_BIT13)
			return asph_error_set(err, -EPROTO, "%s: homing error (method %d): check the "
					      "home switch and homing_method", can_drive_name(d, a), d->homing_method);
		if ((sw & CIA402_SW_BIT12) && (sw & CIA402_SW_TARGET_REACHED))
			break;
		if (transport_ms_left(deadline) == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s: homing did not finish in time",
					      can_drive_name(d, a));
		r = can_bus_idle(d->bus, 1, err);
	}
	if (r == 0)
		r = can_write_cw(d, a, CIA402_CW_ENABLE_OPERATION, deadline, err);
	a->homed = r == 0;
	return r;
}

int can_stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int r = can_check_stopped(d, err);

	for (int i = 0; i < 3 && r == 0; i++)
		if (d->ax[home_order[i]].node)
			r = axis_home(d, &d->ax[home_order[i]], deadline, err);
	return can_finish(d, r, "homing", err);
}
