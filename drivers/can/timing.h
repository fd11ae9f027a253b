/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The time the stage's own motions take, predicted from the driver's
 * options (the measuring time before anything is opened): the axes'
 * profiles at the profile velocity and acceleration, and the expedited
 * SDO exchanges and statusword polls the driver makes around them, step
 * by step as api.c makes them. Pure. docs/driver-can.md, "Predicted
 * measuring time".
 */
#ifndef ASPH_CAN_TIMING_H
#define ASPH_CAN_TIMING_H

#include <stdbool.h>
#include <stddef.h>

/* How the driver reads the positions of a sweep at each trigger. */
enum can_latch {
	CAN_LATCH_NONE,         /* 0x6064 of each axis read back */
	CAN_LATCH_CONTINUOUS,   /* 0x60D5 and 0x60BA of each axis */
	CAN_LATCH_SINGLE,       /* 0x60B9, 0x60BA and the re-arming of 0x60B8 */
};

struct can_timing {
	bool axis[3];           /* the axis has a drive */
	double counts_per_mm[3];
	double speed, acceleration;     /* mm/s, mm/s^2, every axis */
	double sdo_s;           /* one expedited exchange, request and answer */
	double poll_s;          /* the wait between two statusword polls */
	enum can_latch latch;
	bool trigger;           /* a trigger output is wired */
};

/* One expedited SDO exchange at bitrate (bit/s): two data frames of 8
 * bytes with an 11-bit identifier, 111 bit times each with the
 * intermission, without stuffing bits or the drive's time to answer. */
double can_sdo_exchange_s(double bitrate);

/* The driver's move_to() from from to to, from rest to rest. */
double can_move_time(const struct can_timing *t, const double from[3], const double to[3]);

/* The driver's sweep() through the n positions p (3 each, mm) from rest
 * at from, to the last trigger and the touch probes switched off. */
double can_sweep_time(const struct can_timing *t, const double from[3], const double *p,
		      size_t n);

#endif
