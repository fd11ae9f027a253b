/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's result: the characterization of its recorded points, with
 * provenance, and the files in its folder. Worker thread.
 */
#ifndef ASPHD_RESULT_H
#define ASPHD_RESULT_H

#include "asph/error.h"
#include "jobplan.h"

struct asph_instrument_config;
struct runner_job;

/*
 * Characterizes the recorded scan of job, writes the residuals, the map
 * and result.json into job->result_dir and returns the result JSON text
 * (summary, provenance, files).
 */
int result_build(const struct runner_job *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err);

#endif
