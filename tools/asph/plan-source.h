/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Where the points of `asph quality` and `asph plot` come from: a plan file,
 * or a plan computed from --method and one density option. */
#ifndef ASPH_TOOL_PLAN_SOURCE_H
#define ASPH_TOOL_PLAN_SOURCE_H

#include <getopt.h>
#include <stdio.h>

#include "asph/plan.h"
#include "asph/points.h"
#include "asph/quality.h"
#include "asph/surface.h"

enum {
	PLAN_OPT_METHOD = 0x1000,
	PLAN_OPT_H,
	PLAN_OPT_SPACING,
	PLAN_OPT_POINTS,
	PLAN_OPT_QUIET,
	PLAN_OPT_PROFILES,
};

/* getopt_long entries for --method, --h, --spacing, --points, --profiles. */
#define PLAN_SOURCE_LONG_OPTIONS                                          \
	{ "method", required_argument, NULL, PLAN_OPT_METHOD },           \
	{ "h", required_argument, NULL, PLAN_OPT_H },                     \
	{ "spacing", required_argument, NULL, PLAN_OPT_SPACING },         \
	{ "points", required_argument, NULL, PLAN_OPT_POINTS },           \
	{ "profiles", required_argument, NULL, PLAN_OPT_PROFILES }

/* --quiet for the commands whose only quiet is the plan's progress. */
#define PLAN_SOURCE_QUIET_OPTION { "quiet", no_argument, NULL, PLAN_OPT_QUIET }
#define PLAN_SOURCE_QUIET_HELP \
	"  --quiet             no progress of a long plan (CVT) on the terminal\n"

/* The help of --method M: before, the methods from their table, after. */
void plan_method_help(FILE *out, const char *before, const char *after);

/* The help of the density options, --h, --spacing and --points, and of
 * --profiles. */
#define PLAN_DENSITY_HELP                                                                 \
	"  --h H               mean edge length / aperture radius (the paper's h)\n"             \
	"  --spacing MM        mean point spacing on the surface, mm\n"                           \
	"  --points N          approximate number of points\n"                                    \
	PLAN_SOURCE_PROFILES_HELP

/* --profiles, with the density options wherever --method is offered. */
#define PLAN_SOURCE_PROFILES_HELP                                                         \
	"  --profiles N        --method profiles: N profiles through the apex at equal\n"       \
	"                      angles (default 1, at most " PLAN_STRING(ASPH_PLAN_MAX_PROFILES) ")\n"
#define PLAN_STRING(x) PLAN_STRING_(x)
#define PLAN_STRING_(x) #x

/* The help of PLAN_FILE or --method with a density. */
void plan_source_help(FILE *out);

/* The methods whose plan comes with a mesh, from their table: "op, ot, lb". */
void plan_mesh_methods(char *buf, size_t size);

struct plan_source {
	const char *plan_file;
	int quiet;              /* no progress line */
	int have_method;
	enum asph_plan_method method;
	int n_density;
	struct asph_plan_density density;
	unsigned profiles;      /* --profiles; 0: not given */
};

/* Handles one of the options above: 0 when taken, 1 when opt is not one of
 * them, -1 on a bad value (message printed). */
int plan_source_option(struct plan_source *ps, int opt, const char *arg);

/* After option parsing: the remaining positional argument (PLAN_FILE or
 * NULL). -1 (message printed) unless exactly one of PLAN_FILE and --method
 * is given, with exactly one density option for --method. */
int plan_source_finish(struct plan_source *ps, const char *plan_file);

/* Computes the plan of --method and the density, with the progress of a
 * long one on the terminal unless ps->quiet (opts may be NULL). */
int plan_source_compute(const struct plan_source *ps, const struct asph_surface *s,
			const struct asph_plan_options *opts, struct asph_plan **out,
			struct asph_error *err);

/* Reads the file or computes the plan (its mesh, if any, goes into the
 * points' triangles). Prints the error; returns a negative errno. */
int plan_source_load(const struct plan_source *ps, const struct asph_surface *s,
		     struct asph_points **out);

/*
 * What asph quality and asph plot share: the plan source, --chart, the lens,
 * the points and their triangles. Declare with
 *   _cleanup_(plan_quality_clear) struct plan_quality pq = { 0 };
 */
enum { PLAN_OPT_CHART = 0x1100 };
#define PLAN_QUALITY_LONG_OPTIONS \
	PLAN_SOURCE_LONG_OPTIONS, { "chart", required_argument, NULL, PLAN_OPT_CHART }, \
	PLAN_SOURCE_QUIET_OPTION

struct plan_quality {
	struct plan_source src;
	struct asph_quality_options opts;
	struct asph_surface *s;
	struct asph_points *pts;
	struct asph_quality *q;
};

void plan_quality_clear(struct plan_quality *pq);

/* As plan_source_option(), and --chart. */
int plan_quality_option(struct plan_quality *pq, int opt, const char *arg);

/* After option parsing: argv[first..argc) must be LENS [PLAN_FILE]. Loads
 * the lens and the points and measures their triangles. Returns EXIT_OK or
 * the exit code to leave with (the message printed); cmd names the command
 * in messages. */
int plan_quality_run(struct plan_quality *pq, const char *cmd, int argc,
		     char **argv, int first);

/* "ot h=0.02", "fermat 5000 points", or the file name, for titles. */
void plan_source_label(const struct plan_source *ps, char *buf, size_t size);

#endif
