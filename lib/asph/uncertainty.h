/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_UNCERTAINTY_H
#define ASPH_UNCERTAINTY_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/fit.h"
#include "asph/form.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Task-specific measurement uncertainty by Monte Carlo (GUM Supplement 1)
 * on the instrument model (docs/characterization.md, "Measurement
 * uncertainty by Monte Carlo").
 *
 * The recorded points, in scan order, are the best estimate of where the
 * surface is: the fitted surface in the fitted pose plus the residual the
 * characterization found. Each trial adds to them one draw of every
 * contribution of the instrument model below, re-runs the whole
 * characterization (best fit from the reference pose, residual statistics,
 * ISO 14999-4 quantities, slope, R when fitted) and keeps every reported
 * quantity. Their standard deviation over the trials is the standard
 * uncertainty u; the expanded uncertainty is U = 2 u (k = 2).
 */

/* ------------------------------------------------------- instrument model */

/*
 * What the instrument declares about itself. Every member is a standard
 * uncertainty (or a step), >= 0; 0 leaves that contribution out.
 */
struct asph_uncertainty_model {
	/* Probe reading noise, nm: independent per point, Gaussian, along
	 * the probe's measuring axis (machine z). */
	double probe_noise_nm;
	/* Stage position noise, um: independent per point and per axis (x,
	 * y), Gaussian. */
	double position_noise_um;
	/* Encoder resolution (quantization step) of x and y, um: an error
	 * uniform on +-step/2, independent per point and axis. */
	double position_resolution_um;
	/* Residual latency between the position latch and the probe
	 * reading, us: one Gaussian draw per trial, shared by the whole
	 * scan; with scan_speed_mm_s it displaces every point by
	 * speed x latency along the scan direction (the path between its
	 * neighbours in scan order). */
	double latency_us;
	double scan_speed_mm_s;     /* speed along the path, mm/s (not an
				       uncertainty: the latency's lever) */
	/* Drift left after the drift correction, nm: a ramp in z from 0 at
	 * the first point to d at the last, d one Gaussian draw per trial. */
	double drift_residual_nm;
	/* Tip radius uncertainty, um: one Gaussian draw per trial, every
	 * point displaced by it along the fitted surface's normal. */
	double tip_radius_um;
};

/* All contributions 0. */
void asph_uncertainty_model_init(struct asph_uncertainty_model *m);

/* 1 when no contribution is declared (every member 0). */
int asph_uncertainty_model_is_empty(const struct asph_uncertainty_model *m);

/* The members by name (the JSON keys of the instrument configuration's
 * "uncertainty" section): name, unit and a line of help, in declaration
 * order. */
struct asph_uncertainty_field {
	const char *name;       /* "probe_noise_nm", ... */
	const char *unit;       /* "nm", "um", "us", "mm/s" */
	const char *help;
};
const struct asph_uncertainty_field *asph_uncertainty_model_fields(size_t *n);

/*
 * Sets the member `name` to v. -ENOENT for an unknown name (err lists the
 * known ones), -EINVAL for a value that is negative or not finite, or a
 * latency without a scan speed (checked by asph_uncertainty_model_check).
 */
int asph_uncertainty_model_set(struct asph_uncertainty_model *m,
			       const char *name, double v,
			       struct asph_error *err);

/* -EINVAL with the member named in err->field when a value is negative or
 * not finite, or when latency_us > 0 and scan_speed_mm_s is 0. */
int asph_uncertainty_model_check(const struct asph_uncertainty_model *m,
				 struct asph_error *err);

/* The model as a JSON object text (malloc'd), every member by name. */
int asph_uncertainty_model_to_json(const struct asph_uncertainty_model *m,
				   char **out);

/* ------------------------------------------------------------ quantities */

/* The quantities a trial yields; the first ASPH_FIT_N_DOF are the fit's
 * degrees of freedom in enum asph_fit_dof order, R as the curvature c =
 * 1/R (1/mm) the fit varies (U(R) = U(c) / c^2, none when c = 0 lies
 * within U(c)). */
enum asph_mc_quantity {
	ASPH_MC_RMS = ASPH_FIT_N_DOF,  /* residual RMS, nm */
	ASPH_MC_PV,                    /* nm */
	ASPH_MC_PVR,                   /* nm */
	ASPH_MC_A, ASPH_MC_B, ASPH_MC_C,             /* nm */
	ASPH_MC_RMS_T, ASPH_MC_RMS_I, ASPH_MC_RMS_A, /* nm */
	ASPH_MC_SLOPE_RMS, ASPH_MC_SLOPE_MAX,        /* urad */
	ASPH_MC_N_QUANTITIES
};

/* The JSON summary's key of a quantity: "tx", "ty", "tz", "rx", "ry",
 * "c_per_mm", "k", "rz", "rms_nm", "pv_nm", "pvr_nm", "A_nm", "B_nm", "C_nm",
 * "rms_t_nm", "rms_i_nm", "rms_a_nm", "rms_urad", "max_urad". */
const char *asph_mc_quantity_key(enum asph_mc_quantity q);

/* -------------------------------------------------------------- the run */

#define ASPH_MC_DEFAULT_TRIALS 200
#define ASPH_MC_DEFAULT_BLOCK 50
#define ASPH_MC_DEFAULT_MAX_TRIALS 2000
#define ASPH_MC_COVERAGE_FACTOR 2.0

struct asph_mc_options {
	size_t n_trials;        /* 0 = ASPH_MC_DEFAULT_TRIALS */
	/* 1: exactly n_trials. 0: GUM S1 section 7.9's adaptive procedure
	 * (docs/characterization.md): blocks of block_size trials, tested
	 * from n_trials on after every block, until stable or max_trials. */
	int fixed;
	size_t block_size;      /* 0 = ASPH_MC_DEFAULT_BLOCK */
	size_t max_trials;      /* 0 = ASPH_MC_DEFAULT_MAX_TRIALS */
	int significant_digits; /* n_dig of the numerical tolerance; 0 = 1 */
	unsigned long seed;     /* trial t draws from a seed made of (seed, t):
				   the result does not depend on which worker
				   runs which trial, nor in what order */
	/*
	 * A decision instead of a report (asph/plan-search.h): where
	 * decide_U[q] > 0, the adaptive stop tests quantity q only, and only
	 * as far as the decision U <= decide_U[q] needs: its U = k u is
	 * stable when 2 k s_u <= max(decide_precision x decide_U[q],
	 * |U - decide_U[q]| / 2), s_u the spread of the block standard
	 * deviations of GUM S1 7.9.4 (the mean is not tested: the decision
	 * does not depend on it). Once one quantity's U is stable beyond its
	 * threshold the decision is made (the plan fails) and the stop does
	 * not wait for the others. Quantities without a threshold are not
	 * tested. NULL: GUM S1 7.9's numerical tolerance from
	 * significant_digits, on every covered quantity. Copied.
	 */
	const double *decide_U;         /* ASPH_MC_N_QUANTITIES entries */
	double decide_precision;        /* relative, 0 < p < 1; 0 = 0.05 */
};

struct asph_mc_result {
	size_t n_trials;        /* trials run */
	size_t n_failed;        /* trials whose fit failed (left out) */
	int fixed;
	int stable;             /* the adaptive stop's criterion was met */
	size_t block_size;
	int significant_digits;
	unsigned long seed;
	double coverage_factor; /* k = 2 */
	struct asph_uncertainty_model model;
	/* Per quantity: covered (1 when the characterization reports it),
	 * the reference value, the mean over the trials, the standard (u)
	 * and expanded (U = k u) uncertainty; NaN where not covered. */
	int covered[ASPH_MC_N_QUANTITIES];
	double value[ASPH_MC_N_QUANTITIES];
	double mean[ASPH_MC_N_QUANTITIES];
	double u[ASPH_MC_N_QUANTITIES];
	double U[ASPH_MC_N_QUANTITIES];
};

struct asph_mc;

/*
 * The run's workspace: the best estimate of the points, the reference
 * values and room for the values of up to max_trials (n_trials when fixed)
 * trials. xyz (3 n, machine frame, mm, in scan order) is copied; fit_opts
 * are those of the reference fit (its tolerance is not used), ref its
 * result. The surface must outlive the workspace. -EINVAL: bad options or
 * model, a reference fit without a converged pose; -ENOMEM.
 */
int asph_mc_alloc(const struct asph_surface *s, const double *xyz, size_t n,
		  const struct asph_fit_options *fit_opts,
		  const struct asph_fit_result *ref,
		  const struct asph_uncertainty_model *model,
		  const struct asph_mc_options *opts, struct asph_mc **out,
		  struct asph_error *err);
void asph_mc_free(struct asph_mc *mc);

/*
 * A run is driven by its caller, who may share the trials among threads of
 * its own (the library starts none):
 *
 *	done = 0;
 *	while (asph_mc_next_block(mc, done, &first, &count)) {
 *		run trials [first, first + count) with asph_mc_run_trials(),
 *		on any workers in any order;
 *		done = first + count;
 *	}
 *	asph_mc_finish(mc, done, cancelled, &result, &err);
 *
 * Trial t always draws the same numbers, so the result is the same bit for
 * bit whoever runs it.
 */

/* One worker's state: a fit workspace, a point buffer and a generator.
 * Allocate one per thread, once, before the first trial. -ENOMEM. */
struct asph_mc_worker;
int asph_mc_worker_alloc(const struct asph_mc *mc, struct asph_mc_worker **out,
			 struct asph_error *err);
void asph_mc_worker_free(struct asph_mc_worker *w);

/*
 * Runs trials [first, first + count) on the worker w (of this mc) and
 * stores their values in their own slots of mc. Re-entrant: different
 * workers may run disjoint ranges at the same time; nothing else of mc may
 * change meanwhile. A program using it turns GSL's abort handler off, as
 * for the fit. -EINVAL when the range exceeds the workspace's capacity or
 * w belongs to another run.
 */
int asph_mc_run_trials(struct asph_mc *mc, struct asph_mc_worker *w, size_t first,
		       size_t count);

/*
 * The next trials to run, given that trials [0, done) have run: 1 with
 * [*first, *first + *count) to run, 0 when the run is complete. done = 0
 * starts (or restarts) the run with the first n_trials; after that the
 * adaptive stop (not when fixed) tests the trials done and asks for
 * another block until they are stable or max_trials is reached. When done
 * falls short of what was asked, the rest is asked again.
 */
int asph_mc_next_block(struct asph_mc *mc, size_t done, size_t *first, size_t *count);

/* The trials asked for so far (what a progress display counts towards). */
size_t asph_mc_planned(const struct asph_mc *mc);

/*
 * The statistics of trials [0, done) into out. -ECANCELED when cancelled
 * is set or done falls short of what was asked (out then holds the
 * statistics of the trials done), -EDOM when more than half of the trials
 * failed.
 */
int asph_mc_finish(struct asph_mc *mc, size_t done, int cancelled,
		   struct asph_mc_result *out, struct asph_error *err);

/* After asph_mc_finish(): the values of trial t, quantity q at
 * values[t * ASPH_MC_N_QUANTITIES + q] (NaN where not covered or the trial
 * failed), for the *n_trials trials run. */
const double *asph_mc_values(const struct asph_mc *mc, size_t *n_trials);

/*
 * The expanded uncertainties into the fit's result: its uncertainty_k2
 * (method MONTE_CARLO; fringes at the form's wavelength) and its verdict,
 * decided again with them when the result carries one for tolerance t.
 */
void asph_mc_apply(const struct asph_mc_result *mc,
		   const struct asph_tolerance *t,
		   struct asph_fit_result *fit);

/*
 * JSON text (malloc'd) of an object with "uncertainty_k2" (U of every
 * covered quantity under its summary key, fringes included),
 * "uncertainty_standard" (u, the same keys) and "uncertainty_model" (the
 * contributions, trials, failures, seed, stability, k): to be merged into
 * the fit's JSON summary. wavelength_nm converts A, B, C to fringes.
 */
int asph_mc_result_to_json(const struct asph_mc_result *mc,
			   double wavelength_nm, char **out);

#ifdef __cplusplus
}
#endif

#endif
