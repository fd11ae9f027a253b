/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Modbus displacement sensors and probe interfaces: where a reading is in
 * the registers and how it is coded, from a built-in sensor profile or
 * from the configuration (docs/driver-modbus.md, "The probe"). Internal
 * to drivers/modbus/.
 */
#ifndef ASPH_MODBUS_SENSOR_H
#define ASPH_MODBUS_SENSOR_H

#include <stdbool.h>

#include "protocol.h"

enum sensor_profile_id {
	SENSOR_CUSTOM = 0,      /* the configuration's map */
	SENSOR_ORBIT_ACS,       /* Solartron Orbit ACS SI100 / SI200 */
	SENSOR_RF60X,           /* RIFTEK RF60x laser triangulation sensors */
};

/* Ordered as the type option's choices. */
enum sensor_type { SENSOR_S32 = 0, SENSOR_U32, SENSOR_S16, SENSOR_U16, SENSOR_F32 };

/* What the configuration says; a profile fills in what it fixes. */
struct sensor_config {
	enum sensor_profile_id profile;
	int unit;
	bool input;             /* function 4, else 3 */
	int reg;                /* -1: not given */
	enum sensor_type type;
	enum mb_word_order order;
	double scale, offset;   /* mm per count, mm */
	bool scale_set;
	int valid_reg, valid_bit;       /* custom: -1 none */
	int status_reg;         /* orbit-acs: the reading status parameter, -1: not given */
};

struct sensor {
	struct mb_bus *bus;
	struct sensor_config c;
	int value_reg;          /* the register read, the float image's for orbit-acs */
	double range_mm;        /* rf60x: the sensor's measuring range */
	double base_mm;         /* rf60x: its base distance */
	char model[64], serial[64];
};

/* The profiles' names, as the sensor_profile option's choices. */
extern const char *const sensor_profile_names[];

/*
 * Sets the sensor up on bus: the profile's map over the configuration's,
 * and what the sensor tells about itself (rf60x: its range and base
 * distance, serial number). -EINVAL naming the option for a map the
 * profile needs and the configuration leaves out.
 */
int sensor_open(struct sensor *s, struct mb_bus *bus, const struct sensor_config *c,
		unsigned timeout_ms, struct asph_error *err);

/*
 * One reading: raw (the value as sent: counts, or the float), mm (raw
 * scaled, plus offset) and *oor when the sensor says it is out of its
 * range (or the value is not valid). A sensor that cannot measure at all
 * (orbit-acs: no probe, an incompatible probe) is an error with its
 * reason.
 */
int sensor_read(struct sensor *s, unsigned timeout_ms, double *raw, double *mm, bool *oor,
		struct asph_error *err);

#endif
