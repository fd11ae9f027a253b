/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The Monte Carlo's statistics, apart from its trials. Internal header. */
#ifndef ASPH_MC_INTERNAL_H
#define ASPH_MC_INTERNAL_H

#include <stddef.h>

#include "asph/uncertainty.h"

/* The quantities of one characterization; NaN where it has none. */
void mc_quantities(const struct asph_fit_result *r, double q[ASPH_MC_N_QUANTITIES]);

/* The adaptive stop's rule (asph_mc_options). */
struct mc_stop {
	size_t block;
	int ndig;
	/* NULL: GUM's numerical tolerance on every covered quantity; else
	 * the thresholds of U a decision tests against, and its precision */
	const double *decide_U;
	double precision;
};

/* GUM S1 7.9.4 on the first n trials in blocks of stop->block: 1 when every
 * covered quantity's mean and standard uncertainty are stable to the
 * numerical tolerance of ndig significant digits of its uncertainty, or,
 * for a decision, when U of every quantity with a threshold is settled
 * against it. scratch holds 2 n / block doubles. */
int mc_stable(const double *values, size_t n, const int *covered, const struct mc_stop *stop,
	      double *scratch);

/* Mean, u, U of the first n trials; value[] is the reference. */
void mc_summarize(const double *values, size_t n, const int *covered,
		  const double *value, struct asph_mc_result *out);

#endif
