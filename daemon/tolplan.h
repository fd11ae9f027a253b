/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The plan for a job's tolerance (docs/sampling-plans.md, "The plan for a
 * tolerance"): a job whose plan is {"for_tolerance": true} measures the
 * plan with the shortest predicted time whose U (k = 2) is at most
 * capability x T for every toleranced quantity. The search
 * (asph/plan-search.h) runs on the thread that asks for it, its Monte
 * Carlo on a thread per online processor as the job's own uncertainty:
 * the job's worker before it measures, a task's thread for job.estimate.
 * Worker thread.
 */
#ifndef ASPHD_TOLPLAN_H
#define ASPHD_TOLPLAN_H

#include <stdbool.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/plan-search.h"
#include "asph-driver/instrument.h"

struct tolplan_hooks {
	/* Asked between the Monte Carlo's trials: true stops the search
	 * with -ECANCELED. May be NULL. */
	bool (*cancelled)(void *data);
	/* After each plan characterized. May be NULL. */
	void (*step)(void *data, const struct asph_plan_search_status *st);
	void *data;
};

/*
 * Chooses the plan of spec (a stored job specification whose plan asks
 * for the tolerance: jobspec_for_tolerance()) on instrument ic (a copy is
 * used), at most max_points points. On success, *spec_out is spec with
 * the chosen plan ({"method", "density": "points", "value"}) in place of
 * the request and *choice the search's result (asph_plan_search_result_
 * to_json(): the plan, its time, each quantity's U and U/T, the other
 * methods). -EINVAL with err saying why: ic declares no uncertainty, the
 * tolerance limits nothing, no plan meets the capability (naming the
 * quantity and the contribution that dominates its U); -ECANCELED.
 */
int tolplan_choose(const char *spec, uint64_t max_points, const struct asph_instrument_config *ic,
		   const struct tolplan_hooks *hooks, char **spec_out, char **choice,
		   struct asph_error *err);

/* Whether ic declares the uncertainty contributions the search needs:
 * 0, or -EINVAL with err naming the instrument and the section. */
int tolplan_instrument_ok(const struct asph_instrument_config *ic, struct asph_error *err);

/* Whether the stored job specification spec asks for the search. */
bool tolplan_wanted(const char *spec);

/* The choice (tolplan_choose()'s) for a log line: "ci, 1200 points,
 * 245.1 s predicted, the largest U/T 0.243 (rms_i_nm)". */
void tolplan_choice_format(const char *choice, char *buf, size_t size);

/* "ci, 1200 points, 4.1 min: U/T 0.31 (does not meet the capability)":
 * a step for a log line. */
void tolplan_step_format(const struct asph_plan_search_status *st, char *buf, size_t size);

#endif
