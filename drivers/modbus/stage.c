/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The sequences of a Modbus stage: connect, home, move, stop, alarms. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "stage.h"
#include "transport.h"
#include "util-time.h"

/*
 * Oriental Motor AZ series, "direct data operation" (the register numbers
 * and the factory assignment of the remote I/O bits are in
 * docs/driver-modbus.md with the manual they come from).
 */
const struct stage_map stage_profiles[] = {
	{
		.wide = true, .order = MB_HIGH_WORD_FIRST, .start_bit = false,
		.reg_data = 0x0058, .reg_command = 0x007c, .reg_status = 0x007e,
		.reg_position = 0x0120, .reg_alarm = 0x0080, .operation_type = 1,
		.bit_start = 3, .bit_zhome = 4, .bit_stop = 5, .bit_alm_rst = 7,
		.bit_ready = 5, .bit_busy = 13, .bit_in_pos = 14, .bit_alm = 7,
		.bit_home_end = 4,
	},
};

enum { N_DATA = 8, DATA_POSITION = 2, DATA_TRIGGER = 7 };

static const char *axis_name(const struct stage *s, int k)
{
	return s->info.axes[k].name;
}

static int words(const struct stage *s)
{
	return s->map.wide ? 2 : 1;
}

static unsigned ms_left(uint64_t deadline)
{
	return transport_ms_left(deadline);
}

static int read_value(struct stage *s, int k, int reg, uint32_t *v, uint64_t deadline,
		      struct asph_error *err)
{
	uint16_t w[2] = { 0, 0 };
	int r = mb_read_registers(s->bus, s->axes[k].unit, false, reg, words(s), w,
				  ms_left(deadline), err);
	if (r == 0)
		*v = s->map.wide ? mb_get32(w, s->map.order) : w[0];
	return r;
}

static int write_command(struct stage *s, int k, uint32_t bits, uint64_t deadline,
			 struct asph_error *err)
{
	uint16_t w[2] = { 0, 0 };

	if (s->map.wide)
		mb_put32(w, bits, s->map.order);
	else
		w[0] = (uint16_t)bits;
	return mb_write_registers(s->bus, s->axes[k].unit, s->map.reg_command, words(s), w,
				  ms_left(deadline), err);
}

static bool bit(uint32_t v, int b)
{
	return v >> b & 1;
}

static int read_feedback(struct stage *s, int k, int64_t *counts, uint64_t deadline,
			 struct asph_error *err)
{
	uint32_t v = 0;
	int r = read_value(s, k, s->map.reg_position, &v, deadline, err);

	if (r == 0)
		*counts = s->map.wide ? (int32_t)v : (int16_t)v;
	return r;
}

/* The drive of axis k reports an alarm: its code as the reason. */
static int alarm_fault(struct stage *s, int k, uint64_t deadline, struct asph_error *err)
{
	uint32_t code = 0;

	if (read_value(s, k, s->map.reg_alarm, &code, deadline, NULL) < 0)
		return asph_error_set(err, -EPROTO, "axis %s (unit %d): drive alarm (code not readable)",
				      axis_name(s, k), s->axes[k].unit);
	return asph_error_set(err, -EPROTO, "axis %s (unit %d): drive alarm, code 0x%02x "
			      "(the drive's alarm list says what it means; reset with ALM-RST)",
			      axis_name(s, k), s->axes[k].unit, (unsigned)code);
}

/* Best effort after a fault or a stop: STOP to every drive that answers,
 * released again unless latch (a stopped device takes no further motion). */
static void stop_all(struct stage *s, bool latch)
{
	for (int k = 0; k < 3; k++) {
		s->axes[k].known = false;
		uint64_t deadline = now_monotonic_ns();
		if (write_command(s, k, 1u << s->map.bit_stop, deadline, NULL) == 0 && !latch)
			write_command(s, k, 0, deadline, NULL);
	}
}

/* ------------------------------------------------------------- waits */

enum goal { GOAL_MOVED, GOAL_HOMED };

