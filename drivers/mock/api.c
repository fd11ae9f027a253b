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

#include "asph/driver.h"
#include "asph/units.h"
#include "protocol.h"
#include "std.h"
#include "util-time.h"

enum {
	OPT_LENS, OPT_PROBE, OPT_KINEMATICS, OPT_TIP_RADIUS, OPT_STANDOFF,
	OPT_RANGE, OPT_MAX_SLOPE, OPT_SHIFT_X, OPT_SHIFT_Y, OPT_SHIFT_Z,
	OPT_TILT_X, OPT_TILT_Y, OPT_CLOCKING, OPT_FORM, OPT_NOISE, OPT_SEED, OPT_SPEED,
	OPT_RATE, OPT_TIME_FACTOR, OPT_TRAVEL_XY, OPT_TRAVEL_Z, OPT_STREAM,
	OPT_FAIL_AFTER, OPT_TIMEOUT_AT, OPT_OUT_OF_RANGE_AT, N_OPTIONS
};

static const char *const probe_types[] = { "optical", "tactile", NULL };
static const char *const kinematics[] = { "xyz", "r-theta-z", NULL };

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
		       .help = "noise seed: the noise of a plan point depends on the seed and its index only" },
	[OPT_SPEED] = { "speed", ASPH_OPTION_DOUBLE, "20", RANGE(0.001, 10000), .unit = "mm/s",
			.roles = S, .help = "stage speed (and rad/s for theta)" },
	[OPT_RATE] = { "rate", ASPH_OPTION_DOUBLE, "1000", RANGE(0.001, 1e9), .unit = "Hz",
		       .roles = P, .help = "probe readings per second" },
	[OPT_TIME_FACTOR] = { "time_factor", ASPH_OPTION_DOUBLE, "1", RANGE(0, 1000),
			      .help = "scales every simulated duration (0: no waiting)" },
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
};

#undef P
#undef S

struct asph_device {
	atomic_bool stop;
	bool stage;
	double time_factor;
	/* stage */
	double pos[3], speed, travel_xy, travel_z;
	enum asph_kinematics kin;
	bool homed;
	/* probe */
	struct mock_part *part;
	struct asph_probe_info pinfo;
	double rate;            /* readings per simulated second */
	uint64_t n_readings, fail_after, timeout_at, out_of_range_at;
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

/* ----------------------------------------------------------- stage */

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = dev_new(o, true);

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	d->speed = o[OPT_SPEED].d;
	d->travel_xy = o[OPT_TRAVEL_XY].d;
	d->travel_z = o[OPT_TRAVEL_Z].d;
	d->kin = o[OPT_KINEMATICS].i == 1 ? ASPH_KINEMATICS_RTZ : ASPH_KINEMATICS_XYZ;
	*out = d;
	return 0;
}

