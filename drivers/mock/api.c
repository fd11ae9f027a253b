/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The mock instrument: a simulated stage and probe measuring a simulated
 * part, with realistic pacing and fault injection. */
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "asph-driver/driver.h"
#include "asph/units.h"
#include "bench.h"
#include "protocol.h"
#include "std.h"
#include "util-time.h"

enum {
	OPT_LENS, OPT_PROBE, OPT_KINEMATICS, OPT_TIP_RADIUS, OPT_STANDOFF,
	OPT_RANGE, OPT_MAX_SLOPE, OPT_SHIFT_X, OPT_SHIFT_Y, OPT_SHIFT_Z,
	OPT_TILT_X, OPT_TILT_Y, OPT_CLOCKING, OPT_FORM, OPT_NOISE, OPT_SEED, OPT_SPEED,
	OPT_RATE, OPT_TIME_FACTOR, OPT_TRAVEL_XY, OPT_TRAVEL_Z, OPT_STREAM,
	OPT_FAIL_AFTER, OPT_TIMEOUT_AT, OPT_OUT_OF_RANGE_AT,
	/* the physical instrument */
	OPT_BENCH, OPT_ACCEL, OPT_JERK, OPT_SERVO_BANDWIDTH, OPT_ENCODER_RESOLUTION,
	OPT_SETTLE_TIME, OPT_STRAIGHTNESS, OPT_SCALE_ERROR, OPT_CAPTURE, OPT_LATENCY,
	OPT_SLOPE_BIAS, OPT_DROPOUT, OPT_DRIFT_Z, OPT_DRIFT_XY, N_OPTIONS
};

static const char *const probe_types[] = { "optical", "tactile", NULL };
static const char *const kinematics[] = { "xyz", "r-theta-z", NULL };
static const char *const benches[] = { "ideal", "realistic", NULL };
static const char *const captures[] = { "latched", "sampled", "none", NULL };

#define P ASPH_ROLE_PROBE
#define S ASPH_ROLE_STAGE
#define RANGE(lo, hi) .ranged = true, .min = (lo), .max = (hi)

