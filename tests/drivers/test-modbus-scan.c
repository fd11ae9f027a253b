/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A whole measurement of the strong preset through the executor with the
 * Modbus stage and probe against simulated AZ drives and a displacement
 * sensor that measures the mock instrument's part, over TCP and over RTU
 * (drives and sensor on one line): the characterization equals the mock
 * instrument's. And a drive alarm in the middle of a scan ends the file
 * with the reason. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "mock/protocol.h"
#include "modbus-sim.h"
#include "scan-fixture.h"

/* The part: misaligned, with a form error (mock's options, and the same
 * as parameters of mock_part_new for the simulated sensor). */
#define MISALIGNMENT "shift_x=0.0371,shift_y=-0.0213,shift_z=0.0119,tilt_x=231.7,tilt_y=-148.3," \
	"form=5:41.3;9:-23.7;12:17.9"

static const struct mock_part_params part_params = {
	.lens = "strong",
	.pose = { .t = { 0.0371, -0.0213, 0.0119 }, .rx = 231.7e-6, .ry = -148.3e-6 },
	.form = "5:41.3;9:-23.7;12:17.9",
	.seed = 1,
};

/* mm per count of the sensor, counts per mm of the drives */
#define SENSOR_SCALE 1e-8
#define COUNTS_PER_MM 1e5

struct env {
	struct scan_fixture fx;
	struct mock_part *part;
};

/* The sensor looks along +z from the stage's position at the part. */
static int32_t sense(void *data, const double *pos, bool *valid)
{
	struct env *e = data;
	double z;

	*valid = mock_part_probe_z(e->part, pos[0], pos[1], 0, &z) == 0;
	return *valid ? (int32_t)llround((z - pos[2]) / SENSOR_SCALE) : 0;
}

static int setup(void **state)
{
	struct env *e = calloc(1, sizeof(*e));

	assert_non_null(e);
	scan_fixture_init(&e->fx, 150, "modbus");
	assert_int_equal(mock_part_new(&part_params, &e->part, NULL), 0);
	*state = e;
	return 0;
}

static int teardown(void **state)
{
	struct env *e = *state;

	mock_part_free(e->part);
	scan_fixture_fini(&e->fx);
	free(e);
	return 0;
}

/* Measures the plan with the first instrument of c into path. */
static int scan(struct env *e, struct asph_config *c, const char *path, struct asph_error *err)
{
	return fixture_scan(&e->fx, &c->instruments[0], e->fx.plan->xyz, e->fx.plan->n, path, err,
			    false);
}

static void fit(struct env *e, const char *path, struct asph_fit_result *res)
{
	fixture_fit_rigid(&e->fx, path, e->fx.plan->n, res);
}

/* The sensor of a profile sees the part from the stage too: the depth
 * below the probe in mm. */
static bool sense_mm(void *data, const double *pos, double *mm)
{
	struct env *e = data;
	double z;

	if (mock_part_probe_z(e->part, pos[0], pos[1], 0, &z) < 0)
		return false;
	*mm = z - pos[2];
	return true;
}

/* The generic sensor's map in the configuration. */
#define GENERIC_PROBE "\"slave\": 9, \"scale\": 1e-8, \"standoff\": 2, \"range\": 1, " \
	"\"valid_register\": 2"

/* The Modbus bench with the probe's options: address is the simulator's
 * TCP port or pty. */
static struct asph_config *bench_probe(struct env *e, bool rtu, const char *address,
				       const char *probe)
{
	char text[1536], conn[300];
	struct asph_config *c;
	struct asph_error err;

	if (rtu)
		snprintf(conn, sizeof(conn), "\"transport\": \"rtu\", \"device\": \"%s\"", address);
	else
		snprintf(conn, sizeof(conn), "\"port\": %s", address);
	snprintf(text, sizeof(text),
		 "{ \"instruments\": [ { \"name\": \"bench\",\n"
		 "  \"stage\": { \"driver\": \"modbus\", \"options\": { %s,\n"
		 "    \"counts_per_mm\": %g, \"speed\": 20, \"timeout\": 100 } },\n"
		 "  \"probe\": { \"driver\": \"modbus\", \"options\": { %s,\n    %s } } } ] }\n",
		 conn, COUNTS_PER_MM, conn, probe);
	if (asph_config_parse(e->fx.reg, text, strlen(text), "bench.json", &c, &err) < 0)
		fail_msg("%s", err.message);
	return c;
}

