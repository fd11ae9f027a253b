/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_DRIVER_H
#define ASPH_DRIVER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The instrument driver ABI. An instrument is a stage that carries a probe
 * over the part; a driver provides one or both roles. A driver is a
 * constant struct asph_driver: its name, the roles it plays, the options it
 * takes (described well enough for a configuration to be checked before
 * anything opens) and a table of operations per role. docs/drivers.md has
 * the whole contract; the rules every driver keeps:
 *
 * - Every operation returns 0 or a negative errno and then fills the
 *   optional struct asph_error with a reason a person can act on:
 *   -ENODEV the device is gone, -ETIMEDOUT no answer in time, -ERANGE a
 *   travel limit or the probe's range was hit, -EPROTO the device said
 *   something that makes no sense, -ECANCELED stopped by stop(), -EIO a
 *   transport error, -EINVAL a bad argument.
 * - No operation blocks longer than the timeout it is given (ms; 0 means
 *   "do not wait": poll once).
 * - stop() may be called from any thread while another operation of the
 *   same device runs; it must return promptly and make that operation
 *   return -ECANCELED. No other operation is called concurrently.
 *
 * The header is self-contained: a driver built outside the tree needs no
 * library symbol (struct asph_error may be filled directly).
 */

/*
 * The ABI's version: the major number grows on any incompatible change of
 * the structures below (including struct asph_error of asph/error.h, which
 * drivers fill), the minor number when members are appended to them. A
 * driver records the version it was built with; the host loads drivers of
 * its major version and of any minor version up to its own, and reads
 * nothing a driver's minor version does not have (docs/drivers.md).
 *
 *   1.0  the first version
 *   1.1  measured positions with their source in readings, timed (PVT)
 *        sweeps with the positions a stage latched or sampled, the device
 *        clock, the probe's latency, attach() of a probe to its stage,
 *        invalid readings, the attempt and kind of a measurement, axis
 *        accelerations and jerks, and describe() without opening
 *   1.2  the settling a stage advises for step and measure, the clock of a
 *        simulated stage aligned (clock_align)
 *   1.3  the time of a stage's own moves and sweeps predicted from its
 *        options (motion_time)
 */
#define ASPH_DRIVER_ABI_MAJOR 1
#define ASPH_DRIVER_ABI_MINOR 3
#define ASPH_DRIVER_ABI(major, minor) ((uint32_t)(major) | (uint32_t)(minor) << 16)
#define ASPH_DRIVER_ABI_VERSION ASPH_DRIVER_ABI(ASPH_DRIVER_ABI_MAJOR, ASPH_DRIVER_ABI_MINOR)
#define ASPH_DRIVER_ABI_MAJOR_OF(v) ((uint32_t)(v) & 0xffffu)
#define ASPH_DRIVER_ABI_MINOR_OF(v) ((uint32_t)(v) >> 16)

#define ASPH_DRIVER_MAX_AXES 3

enum asph_driver_role {
	ASPH_ROLE_STAGE = 1u << 0,
	ASPH_ROLE_PROBE = 1u << 1,
};

/* ------------------------------------------------------------ options */

enum asph_option_type {
	ASPH_OPTION_BOOL = 0,   /* true/false, yes/no, on/off, 1/0 */
	ASPH_OPTION_INT,        /* 64-bit signed */
	ASPH_OPTION_DOUBLE,
	ASPH_OPTION_STRING,
	ASPH_OPTION_ENUM,       /* one of choices */
};

/* In reading order, not packed: descriptors are a few static tables, and
 * the layout is part of driver ABI version 1. */
struct asph_option_desc { /* NOLINT(clang-analyzer-optin.performance.Padding) */
	const char *name;               /* [a-z0-9_]+ */
	enum asph_option_type type;
	const char *default_value;      /* text, parsed as a user's value */
	bool ranged;                    /* INT, DOUBLE: min..max applies */
	double min, max;                /* inclusive */
	const char *unit;               /* "mm", "nm", "Hz", ... or NULL */
	const char *const *choices;     /* ENUM: NULL-terminated */
	unsigned roles;                 /* roles that use it; 0 = all */
	const char *help;
};

/* A resolved option, parallel to the driver's descriptors. */
struct asph_option_value {
	enum asph_option_type type;
	bool set;               /* given by the configuration, not default */
	bool b;
	int64_t i;              /* INT; ENUM: index into choices */
	double d;
	const char *s;          /* STRING; ENUM: the choice; valid until the
				 * device is closed */
};

/* ------------------------------------------------------------- stage */

