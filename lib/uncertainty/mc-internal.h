/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The Monte Carlo's statistics, apart from its trials. Internal header. */
#ifndef ASPH_MC_INTERNAL_H
#define ASPH_MC_INTERNAL_H

#include <stddef.h>

#include "asph/uncertainty.h"

/* The quantities of one characterization; NaN where it has none. */
void mc_quantities(const struct asph_fit_result *r, double q[ASPH_MC_N_QUANTITIES]);

/* GUM S1 7.9.4 on the first n trials in blocks of `block`: 1 when every
 * covered quantity's mean and standard uncertainty are stable to the
 * numerical tolerance of `ndig` significant digits of its uncertainty.
 * scratch holds 2 n / block doubles. */
int mc_stable(const double *values, size_t n, const int *covered, size_t block, int ndig,
	      double *scratch);

/* Mean, u, U of the first n trials; value[] is the reference. */
void mc_summarize(const double *values, size_t n, const int *covered,
		  const double *value, struct asph_mc_result *out);

#endif