static const struct asph_option_desc mock_options[N_OPTIONS] = {
	[OPT_LENS] = { "lens", ASPH_OPTION_STRING, "", .roles = P,
		       .help = "the part: a preset (weak, strong, turning-point) or a prescription file; "
			       "unset, the lens being measured (strong without a job)" },
	[OPT_PROBE] = { "probe", ASPH_OPTION_ENUM, "optical", .choices = probe_types, .roles = P,
			.help = "probe type" },
	[OPT_KINEMATICS] = { "kinematics", ASPH_OPTION_ENUM, "xyz", .choices = kinematics,
			     .roles = S, .help = "stage axes: x, y, z or a rotary table r, theta, z" },
	[OPT_TIP_RADIUS] = { "tip_radius", ASPH_OPTION_DOUBLE, "0.5", RANGE(0.01, 10), .unit = "mm",
			     .roles = P, .help = "tip ball radius of the tactile probe" },
	[OPT_STANDOFF] = { "standoff", ASPH_OPTION_DOUBLE, "2", RANGE(0, 100), .unit = "mm",
			   .roles = P, .help = "reading the probe wants on the nominal surface" },
	[OPT_RANGE] = { "range", ASPH_OPTION_DOUBLE, "1", RANGE(0.001, 100), .unit = "mm",
			.roles = P, .help = "measuring range, centred on the standoff" },
	[OPT_MAX_SLOPE] = { "max_slope", ASPH_OPTION_DOUBLE, "0", RANGE(0, 90), .unit = "deg",
			    .roles = P, .help = "steepest surface the probe reads (0 = any)" },
	[OPT_SHIFT_X] = { "shift_x", ASPH_OPTION_DOUBLE, "0", RANGE(-5, 5), .unit = "mm",
			  .roles = P, .help = "part misalignment: shift along x" },
	[OPT_SHIFT_Y] = { "shift_y", ASPH_OPTION_DOUBLE, "0", RANGE(-5, 5), .unit = "mm",
			  .roles = P, .help = "part misalignment: shift along y" },
	[OPT_SHIFT_Z] = { "shift_z", ASPH_OPTION_DOUBLE, "0", RANGE(-5, 5), .unit = "mm",
			  .roles = P, .help = "part misalignment: shift along z" },
	[OPT_TILT_X] = { "tilt_x", ASPH_OPTION_DOUBLE, "0", RANGE(-50000, 50000), .unit = "urad",
			 .roles = P, .help = "part misalignment: rotation about x (rx of asph fit)" },
	[OPT_TILT_Y] = { "tilt_y", ASPH_OPTION_DOUBLE, "0", RANGE(-50000, 50000), .unit = "urad",
			 .roles = P, .help = "part misalignment: rotation about y (ry of asph fit)" },
	[OPT_CLOCKING] = { "clocking", ASPH_OPTION_DOUBLE, "0", RANGE(-3141593, 3141593),
			   .unit = "urad", .roles = P,
			   .help = "part misalignment: rotation about its own axis, applied first (rz of asph fit)" },
	[OPT_FORM] = { "form", ASPH_OPTION_STRING, "", .unit = "nm", .roles = P,
		       .help = "form error as Zernike terms, NOLL:NM pairs separated by ';' (e.g. 4:30;9:-12)" },
	[OPT_NOISE] = { "noise", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e6), .unit = "nm", .roles = P,
			.help = "Gaussian noise of the readings (standard deviation)" },
	[OPT_SEED] = { "seed", ASPH_OPTION_INT, "1", RANGE(0, 4294967295.0), .roles = P,
		       .help = "seed of the random effects: they depend on it and on the measurement "
			       "(plan index, attempt) only" },
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "20", RANGE(0.001, 10000), .unit = "mm/s",
			.roles = S, .help = "stage speed of each axis (and rad/s for theta)" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "1000", RANGE(0.001, 1e9), .unit = "Hz",
		       .roles = P, .help = "probe readings per second" },
	[OPT_TIME_FACTOR] = { "time_factor", ASPH_OPTION_DOUBLE, "1", RANGE(0, 1000),
			      .help = "wall-clock seconds per simulated second (0: no waiting; the "
				      "physics runs on the simulated clock either way)" },
	[OPT_TRAVEL_XY] = { "travel_xy", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			    .roles = S, .help = "x and y (or r) travel: -travel_xy .. travel_xy" },
	[OPT_TRAVEL_Z] = { "travel_z", ASPH_OPTION_DOUBLE, "50", RANGE(0.1, 10000), .unit = "mm",
			   .roles = S, .help = "z travel: -travel_z .. travel_z" },
	[OPT_STREAM] = { "stream", ASPH_OPTION_BOOL, "true",
			 .help = "optical probe streams along sweeps of the stage" },
	[OPT_FAIL_AFTER] = { "fail_after", ASPH_OPTION_INT, "0", RANGE(0, 1e15), .unit = "points",
			     .roles = P, .help = "fault: the probe disconnects after N readings (0 = never)" },
	[OPT_TIMEOUT_AT] = { "timeout_at", ASPH_OPTION_INT, "0", RANGE(0, 1e15), .unit = "points",
			     .roles = P, .help = "fault: reading N never answers (0 = never)" },
	[OPT_OUT_OF_RANGE_AT] = { "out_of_range_at", ASPH_OPTION_INT, "0", RANGE(0, 1e15),
				  .unit = "points", .roles = P,
				  .help = "fault: reading N is out of range (0 = never)" },
	[OPT_BENCH] = { "bench", ASPH_OPTION_ENUM, "ideal", .choices = benches,
			.help = "preset of the physical options: ideal (all off) or realistic (a good "
				"bench: docs/drivers.md); options given set themselves over it" },
	[OPT_ACCEL] = { "accel", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e7), .unit = "mm/s^2", .roles = S,
			.help = "acceleration limit of each axis (0 = none)" },
	[OPT_JERK] = { "jerk", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e10), .unit = "mm/s^3", .roles = S,
		       .help = "jerk limit of each axis (0 = none)" },
	[OPT_SERVO_BANDWIDTH] = { "servo_bandwidth", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1e6),
				  .unit = "Hz", .roles = S,
				  .help = "servo loop bandwidth: the axes lag their command by v / (2 pi f) "
					  "- a / (2 pi f)^2 + ... (0 = exactly on it)" },
	[OPT_ENCODER_RESOLUTION] = { "encoder_resolution", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1),
				     .unit = "mm", .roles = S,
				     .help = "step of the linear encoders (0 = exact)" },
	[OPT_SETTLE_TIME] = { "settle_time", ASPH_OPTION_DOUBLE, "0", RANGE(0, 10), .unit = "s",
			      .roles = S,
			      .help = "after a move the stage rings down to 1 nm within this time (0 = none)" },
	[OPT_STRAIGHTNESS] = { "straightness", ASPH_OPTION_DOUBLE, "0", RANGE(-1000, 1000),
			       .unit = "um", .roles = S,
			       .help = "bow of the x and y guides in z, PV over the travel (the encoders "
				       "do not see it)" },
	[OPT_SCALE_ERROR] = { "scale_error", ASPH_OPTION_DOUBLE, "0", RANGE(-10000, 10000),
			      .unit = "ppm", .roles = S,
			      .help = "error of the linear encoders' scales" },
	[OPT_CAPTURE] = { "capture", ASPH_OPTION_ENUM, "latched", .choices = captures, .roles = S,
			  .help = "positions during sweeps: latched on the probe's trigger, sampled every "
				  "servo period (1 ms), or none" },
	[OPT_LATENCY] = { "latency", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1), .unit = "s", .roles = P,
			  .help = "from the probe's trigger to the instant it samples" },
	[OPT_SLOPE_BIAS] = { "slope_bias", ASPH_OPTION_DOUBLE, "0", RANGE(-1e6, 1e6),
			     .unit = "nm/deg^2", .roles = P,
			     .help = "reading error per square degree of surface slope (chromatic "
				     "confocal probes)" },
	[OPT_DROPOUT] = { "dropout", ASPH_OPTION_DOUBLE, "0", RANGE(0, 1), .roles = P,
			  .help = "probability of an invalid reading at max_slope (falling as the "
				  "sixth power of slope / max_slope; everywhere without max_slope)" },
	[OPT_DRIFT_Z] = { "drift_z", ASPH_OPTION_DOUBLE, "0", RANGE(-1e6, 1e6), .unit = "nm/min",
			  .roles = P, .help = "thermal drift of the part against the probe along z: "
					      "linear plus a 20-minute cycle" },
	[OPT_DRIFT_XY] = { "drift_xy", ASPH_OPTION_DOUBLE, "0", RANGE(-1e6, 1e6), .unit = "nm/min",
			   .roles = P, .help = "the same across, along (0.8, 0.6) in x, y" },
};