enum asph_kinematics {
	/* axes x, y, z in mm */
	ASPH_KINEMATICS_XYZ = 0,
	/* axes r (mm), theta (rad, a rotary table under the part), z (mm);
	 * x = r cos theta, y = r sin theta */
	ASPH_KINEMATICS_RTZ,
};

struct asph_axis_info {
	char name[16];          /* "x", "theta", ... */
	char unit[8];           /* "mm" or "rad" */
	double min, max;        /* travel limits, in unit */
	double max_speed;       /* unit per s; 0 = unknown */
};

struct asph_stage_info {
	enum asph_kinematics kinematics;
	unsigned n_axes;
	struct asph_axis_info axes[ASPH_DRIVER_MAX_AXES];
	char model[64];
	char serial[64];
	/* 1.1: per axis, unit per s^2 and s^3; 0 = unknown */
	double max_accel[ASPH_DRIVER_MAX_AXES];
	double max_jerk[ASPH_DRIVER_MAX_AXES];
	/* 1.2: the settling the stage advises for step and measure, used
	 * where the instrument sets none (docs/scanning.md): read once the
	 * read-back has stayed within settle_window (mm) of the target for
	 * settle_dwell (s); 0 = no advice */
	double settle_window;
	double settle_dwell;
};

enum asph_stage_state {
	ASPH_STAGE_IDLE = 0,
	ASPH_STAGE_MOVING,
	ASPH_STAGE_HOMING,
	ASPH_STAGE_NOT_HOMED,
	ASPH_STAGE_FAULT,
	ASPH_STAGE_DISCONNECTED,
};

struct asph_stage_status {
	enum asph_stage_state state;
	bool homed;
	double position[ASPH_DRIVER_MAX_AXES];
	char detail[128];       /* e.g. the drive's fault text */
};

struct asph_device;             /* each driver defines its own */
struct asph_driver;

/*
 * Where a measured position came from (1.1). The executor records it with
 * every point; a point whose position is COMMANDED is flagged as such.
 */
enum asph_position_source {
	ASPH_POSITION_NONE = 0,         /* not known here */
	/* the controller captured its encoders on the probe's trigger
	 * (position capture, touch-probe latch) */
	ASPH_POSITION_LATCHED,
	/* asked for after the stage settled */
	ASPH_POSITION_READ_BACK,
	/* positions sampled by time, interpolated to the reading's instant
	 * on the device timebase */
	ASPH_POSITION_INTERPOLATED,
	/* nothing better: the position the stage was sent to */
	ASPH_POSITION_COMMANDED,
};

/*
 * A knot of a timed sweep (1.1): the stage passes position at t with
 * velocity, following the cubic Hermite curve between knots (PVT mode).
 * t is in seconds from the end of the previous timed sweep when the stage
 * is still moving along it, else from the start of the call. A knot with
 * trigger fires the probe's trigger as the command passes it.
 */
struct asph_pvt {
	double t;
	double position[ASPH_DRIVER_MAX_AXES];  /* the stage's axes */
	double velocity[ASPH_DRIVER_MAX_AXES];  /* per s */
	uint32_t trigger;                       /* 1: a reading is taken here */
	uint32_t reserved;                      /* 0 */
};

/*
 * A position the stage measured during its last sweep (1.1): LATCHED at
 * its trigger-th trigger (0 for the first of the sweep), or READ_BACK at
 * t_ns, a sample by time (the executor interpolates between samples to a
 * reading's instant: INTERPOLATED). t_ns is on the device's timebase.
 */
struct asph_position_sample {
	uint64_t t_ns;
	double position[ASPH_DRIVER_MAX_AXES];
	uint32_t source;                        /* enum asph_position_source */
	uint32_t trigger;
};

struct asph_stage_ops {
	int (*open)(const struct asph_driver *drv,
		    const struct asph_option_value *options,
		    unsigned timeout_ms, struct asph_device **out,
		    struct asph_error *err);
	void (*close)(struct asph_device *dev);
	int (*info)(struct asph_device *dev, struct asph_stage_info *out,
		    struct asph_error *err);
	int (*home)(struct asph_device *dev, unsigned timeout_ms,
		    struct asph_error *err);
	/* Moves to target (n_axes values in the axes' units) and returns when
	 * the stage is there and settled. */
	int (*move_to)(struct asph_device *dev, const double *target,
		       unsigned timeout_ms, struct asph_error *err);
	/* Optional (NULL): a continuous motion through n positions without
	 * stopping, for probes that stream. */
	int (*sweep)(struct asph_device *dev, const double *positions,
		     size_t n, unsigned timeout_ms, struct asph_error *err);
	int (*position)(struct asph_device *dev, double *pos,
			unsigned timeout_ms, struct asph_error *err);
	int (*status)(struct asph_device *dev, struct asph_stage_status *out,
		      unsigned timeout_ms, struct asph_error *err);
	/* Any thread; stops motion at once. */
	int (*stop)(struct asph_device *dev, struct asph_error *err);

