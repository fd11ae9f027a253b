/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_PLAN_SEARCH_H
#define ASPH_PLAN_SEARCH_H

#include <stddef.h>

#include "asph/characterize.h"
#include "asph/error.h"
#include "asph/fit.h"
#include "asph/plan.h"
#include "asph/progress.h"
#include "asph/surface.h"
#include "asph/tolerance.h"
#include "asph/uncertainty.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The plan for a tolerance (docs/sampling-plans.md, "The plan for a
 * tolerance"): the plan with the shortest predicted measuring time whose
 * expanded uncertainty U (k = 2) is at most capability x T for every
 * toleranced quantity, T the quantity's limit.
 *
 * Each candidate plan is measured in simulation: a part at the tolerance's
 * limit (its form error, in the shape each quantity measures, scaled on
 * the plan so that the quantity reads its limit) is characterized on the
 * plan's points with the instrument's Monte Carlo, by
 * asph_characterize_points() as a job's own uncertainty is. The search
 * runs over the plan methods and, per method, the number of points:
 * bracketed from the coarsest plan upwards, then bisected, with U^2 = a/N
 * + b per quantity fitted to every Monte Carlo run of the method (which
 * pools their trials), and the Monte Carlo's adaptive stop told the
 * threshold it decides. A method is tried first at the number of points
 * that takes as long as the best plan so far: when it fails there it
 * cannot be quicker, and that one run says how far it was.
 *
 * libasph starts no threads and does no I/O: the Monte Carlo runs through
 * the caller's function (asph_characterize_mc_fn) and the measuring time
 * through another (the scan executor's prediction on the instrument).
 */

/* The instrument's contributions, grouped as the verdict names them. */
enum asph_plan_search_contribution {
	ASPH_PLAN_SEARCH_PROBE = 0,     /* probe_noise_nm */
	ASPH_PLAN_SEARCH_POSITION,      /* position_noise_um,
					   position_resolution_um, latency_us */
	ASPH_PLAN_SEARCH_DRIFT,         /* drift_residual_nm */
	ASPH_PLAN_SEARCH_TIP,           /* tip_radius_um */
	ASPH_PLAN_SEARCH_N_CONTRIBUTIONS
};

/* "probe noise", "position", "drift", "tip" */
const char *asph_plan_search_contribution_name(enum asph_plan_search_contribution c);
/* "probe_noise", "position", "drift", "tip": the JSON keys */
const char *asph_plan_search_contribution_key(enum asph_plan_search_contribution c);

/* The predicted measuring time of a plan, s: 0 or a negative errno with
 * err set. */
typedef int (*asph_plan_time_fn)(void *data, const struct asph_plan *plan, double *seconds,
				 struct asph_error *err);

#define ASPH_PLAN_SEARCH_DEFAULT_CAPABILITY 0.25
#define ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS 200000
#define ASPH_PLAN_SEARCH_DEFAULT_BUDGET 20000
/* The coarsest plan: this many points per term of the fit's Zernike
 * decomposition. */
#define ASPH_PLAN_SEARCH_POINTS_PER_TERM 10

struct asph_plan_search_options {
	/* The largest U / T allowed, in (0, 1]; 0 = 0.25. */
	double capability;
	/* T of each quantity in its unit (asph/uncertainty.h: nm, urad, mm
	 * for R); 0 where it is not limited. asph_plan_search_limits()
	 * fills them from a tolerance; a test may limit any quantity the
	 * Monte Carlo reports (the pose too). */
	double limit[ASPH_MC_N_QUANTITIES];
	/* The methods to try (bits 1 << enum asph_plan_method); 0 = all
	 * but the line profiles. */
	unsigned methods;
	/* The coarsest and finest plans tried; 0 = the defaults: at least
	 * ASPH_PLAN_SEARCH_POINTS_PER_TERM points per Zernike term of the
	 * fit, and no spacing above the slope's evaluation length when a
	 * slope is limited; at most ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS. */
	size_t min_points, max_points;
	/* The most characterizations the search may run (a Monte Carlo
	 * trial is one); 0 = ASPH_PLAN_SEARCH_DEFAULT_BUDGET. The search
	 * stops there and says so. */
	size_t budget;
	/* The characterization, as the job's: DOF, residual, Zernike terms
	 * and the tolerance (its wavelength and slope length; may be NULL). */
	struct asph_fit_options fit;
	/* The instrument's contributions (not all 0). */
	struct asph_uncertainty_model model;
	/* The Monte Carlo's seed and trials (n_trials, block_size; 0: 100
	 * trials in blocks of 25, then the adaptive stop up to max_trials);
	 * decide_U is the search's own. */
	struct asph_mc_options mc;
	/* The relative precision of U each decision needs (the adaptive
	 * stop's); 0 = 0.05. */
	double precision;
	asph_characterize_mc_fn run_mc;         /* required */
	void *run_mc_data;
	asph_plan_time_fn plan_time;            /* required */
	void *plan_time_data;
	/* Between the steps (a plan characterized): the characterizations
	 * run of the budget; a non-zero return cancels (-ECANCELED). */
	struct asph_progress progress;
};

/*
 * T of every quantity t limits into limit[] (0 elsewhere): A, B, C, RMSt,
 * RMSi, RMSa in nm, the slopes in urad, R - R_nominal in mm. -EINVAL when t
 * limits nothing.
 */
int asph_plan_search_limits(const struct asph_tolerance *t,
			    double limit[ASPH_MC_N_QUANTITIES], struct asph_error *err);

/* One limited quantity on one plan. */
struct asph_plan_search_quantity {
	enum asph_mc_quantity q;
	double limit;           /* T */
	double U;               /* of the model fitted to the method's runs
				   (NaN: not computed on the plan) */
	double ratio;           /* U / T */
	double U_run;           /* of this plan's own Monte Carlo */
};

/* What became of a method. */
enum asph_plan_search_outcome {
	ASPH_PLAN_SEARCH_NOT_TRIED = 0, /* not among the methods, or the
					   budget ran out first */
	ASPH_PLAN_SEARCH_CHOSEN,
	ASPH_PLAN_SEARCH_SLOWER,        /* its plan meeting the ratio takes
					   longer than the chosen one */
	ASPH_PLAN_SEARCH_TOO_SLOW,      /* its coarsest plan already takes
					   longer than the chosen one */
	ASPH_PLAN_SEARCH_IMPOSSIBLE,    /* no plan up to max_points meets
					   the ratio */
	ASPH_PLAN_SEARCH_FAILED,        /* its plan could not be computed or
					   timed (message) */
};

/* "not-tried", "chosen", "slower", "too-slow", "impossible", "failed" */
const char *asph_plan_search_outcome_name(enum asph_plan_search_outcome o);

#define ASPH_PLAN_SEARCH_MAX_QUANTITIES 9

struct asph_plan_search_method {
	enum asph_plan_method method;
	enum asph_plan_search_outcome outcome;
	/* Its plan that meets the ratio (CHOSEN, and SLOWER when it was
	 * searched), else the plan that decided its outcome: for SLOWER the
	 * plan of as many points as take the chosen plan's time, which
	 * fails the ratio; for TOO_SLOW its coarsest; for IMPOSSIBLE its
	 * finest tried. */
	size_t points;
	double spacing_mm, h;
	double seconds;
	double ratio;           /* the largest U / T there */
	enum asph_mc_quantity worst;    /* whose ratio that is */
	/* SLOWER without a plan of its own: about the time it would need,
	 * U falling as 1/sqrt(N) from the plan above (NaN: not known). */
	double needed_seconds;
	size_t evaluations;     /* plans characterized with the Monte Carlo */
	size_t characterizations;
	char message[160];      /* FAILED: why (cut to fit) */
};

struct asph_plan_search_result {
	int found;              /* a plan meets the ratio */
	int budget_exhausted;   /* the search stopped at its budget */
	double capability;
	/* The chosen plan (found): computed again with
	 * asph_plan_compute_opts(surface, method, density, ...). */
	enum asph_plan_method method;
	struct asph_plan_density density;       /* ASPH_DENSITY_POINTS */
	size_t points;
	double spacing_mm, h;
	double seconds;         /* its predicted measuring time */
	/* Each limited quantity on the chosen plan, or, when none was
	 * found, on the best plan tried (the smallest largest ratio). */
	size_t n_quantities;
	struct asph_plan_search_quantity quantity[ASPH_PLAN_SEARCH_MAX_QUANTITIES];
	/* Every method in enum order. */
	struct asph_plan_search_method methods[ASPH_PLAN_N_METHODS];
	/* No plan found: the quantity furthest from the ratio on the best
	 * plan tried, the contribution that dominates its U there (each
	 * contribution's Monte Carlo alone), and each one's U (NaN where
	 * the instrument declares none). */
	enum asph_mc_quantity failing;
	enum asph_plan_search_contribution dominant;
	double contribution_U[ASPH_PLAN_SEARCH_N_CONTRIBUTIONS];
	/* The simulated part: its Zernike terms (Noll j, nm) on the chosen
	 * (or best) plan. */
	size_t n_terms;
	struct asph_synth_term terms[4];
	size_t evaluations;
	size_t characterizations;       /* Monte Carlo trials, reference
					   fits and the part's scaling */
	size_t min_points, max_points;  /* the range searched */
};

struct asph_plan_search;

/*
 * The search for surface s (which must outlive it) with opts (copied).
 * -EINVAL with err naming what for: a capability outside (0, 1], no limit,
 * a limit that is negative or not finite, an empty model, a missing
 * function, min_points above max_points, no method. -ENOMEM.
 */
int asph_plan_search_alloc(const struct asph_surface *s,
			   const struct asph_plan_search_options *opts,
			   struct asph_plan_search **out, struct asph_error *err);
void asph_plan_search_free(struct asph_plan_search *ps);

/*
 * One step: the next plan computed, timed and characterized with the
 * Monte Carlo (or, at the end, the contributions' runs). 1 while there
 * is more to do, 0 when the search is over (the result is ready), or a
 * negative errno: -ECANCELED when the Monte Carlo's function or the
 * progress cancelled, else the error of a characterization that should
 * not fail.
 */
int asph_plan_search_iterate(struct asph_plan_search *ps, struct asph_error *err);

/* All the steps, telling opts.progress after each. */
int asph_plan_search_run(struct asph_plan_search *ps, struct asph_error *err);

/* What the last step did, for a progress display. */
struct asph_plan_search_status {
	enum asph_plan_method method;   /* of the plan characterized last */
	size_t points;
	double seconds;
	double ratio;                   /* its largest U / T (NaN: none yet) */
	int passed;                     /* it meets the ratio */
	size_t evaluations, characterizations, budget;
};
void asph_plan_search_status(const struct asph_plan_search *ps,
			     struct asph_plan_search_status *out);

/* A limited quantity's name in the result: the verdict's item name for
 * what a tolerance limits ("A_nm", ..., "slope_rms_urad",
 * "slope_max_urad", "R_deviation_mm"), else asph_mc_quantity_key(). */
const char *asph_plan_search_quantity_name(enum asph_mc_quantity q);

/* After the search: the result. */
const struct asph_plan_search_result *asph_plan_search_result(const struct asph_plan_search *ps);

/*
 * The result as JSON text (malloc'd): {"found", "capability", "plan":
 * {"method", "density", "value", "points", "spacing_mm", "h"},
 * "estimate_s", "quantities": [{"quantity", "limit", "U", "ratio",
 * "U_run"}], "methods": [{"method", "outcome", "points", "h", "estimate_s",
 * "ratio", "worst", "needed_s"}], "impossible": null or {"quantity",
 * "dominant", "contributions": {...}}, "part": [{"j", "nm"}],
 * "evaluations", "characterizations", "budget_exhausted", "points_range"}.
 * Quantities by their summary keys (asph_mc_quantity_key()). 0 or -ENOMEM.
 */
int asph_plan_search_result_to_json(const struct asph_plan_search_result *r, char **out);

#ifdef __cplusplus
}
#endif

#endif