static int settled(struct stage *s, int k, uint32_t st, enum goal g, bool *done,
		   uint64_t deadline, struct asph_error *err)
{
	const struct stage_map *m = &s->map;
	int64_t pos = 0;

	*done = false;
	if (!bit(st, m->bit_ready) || bit(st, m->bit_busy))
		return 0;
	if (g == GOAL_HOMED) {
		*done = bit(st, m->bit_home_end);
		return 0;
	}
	if (!bit(st, m->bit_in_pos))
		return 0;
	int r = read_feedback(s, k, &pos, deadline, err);
	if (r == 0)
		*done = llabs(pos - s->axes[k].target) <= s->window;
	return r;
}

/*
 * A hint when the feedback position of axis k is far outside the travel
 * while the same registers read in the other word order are inside it:
 * the configured word_order is likely wrong, and so homing or a move
 * never seems to end. Empty when there is nothing to say.
 */
static void word_order_hint(struct stage *s, int k, uint64_t deadline, char *hint, size_t size)
{
	const struct asph_axis_info *a = &s->info.axes[k];
	uint16_t w[2] = { 0, 0 };
	double span = a->max - a->min, c = s->axes[k].counts_per_unit;

	hint[0] = '\0';
	if (!s->map.wide || mb_read_registers(s->bus, s->axes[k].unit, false, s->map.reg_position,
					      2, w, ms_left(deadline), NULL) < 0)
		return;
	enum mb_word_order other = s->map.order == MB_HIGH_WORD_FIRST ? MB_LOW_WORD_FIRST
								       : MB_HIGH_WORD_FIRST;
	double as_set = (int32_t)mb_get32(w, s->map.order) / c;
	double swapped = (int32_t)mb_get32(w, other) / c;
	bool inside = swapped >= a->min - span && swapped <= a->max + span;
	if ((as_set < a->min - span || as_set > a->max + span) && inside)
		snprintf(hint, size, "; its position reads %.6g %s, far outside the travel, and "
			 "%.6g %s with the words swapped: check word_order (now %s)",
			 as_set, a->unit, swapped, a->unit,
			 s->map.order == MB_HIGH_WORD_FIRST ? "high-first" : "low-first");
}

/* The end of a wait kept for reading the position a timeout message
 * reports on: a twentieth of the timeout, at most 50 ms. */
static unsigned hint_reserve(unsigned timeout_ms)
{
	return timeout_ms / 20 < 50 ? timeout_ms / 20 : 50;
}

static int waited_out(struct stage *s, unsigned mask, enum goal g, uint64_t deadline,
		      unsigned timeout_ms, struct asph_error *err)
{
	char hint[192];

	for (int k = 0; k < 3; k++) {
		if (!(mask >> k & 1))
			continue;
		word_order_hint(s, k, deadline, hint, sizeof(hint));
		return asph_error_set(err, -ETIMEDOUT, "axis %s (unit %d): %s within %u ms%s",
				      axis_name(s, k), s->axes[k].unit,
				      g == GOAL_HOMED ? "homing did not finish"
						      : "did not reach its target",
				      timeout_ms, hint);
	}
	return 0;
}

static void nap(unsigned ms, uint64_t deadline)
{
	unsigned left = ms_left(deadline);
	if (ms > left)
		ms = left;
	msleep(ms);
}

/*
 * Polls the axes of mask until each reaches goal. With ack, each axis
 * first has to acknowledge the command bit it was given (READY off, BUSY
 * on, or the goal reached already), which then is released.
 */
static int wait_axes(struct stage *s, unsigned mask, enum goal g, bool ack, uint64_t deadline,
		     unsigned timeout_ms, struct asph_error *err)
{
	unsigned acked = ack ? 0 : mask;

	for (;;) {
		for (int k = 0; k < 3; k++) {
			uint32_t st = 0;
			bool done;
			if (!(mask >> k & 1))
				continue;
			int r = read_value(s, k, s->map.reg_status, &st, deadline, err);
			if (r < 0)
				return r;
			if (bit(st, s->map.bit_alm))
				return alarm_fault(s, k, deadline, err);
			r = settled(s, k, st, g, &done, deadline, err);
			if (r < 0)
				return r;
			bool acknowledged = done || !bit(st, s->map.bit_ready) ||
					    bit(st, s->map.bit_busy);
			if (!(acked >> k & 1) && acknowledged) {
				r = write_command(s, k, 0, deadline, err);
				if (r < 0)
					return r;
				acked |= 1u << k;
			}
			if (done && (acked >> k & 1))
				mask &= ~(1u << k);
		}
		if (!mask)
			return 0;
		if (atomic_load(s->stop))
			return asph_error_set(err, -ECANCELED, "motion stopped");
		if (ms_left(deadline) <= hint_reserve(timeout_ms))
			return waited_out(s, mask, g, deadline, timeout_ms, err);
		nap(s->poll_ms, deadline);
	}
}