	/* ---- 1.1: each optional (NULL); a 1.0 driver does not have them */

	/* A timed sweep through n knots (PVT); returns when the stage has
	 * passed the last one. The trigger knots fire the probe's trigger. */
	int (*sweep_pvt)(struct asph_device *dev, const struct asph_pvt *knots, size_t n,
			 unsigned timeout_ms, struct asph_error *err);
	/* The positions measured during the last sweep (either kind), in
	 * order: at most max into out, *n of them. */
	int (*sweep_trace)(struct asph_device *dev, struct asph_position_sample *out,
			   size_t max, size_t *n, unsigned timeout_ms, struct asph_error *err);
	/* The device's timebase now, ns: what its timestamps and an attached
	 * probe's count in. Without it: CLOCK_MONOTONIC. */
	int (*clock)(struct asph_device *dev, uint64_t *t_ns);
	/* The info as the options describe it, without a device (for
	 * estimates before anything is opened). */
	int (*describe)(const struct asph_driver *drv, const struct asph_option_value *options,
			struct asph_stage_info *out, struct asph_error *err);
	/* ---- 1.2: optional (NULL); a driver of 1.0 or 1.1 does not have it */
	/* A simulated stage, at rest: its clock reads t_ns from now on, and
	 * whatever it simulates keeps its age (a move that ended a moment ago
	 * still ended a moment ago). The executor aligns the clock after every
	 * round of drift references, so that a resumed scan goes on with the
	 * time of the interrupted one (docs/scanning.md, "Resuming"). A stage
	 * on the world's time has none. */
	int (*clock_align)(struct asph_device *dev, uint64_t t_ns, struct asph_error *err);
	/* ---- 1.3: optional (NULL); a driver of 1.0 .. 1.2 does not have it */
	/* The time (s) the stage's own motion takes, predicted from its
	 * options without a device (estimates before anything is opened):
	 * sweep, a sweep() through the n positions from rest at from; else
	 * move_to() from from to each of them in turn. Without it the
	 * executor predicts from the axes' limits alone. */
	int (*motion_time)(const struct asph_driver *drv, const struct asph_option_value *options,
			   const double *from, const double *positions, size_t n, bool sweep,
			   double *seconds, struct asph_error *err);
};

/* ------------------------------------------------------------- probe */

enum asph_probe_type {
	ASPH_PROBE_TACTILE = 0,
	ASPH_PROBE_OPTICAL,
};

/*
 * Geometry. The probe measures along the machine's +z axis (into the part,
 * as the surface's z). A reading v places the measured point at
 * z = stage z + v, at the stage's x, y: for a tactile probe the centre of
 * its tip ball, for an optical probe the surface. Readings between
 * range_min and range_max are valid; standoff is the reading the probe
 * wants when the surface is where it is expected (the executor positions
 * the stage so), inside the range.
 */
struct asph_probe_info {
	enum asph_probe_type type;
	double tip_radius;      /* mm; 0 for optical probes */
	double range_min, range_max; /* mm */
	double standoff;        /* mm */
	double max_slope;       /* rad: steepest surface it reads; 0 = any */
	double rate;            /* readings per second; 0 = unknown */
	bool can_stream;
	char model[64];
	char serial[64];
	/* 1.1: s from the trigger (the reading's t_ns) to the instant the
	 * probe samples the surface; the executor compensates it */
	double latency;
};

/*
 * Where the stage is when the probe reads. The executor passes what the
 * stage reported (not what it was asked for) and the plan point the
 * reading is for. A probe whose data does not depend on position ignores
 * both; a simulated probe computes its reading from the position, and a
 * recorded one looks the reading up by plan index. This keeps the probe
 * independent of which stage driver carries it.
 */
enum asph_measurement_kind {
	ASPH_MEASURE_PLAN = 0,          /* a plan point: plan_index */
	ASPH_MEASURE_REFERENCE,         /* a drift reference: plan_index is its
					   number in the scan's reference set */
};