/* bench=realistic: what a user meets on a good bench (docs/drivers.md). An
 * option the configuration sets itself is kept. */
static const struct {
	int option;
	double value;
} realistic[] = {
	{ OPT_ACCEL, 1000 },                    /* mm/s^2 */
	{ OPT_JERK, 50000 },                    /* mm/s^3 */
	/* following error v / (2 pi f): 4.997 um at 20 mm/s */
	{ OPT_SERVO_BANDWIDTH, 637 },
	{ OPT_ENCODER_RESOLUTION, 1e-6 },       /* 1 nm */
	{ OPT_SETTLE_TIME, 0.02 },
	{ OPT_LATENCY, 0.0005 },
	{ OPT_DRIFT_Z, 20 },                    /* nm/min */
};

/* The value of option k, the preset's when the configuration left it. */
static double opt(const struct asph_option_value *o, int k)
{
	if (!o[k].set && o[OPT_BENCH].i == 1)
		for (size_t i = 0; i < sizeof(realistic) / sizeof(realistic[0]); i++)
			if (realistic[i].option == k)
				return realistic[i].value;
	return o[k].d;
}

#undef P
#undef S

struct asph_device {
	atomic_bool stop;
	bool stage;
	double time_factor;
	/* stage */
	struct mock_bench *bench;       /* the stage's; a mounted probe shares it */
	struct mock_stage_params sp;
	double travel_z;
	struct asph_stage_info info;    /* as described: the axes' ranges */
	bool homed;
	/* probe */
	struct mock_part *part;
	struct asph_probe_info pinfo;
	struct mock_probe_params pp;
	struct mock_bench *mounted;     /* the bench of the stage it is on */
	uint64_t t0_ns;                 /* its own clock's start, off a bench */
	uint64_t n_readings, fail_after, timeout_at, out_of_range_at;
	struct mock_trigger *trig;      /* the triggers a stream takes */
	size_t trig_cap;
};