static void dev_close(struct asph_device *d)
{
	if (d)
		mock_part_free(d->part);
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

static int stage_info(struct asph_device *d, struct asph_stage_info *out,
		      struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->kinematics = d->kin;
	out->n_axes = 3;
	/* the speed as the executor sees it: scaled by the time factor
	 * (0: no limit) */
	double v = d->time_factor > 0 ? d->speed / d->time_factor : 0;
	if (d->kin == ASPH_KINEMATICS_RTZ) {
		axis(&out->axes[0], "r", "mm", 0, d->travel_xy, v);
		/* an endless rotary table, limited only to keep angles exact */
		axis(&out->axes[1], "theta", "rad", -1e6, 1e6, v);
	} else {
		axis(&out->axes[0], "x", "mm", -d->travel_xy, d->travel_xy, v);
		axis(&out->axes[1], "y", "mm", -d->travel_xy, d->travel_xy, v);
	}
	axis(&out->axes[2], "z", "mm", -d->travel_z, d->travel_z, v);
	snprintf(out->model, sizeof(out->model), "mock stage");
	snprintf(out->serial, sizeof(out->serial), "MOCK-0001");
	return 0;
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	double dist = fabs(d->pos[0]) + fabs(d->pos[1]) + fabs(d->pos[2]);
	int r = mock_wait(&d->stop, d->time_factor * dist / d->speed, timeout_ms);

	if (r == -ECANCELED)
		return asph_error_set(err, r, "homing stopped");
	if (r < 0)
		return asph_error_set(err, r, "homing did not finish within %u ms", timeout_ms);
	memset(d->pos, 0, sizeof(d->pos));
	d->homed = true;
	return 0;
}

static int check_target(const struct asph_device *d, const double *t, struct asph_error *err)
{
	struct asph_stage_info info;

	stage_info((struct asph_device *)d, &info, NULL);
	for (int k = 0; k < 3; k++)
		if (!(t[k] >= info.axes[k].min && t[k] <= info.axes[k].max))
			return asph_error_set(err, -ERANGE,
					      "axis %s: target %.6f %s is outside %.6g .. %.6g",
					      info.axes[k].name, t[k], info.axes[k].unit,
					      info.axes[k].min, info.axes[k].max);
	return 0;
}

static int stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		      struct asph_error *err)
{
	if (!d->homed)
		return asph_error_set(err, -EPROTO, "stage is not homed");
	int r = check_target(d, t, err);
	if (r < 0)
		return r;
	if (d->time_factor > 0) {
		double dist = 0;
		for (int k = 0; k < 3; k++)
			dist = fmax(dist, fabs(t[k] - d->pos[k]));
		r = mock_wait(&d->stop, d->time_factor * dist / d->speed, timeout_ms);
		if (r == -ECANCELED)
			return asph_error_set(err, r, "motion stopped");
		if (r < 0)
			return asph_error_set(err, r, "move did not finish within %u ms", timeout_ms);
	} else if (atomic_load_explicit(&d->stop, memory_order_relaxed)) {
		return asph_error_set(err, -ECANCELED, "motion stopped");
	}
	memcpy(d->pos, t, sizeof(d->pos));
	return 0;
}

static int stage_sweep(struct asph_device *d, const double *pos, size_t n,
		       unsigned timeout_ms, struct asph_error *err)
{
	/* Endpoints are checked as every point was checked by the executor;
	 * the time is the path length at speed. */
	double len = 0;
	const double *prev = d->pos;

	if (!d->homed)
		return asph_error_set(err, -EPROTO, "stage is not homed");
	if (n == 0)
		return 0;
	for (size_t i = 0; i < n && d->time_factor > 0; i++) {
		len += hypot(hypot(pos[3 * i] - prev[0], pos[3 * i + 1] - prev[1]),
			     pos[3 * i + 2] - prev[2]);
		prev = pos + 3 * i;
	}
	int r = check_target(d, pos + 3 * (n - 1), err);
	if (r == 0 && d->time_factor > 0)
		r = mock_wait(&d->stop, d->time_factor * len / d->speed, timeout_ms);
	else if (r == 0 && atomic_load_explicit(&d->stop, memory_order_relaxed))
		r = -ECANCELED;
	if (r == -ECANCELED)
		return asph_error_set(err, r, "motion stopped");
	if (r == -ETIMEDOUT)
		return asph_error_set(err, r, "sweep did not finish within %u ms", timeout_ms);
	if (r < 0)
		return r;
	memcpy(d->pos, pos + 3 * (n - 1), sizeof(d->pos));
	return 0;
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	memcpy(pos, d->pos, sizeof(d->pos));
	return 0;
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->state = d->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	out->homed = d->homed;
	memcpy(out->position, d->pos, sizeof(d->pos));
	return 0;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	return 0;
}

