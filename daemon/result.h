/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's result: the characterization of its recorded points, with
 * provenance, and the files in its folder. Worker thread.
 */
#ifndef ASPHD_RESULT_H
#define ASPHD_RESULT_H

#include <stdint.h>

#include "asph/error.h"
#include "jobplan.h"

struct asph_instrument_config;

/* The recorded job to characterize. */
struct result_source {
	int64_t job;
	const char *scan_path;  /* the recorded scan */
	const char *dir;        /* where the result files go; exists */
	const char *metadata;   /* the job's metadata of the scan header (JSON) */
};

/*
 * Characterizes the recorded scan of job, writes the residuals, the map
 * and result.json into job->dir and returns the result JSON text
 * (summary, provenance, files).
 */
int result_build(const struct result_source *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err);

#endif
