/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_INSTRUMENT_H
#define ASPH_INSTRUMENT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph-driver/driver.h"
#include "asph/error.h"
#include "asph/uncertainty.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The host side of the driver interface: the registry of drivers (built in
 * and plugins), option values checked against a driver's descriptors, and
 * instruments (a stage driver and a probe driver with their options) from a
 * configuration file or a spec such as "mock:rate=20000".
 */

/* -------------------------------------------------------- registry */

struct asph_registry;

/* A registry with the built-in drivers (those of meson's `drivers`). */
int asph_registry_new(struct asph_registry **out, struct asph_error *err);
void asph_registry_free(struct asph_registry *r);

/*
 * Loads one plugin (a shared object exporting ASPH_DRIVER_PLUGIN_SYMBOL).
 * Its code runs in this process, so before it is opened the file must
 * belong to root or to the user running this, be writable by no one else,
 * and every directory above it be trusted the same way (owned by root or
 * that user, not writable by others unless sticky): -EPERM (or -ENOENT)
 * with the step that is not, and nothing of it runs.
 * -ENOEXEC with the reason for a file that is not a plugin, -EPROTO for an
 * ABI version other than ours, -EINVAL for a malformed driver table (bad
 * name, options whose defaults do not parse, missing operations), -EEXIST
 * for a driver name already registered.
 */
int asph_registry_load_plugin(struct asph_registry *r, const char *path,
			      struct asph_error *err);

/* Called for each plugin of a directory that does not load. */
typedef void (*asph_registry_warn_fn)(const struct asph_error *err,
				      void *data);

/* Loads every *.so of dir (sorted by name); a plugin that fails is reported
 * through warn (may be NULL) and skipped. Returns the number loaded, or
 * -errno when dir cannot be read (-ENOENT is not an error: returns 0). */
int asph_registry_load_dir(struct asph_registry *r, const char *dir,
			   asph_registry_warn_fn warn, void *data,
			   struct asph_error *err);

/* The default plugin directories: $ASPH_DRIVER_PATH (colon-separated) if
 * set, else the installed one. */
int asph_registry_load_default_dirs(struct asph_registry *r,
				    asph_registry_warn_fn warn, void *data,
				    struct asph_error *err);

size_t asph_registry_count(const struct asph_registry *r);
const struct asph_driver *asph_registry_get(const struct asph_registry *r,
					    size_t i);
/* Where a driver came from: "built-in" or the plugin's path. */
const char *asph_registry_origin(const struct asph_registry *r, size_t i);
const struct asph_driver *asph_registry_find(const struct asph_registry *r,
					     const char *name);

/* A profile a driver's "profile" option can name, found at run time in
 * the profile directories (the line driver's profile files). */
struct asph_driver_profile {
	char name[64];
	unsigned roles;         /* enum asph_driver_role; 0 when it does not load */
	char description[128];
	char reference[128];    /* the document it follows */
	char path[512];         /* the file the name loads */
	char error[512];        /* why it does not load, "" when it does */
};

/*
 * The profiles driver i's "profile" option can name, as the profile
 * directories hold them now, one per name, sorted. *n is 0 for a driver
 * whose profiles are not files. The array is malloc'd (free() it).
 */
int asph_registry_profiles(const struct asph_registry *r, size_t i,
			   struct asph_driver_profile **out, size_t *n,
			   struct asph_error *err);

/* Checks a driver table as the registry does (plugins are checked on
 * load). */
int asph_driver_validate(const struct asph_driver *d, struct asph_error *err);

/* Every driver with its roles and options, as asph drivers --json prints
 * it and asphd's driver.list answers: { "driver_abi": N, "drivers": [ {
 * "name", "description", "version", "origin", "roles", "options": [ {
 * "name", "type", "default", "unit", "min", "max", "choices", "roles",
 * "help" } ], "profiles": [ { "name", "roles", "description", "reference",
 * "path", "error" } ] } ] }. min and max only for a ranged option, choices
 * only for an enum; a text the driver leaves out is null; roles are always
 * named (an option of both roles has ["stage", "probe"]); profiles as
 * asph_registry_profiles() finds them (empty for a driver without profile
 * files; error null for one that loads). malloc'd. Fails, saying why in
 * err, when a driver's profiles cannot be listed (a profile directory
 * that cannot be searched). */
int asph_registry_to_json(const struct asph_registry *r, bool pretty,
			  char **out, struct asph_error *err);

/* "MAJOR.MINOR" of a driver ABI version, in buf (returned). */
const char *asph_driver_abi_text(uint32_t version, char *buf, size_t size);

const char *asph_option_type_name(enum asph_option_type t);
const char *asph_kinematics_name(enum asph_kinematics k);
const char *asph_probe_type_name(enum asph_probe_type t);

