/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Modbus sensors: the built-in maps and reading one value (sensor.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "sensor.h"

const char *const sensor_profile_names[] = { "custom", "orbit-acs", "rf60x", NULL };

/*
 * Solartron Orbit ACS (SI100, SI200), from "503110 - Orbit ACS Manual",
 * Issue 9, chapter 16: every parameter has an IEEE-754 float image at its
 * address + 8000, read as two registers in one request (16.2.9); the SI
 * refuses a request for part of a parameter of several registers (16.2.3);
 * the reading status parameter says whether a reading is valid (9.4.3).
 * The parameters' addresses are in "503116 Orbit ACS Modbus Parameter Map
 * - SI100/SI200", which the configuration gives (register,
 * status_register).
 */
#define ORBIT_FLOAT_IMAGE 8000
enum {
	ORBIT_OK = 0, ORBIT_UNDER_RANGE = 18, ORBIT_OVER_RANGE = 19,
	ORBIT_INCOMPATIBLE_PROBE = 246, ORBIT_NO_PROBE = 247,
};

/*
 * RIFTEK RF60x (RF602, RF603; also sold as Acuity AR100), from "Laser
 * Triangulation Sensors. RF602 Series. User's manual", revision 1.2.0
 * (28.01.2019): 11.8.1 the input registers, 3 serial number, 4 base
 * distance (mm), 5 measurement range (mm), 6 measured value; 11.7.7 the
 * value D is normalised so that 4000h is the whole range S: X = D * S /
 * 4000h mm, from the start of the range.
 */
enum { RF_SERIAL = 3, RF_BASE = 4, RF_RANGE = 5, RF_VALUE = 6 };
#define RF_FULL_SCALE 16384.0

static int need(const struct sensor_config *c, int value, const char *option, const char *what,
		struct asph_error *err)
{
	if (value >= 0)
		return 0;
	return asph_error_set_at(err, -EINVAL, NULL, 0, 0, option,
				 "sensor_profile %s: option '%s' must give %s",
				 sensor_profile_names[c->profile], option, what);
}

static int rf60x_open(struct sensor *s, unsigned timeout_ms, struct asph_error *err)
{
	uint16_t w[3];
	int r = mb_read_registers(s->bus, s->c.unit, true, RF_SERIAL, 3, w, timeout_ms, err);

	if (r < 0)
		return r;
	if (w[RF_RANGE - RF_SERIAL] == 0)
		return asph_error_set(err, -EPROTO, "unit %d: the sensor reports a measurement range "
				      "of 0 mm (input register %d): not an RF60x?", s->c.unit, RF_RANGE);
	s->base_mm = w[RF_BASE - RF_SERIAL];
	s->range_mm = w[RF_RANGE - RF_SERIAL];
	s->value_reg = RF_VALUE;
	if (!s->c.scale_set)
		s->c.scale = s->range_mm / RF_FULL_SCALE;
	s->c.input = true;
	s->c.type = SENSOR_U16;
	snprintf(s->model, sizeof(s->model), "RIFTEK RF60x, %g mm from %g mm", s->range_mm,
		 s->base_mm);
	snprintf(s->serial, sizeof(s->serial), "%u", (unsigned)w[0]);
	return 0;
}

int sensor_open(struct sensor *s, struct mb_bus *bus, const struct sensor_config *c,
		unsigned timeout_ms, struct asph_error *err)
{
	int r = 0;

	memset(s, 0, sizeof(*s));
	s->bus = bus;
	s->c = *c;
	s->value_reg = c->reg;
	snprintf(s->model, sizeof(s->model), "Modbus displacement sensor");
	snprintf(s->serial, sizeof(s->serial), "unit %d", c->unit);
	switch (c->profile) {
	case SENSOR_CUSTOM:
		return need(c, c->reg, "register", "the address of the value", err);
	case SENSOR_ORBIT_ACS:
		r = need(c, c->reg, "register", "the reading parameter's address (document 503116)",
			 err);
		if (r == 0)
			r = need(c, c->status_reg, "status_register",
				 "the reading status parameter's address (document 503116)", err);
		if (r == 0 && c->reg > 65535 - ORBIT_FLOAT_IMAGE)
			r = asph_error_set_at(err, -ERANGE, NULL, 0, 0, "register",
					      "sensor_profile orbit-acs: register %d has no float "
					      "image (at register + %d, at most 65535)", c->reg,
					      ORBIT_FLOAT_IMAGE);
		if (r < 0)
			return r;
		s->value_reg = c->reg + ORBIT_FLOAT_IMAGE;
		s->c.type = SENSOR_F32;
		if (!c->scale_set)
			s->c.scale = 1;         /* the SI's reading, in mm */
		snprintf(s->model, sizeof(s->model), "Solartron Orbit ACS");
		return 0;
	case SENSOR_RF60X:
		return rf60x_open(s, timeout_ms, err);
	}
	return asph_error_set(err, -EINVAL, "unknown sensor profile");
}

static int words(enum sensor_type t)
{
	return t == SENSOR_S16 || t == SENSOR_U16 ? 1 : 2;
}

/* The value of the registers w as the type codes it. */
static double decode(const struct sensor *s, const uint16_t *w)
{
	uint32_t v = words(s->c.type) == 2 ? mb_get32(w, s->c.order) : w[0];
	float f;

	switch (s->c.type) {
	case SENSOR_S32: return (double)(int32_t)v;
	case SENSOR_U32: return (double)v;
	case SENSOR_S16: return (double)(int16_t)w[0];
	case SENSOR_U16: return (double)w[0];
	case SENSOR_F32:
		memcpy(&f, &v, sizeof(f));
		return (double)f;
	}
	return NAN;
}

/* The Orbit ACS reading status: 0 valid, under or over range a reading
 * out of range, no usable probe an error. */
static int orbit_status(const struct sensor *s, unsigned timeout_ms, bool *oor,
			struct asph_error *err)
{
	uint16_t st;
	int r = mb_read_registers(s->bus, s->c.unit, s->c.input, s->c.status_reg, 1, &st,
				  timeout_ms, err);

	if (r < 0)
		return r;
	switch (st) {
	case ORBIT_OK:
		return 0;
	case ORBIT_UNDER_RANGE:
	case ORBIT_OVER_RANGE:
		*oor = true;
		return 0;
	case ORBIT_INCOMPATIBLE_PROBE:
		return asph_error_set(err, -EPROTO, "unit %d: Orbit ACS reading status 246: an "
				      "incompatible probe is connected", s->c.unit);
	case ORBIT_NO_PROBE:
		return asph_error_set(err, -EPROTO, "unit %d: Orbit ACS reading status 247: no "
				      "probe is connected", s->c.unit);
	}
	return asph_error_set(err, -EPROTO, "unit %d: Orbit ACS reading status %u, which the "
			      "manual (503110, 9.4.3) does not list", s->c.unit, (unsigned)st);
}

int sensor_read(struct sensor *s, unsigned timeout_ms, double *raw, double *mm, bool *oor,
		struct asph_error *err)
{
	uint16_t w[2], flag = 0xffff;
	int r = mb_read_registers(s->bus, s->c.unit, s->c.input, s->value_reg, words(s->c.type), w,
				  timeout_ms, err);

	*oor = false;
	if (r == 0 && s->c.profile == SENSOR_ORBIT_ACS)
		r = orbit_status(s, timeout_ms, oor, err);
	if (r == 0 && s->c.profile == SENSOR_CUSTOM && s->c.valid_reg >= 0)
		r = mb_read_registers(s->bus, s->c.unit, s->c.input, s->c.valid_reg, 1, &flag,
				      timeout_ms, err);
	if (r < 0)
		return r;
	*raw = decode(s, w);
	if (!isfinite(*raw))
		return asph_error_set(err, -EPROTO, "unit %d: register %d holds %g, not a number "
				      "(check type and word_order)", s->c.unit, s->value_reg, *raw);
	if (!(flag >> s->c.valid_bit & 1))
		*oor = true;
	/* the ends of the normalised range are where the sensor saturates:
	 * not trusted as a reading */
	if (s->c.profile == SENSOR_RF60X && (*raw <= 0 || *raw >= RF_FULL_SCALE))
		*oor = true;
	*mm = *raw * s->c.scale + s->c.offset;
	return 0;
}
