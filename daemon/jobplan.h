/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A stored job specification (jobspec.h) made ready to measure: the
 * surface, the sampling plan, the fit options, and the JSON texts the scan
 * header and the result record. Worker thread.
 */
#ifndef ASPHD_JOBPLAN_H
#define ASPHD_JOBPLAN_H

#include <stdint.h>

#include "asph/error.h"
#include "asph/fit.h"
#include "asph-driver/instrument.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "asph/tolerance.h"

struct job_plan {
	struct asph_prescription prescription;
	struct asph_surface *surface;
	struct asph_plan *plan;
	struct asph_fit_options fit;   /* .tolerance: &tolerance when the job has one */
	struct asph_tolerance tolerance;
	char *prescription_json;
	char *plan_json;        /* method, density, spacing, points */
	char *fit_json;
	char *tolerance_json;   /* as submitted, or NULL */
	char *lens_name;        /* or NULL */
};

/* Parses spec and computes its plan (at most max_points points). On
 * failure jp holds what was built: release it all the same. */
int job_plan_build(const char *spec, uint64_t max_points, struct job_plan *jp,
		   struct asph_error *err);
void job_plan_release(struct job_plan *jp);
/* As job_plan_build() without the plan (jp->plan NULL): the lens, its
 * surface, the fit and the tolerance, for the search that chooses the
 * plan (tolplan.h). Release jp all the same. */
int job_plan_build_part(const char *spec, struct job_plan *jp, struct asph_error *err);

/* The predicted measuring time of the job spec on instrument c (the
 * daemon measures streamed where it can): asph_scan_estimate() on a copy
 * of c carrying the job's lens. */
int job_plan_estimate(const char *spec, uint64_t max_points,
		      const struct asph_instrument_config *c, double *seconds,
		      struct asph_error *err);

#endif