static struct asph_device *dev_new(const struct asph_option_value *o, bool stage)
{
	struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return NULL;
	atomic_init(&d->stop, false);
	d->stage = stage;
	d->time_factor = o[OPT_TIME_FACTOR].d;
	return d;
}

/* Waits the wall-clock time of seconds of simulated time, watching stop. */
static int pace(struct asph_device *d, double seconds, unsigned timeout_ms, const char *what,
		struct asph_error *err)
{
	int r = 0;

	if (d->time_factor > 0 && seconds > 0)
		r = mock_wait(&d->stop, d->time_factor * seconds, timeout_ms);
	else if (atomic_load_explicit(&d->stop, memory_order_relaxed))
		r = -ECANCELED;
	if (r == -ECANCELED)
		return asph_error_set(err, r, "%s stopped", what);
	if (r < 0)
		return asph_error_set(err, r, "%s did not finish within %u ms", what, timeout_ms);
	return 0;
}

/* ----------------------------------------------------------- stage */

static void stage_params(const struct asph_option_value *o, struct mock_stage_params *sp)
{
	memset(sp, 0, sizeof(*sp));
	sp->rtz = o[OPT_KINEMATICS].i == 1;
	for (int k = 0; k < 3; k++) {
		sp->lim.speed[k] = o[OPT_SPEED].d;
		sp->lim.accel[k] = opt(o, OPT_ACCEL);
		sp->lim.jerk[k] = opt(o, OPT_JERK);
	}
	sp->servo_bandwidth = opt(o, OPT_SERVO_BANDWIDTH);
	sp->encoder_resolution = opt(o, OPT_ENCODER_RESOLUTION);
	sp->settle_time = opt(o, OPT_SETTLE_TIME);
	sp->straightness = opt(o, OPT_STRAIGHTNESS) * 1e-3;
	sp->scale_error = opt(o, OPT_SCALE_ERROR) * 1e-6;
	sp->travel_xy = o[OPT_TRAVEL_XY].d;
	sp->capture = (enum mock_capture)o[OPT_CAPTURE].i;
}

static void describe_stage(const struct mock_stage_params *sp, double travel_z,
			   struct asph_stage_info *out);

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = dev_new(o, true);

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	stage_params(o, &d->sp);
	d->travel_z = o[OPT_TRAVEL_Z].d;
	describe_stage(&d->sp, d->travel_z, &d->info);
	if (mock_bench_new(&d->sp, &d->bench) < 0) {
		free(d);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	*out = d;
	return 0;
}

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	mock_part_free(d->part);
	mock_bench_free(d->bench);
	free(d->trig);
	free(d);
}