struct asph_probe_context {
	uint64_t plan_index;
	double machine[ASPH_DRIVER_MAX_AXES];   /* the stage's axes */
	double xyz[3];          /* the same in the cartesian frame, mm */
	/* 1.1 */
	uint32_t kind;          /* enum asph_measurement_kind */
	uint32_t attempt;       /* earlier measurements of this point in the
				   scan (a re-measurement, a reference's
				   round) */
};

enum asph_reading_flags {
	ASPH_READING_OUT_OF_RANGE = 1u << 0,    /* value is not a measurement */
	ASPH_READING_LOW_SIGNAL = 1u << 1,
	/* The probe knows the measured point itself (xyz, final, already
	 * compensated): a recorded scan played back. */
	ASPH_READING_ABSOLUTE = 1u << 2,
	ASPH_READING_TIP_COMPENSATED = 1u << 3, /* with ABSOLUTE */
	/* 1.1: the probe got no valid sample (too little light, a steep
	 * slope): value is not a measurement; the point is measured again */
	ASPH_READING_INVALID = 1u << 4,
	/* 1.1: ABSOLUTE, recorded with a commanded position */
	ASPH_READING_COMMANDED = 1u << 5,
};

struct asph_reading {
	double value;           /* mm along the probe axis */
	double raw;             /* the probe's own number, its units */
	double xyz[3];          /* ASPH_READING_ABSOLUTE only */
	uint64_t t_ns;          /* the trigger's instant: CLOCK_MONOTONIC, or
				   the stage's clock for an attached probe;
				   0 = unknown */
	uint32_t flags;         /* enum asph_reading_flags */
	/* 1.1: where the stage was, if the probe knows (encoder inputs of
	 * its own); the executor fills what it measured otherwise */
	uint32_t position_source;               /* enum asph_position_source */
	double position[ASPH_DRIVER_MAX_AXES];  /* the stage's axes */
	uint64_t position_t_ns;
};

struct asph_probe_ops {
	int (*open)(const struct asph_driver *drv,
		    const struct asph_option_value *options,
		    unsigned timeout_ms, struct asph_device **out,
		    struct asph_error *err);
	void (*close)(struct asph_device *dev);
	int (*info)(struct asph_device *dev, struct asph_probe_info *out,
		    struct asph_error *err);
	/* One reading at the current position. */
	int (*read)(struct asph_device *dev,
		    const struct asph_probe_context *ctx,
		    struct asph_reading *out, unsigned timeout_ms,
		    struct asph_error *err);
	/* Optional (NULL): readings along a sweep, one per position, each
	 * timestamped. On failure *n_done readings are valid. */
	int (*stream)(struct asph_device *dev,
		      const struct asph_probe_context *ctx, size_t n,
		      struct asph_reading *out, size_t *n_done,
		      unsigned timeout_ms, struct asph_error *err);
	/* Any thread; interrupts read and stream. */
	int (*stop)(struct asph_device *dev, struct asph_error *err);

	/* ---- 1.1: each optional (NULL) */

	/* The probe is mounted on this stage (called once both are open;
	 * the stage outlives the probe). 1 when the probe is wired to it:
	 * the stage's trigger fires it and its timestamps count in the
	 * stage's clock; 0 when it is not; or a negative errno. */
	int (*attach)(struct asph_device *dev, const struct asph_driver *stage_driver,
		      struct asph_device *stage);
	/* The info as the options describe it, without a device. */
	int (*describe)(const struct asph_driver *drv, const struct asph_option_value *options,
			struct asph_probe_info *out, struct asph_error *err);
};

/* ------------------------------------------------------------ driver */

struct asph_driver {
	uint32_t abi_version;           /* ASPH_DRIVER_ABI_VERSION it was built with */
	const char *name;               /* [a-z0-9_-]+, unique */
	const char *description;
	const char *version;
	unsigned roles;                 /* enum asph_driver_role */
	const struct asph_option_desc *options;
	size_t n_options;
	const struct asph_stage_ops *stage;     /* with ASPH_ROLE_STAGE */
	const struct asph_probe_ops *probe;     /* with ASPH_ROLE_PROBE */
};

/*
 * Drivers built outside the tree are shared objects in the plugin
 * directory that export this function. It stores the ABI version the
 * plugin was built with in *abi_version and returns its drivers (*n of
 * them); the host refuses a plugin of another major version, or of a minor
 * version newer than its own, before touching the table.
 */
#define ASPH_DRIVER_PLUGIN_SYMBOL "asph_driver_plugin"

typedef const struct asph_driver *const *(*asph_driver_plugin_fn)(
	uint32_t *abi_version, size_t *n);

#ifdef __cplusplus
}
#endif

#endif