static struct asph_config *bench(struct env *e, bool rtu, const char *address)
{
	return bench_probe(e, rtu, address, GENERIC_PROBE);
}

static struct mbsim *sim_start_kind(struct env *e, bool rtu, enum mbsim_sensor_kind kind,
				    char *address, size_t size)
{
	struct mbsim_config sc = {
		.rtu = rtu, .map = stage_profiles[0], .drive_units = { 1, 2, 3 },
		.counts_per_unit = { COUNTS_PER_MM, COUNTS_PER_MM, COUNTS_PER_MM },
		.sensor_unit = 9, .sense = sense, .sense_data = e, .time_scale = 1e-4,
		.sensor_kind = kind, .sense_mm = sense_mm, .rf_range_mm = 2, .rf_base_mm = 30,
		.orbit_reading = 40, .orbit_status = 42, .orbit_range_mm = 2,
	};
	struct mbsim *sim;

	assert_int_equal(mbsim_start(&sc, &sim, address, size), 0);
	return sim;
}

static struct mbsim *sim_start(struct env *e, bool rtu, char *address, size_t size)
{
	return sim_start_kind(e, rtu, MBSIM_SENSOR_GENERIC, address, size);
}

/* Measures the plan with the Modbus bench, its sensor of kind read with
 * the probe options given, on the simulators; the fit. */
static void measure_sensor(struct env *e, bool rtu, enum mbsim_sensor_kind kind, const char *probe,
			   struct asph_fit_result *res)
{
	struct asph_error err;
	char path[128], address[128];

	struct mbsim *sim = sim_start_kind(e, rtu, kind, address, sizeof(address));
	struct asph_config *c = bench_probe(e, rtu, address, probe);
	if (scan(e, c, new_path(&e->fx, path, sizeof(path)), &err) < 0)
		fail_msg("modbus %s: %s", rtu ? "rtu" : "tcp", err.message);
	asph_config_free(c);
	mbsim_stop(sim);
	fit(e, path, res);
}

static void measure_modbus(struct env *e, bool rtu, struct asph_fit_result *res)
{
	measure_sensor(e, rtu, MBSIM_SENSOR_GENERIC, GENERIC_PROBE, res);
}

static void assert_close_fit(const char *what, const struct asph_fit_result *a,
			     const struct asph_fit_result *b, double shift, double tilt, double nm)
{
	for (int k = 0; k < 3; k++)
		if (fabs(a->value[ASPH_FIT_TX + k] - b->value[ASPH_FIT_TX + k]) > shift)
			fail_msg("%s t%d: %.12g, mock %.12g", what, k, a->value[ASPH_FIT_TX + k],
				 b->value[ASPH_FIT_TX + k]);
	for (int k = 0; k < 2; k++)
		if (fabs(a->value[ASPH_FIT_RX + k] - b->value[ASPH_FIT_RX + k]) > tilt)
			fail_msg("%s r%d: %.12g, mock %.12g", what, k, a->value[ASPH_FIT_RX + k],
				 b->value[ASPH_FIT_RX + k]);
	static const int terms[] = { 5, 9, 12 };
	for (size_t k = 0; k < 3; k++) {
		double za = a->zernike[terms[k] - 1].v, zb = b->zernike[terms[k] - 1].v;
		if (fabs(za - zb) > nm)
			fail_msg("%s Z%d: %.6f nm, mock %.6f nm", what, terms[k], za, zb);
	}
}

/*
 * Both measure the same part without noise; the Modbus sensor rounds each
 * reading to 1e-8 mm (at most 5e-9 mm off) and measures where the drives
 * are (10 nm counts), which is on the same surface. So the pose agrees
 * far below the tolerances of characterization, and each Zernike term
 * within a few thousandths of a nm.
 */
static void assert_same_fit(const struct asph_fit_result *bus, const struct asph_fit_result *mock)
{
	assert_close_fit("modbus", bus, mock, 1e-8, 1e-9, 0.005);
	assert_true(fabs(bus->rms.v - mock->rms.v) < 0.005);
}

/* The mock's fit of the part. */
static void mock_fit(struct env *e, struct asph_fit_result *mock)
{
	struct asph_config *c;
	struct asph_error err;
	char path[128];

	assert_int_equal(asph_instrument_spec_parse(e->fx.reg, "mock:time_factor=0," MISALIGNMENT,
						    &c, NULL), 0);
	if (scan(e, c, new_path(&e->fx, path, sizeof(path)), &err) < 0)
		fail_msg("mock: %s", err.message);
	asph_config_free(c);
	fit(e, path, mock);
}