/* ----------------------------------------------------------- probe */

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
		.noise_nm = o[OPT_NOISE].d,
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
	struct asph_probe_info *pi = &d->pinfo;
	std_probe_geometry(pi, tactile, pp.tip_radius, o[OPT_STANDOFF].d, o[OPT_RANGE].d);
	pi->max_slope = o[OPT_MAX_SLOPE].d * M_PI / 180;
	d->rate = o[OPT_RATE].d;
	pi->rate = d->time_factor > 0 ? d->rate / d->time_factor : 0;
	pi->can_stream = !tactile && o[OPT_STREAM].b;
	snprintf(pi->model, sizeof(pi->model), "mock %s probe", tactile ? "tactile" : "optical");
	snprintf(pi->serial, sizeof(pi->serial), "MOCK-0002");
	d->fail_after = (uint64_t)o[OPT_FAIL_AFTER].i;
	d->timeout_at = (uint64_t)o[OPT_TIMEOUT_AT].i;
	d->out_of_range_at = (uint64_t)o[OPT_OUT_OF_RANGE_AT].i;
	*out = d;
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out,
		      struct asph_error *err)
{
	*out = d->pinfo;
	return 0;
}

/* One reading without pacing; faults by reading number. */
static int measure(struct asph_device *d, const struct asph_probe_context *ctx,
		   struct asph_reading *out, uint64_t t_ns, unsigned timeout_ms,
		   struct asph_error *err)
{
	uint64_t k = d->n_readings + 1;
	double z;

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
	memset(out, 0, sizeof(*out));
	out->t_ns = t_ns;
	if (k == d->out_of_range_at || mock_part_probe_z(d->part, ctx->xyz[0], ctx->xyz[1], ctx->plan_index, &z) < 0) {
		out->value = NAN;
		out->raw = NAN;
		out->flags = ASPH_READING_OUT_OF_RANGE;
		return 0;
	}
	out->value = z - ctx->xyz[2];
	out->raw = out->value;
	std_reading_check_range(out, &d->pinfo);
	return 0;
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	if (d->time_factor > 0) {
		int r = mock_wait(&d->stop, d->time_factor / d->rate, timeout_ms);
		if (r < 0)
			return asph_error_set(err, r, r == -ECANCELED ? "reading stopped"
								   : "reading took longer than the timeout");
	} else if (atomic_load_explicit(&d->stop, memory_order_relaxed)) {
		return asph_error_set(err, -ECANCELED, "reading stopped");
	}
	return measure(d, ctx, out, now_monotonic_ns(), timeout_ms, err);
}

static int probe_stream(struct asph_device *d, const struct asph_probe_context *ctx,
			size_t n, struct asph_reading *out, size_t *n_done,
			unsigned timeout_ms, struct asph_error *err)
{
	*n_done = 0;
	if (!d->pinfo.can_stream)
		return asph_error_set(err, -ENOTSUP, "this probe does not stream");
	if (d->time_factor > 0) {
		int r = mock_wait(&d->stop, d->time_factor * (double)n / d->rate, timeout_ms);
		if (r < 0)
			return asph_error_set(err, r, r == -ECANCELED ? "streaming stopped"
								   : "stream took longer than the timeout");
	} else if (atomic_load_explicit(&d->stop, memory_order_relaxed)) {
		return asph_error_set(err, -ECANCELED, "streaming stopped");
	}
	/* the readings of a sweep are spread over it at the probe's rate */
	uint64_t t0 = now_monotonic_ns();
	double dt = d->time_factor * 1e9 / d->rate;
	uint64_t t_end = t0 - (uint64_t)((double)n * dt);
	for (size_t i = 0; i < n; i++) {
		int r = measure(d, ctx + i, out + i, t_end + (uint64_t)((double)(i + 1) * dt),
				timeout_ms, err);
		if (r < 0)
			return r;
		*n_done = i + 1;
	}
	return 0;
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
};

static const struct asph_probe_ops mock_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stream = probe_stream,
	.stop = dev_stop,
};

const struct asph_driver mock_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "mock",
	.description = "simulated stage and probe measuring a simulated part",
	.version = "1.0",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = mock_options,
	.n_options = N_OPTIONS,
	.stage = &mock_stage,
	.probe = &mock_probe,
};