/* ------------------------------------------------------- operations */

/* Ends an operation: a fault stops every drive; a stop latches. */
static int finish(struct stage *s, int r)
{
	if (r < 0)
		stop_all(s, r == -ECANCELED || atomic_load(s->stop));
	return r;
}

int stage_connect(struct stage *s, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	bool homed = true;

	for (int k = 0; k < 3; k++) {
		uint32_t st = 0;
		int r = read_value(s, k, s->map.reg_status, &st, deadline, err);
		/* take over the command bits: nothing left set from before */
		if (r == 0)
			r = write_command(s, k, 0, deadline, err);
		if (r < 0)
			return r;
		homed = homed && bit(st, s->map.bit_home_end);
	}
	/* a drive with an absolute encoder keeps its home over a power cycle */
	s->homed = homed;
	return 0;
}

static int clear_alarms(struct stage *s, uint64_t deadline, struct asph_error *err)
{
	for (int k = 0; k < 3; k++) {
		uint32_t st = 0;
		int r = read_value(s, k, s->map.reg_status, &st, deadline, err);
		if (r < 0 || !bit(st, s->map.bit_alm))
			continue;
		if (!s->reset_alarm)
			return alarm_fault(s, k, deadline, err);
		r = write_command(s, k, 1u << s->map.bit_alm_rst, deadline, err);
		if (r == 0)
			r = write_command(s, k, 0, deadline, err);
		if (r < 0)
			return r;
	}
	return 0;
}

/* z first, clear of the part, then x and y together. */
int stage_home(struct stage *s, unsigned timeout_ms, struct asph_error *err)
{
	static const unsigned groups[] = { 1u << 2, 1u << 0 | 1u << 1 };
	uint64_t deadline = transport_deadline(timeout_ms);

	if (atomic_load(s->stop))
		return asph_error_set(err, -ECANCELED, "stage is stopped");
	s->homed = false;
	int r = clear_alarms(s, deadline, err);
	for (size_t g = 0; r == 0 && g < 2; g++) {
		for (int k = 0; r == 0 && k < 3; k++)
			if (groups[g] >> k & 1)
				r = write_command(s, k, 1u << s->map.bit_zhome, deadline, err);
		if (r == 0)
			r = wait_axes(s, groups[g], GOAL_HOMED, true, deadline, timeout_ms, err);
	}
	for (int k = 0; k < 3; k++)
		s->axes[k].known = false;
	s->homed = r == 0;
	return finish(s, r);
}

/* The largest value a register of the map holds: speed, acceleration
 * and current are magnitudes (unsigned 16-bit, or a signed 32-bit pair
 * as the drive reads its data block). */
static double register_max(const struct stage_map *m)
{
	return m->wide ? INT32_MAX : UINT16_MAX;
}

int stage_check_setting(const struct stage *s, const char *option, double value,
			const char *unit, double counts, struct asph_error *err)
{
	double max = register_max(&s->map);

	if (llround(counts) <= max)
		return 0;
	asph_error_set(err, -ERANGE,
		       "option '%s': %g %s is %.0f drive units, which do not fit the drive's "
		       "%d-bit register (at most %.0f); lower it or change counts_per_mm",
		       option, value, unit, counts, s->map.wide ? 32 : 16, max);
	asph_error_locate(err, NULL, 0, 0, option);
	return -ERANGE;
}

