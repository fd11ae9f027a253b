/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph plan --for-tolerance: the plan chosen for a tolerance on an
 * instrument (asph/plan-search.h), its options, its search on the
 * terminal and its report. */
#ifndef ASPH_TOOL_PLAN_TOLERANCE_H
#define ASPH_TOOL_PLAN_TOLERANCE_H

#include <stddef.h>

#include "asph/plan.h"
#include "asph/surface.h"

enum {
	OPT_PT_FOR_TOLERANCE = 0x2100,
	OPT_PT_INSTRUMENT,
	OPT_PT_CAPABILITY,
	OPT_PT_DOF,
	OPT_PT_SEED,
	OPT_PT_THREADS,
	OPT_PT_JSON,
};

#define PLAN_TOLERANCE_LONG_OPTIONS                                            \
	{ "for-tolerance", required_argument, NULL, OPT_PT_FOR_TOLERANCE },    \
	{ "instrument", required_argument, NULL, OPT_PT_INSTRUMENT },          \
	{ "capability", required_argument, NULL, OPT_PT_CAPABILITY },          \
	{ "dof", required_argument, NULL, OPT_PT_DOF },                        \
	{ "seed", required_argument, NULL, OPT_PT_SEED },                      \
	{ "threads", required_argument, NULL, OPT_PT_THREADS },                \
	{ "json", no_argument, NULL, OPT_PT_JSON }

struct plan_tolerance_cli {
	const char *tolerance;          /* --for-tolerance */
	const char *instrument;
	double capability;              /* 0: the default */
	const char *dof;
	unsigned long seed;
	int seed_set;
	int threads;
	int json;
	int given;                      /* any of these options */
};

/* One of the options above: 0 taken, 1 not one of them, -1 refused
 * (message printed). */
int plan_tolerance_option(struct plan_tolerance_cli *c, int opt, const char *arg);

/*
 * The search on lens s (named lens) over the methods (a mask; 0 = all), at
 * most max_points points, reported on standard output (text or --json),
 * its steps on a terminal unless quiet. On success *method and *density
 * name the chosen plan (to compute and write, with -o); *found is 0 when no
 * plan meets the ratio. Returns an exit code (EXIT_OK when the search ran,
 * found or not).
 */
int plan_tolerance_run(const struct plan_tolerance_cli *c, const char *lens,
		       const struct asph_surface *s, unsigned methods, size_t max_points,
		       int quiet, int *found, enum asph_plan_method *method,
		       struct asph_plan_density *density);

#endif
