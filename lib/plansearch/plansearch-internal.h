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

/*
 * U^2 = a / N + b of quantity q, fitted to the runs evals[] of one method
 * whose N lies within a factor 4 of n, each weighted by its trials
 * (var(U^2) = 2 U^4 / M), a and b >= 0; with one run b = 0. *U_out at n,
 * *root the N where it meets limit (0 when it meets it everywhere,
 * INFINITY when nowhere), *floor_beyond 1 when b is beyond limit^2 by
 * more than twice its standard error. 0, or -EDOM without a run to fit.
 */
int ps_model(const struct ps_eval *evals, size_t n_evals, int q, double n, double limit,
	     double *U_out, double *root, int *floor_beyond);

#endif
