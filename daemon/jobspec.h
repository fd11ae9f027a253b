/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's specification: what job.submit asked for (lens, plan, fit),
 * checked and normalized into the JSON text the job store keeps and the
 * worker measures from (jobplan.h reads it back). Event loop thread.
 *
 * The specification: {"lens": {"name": PRESET or null, "prescription":
 * {...}}, "plan": {"method", "density": "h" | "spacing" | "points"
 * (asph_plan_density_name()), "value"}, "fit": {"dof", "residual", "robust", "zernike"}}.
 */
#ifndef ASPHD_JOBSPEC_H
#define ASPHD_JOBSPEC_H

#include <stdint.h>

#include <jansson.h>

#include "asph-proto.h"
#include "asph/plan.h"

/*
 * Checks job.submit's lens, plan and fit members and builds the normalized
 * spec. Returns 0, or a protocol error code (PROTO_INVALID_PARAMS,
 * PROTO_INVALID_LENS, PROTO_INVALID_PLAN, PROTO_LIMIT_REACHED) with why.
 * *points is the plan's (estimated) number of points.
 */
int jobspec_from_params(json_t *params, uint64_t max_points, json_t **spec,
			uint64_t *points, struct proto_why *why);

#endif