static void axis(struct asph_axis_info *a, const char *name, const char *unit,
		 double lo, double hi, double speed)
{
	snprintf(a->name, sizeof(a->name), "%s", name);
	snprintf(a->unit, sizeof(a->unit), "%s", unit);
	a->min = lo;
	a->max = hi;
	a->max_speed = speed;
}

/* The stage as its parameters say (open or not): speeds and the rest in
 * simulated time, which the executor plans in. */
static void describe_stage(const struct mock_stage_params *sp, double travel_z,
			   struct asph_stage_info *out)
{
	memset(out, 0, sizeof(*out));
	out->kinematics = sp->rtz ? ASPH_KINEMATICS_RTZ : ASPH_KINEMATICS_XYZ;
	out->n_axes = 3;
	if (sp->rtz) {
		axis(&out->axes[0], "r", "mm", 0, sp->travel_xy, sp->lim.speed[0]);
		/* an endless rotary table, limited only to keep angles exact */
		axis(&out->axes[1], "theta", "rad", -1e6, 1e6, sp->lim.speed[1]);
	} else {
		axis(&out->axes[0], "x", "mm", -sp->travel_xy, sp->travel_xy, sp->lim.speed[0]);
		axis(&out->axes[1], "y", "mm", -sp->travel_xy, sp->travel_xy, sp->lim.speed[1]);
	}
	axis(&out->axes[2], "z", "mm", -travel_z, travel_z, sp->lim.speed[2]);
	for (int k = 0; k < 3; k++) {
		out->max_accel[k] = sp->lim.accel[k];
		out->max_jerk[k] = sp->lim.jerk[k];
	}
	mock_stage_settling(sp, &out->settle_window, &out->settle_dwell);
	snprintf(out->model, sizeof(out->model), "mock stage");
	snprintf(out->serial, sizeof(out->serial), "MOCK-0001");
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out,
		      struct asph_error *err)
{
	*out = d->info;
	return 0;
}

static int stage_describe(const struct asph_driver *drv, const struct asph_option_value *o,
			  struct asph_stage_info *out, struct asph_error *err)
{
	struct mock_stage_params sp;

	stage_params(o, &sp);
	describe_stage(&sp, o[OPT_TRAVEL_Z].d, out);
	return 0;
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	double at[3];

	mock_bench_target(d->bench, at);
	double dist = fabs(at[0]) + fabs(at[1]) + fabs(at[2]);
	int r = pace(d, dist / d->sp.lim.speed[0], timeout_ms, "homing", err);
	if (r < 0)
		return r;
	mock_bench_home(d->bench);
	d->homed = true;
	return 0;
}

static int check_target(const struct asph_device *d, const double *t, struct asph_error *err)
{
	const struct asph_axis_info *ax = d->info.axes;

	for (int k = 0; k < 3; k++)
		if (!(t[k] >= ax[k].min && t[k] <= ax[k].max))
			return asph_error_set(err, -ERANGE,
					      "axis %s: target %.6f %s is outside %.6g .. %.6g",
					      ax[k].name, t[k], ax[k].unit, ax[k].min, ax[k].max);
	return 0;
}

static int ready(struct asph_device *d, struct asph_error *err)
{
	if (!d->homed)
		return asph_error_set(err, -EPROTO, "stage is not homed");
	if (atomic_load_explicit(&d->stop, memory_order_relaxed))
		return asph_error_set(err, -ECANCELED, "motion stopped");
	return 0;
}

static int stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		      struct asph_error *err)
{
	int r = ready(d, err);

	if (r == 0)
		r = check_target(d, t, err);
	if (r < 0)
		return r;
	/* the stage is there when the wait is over, not when it is cut short */
	r = pace(d, mock_bench_move_duration(d->bench, t), timeout_ms, "move", err);
	if (r == 0)
		mock_bench_move(d->bench, t);
	return r;
}

static int stage_sweep(struct asph_device *d, const double *pos, size_t n,
		       unsigned timeout_ms, struct asph_error *err)
{
	int r = ready(d, err);

	/* the executor checked every point; the end is checked here */
	if (r == 0 && n)
		r = check_target(d, pos + 3 * (n - 1), err);
	if (r < 0 || n == 0)
		return r;
	return pace(d, mock_bench_sweep(d->bench, pos, n), timeout_ms, "sweep", err);
}

