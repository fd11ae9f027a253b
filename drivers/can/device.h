/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The CAN driver's device (api.c): a stage of up to three CiA 402 drives,
 * one node per axis, or a probe node; and the sequences the stage runs on
 * it, one file per family:
 *
 *   api.c      the options and the driver table; open, close, info, the
 *              prediction of its moves, position, status; the probe
 *   sweep.c    sweeps with buffered set points and the trigger line
 *   move.c     moves in profile position mode
 *   home.c     homing
 *   latch.c    the drives' touch probes
 *   cia402.c   a drive's objects over SDO, its faults, the CiA 402 state
 *              machine to "operation enabled"
 *
 * Each calls only those below it. Internal to drivers/can/.
 */
#ifndef ASPH_CAN_DEVICE_H
#define ASPH_CAN_DEVICE_H

#include <math.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph-driver/driver.h"
#include "bus.h"

enum { TOUCH_PROBE_AUTO, TOUCH_PROBE_ON, TOUCH_PROBE_OFF };

struct axis {
	uint8_t node;           /* 0: no drive, the axis stays at 0 */
	double counts_per_mm, min, max;
	bool homed;
	bool pp;                /* profile position mode and its parameters set */
	bool target_valid;      /* target is where the drive was last sent */
	int32_t target;
	enum { TP_NONE, TP_SINGLE, TP_CONTINUOUS } tp;  /* its touch probe 1 */
	uint16_t tp_count;      /* 0x60D5 after the last latch */
};

struct asph_device {
	struct can_bus *bus;
	atomic_bool stopped;
	char *iface;            /* whole: a unix socket path must not be cut */
	uint8_t nodes[3];
	unsigned n_nodes;
	unsigned hb_ms, hb_timeout_ms, sdo_ms;
	int nmt_reset;
	/* stage */
	struct axis ax[3];
	double speed, acceleration, homing_speed;
	int homing_method;
	bool fault_reset;
	/* sweeps: the trigger line, the positions measured */
	int touch_probe;
	uint8_t trigger_node, trigger_bit;      /* bit 0: no trigger wiring */
	uint32_t outputs;                       /* 0x60FE:01 of trigger_node */
	struct asph_position_sample *trace;
	size_t trace_n, trace_read, trace_cap;
	/* probe */
	uint16_t p_index;
	uint8_t p_sub;
	int p_format;
	double p_scale, p_offset;
	struct asph_probe_info pinfo;
};

/* The wait between two polls of a statusword while an axis is under way. */
#define POLL_MS 1

extern const char *const can_axis_names[3];

static inline int32_t counts(const struct axis *a, double mm)
{
	return (int32_t)llround(mm * a->counts_per_mm);
}

/* ---------------------------------------------------------- cia402.c */

/* What is left of an SDO's timeout before deadline. */
unsigned can_sdo_time(const struct asph_device *d, uint64_t deadline);
/* "x (node 3)": the axis' drive in reasons. */
const char *can_drive_name(const struct asph_device *d, const struct axis *a);
int can_read_u16(struct asph_device *d, uint8_t node, uint16_t index, uint16_t *v,
		 uint64_t deadline, struct asph_error *err);
int can_write_obj(struct asph_device *d, uint8_t node, uint16_t index, uint8_t sub,
		  uint32_t v, uint8_t size, uint64_t deadline, struct asph_error *err);
int can_write_cw(struct asph_device *d, const struct axis *a, uint16_t cw, uint64_t deadline,
		 struct asph_error *err);
/* -EPROTO naming the drive's error code (0x603F, else its last EMCY). */
int can_drive_fault(struct asph_device *d, const struct axis *a, const char *why,
		    struct asph_error *err);
/* Ends a stage operation: a fault stops every axis; a stop keeps its
 * reason simple. */
int can_finish(struct asph_device *d, int r, const char *what, struct asph_error *err);
int can_check_stopped(struct asph_device *d, struct asph_error *err);
/* The CiA 402 state machine driven to "operation enabled", one
 * transition per statusword read. */
int can_axis_enable(struct asph_device *d, struct axis *a, uint64_t deadline,
		    struct asph_error *err);
/* Reads the statusword of a drive that must stay enabled. */
int can_enabled_sw(struct asph_device *d, const struct axis *a, uint16_t *sw, uint64_t deadline,
		   struct asph_error *err);

/* ----------------------------------------------------------- latch.c */

/* Whether a's drive has a touch probe, and its edge counter. */
int can_detect_touch_probe(struct asph_device *d, struct axis *a, uint64_t deadline,
			   struct asph_error *err);
/* Every axis latches: positions during sweeps are the drives' own. */
bool can_latching(const struct asph_device *d);
int can_write_tp(struct asph_device *d, const struct axis *a, uint16_t f, uint64_t deadline,
		 struct asph_error *err);
/* Touch probe 1 armed on the rising edge of its input. */
int can_arm_touch_probe(struct asph_device *d, struct axis *a, uint64_t deadline,
			struct asph_error *err);
/* The position a's drive latched on the trigger just fired, counts. */
int can_read_latch(struct asph_device *d, struct axis *a, int32_t *at, uint64_t deadline,
		   struct asph_error *err);

/* ------------------------------------------------------------ home.c */

int can_stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err);

/* ------------------------------------------------------------ move.c */

/* Profile position mode with the profile's speed and accelerations. */
int can_axis_pp(struct asph_device *d, struct axis *a, uint64_t deadline,
		struct asph_error *err);
/* A target every axis can reach: within its limits, homed, 0 without a
 * drive. */
int can_check_target(const struct asph_device *d, const double *t, struct asph_error *err);
/* The statusword of an axis in motion, which must not have a following
 * error or a limit. */
int can_motion_sw(struct asph_device *d, const struct axis *a, uint16_t *out,
		  uint64_t deadline, struct asph_error *err);
/* 1 when the axis is at its target, 0 while it moves. */
int can_axis_arrived(struct asph_device *d, const struct axis *a, uint64_t deadline,
		     struct asph_error *err);
int can_stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		   struct asph_error *err);

/* ----------------------------------------------------------- sweep.c */

int can_stage_sweep(struct asph_device *d, const double *p, size_t n, unsigned timeout_ms,
		    struct asph_error *err);
/* The positions of the last sweep, one per trigger, each handed out once. */
int can_stage_trace(struct asph_device *d, struct asph_position_sample *out, size_t max,
		    size_t *n, unsigned timeout_ms, struct asph_error *err);

#endif
