/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's specification (what job.submit asked for, normalized) and its
 * result (characterization of the recorded points with provenance).
 */
#ifndef ASPHD_RESULT_H
#define ASPHD_RESULT_H

#include <stdint.h>

#include <jansson.h>

#include "asph-proto.h"
#include "asph/error.h"
#include "asph/fit.h"
#include "asph/plan.h"
#include "asph/prescription.h"

struct asph_instrument_config;
struct runner_job;

/*
 * Checks job.submit's lens, plan and fit members and builds the normalized
 * spec. Returns 0, or a protocol error code (PROTO_INVALID_PARAMS,
 * PROTO_INVALID_LENS, PROTO_INVALID_PLAN, PROTO_LIMIT_REACHED) with why.
 * *points is the plan's (estimated) number of points.
 */
int spec_from_params(json_t *params, uint64_t max_points, json_t **spec,
		     uint64_t *points, struct proto_why *why);

/* The spec made ready to measure. */
struct job_plan {
	struct asph_prescription prescription;
	struct asph_surface *surface;
	struct asph_plan *plan;
	struct asph_fit_options fit;
	char *prescription_json;
	char *plan_json;        /* method, density, spacing, points */
	char *fit_json;
	char *lens_name;        /* or NULL */
};

int job_plan_build(const char *spec, uint64_t max_points, struct job_plan *jp,
		   struct asph_error *err);
void job_plan_release(struct job_plan *jp);

/*
 * Characterizes the recorded scan of job, writes the residuals, the map
 * and result.json into job->result_dir and returns the result JSON text
 * (summary, provenance, files).
 */
int result_build(const struct runner_job *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err);

#endif
