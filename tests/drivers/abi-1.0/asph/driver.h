/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_DRIVER_H
/* The driver ABI 1.0 header exactly as released: tests build a plugin
 * against it to check that plugins of the older minor version still load
 * and work (tests/drivers/meson.build). Not to be changed. */
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

/* Bumped on any incompatible change of the structures below, including
 * struct asph_error of asph/error.h, which drivers fill. */
#define ASPH_DRIVER_ABI_VERSION 1

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
};

/*
 * Where the stage is when the probe reads. The executor passes what the
 * stage reported (not what it was asked for) and the plan point the
 * reading is for. A probe whose data does not depend on position ignores
 * both; a simulated probe computes its reading from the position, and a
 * recorded one looks the reading up by plan index. This keeps the probe
 * independent of which stage driver carries it.
 */
struct asph_probe_context {
	uint64_t plan_index;
	double machine[ASPH_DRIVER_MAX_AXES];   /* the stage's axes */
	double xyz[3];          /* the same in the cartesian frame, mm */
};

enum asph_reading_flags {
	ASPH_READING_OUT_OF_RANGE = 1u << 0,    /* value is not a measurement */
	ASPH_READING_LOW_SIGNAL = 1u << 1,
	/* The probe knows the measured point itself (xyz, final, already
	 * compensated): a recorded scan played back. */
	ASPH_READING_ABSOLUTE = 1u << 2,
	ASPH_READING_TIP_COMPENSATED = 1u << 3, /* with ABSOLUTE */
};

struct asph_reading {
	double value;           /* mm along the probe axis */
	double raw;             /* the probe's own number, its units */
	double xyz[3];          /* ASPH_READING_ABSOLUTE only */
	uint64_t t_ns;          /* CLOCK_MONOTONIC, 0 = unknown */
	uint32_t flags;         /* enum asph_reading_flags */
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
};

/* ------------------------------------------------------------ driver */

struct asph_driver {
	uint32_t abi_version;           /* ASPH_DRIVER_ABI_VERSION */
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
 * them); the host refuses a plugin whose version differs from its own
 * before touching the table.
 */
#define ASPH_DRIVER_PLUGIN_SYMBOL "asph_driver_plugin"

typedef const struct asph_driver *const *(*asph_driver_plugin_fn)(
	uint32_t *abi_version, size_t *n);

#ifdef __cplusplus
}
#endif

#endif
