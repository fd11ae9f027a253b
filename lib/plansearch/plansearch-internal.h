/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The plan search's pieces shared by its files. Internal header. */
#ifndef ASPH_PLANSEARCH_INTERNAL_H
#define ASPH_PLANSEARCH_INTERNAL_H

#include <stddef.h>

#include "asph/plan-search.h"

#define NQ ASPH_MC_N_QUANTITIES

/* A plan characterized with the Monte Carlo: its own U per quantity. */
struct ps_eval {
	size_t request;         /* the points asked for (the plan's density) */
	size_t n;               /* the plan's points */
	double spacing_mm, seconds;
	double U[NQ];           /* NaN where not limited or not computed */
	size_t trials;          /* the Monte Carlo's, which weigh it */
	int computed;           /* every limited quantity was computed */
	struct asph_synth_term terms[3];        /* the part's form error */
	size_t n_terms;
};

/* The runs of a model that can tell a from b span at least this factor
 * in N. */
#define PS_MIN_SPAN 1.5

/* Runs spanning this factor in N tell the floor at twice its standard
 * error; runs closer together at three times (the floor's stop). A step
 * of 16 gives it, its points within a few % of the request. */
#define PS_WIDE_SPAN 12.0

/* The floor of U beyond the threshold by at least this factor (less
 * twice the floor's standard error) ends a method: beyond what the Monte
 * Carlo's error and a model that is only about right can account for. */
#define PS_FLOOR_MARGIN 1.1

/*
 * U^2 = a / N + b of quantity q, fitted to the runs evals[] of one method,
 * each weighted by its trials (var(U^2) = 2 U^4 / M), a and b >= 0; with
 * one run b = 0. *U_out at n and *root, the N where U meets limit (0 when
 * it meets it everywhere, INFINITY when nowhere), are those of the runs
 * whose N lies within a factor 4 of n when two or more of them span a
 * factor 1.5, else of all the method's runs. *floor_beyond is 1 when the
 * floor b of all the method's runs (spanning a factor 1.5 or more), less
 * twice its standard error (three times while they span less than
 * PS_WIDE_SPAN), is beyond (PS_FLOOR_MARGIN limit)^2, and the finest run's
 * own U fails limit by more than twice its standard error.
 * 0, or -EDOM without a run to fit.
 */
int ps_model(const struct ps_eval *evals, size_t n_evals, int q, double n, double limit,
	     double *U_out, double *root, int *floor_beyond);

#endif