/* ---------------------------------------------------------- options */

struct asph_options;

/* Values for drv's options, all at their defaults. */
int asph_options_new(const struct asph_driver *drv, struct asph_options **out,
		     struct asph_error *err);
void asph_options_free(struct asph_options *o);

/*
 * Sets an option from text. -ENOENT for an unknown option, -EINVAL for a
 * value of the wrong type, -ERANGE for one outside the range or not among
 * the choices; err names the option (field) and says what it accepts.
 */
int asph_options_set(struct asph_options *o, const char *name,
		     const char *text, struct asph_error *err);

/*
 * Gives option name the value text unless the configuration set it: the
 * value stays "not set", so the next call replaces it. 1 when it was
 * given, 0 when the driver has no such option or the configuration set
 * it, else the error of asph_options_set().
 */
int asph_options_set_default(struct asph_options *o, const char *name,
			     const char *text, struct asph_error *err);

/* An independent copy of o: the same values, set or not. */
int asph_options_copy(const struct asph_options *o, struct asph_options **out,
		      struct asph_error *err);

/* The values, parallel to the driver's option descriptors. */
const struct asph_option_value *
asph_options_values(const struct asph_options *o);
const struct asph_driver *asph_options_driver(const struct asph_options *o);

/* The index of option name among drv's descriptors, or -1. */
int asph_option_index(const struct asph_driver *drv, const char *name);

/* The value as text, as asph_options_set() takes it (buf returned). */
const char *asph_option_value_format(const struct asph_option_value *v,
				     char *buf, size_t size);

/* ----------------------------------------------------- acquisition */

#define ASPH_MAX_REFERENCES 16

/*
 * How the executor acquires with an instrument, whatever its drivers
 * (docs/scanning.md): the settling window and time of step and measure,
 * drift control (how often, and where the reference points are), and how
 * often a dropout is measured again.
 */
struct asph_acquisition {
	double settle_window;           /* mm; the read-back's distance to the target */
	double settle_dwell;            /* s inside the window before the reading */
	/* references every drift_interval_s of instrument time or every
	 * drift_interval_points points, whichever comes first; neither: no
	 * drift control */
	double drift_interval_s;
	uint64_t drift_interval_points;
	size_t n_references;
	double references[ASPH_MAX_REFERENCES][2];      /* x, y on the nominal surface, mm */
	unsigned retries;               /* further tries of a point read invalid */
	unsigned set;                   /* enum asph_acquisition_set: given, not defaults */
};

/* The settings an instrument gives itself (asph_acquisition_set()), which
 * no advice of its stage replaces. */
enum asph_acquisition_set {
	ASPH_ACQUISITION_SET_SETTLE_WINDOW = 1u << 0,
	ASPH_ACQUISITION_SET_SETTLE_DWELL = 1u << 1,
};

/* The defaults: window 1 um, no dwell, references at the vertex every 60 s,
 * 3 retries. */
void asph_acquisition_defaults(struct asph_acquisition *a);

/*
 * Sets one setting from text, as a spec or a configuration gives it:
 * settle_window (um), settle_dwell (s), drift_interval ("60s", "5000points",
 * "off"), drift_references ("vertex" or "X:Y;X:Y;..." in mm), retries.
 * -ENOENT when name is none of them, -EINVAL or -ERANGE for a bad value
 * (err names the setting).
 */
int asph_acquisition_set(struct asph_acquisition *a, const char *name, const char *text,
			 struct asph_error *err);

/* The settling the stage advises (stage info, driver ABI 1.2) where the
 * instrument did not set its own. */
void asph_acquisition_advised(struct asph_acquisition *a, const struct asph_stage_info *si);

/* Whether drift control is on. */
bool asph_acquisition_drift(const struct asph_acquisition *a);

/* ----------------------------------------------------- instruments */

struct asph_instrument_config {
	char name[64];
	const struct asph_driver *stage_driver;
	const struct asph_driver *probe_driver;
	struct asph_options *stage_options;
	struct asph_options *probe_options;
	struct asph_acquisition acquisition;
	/* The instrument's declared uncertainty contributions (the optional
	 * "uncertainty" section of a configuration file, docs/drivers.md);
	 * has_uncertainty 0 when it declares none. */
	int has_uncertainty;
	struct asph_uncertainty_model uncertainty;
};

struct asph_config {
	size_t n;
	struct asph_instrument_config *instruments;
};

/*
 * A spec in the style of sigrok-cli: NAME[:key=value,...]. The driver NAME
 * plays both roles (so it must have both) and the options apply to each
 * role that uses them; the acquisition settings (asph_acquisition_set())
 * go to the instrument. The instrument is named NAME.
 */