/* Over TCP, and over RTU with the drives and the sensor on one line. */
static void test_same_as_mock(void **state)
{
	struct env *e = *state;
	struct asph_fit_result mock, bus;

	mock_fit(e, &mock);
	for (int rtu = 0; rtu < 2; rtu++) {
		measure_modbus(e, rtu, &bus);
		assert_same_fit(&bus, &mock);
	}
}

/*
 * A sensor of coarse resolution: its rounding adds to the fit's
 * uncertainty of each degree of freedom what the fit itself estimates
 * from the residuals, u_q = sqrt(u_sensor^2 - u_mock^2) (the rest is the
 * part's form error, the same in both); each may differ from the mock's
 * by three times that. The Zernike terms by nm.
 */
static void assert_within_quantization(const char *what, const struct asph_fit_result *a,
				       const struct asph_fit_result *b, double nm)
{
	for (int k = ASPH_FIT_TX; k <= ASPH_FIT_RY; k++) {
		double uq = sqrt(fmax(a->uncertainty[k] * a->uncertainty[k] -
				      b->uncertainty[k] * b->uncertainty[k], 0));
		if (!(fabs(a->value[k] - b->value[k]) <= 3 * uq))
			fail_msg("%s dof %d: %.12g, mock %.12g, 3 u_q %.3g", what, k, a->value[k],
				 b->value[k], 3 * uq);
	}
	assert_close_fit(what, a, b, INFINITY, INFINITY, nm);
}

/*
 * The sensor profiles through the executor, over TCP and RTU. Orbit ACS
 * sends its reading as a float: each rounded by at most half an ulp of
 * 2 mm (1.2e-7 mm), so the pose agrees to 1e-7 mm and 1e-8 rad, and the
 * Zernike terms to 0.05 nm. The RF60x sends 14 bits over its 2 mm range:
 * steps of 1.22e-4 mm, a rounding spread of 3.5e-5 mm (35 nm) a reading;
 * over 150 readings a Zernike term's is some 5 nm (allowed 20), and the
 * pose within what the rounding adds to its uncertainty.
 */
static void test_sensor_profiles(void **state)
{
	struct env *e = *state;
	struct asph_fit_result mock, bus;

	mock_fit(e, &mock);
	for (int rtu = 0; rtu < 2; rtu++) {
		measure_sensor(e, rtu, MBSIM_SENSOR_ORBIT_ACS, "\"slave\": 9, \"sensor_profile\": "
			       "\"orbit-acs\", \"register\": 40, \"status_register\": 42, "
			       "\"table\": \"holding\", \"standoff\": 1, \"range\": 2", &bus);
		assert_close_fit("orbit-acs", &bus, &mock, 1e-7, 1e-8, 0.05);
		measure_sensor(e, rtu, MBSIM_SENSOR_RF60X, "\"slave\": 9, \"sensor_profile\": "
			       "\"rf60x\"", &bus);
		assert_within_quantization("rf60x", &bus, &mock, 20);
	}
}

static void test_alarm_ends_scan(void **state)
{
	struct env *e = *state;
	struct asph_config *c;
	struct asph_error err;
	char path[128], port[16];

	struct mbsim *sim = sim_start(e, false, port, sizeof(port));
	/* the y drive fails at its 40th move */
	mbsim_inject(sim, 2, MBSIM_ALARM, 0x42, 40, -1);
	c = bench(e, false, port);
	int r = scan(e, c, new_path(&e->fx, path, sizeof(path)), &err);
	if (r != -EPROTO || !strstr(err.message, "axis y (unit 2): drive alarm, code 0x42"))
		fail_msg("%d %s", r, err.message);
	struct mbsim_stats ss;
	mbsim_stats(sim, &ss);
	mbsim_stop(sim);
	asph_config_free(c);
	for (int k = 0; k < 3; k++)
		assert_true(ss.stops[k] >= 1);
	struct asph_scanfile *s = read_scan(path);
	assert_int_equal(s->report.outcome, ASPH_SCANFILE_FAILED);
	assert_non_null(strstr(s->report.reason, "code 0x42"));
	assert_true(s->n > 0 && s->n < e->fx.plan->n);
	asph_scanfile_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_same_as_mock),
		cmocka_unit_test(test_sensor_profiles),
		cmocka_unit_test(test_alarm_ends_scan),
	};
	return cmocka_run_group_tests(tests, setup, teardown);
}