static int stage_sweep_pvt(struct asph_device *d, const struct asph_pvt *k, size_t n,
			   unsigned timeout_ms, struct asph_error *err)
{
	double seconds;
	int r = ready(d, err);

	for (size_t i = 0; i < n && r == 0; i++)
		r = check_target(d, k[i].position, err);
	if (r == 0)
		r = mock_bench_sweep_pvt(d->bench, k, n, &seconds, err);
	if (r < 0)
		return r;
	return pace(d, seconds, timeout_ms, "sweep", err);
}

static int stage_trace(struct asph_device *d, struct asph_position_sample *out, size_t max,
		       size_t *n, unsigned timeout_ms, struct asph_error *err)
{
	*n = mock_bench_trace(d->bench, out, max);
	return 0;
}

static int stage_clock(struct asph_device *d, uint64_t *t_ns)
{
	*t_ns = (uint64_t)llround(mock_bench_now(d->bench) * 1e9);
	return 0;
}

static int stage_clock_align(struct asph_device *d, uint64_t t_ns, struct asph_error *err)
{
	mock_bench_align(d->bench, (double)t_ns * 1e-9);
	return 0;
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	mock_bench_read_position(d->bench, pos);
	return pace(d, MOCK_READ_S, timeout_ms, "reading the position", err);
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->state = d->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	out->homed = d->homed;
	mock_bench_target(d->bench, out->position);
	return 0;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	return 0;
}

/* ----------------------------------------------------------- probe */

static void probe_params(const struct asph_option_value *o, struct mock_probe_params *pp)
{
	memset(pp, 0, sizeof(*pp));
	pp->latency = opt(o, OPT_LATENCY);
	pp->rate = o[OPT_RATE].d;
	pp->slope_bias = opt(o, OPT_SLOPE_BIAS) * 1e-6;
	pp->dropout = opt(o, OPT_DROPOUT);
	pp->max_slope = o[OPT_MAX_SLOPE].d * M_PI / 180;
	pp->noise = asph_nm_to_mm((asph_nm){ o[OPT_NOISE].d });
	pp->seed = (uint64_t)o[OPT_SEED].i;
	/* nm/min to mm/s */
	pp->drift_z = opt(o, OPT_DRIFT_Z) * 1e-6 / 60;
	pp->drift_xy = opt(o, OPT_DRIFT_XY) * 1e-6 / 60;
}

static void describe_probe(const struct asph_option_value *o, struct asph_probe_info *pi)
{
	bool tactile = o[OPT_PROBE].i == 1;

	memset(pi, 0, sizeof(*pi));
	std_probe_geometry(pi, tactile, o[OPT_TIP_RADIUS].d, o[OPT_STANDOFF].d, o[OPT_RANGE].d);
	pi->max_slope = o[OPT_MAX_SLOPE].d * M_PI / 180;
	pi->rate = o[OPT_RATE].d;
	pi->can_stream = !tactile && o[OPT_STREAM].b;
	pi->latency = opt(o, OPT_LATENCY);
	snprintf(pi->model, sizeof(pi->model), "mock %s probe", tactile ? "tactile" : "optical");
	snprintf(pi->serial, sizeof(pi->serial), "MOCK-0002");
}

