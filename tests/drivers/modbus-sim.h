/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Simulated Modbus devices for the driver tests, built on libmodbus's
 * server side: up to three positioning drives that follow a stage register
 * map (the AZ direct data operation by default: the data block starts a
 * move, START/ZHOME/STOP/ALM-RST commands, READY/BUSY/IN-POS/ALM/HOME-END
 * status, feedback position, alarm code) with motion over (scaled) time,
 * and a displacement sensor whose reading a callback computes from the
 * drives' positions. Served on a thread over TCP on 127.0.0.1 (a free
 * port) or over RTU on a pseudo-terminal. Faults can be injected per unit.
 */
#ifndef ASPH_TEST_MODBUS_SIM_H
#define ASPH_TEST_MODBUS_SIM_H

#include <stdbool.h>
#include <stdint.h>

#include "modbus/stage.h"

/* Sensor registers (input and holding alike): the value, s32 high word
 * first at 0 and 1, and the status at 2 with bit 0 set while valid. */
enum { MBSIM_SENSOR_VALUE = 0, MBSIM_SENSOR_STATUS = 2 };

/* The reading in counts from the drives' positions (axis units); *valid
 * false for no reading. */
typedef int32_t (*mbsim_sense_fn)(void *data, const double *pos, bool *valid);

/* The sensor's register map. */
enum mbsim_sensor_kind {
	MBSIM_SENSOR_GENERIC = 0,       /* MBSIM_SENSOR_VALUE, _STATUS above */
	/* RIFTEK RF60x (RF602 Series User's manual, rev. 1.2.0, 11.7.7 and
	 * 11.8): input registers 1..6 only (6: the measured value D, 4000h
	 * the whole range), holding registers 10..41 */
	MBSIM_SENSOR_RF60X,
	/* Solartron Orbit ACS SI100/SI200 (503110 Orbit ACS Manual, issue 9):
	 * the reading parameter at orbit_reading (s32, 4 decimal places of a
	 * mm) and its status at orbit_status, each with its float image at
	 * address + 8000; a request for part of a parameter of two registers
	 * is refused (exception 2) */
	MBSIM_SENSOR_ORBIT_ACS,
};

/* The reading in mm (RF60x: from the start of its range; Orbit: the
 * probe's travel) from the drives' positions; false for no target. */
typedef bool (*mbsim_sense_mm_fn)(void *data, const double *pos, double *mm);

struct mbsim_config {
	bool rtu;
	struct stage_map map;           /* what the drives speak */
	int drive_units[3];             /* 0 = no drive */
	double counts_per_unit[3];
	int sensor_unit;                /* 0 = no sensor */
	mbsim_sense_fn sense;
	void *sense_data;
	double time_scale;              /* real seconds per simulated one */
	/* a sensor other than the generic one */
	enum mbsim_sensor_kind sensor_kind;
	mbsim_sense_mm_fn sense_mm;
	double rf_range_mm, rf_base_mm; /* RF60x: integers, as its registers hold them */
	int orbit_reading, orbit_status;/* Orbit ACS: the parameters' addresses */
	enum mb_word_order orbit_order; /* of the float images */
	double orbit_range_mm;          /* the probe's travel: beyond it 18/19 */
};

enum mbsim_fault {
	MBSIM_EXCEPTION,        /* answers with exception `code` */
	MBSIM_SILENT,           /* does not answer */
	MBSIM_GARBLE,           /* RTU: the answer with a bad CRC */
	MBSIM_ALARM,            /* the drive raises alarm `code`: at once, or
				 * with count > 0 at its count-th start */
	MBSIM_DELAY,            /* answers `code` ms late, busy meanwhile (a
				 * slow device: later requests wait their turn) */
};

struct mbsim;

/* Starts serving; *address is the port (TCP) or the pty's path (RTU). */
int mbsim_start(const struct mbsim_config *c, struct mbsim **out,
		char *address, size_t size);
void mbsim_stop(struct mbsim *s);

/* The next count requests to unit (count < 0: all of them) get fault;
 * with a register >= 0 only requests that touch it. */
void mbsim_inject(struct mbsim *s, int unit, enum mbsim_fault fault,
		  int code, int count, int reg);
void mbsim_clear_faults(struct mbsim *s);

/* Orbit ACS: the reading status from now on (246: incompatible probe,
 * 247: no probe); -1: the status of the reading again. */
void mbsim_orbit_status(struct mbsim *s, int status);

/* What the simulation did, for the tests' checks. */
struct mbsim_stats {
	unsigned requests;
	unsigned starts[3];     /* motions started per drive */
	unsigned homings[3];
	unsigned stops[3];      /* STOP commands seen */
	bool stop_held[3];      /* STOP still set */
	double position[3];     /* axis units */
	bool home_end[3];
};
void mbsim_stats(struct mbsim *s, struct mbsim_stats *out);

#endif
