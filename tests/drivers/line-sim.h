/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Simulated line-protocol devices for the line driver's tests, each
 * written from the vendor's command reference named in
 * docs/driver-line.md and as strict as the device: stages whose axes move
 * over (scaled) time, and displacement sensors and gauges whose reading a
 * callback computes from where the stage is. Served on a thread over TCP
 * on 127.0.0.1 (a free port; a new connection is accepted after one is
 * lost) or over a pseudo-terminal pair (the driver opens the slave).
 */
#ifndef ASPH_TEST_LINE_SIM_H
#define ASPH_TEST_LINE_SIM_H

#include <stdbool.h>
#include <stddef.h>

enum linesim_kind {
	LINESIM_PI = 0,         /* PI GCS 2.0 */
	LINESIM_NEWPORT,        /* Newport ESP301 */
	LINESIM_AEROTECH,       /* Aerotech Ensemble ASCII */
	LINESIM_LINUXCNC,       /* linuxcncrsh */
	LINESIM_KEYENCE,        /* Keyence LK-G */
	LINESIM_SYLVAC,         /* Sylvac gauge */
	LINESIM_MITUTOYO,       /* Mitutoyo USB-ITN, virtual COM */
	LINESIM_COUNT
};

/* The reading (mm) of a sensor from where the stage is; false for none. */
typedef bool (*linesim_sense_fn)(void *data, double *mm);

struct linesim_config {
	enum linesim_kind kind;
	bool serial;                    /* a pty instead of TCP */
	double time_scale;              /* real seconds per simulated one */
	double travel;                  /* stage: soft limits -travel .. travel, mm */
	double speed;                   /* stage: mm/s */
	linesim_sense_fn sense;         /* sensor */
	void *sense_data;
	/* serial: a symbolic link to the pty, as udev's /dev/serial/by-id
	 * names are; the address given back is then this path. After a
	 * disconnect, with replug, the line comes back after replug_s
	 * (real seconds) on a new pty the link points to, as a USB adapter
	 * that re-enumerates; the device keeps its state meanwhile. */
	const char *link;
	bool replug;
	double replug_s;
};

enum linesim_fault {
	LINESIM_NONE = 0,
	LINESIM_DEVICE_ERROR,   /* the count-th move (reading) is refused with
				 * the device's own error */
	LINESIM_GARBLE,         /* its reply (or the next one) is line noise */
	LINESIM_STALL,          /* from it on, the device answers nothing */
	LINESIM_DISCONNECT,     /* the connection drops in the middle of it */
	LINESIM_PARTIAL,        /* its reply comes without a line end */
};

struct linesim;

int linesim_start(const struct linesim_config *c, struct linesim **out, char *address,
		  size_t size);
void linesim_stop(struct linesim *s);

/* The count-th move command of a stage, or reading of a sensor, from
 * now (1: the next) gets fault. */
void linesim_inject(struct linesim *s, enum linesim_fault fault, int count);

struct linesim_stats {
	unsigned commands, moves, readings, stops, connections;
	double position[3];             /* mm, now */
	bool moving;
	bool homed;
};
void linesim_stats(struct linesim *s, struct linesim_stats *out);

/* A gauge sends its reading unasked, as when the operator presses its
 * data button or foot switch (Mitutoyo, Sylvac). */
void linesim_operator(struct linesim *s);

/* Where a stage simulator's axes are now (mm): what a sensor riding on
 * it sees. */
void linesim_position(struct linesim *s, double pos[3]);

#endif
