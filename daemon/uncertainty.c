/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Worker thread: the Monte Carlo uncertainty of a job's characterization. */
#include <errno.h>

#include "asph-driver/instrument.h"
#include "asph-mc/mc-runner.h"
#include "asph/uncertainty.h"
#include "uncertainty.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_mc *, asph_mc_free)

/* Between trials: tells the progress; a non-zero answer stops the run. */
static int on_progress(void *data, size_t done, size_t planned)
{
	const struct result_source *job = data;

	if (job->trials)
		job->trials(job->trials_data, done, planned, false);
	return job->cancelled && job->cancelled(job->cancelled_data);
}

int result_uncertainty(const struct result_source *job, const struct job_plan *jp,
		       const struct asph_instrument_config *ic,
		       const struct asph_points *points, struct asph_fit_result *res,
		       json_t **add, struct asph_error *err)
{
	_cleanup_(asph_mc_freep) struct asph_mc *mc = NULL;
	_cleanup_free_ char *text = NULL;
	struct asph_mc_result out;
	struct asph_mc_options o = { .seed = 1 };
	struct asph_mc_threads th = { .progress = on_progress, .progress_data = (void *)job };
	int r;

	*add = NULL;
	if (!ic->has_uncertainty || !res->converged)
		return 0;
	r = asph_mc_alloc(jp->surface, points->xyz, points->n, &jp->fit, res, &ic->uncertainty,
			  &o, &mc, err);
	if (r == 0) {
		/* the first block: what the run plans before its adaptive stop */
		if (job->trials)
			job->trials(job->trials_data, 0, ASPH_MC_DEFAULT_TRIALS, false);
		r = asph_mc_run_threads(mc, &th, &out, err);
	}
	if (r < 0)
		return r;
	if (job->trials)
		job->trials(job->trials_data, out.n_trials, out.n_trials, true);
	asph_mc_apply(&out, jp->fit.tolerance, res);
	if (asph_mc_result_to_json(&out, res->form.wavelength_nm, &text) < 0 ||
	    !(*add = json_loads(text, 0, NULL)))
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}
