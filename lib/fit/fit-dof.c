/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The parameters a fit varies: their indices into the full parameter
 * vector, and the solver's start vector and covariance sized to them.
 * The areal fit sets them once; a profile fit narrows them to what its
 * traces can see. */
#include <errno.h>

#include <gsl/gsl_matrix.h>
#include <gsl/gsl_vector.h>

#include "asph/fit.h"
#include "fit-internal.h"

int fit_select_dof(struct asph_fit *w, unsigned mask, struct asph_error *err)
{
	int p = 0;

	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (mask & ASPH_FIT_DOF_BIT(d))
			w->idx[p++] = d;
	w->opt.dof = mask;
	w->p = p;
	if (w->x0 && w->x0->size == (size_t)p)
		return 0;
	gsl_vector_free(w->x0);
	gsl_matrix_free(w->covar);
	w->x0 = gsl_vector_alloc((size_t)p);
	w->covar = gsl_matrix_alloc((size_t)p, (size_t)p);
	if (!w->x0 || !w->covar)
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}
