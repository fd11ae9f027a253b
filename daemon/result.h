/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's result: the characterization of its recorded points, with
 * provenance, and the files in its folder. Worker thread.
 */
#ifndef ASPHD_RESULT_H
#define ASPHD_RESULT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "jobplan.h"

struct asph_instrument_config;

/* The recorded job to characterize. */
struct result_source {
	int64_t job;
	int dir_fd;             /* its folder: the recorded scan, the result files */
	const char *dir;        /* the same as a path, for messages */
	const char *metadata;   /* the job's metadata of the scan header (JSON) */
	/* Asked between the steps: true stops with -ECANCELED before anything
	 * is written. May be NULL. */
	bool (*cancelled)(void *data);
	void *cancelled_data;
	/* The Monte Carlo's progress: done of planned trials; last is set
	 * once, when it has completed (done == planned). May be NULL. */
	void (*trials)(void *data, size_t done, size_t planned, bool last);
	void *trials_data;
};

/*
 * Characterizes the recorded scan of job (read through dir_fd, never
 * through a symlink), writes the residuals, the map and result.json into
 * the folder (each created exclusively under a temporary name and renamed
 * into place, 0640) and returns the result JSON text (summary,
 * provenance, files).
 */
int result_build(const struct result_source *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err);

/*
 * The same for a job of measured data: the file name of its folder read
 * as ro says (the format the submission found), characterized as asph
 * fit characterizes points (no Monte Carlo: the instrument that measured
 * them is not the daemon's), and its result files, which list it as
 * "measured".
 */
struct asph_points_read_options;
int result_build_measured(const struct result_source *job, const struct job_plan *jp,
			  const struct asph_points_read_options *ro, const char *name,
			  char **out, struct asph_error *err);

#endif