static int probe_describe(const struct asph_driver *drv, const struct asph_option_value *o,
			  struct asph_probe_info *out, struct asph_error *err)
{
	describe_probe(o, out);
	return 0;
}

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = dev_new(o, false);
	bool tactile = o[OPT_PROBE].i == 1;
	struct mock_part_params pp = {
		.lens = o[OPT_LENS].s,
		.pose = { .t = { o[OPT_SHIFT_X].d, o[OPT_SHIFT_Y].d, o[OPT_SHIFT_Z].d },
			  .rx = o[OPT_TILT_X].d * 1e-6, .ry = o[OPT_TILT_Y].d * 1e-6,
			  .rz = o[OPT_CLOCKING].d * 1e-6 },
		.form = o[OPT_FORM].s,
		/* the probe adds the noise of each measurement itself */
		.noise_nm = 0,
		.seed = (unsigned long)o[OPT_SEED].i,
		.tip_radius = tactile ? o[OPT_TIP_RADIUS].d : 0,
	};

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	int r = mock_part_new(&pp, &d->part, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	describe_probe(o, &d->pinfo);
	probe_params(o, &d->pp);
	d->t0_ns = now_monotonic_ns();
	d->fail_after = (uint64_t)o[OPT_FAIL_AFTER].i;
	d->timeout_at = (uint64_t)o[OPT_TIMEOUT_AT].i;
	d->out_of_range_at = (uint64_t)o[OPT_OUT_OF_RANGE_AT].i;
	*out = d;
	return 0;
}

/* Mounted on a mock stage, the probe is wired to it: the bench's trigger
 * fires it, it samples where the stage truly is, on the bench's clock. */
static int probe_attach(struct asph_device *d, const struct asph_driver *stage_driver,
			struct asph_device *stage)
{
	if (stage_driver->stage->open != stage_open)
		return 0;
	d->mounted = stage->bench;
	mock_bench_mount_probe(d->mounted, &d->pp);
	return 1;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out,
		      struct asph_error *err)
{
	*out = d->pinfo;
	return 0;
}

/* The faults by reading number: 0 to read, else the error. */
static int fault(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t k = d->n_readings + 1;

	if (d->fail_after && d->n_readings >= d->fail_after)
		return asph_error_set(err, -ENODEV, "probe disconnected after %llu readings",
				      (unsigned long long)d->n_readings);
	if (k == d->timeout_at) {
		int r = mock_wait(&d->stop, d->time_factor * timeout_ms / 1000.0, timeout_ms);
		if (r == -ECANCELED)
			return asph_error_set(err, r, "reading stopped");
		return asph_error_set(err, -ETIMEDOUT, "probe did not answer reading %llu within %u ms",
				      (unsigned long long)k, timeout_ms);
	}
	d->n_readings = k;
	return 0;
}

/*
 * The reading of a sample: the part drifted by d against the probe, seen
 * from the probe's reference point c at time t, with the slope's bias, a
 * dropout near the steepest slope and the noise of this measurement.
 */
static void measure(struct asph_device *d, const struct asph_probe_context *ctx,
		    const double c[3], double t, uint64_t t_ns, struct asph_reading *out)
{
	double drift[3], z;

	memset(out, 0, sizeof(*out));
	out->t_ns = t_ns;
	mock_drift(&d->pp, t, drift);
	double x = c[0] - drift[0], y = c[1] - drift[1];
	if (d->n_readings == d->out_of_range_at ||
	    mock_part_probe_z(d->part, x, y, ctx->plan_index, &z) < 0) {
		out->value = out->raw = NAN;
		out->flags = ASPH_READING_OUT_OF_RANGE;
		return;
	}
	double slope = (d->pp.slope_bias != 0 || d->pp.dropout > 0) ? mock_part_slope(d->part, x, y) : 0;
	if (d->pp.dropout > 0 &&
	    mock_uniform(d->pp.seed, ctx->kind, ctx->plan_index, ctx->attempt) <
		    mock_dropout_probability(&d->pp, slope)) {
		out->value = out->raw = NAN;
		out->flags = ASPH_READING_INVALID;
		return;
	}
	out->value = z + drift[2] - c[2];
	if (d->pp.slope_bias != 0) {
		double deg = slope * 180 / M_PI;
		out->value += d->pp.slope_bias * deg * deg;
	}
	if (d->pp.noise > 0)
		out->value += d->pp.noise * mock_gaussian(d->pp.seed, ctx->kind, ctx->plan_index,
							  ctx->attempt);
	out->raw = out->value;
	std_reading_check_range(out, &d->pinfo);
}

