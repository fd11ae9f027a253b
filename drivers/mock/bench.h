/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The mock instrument's physics: a stage whose axes follow their command
 * through a servo loop, read by encoders, with geometric errors and
 * ringing after moves; a probe that samples the part a latency after its
 * trigger, with slope bias, dropouts and noise; and a thermal drift of the
 * part against the probe. Everything runs on a simulated clock (seconds
 * since the bench was made), so that the physics is the same whether the
 * driver waits for it or not. docs/drivers.md ("The mock instrument")
 * states the model with its formulas. Internal.
 */
#ifndef ASPH_MOCK_BENCH_H
#define ASPH_MOCK_BENCH_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph-driver/driver.h"
#include "asph/error.h"
#include "asph/motion.h"

enum mock_capture {
	MOCK_CAPTURE_LATCHED = 0,       /* encoders latched on the probe's trigger */
	MOCK_CAPTURE_SAMPLED,           /* encoders logged every servo period */
	MOCK_CAPTURE_NONE,              /* no positions during sweeps */
};

struct mock_stage_params {
	bool rtz;                       /* axes r, theta, z */
	struct asph_motion_limits lim;  /* speed, accel, jerk per axis */
	double servo_bandwidth;         /* Hz; 0 = the axes are where commanded */
	double encoder_resolution;      /* mm; 0 = exact */
	double settle_time;             /* s; 0 = no ringing after a move */
	double straightness;            /* mm PV over the travel */
	double scale_error;             /* relative (ppm * 1e-6) */
	double travel_xy;               /* mm */
	enum mock_capture capture;
};

struct mock_probe_params {
	double latency;                 /* s */
	double rate;                    /* readings per s */
	double slope_bias;              /* mm per deg^2 */
	double dropout;                 /* probability */
	double max_slope;               /* rad; 0 = any */
	double noise;                   /* mm, standard deviation */
	uint64_t seed;
	double drift_z, drift_xy;       /* mm per s of the linear part */
};

/* What the probe sees at a sample: the stage's true cartesian position
 * (the probe reference point) and the time. */
struct mock_sample {
	double t;
	double pos[3];
};

/* A trigger of a sweep: when, the encoders latched then, and the sample the
 * probe took a latency later. */
struct mock_trigger {
	double t;
	double latched[3];              /* machine axes */
	struct mock_sample sample;
	bool sampled;                   /* the simulation has passed the sample */
};

struct mock_bench;

int mock_bench_new(const struct mock_stage_params *sp, struct mock_bench **out);
void mock_bench_free(struct mock_bench *b);

/* The probe mounted on the bench (its latency decides when it samples). */
void mock_bench_mount_probe(struct mock_bench *b, const struct mock_probe_params *pp);
bool mock_bench_has_probe(const struct mock_bench *b);

/* Simulated seconds since the bench was made. */
double mock_bench_now(const struct mock_bench *b);
/* The clock set to t, every state keeping its age; the axes at rest on
 * their command once within RING_NONE of it. */
void mock_bench_align(struct mock_bench *b, double t);
/* Lets time pass at rest (the probe waiting for its sample). */
void mock_bench_idle(struct mock_bench *b, double seconds);

/* The stage at rest at zero after homing. */
void mock_bench_home(struct mock_bench *b);
/* The command target and where the last motion ended (machine axes). */
void mock_bench_target(const struct mock_bench *b, double m[3]);

/* How long a move to target takes, without making it. */
double mock_bench_move_duration(const struct mock_bench *b, const double target[3]);

/* A straight move to target; returns its duration (the drive reports
 * target reached at the command's end; the axes still settle). */
double mock_bench_move(struct mock_bench *b, const double target[3]);

/* A sweep through positions at the stage's speed (ABI 1.0 sweeps), a
 * trigger at each; returns its duration. */
double mock_bench_sweep(struct mock_bench *b, const double *pos, size_t n);

/* A PVT sweep (ABI 1.1): the command follows the Hermite curve through the
 * knots; the trigger knots fire the probe. -EINVAL when the knots' times do
 * not increase, -EPROTO when the triggers come faster than the probe
 * reads. Returns the duration in *seconds. */
int mock_bench_sweep_pvt(struct mock_bench *b, const struct asph_pvt *k, size_t n,
			 double *seconds, struct asph_error *err);

/* The encoders now, after one read-back (the query takes MOCK_READ_S). */
#define MOCK_READ_S 0.0005
void mock_bench_read_position(struct mock_bench *b, double m[3]);

/* The stage's true cartesian position at time t (t at most the simulated
 * time, or at rest after it). */
void mock_bench_true_position(struct mock_bench *b, double t, double c[3]);

/* Triggers not yet taken by the probe: the oldest n. -EPROTO when fewer
 * are there, or when a sample lies ahead of the simulation while the stage
 * still moves (a reading asked for before its sample was taken). */
int mock_bench_take_triggers(struct mock_bench *b, size_t n, struct mock_trigger *out,
			     struct asph_error *err);
/* A software trigger now (step and measure): the sample a latency on. */
void mock_bench_trigger_now(struct mock_bench *b, struct mock_trigger *out);

/* The positions measured during sweeps since the last call: at most max. */
size_t mock_bench_trace(struct mock_bench *b, struct asph_position_sample *out, size_t max);

/* ------------------------------------------------------------ physics */

/* The settling a stage with these parameters advises for step and
 * measure (mm, s): when it rings after moves, 10 nm for a period of the
 * ringing; else none (0). */
void mock_stage_settling(const struct mock_stage_params *sp, double *window, double *dwell);

/* The drift of the part against the probe at t: along x, y, z (mm). */
void mock_drift(const struct mock_probe_params *pp, double t, double d[3]);

/* The probability of a dropout at a surface slope (rad). */
double mock_dropout_probability(const struct mock_probe_params *pp, double slope);

/* A standard Gaussian and a uniform number in [0, 1) that depend only on
 * the seed, the kind of measurement, its index and its attempt. The
 * Gaussian of a plan point's first attempt is the one the mock always
 * gave it. */
double mock_gaussian(uint64_t seed, uint32_t kind, uint64_t index, uint32_t attempt);
double mock_uniform(uint64_t seed, uint32_t kind, uint64_t index, uint32_t attempt);

#endif
