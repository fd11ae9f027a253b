/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The Monte Carlo uncertainty of a job's characterization, on the worker
 * thread, when its instrument declares uncertainty contributions. */
#ifndef ASPHD_UNCERTAINTY_H
#define ASPHD_UNCERTAINTY_H

#include <jansson.h>

#include "asph/fit.h"
#include "asph/points.h"
#include "jobplan.h"
#include "result.h"

struct asph_instrument_config;

/*
 * With contributions declared by ic: runs the Monte Carlo on the job's
 * points (docs/characterization.md, defaults: N = 200 with the adaptive
 * stop, every online processor, seed 1), puts U into res (uncertainty_k2
 * and the verdict) and its keys into *add (a JSON object to merge into the
 * summary). Without contributions *add is NULL and nothing runs. The
 * job's cancellation is asked between trials (-ECANCELED).
 */
int result_uncertainty(const struct result_source *job, const struct job_plan *jp,
		       const struct asph_instrument_config *ic,
		       const struct asph_points *points, struct asph_fit_result *res,
		       json_t **add, struct asph_error *err);

#endif