int asph_instrument_spec_parse(const struct asph_registry *reg,
			       const char *spec,
			       struct asph_config **out,
			       struct asph_error *err);

/*
 * A JSON configuration file (format in docs/drivers.md):
 *   { "instruments": [ { "name": ..., "stage": { "driver": ...,
 *     "options": { ... } }, "probe": { ... }, "acquisition": { ... } } ] }
 * Errors carry the file, line, column and the dotted field.
 */
int asph_config_load(const struct asph_registry *reg, const char *path,
		     struct asph_config **out, struct asph_error *err);
int asph_config_parse(const struct asph_registry *reg, const char *text,
		      size_t len, const char *source,
		      struct asph_config **out, struct asph_error *err);
void asph_config_free(struct asph_config *c);

/*
 * What a --instrument argument names: an existing file (FILE, or
 * FILE#NAME for one of several instruments; FILE alone takes the first),
 * else a spec.
 */
int asph_config_resolve(const struct asph_registry *reg, const char *arg,
			struct asph_config **out, size_t *index,
			struct asph_error *err);

/*
 * A configuration of one instrument that is a copy of c, options included:
 * the caller's own to change (a worker sets the lens of each job on its
 * copy while the loaded configuration stays as it was read).
 * asph_config_free() frees it.
 */
int asph_instrument_config_copy(const struct asph_instrument_config *c,
				struct asph_config **out, struct asph_error *err);

/*
 * The lens a job measures, for drivers that simulate the part: a string
 * option named "lens" of the stage's or the probe's driver that the
 * configuration leaves unset takes prescription_json (the lens's
 * prescription as JSON text, asph_prescription_to_json()). One the
 * configuration sets is kept: that is how a wrong part is simulated.
 * Call it before each job's asph_instrument_open().
 */
int asph_instrument_config_set_lens(struct asph_instrument_config *c,
				    const char *prescription_json,
				    struct asph_error *err);

/* The instrument as JSON text (drivers, versions, every option's value,
 * the acquisition settings), for the recorded scan's header. malloc'd. */
int asph_instrument_config_to_json(const struct asph_instrument_config *c,
				   char **out);

/*
 * An instrument with its devices open. stage_ops and probe_ops are the
 * drivers' operations as this program may call them: those a driver of an
 * older ABI minor version does not have are NULL. Readings go through
 * asph_instrument_read() and asph_instrument_stream(), which also take
 * them from drivers of ABI 1.0 (whose structures are shorter).
 */
struct asph_instrument {
	const struct asph_instrument_config *config;
	const struct asph_driver *stage_driver, *probe_driver;
	struct asph_device *stage, *probe;
	struct asph_stage_info stage_info;
	struct asph_probe_info probe_info;
	struct asph_stage_ops stage_ops;
	struct asph_probe_ops probe_ops;
	/* the probe is wired to the stage: triggered by its sweeps, its
	 * timestamps in the stage's clock */
	bool attached;
	/* a probe's reading timestamps count in the instrument's clock */
	bool shared_timebase;
	void *scratch;          /* for readings of ABI 1.0 probes */
	size_t scratch_n;
};

/* Opens the stage, then the probe, reads their info and attaches the probe
 * to the stage. c must outlive the instrument. */
int asph_instrument_open(const struct asph_instrument_config *c,
			 unsigned timeout_ms, struct asph_instrument **out,
			 struct asph_error *err);
void asph_instrument_close(struct asph_instrument *inst);

/* The probe's read and stream, for a driver of any ABI minor version; the
 * members a probe's version does not have come back 0. */
int asph_instrument_read(struct asph_instrument *inst, const struct asph_probe_context *ctx,
			 struct asph_reading *out, unsigned timeout_ms, struct asph_error *err);
int asph_instrument_stream(struct asph_instrument *inst, const struct asph_probe_context *ctx,
			   size_t n, struct asph_reading *out, size_t *n_done,
			   unsigned timeout_ms, struct asph_error *err);

/* The instrument's clock, ns: the stage's when it has one (a simulated
 * instrument counts simulated time), else CLOCK_MONOTONIC. */
uint64_t asph_instrument_clock(struct asph_instrument *inst);

/*
 * The info of c's stage and probe as their options describe them, without
 * opening anything (for estimates). -ENOTSUP when a driver cannot say
 * (err names it).
 */
int asph_instrument_describe(const struct asph_instrument_config *c,
			     struct asph_stage_info *stage, struct asph_probe_info *probe,
			     struct asph_error *err);

/* The ABI minor version a driver was built with. */
unsigned asph_driver_abi_minor(const struct asph_driver *d);

#ifdef __cplusplus
}
#endif

#endif