/* Off a mock stage: the probe knows only where it is told it is, and
 * counts time on its own clock. */
static double own_time(const struct asph_device *d)
{
	return (double)(now_monotonic_ns() - d->t0_ns) * 1e-9 /
	       (d->time_factor > 0 ? d->time_factor : 1);
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	int r = fault(d, timeout_ms, err);

	if (r < 0)
		return r;
	if (!d->mounted) {
		r = pace(d, 1 / d->pp.rate, timeout_ms, "reading", err);
		if (r == 0)
			measure(d, ctx, ctx->xyz, own_time(d), now_monotonic_ns(), out);
		return r;
	}
	double t0 = mock_bench_now(d->mounted);
	struct mock_trigger tr;
	mock_bench_trigger_now(d->mounted, &tr);
	r = pace(d, mock_bench_now(d->mounted) - t0, timeout_ms, "reading", err);
	if (r == 0)
		measure(d, ctx, tr.sample.pos, tr.sample.t, (uint64_t)llround(tr.t * 1e9), out);
	return r;
}

static int probe_stream(struct asph_device *d, const struct asph_probe_context *ctx,
			size_t n, struct asph_reading *out, size_t *n_done,
			unsigned timeout_ms, struct asph_error *err)
{
	int r = 0;

	*n_done = 0;
	if (!d->pinfo.can_stream)
		return asph_error_set(err, -ENOTSUP, "this probe does not stream");
	if (!d->mounted) {
		/* readings at the positions given, at the probe's rate */
		r = pace(d, (double)n / d->pp.rate, timeout_ms, "streaming", err);
		uint64_t t_end = now_monotonic_ns();
		double dt = d->time_factor * 1e9 / d->pp.rate;
		for (size_t i = 0; i < n && r == 0; i++) {
			r = fault(d, timeout_ms, err);
			if (r == 0) {
				uint64_t t = t_end - (uint64_t)((double)(n - 1 - i) * dt);
				measure(d, ctx + i, ctx[i].xyz, own_time(d), t, out + i);
				*n_done = i + 1;
			}
		}
		return r;
	}
	if (n > d->trig_cap) {
		struct mock_trigger *t = realloc(d->trig, n * sizeof(*t));
		if (!t)
			return asph_error_set(err, -ENOMEM, "out of memory");
		d->trig = t;
		d->trig_cap = n;
	}
	double t0 = mock_bench_now(d->mounted);
	r = mock_bench_take_triggers(d->mounted, n, d->trig, err);
	if (r == 0)
		r = pace(d, mock_bench_now(d->mounted) - t0, timeout_ms, "streaming", err);
	for (size_t i = 0; i < n && r == 0; i++) {
		r = fault(d, timeout_ms, err);
		if (r == 0) {
			measure(d, ctx + i, d->trig[i].sample.pos, d->trig[i].sample.t,
				(uint64_t)llround(d->trig[i].t * 1e9), out + i);
			*n_done = i + 1;
		}
	}
	return r;
}

static const struct asph_stage_ops mock_stage = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = stage_home,
	.move_to = stage_move,
	.sweep = stage_sweep,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
	.sweep_pvt = stage_sweep_pvt,
	.sweep_trace = stage_trace,
	.clock = stage_clock,
	.describe = stage_describe,
	.clock_align = stage_clock_align,
};

static const struct asph_probe_ops mock_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stream = probe_stream,
	.stop = dev_stop,
	.attach = probe_attach,
	.describe = probe_describe,
};

const struct asph_driver mock_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "mock",
	.description = "simulated stage and probe measuring a simulated part: a physical virtual "
		       "instrument",
	.version = "2.0",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = mock_options,
	.n_options = N_OPTIONS,
	.stage = &mock_stage,
	.probe = &mock_probe,
};
