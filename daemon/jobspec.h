/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's specification: what job.submit asked for (lens, plan, fit),
 * checked and normalized into the JSON text the job store keeps and the
 * worker measures from (jobplan.h reads it back). Pure: a task's thread
 * (estimate.h) runs it, since a freeform surface takes time to build.
 *
 * The specification: {"lens": {"name": PRESET or null, "prescription":
 * {...}}, "plan": {"method", "density": "h" | "spacing" | "points"
 * (asph_plan_density_name()), "value"} or {"for_tolerance": true,
 * "capability", "method"?}, "fit": {"dof", "residual", "robust", "zernike"}}.
 * A job of measured data has, in place of "plan", "measured": {"format":
 * the format read (asph_points_format_name()), "units": a unit name or
 * null, "file": the data's name in the job's folder}; its request's
 * "measured" names a descriptor its client passed ("fd") instead of a file.
 */
#ifndef ASPHD_JOBSPEC_H
#define ASPHD_JOBSPEC_H

#include <stdbool.h>
#include <stdint.h>

#include <jansson.h>

#include "asph-proto.h"
#include "asph/plan.h"
#include "asph/surface.h"

/* What a plan may cost (settings_limits: max_plan_points,
 * max_plan_point_terms). */
struct jobspec_limits {
	uint64_t max_points;
	uint64_t max_point_terms;       /* points times the surface's terms */
};

/*
 * Checks job.submit's lens, plan and fit members and builds the normalized
 * spec. Returns 0, or a protocol error code (PROTO_INVALID_PARAMS,
 * PROTO_INVALID_LENS, PROTO_INVALID_PLAN, PROTO_LIMIT_REACHED) with why.
 * *points is the plan's (estimated) number of points. A plan over a
 * limit is refused naming it, before its surface is built where the
 * number of points was given.
 */
int jobspec_from_params(json_t *params, const struct jobspec_limits *lim, json_t **spec,
			uint64_t *points, struct proto_why *why);

/* The highest descriptor index a request may name ("measured.fd"). */
#define JOBSPEC_MAX_FD 3

/* The checks of job.submit's "measured" alone (as jobspec_from_params()
 * makes them), for the loop before it takes the descriptor: 0 or
 * PROTO_INVALID_PARAMS with why. */
int jobspec_check_measured(json_t *params, struct proto_why *why);

/* Whether spec is of measured data ("measured", no plan). */
bool jobspec_measured(const json_t *spec);

/* Whether spec's plan is to be chosen for its tolerance (tolplan.h):
 * "plan": {"for_tolerance": true, "capability", "method"?}. */
bool jobspec_for_tolerance(const json_t *spec);

/* The terms of a prescription: its base, and each coefficient that is
 * not zero (what one evaluation of its sag costs). */
unsigned jobspec_terms(const struct asph_prescription *p);

#endif