static int start_axis(struct stage *s, int k, uint64_t deadline, struct asph_error *err)
{
	const struct stage_axis *a = &s->axes[k];
	/* every value was checked against the register width when the stage
	 * was opened (stage_check_setting) */
	int32_t v[N_DATA] = {
		0, s->map.operation_type, (int32_t)a->target, (int32_t)llround(a->speed),
		(int32_t)llround(a->accel), (int32_t)llround(a->accel),
		(int32_t)llround(s->current * 10), s->map.start_bit ? 0 : 1,
	};
	uint16_t w[2 * N_DATA];
	int n = words(s);

	for (int i = 0; i < N_DATA; i++) {
		if (n == 2)
			mb_put32(w + 2 * (size_t)i, (uint32_t)v[i], s->map.order);
		else
			w[i] = (uint16_t)v[i];
	}
	int r = mb_write_registers(s->bus, a->unit, s->map.reg_data, n * N_DATA, w,
				   ms_left(deadline), err);
	if (r == 0 && s->map.start_bit)
		r = write_command(s, k, 1u << s->map.bit_start, deadline, err);
	return r;
}

static int check_target(const struct stage *s, const double *t, int64_t *counts,
			struct asph_error *err)
{
	for (int k = 0; k < 3; k++) {
		const struct asph_axis_info *a = &s->info.axes[k];
		double c = t[k] * s->axes[k].counts_per_unit;
		bool fits = s->map.wide ? fabs(c) <= INT32_MAX : fabs(c) <= INT16_MAX;
		if (!(t[k] >= a->min && t[k] <= a->max) || !fits)
			return asph_error_set(err, -ERANGE, "axis %s: target %.6f %s is outside "
					      "%.6g .. %.6g", a->name, t[k], a->unit, a->min, a->max);
		counts[k] = llround(c);
	}
	return 0;
}

int stage_move(struct stage *s, const double *target, unsigned timeout_ms,
	       struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	int64_t counts[3] = { 0, 0, 0 };
	unsigned mask = 0;

	if (atomic_load(s->stop))
		return asph_error_set(err, -ECANCELED, "stage is stopped");
	if (!s->homed)
		return asph_error_set(err, -EPROTO, "stage is not homed");
	int r = check_target(s, target, counts, err);
	if (r < 0)
		return r;
	for (int k = 0; k < 3; k++) {
		/* an axis already there is left alone: one write less, and no
		 * start of a zero-length operation */
		if (s->axes[k].known && s->axes[k].target == counts[k])
			continue;
		s->axes[k].target = counts[k];
		s->axes[k].known = false;
		mask |= 1u << k;
	}
	for (int k = 0; r == 0 && k < 3; k++)
		if (mask >> k & 1)
			r = start_axis(s, k, deadline, err);
	if (r == 0)
		r = wait_axes(s, mask, GOAL_MOVED, s->map.start_bit, deadline, timeout_ms, err);
	for (int k = 0; r == 0 && k < 3; k++)
		s->axes[k].known = true;
	return finish(s, r);
}

int stage_position(struct stage *s, double *pos, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);

	if (atomic_load(s->stop))
		return asph_error_set(err, -ECANCELED, "stage is stopped");
	for (int k = 0; k < 3; k++) {
		int64_t c = 0;
		int r = read_feedback(s, k, &c, deadline, err);
		if (r < 0)
			return r;
		pos[k] = (double)c / s->axes[k].counts_per_unit;
	}
	return 0;
}

int stage_status(struct stage *s, struct asph_stage_status *out, unsigned timeout_ms,
		 struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	struct asph_error e;

	memset(out, 0, sizeof(*out));
	out->homed = s->homed;
	out->state = s->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	for (int k = 0; k < 3; k++) {
		uint32_t st = 0;
		int64_t c = 0;
		int r = read_value(s, k, s->map.reg_status, &st, deadline, &e);
		if (r == 0)
			r = read_feedback(s, k, &c, deadline, &e);
		if (r == -ENODEV) {
			out->state = ASPH_STAGE_DISCONNECTED;
			snprintf(out->detail, sizeof(out->detail), "%.127s", e.message);
			return 0;
		}
		if (r < 0) {
			asph_error_set(err, r, "%s", e.message);
			return r;
		}
		out->position[k] = (double)c / s->axes[k].counts_per_unit;
		if (bit(st, s->map.bit_alm) && out->state != ASPH_STAGE_FAULT) {
			out->state = ASPH_STAGE_FAULT;
			alarm_fault(s, k, deadline, &e);
			snprintf(out->detail, sizeof(out->detail), "%.127s", e.message);
		} else if (bit(st, s->map.bit_busy) && out->state != ASPH_STAGE_FAULT) {
			out->state = ASPH_STAGE_MOVING;
		}
	}
	return 0;
}
