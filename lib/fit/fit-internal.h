/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The fit workspace, shared by lib/fit.c (solver) and lib/fit-residual.c
 * (statistics). Internal. */
#ifndef ASPH_FIT_INTERNAL_H
#define ASPH_FIT_INTERNAL_H

#include <gsl/gsl_multilarge_nlinear.h>

#include "asph/fit.h"
#include "fit-model.h"

/* J^T u and J^T J (its lower triangle) over the solver's y. */
struct fit_sums {
	double jtu[ASPH_FIT_N_DOF];
	double jtj[ASPH_FIT_N_DOF][ASPH_FIT_N_DOF];
};

enum fit_phase {
	FIT_PHASE_IDLE = 0,
	FIT_PHASE_RUNNING,
	FIT_PHASE_DONE,
};

struct asph_fit {
	struct asph_fit_options opt;
	struct fit_model model;
	size_t n_max, n;
	const double *xyz;

	/* Parameters: full[] holds every DOF; the solver sees the chosen ones
	 * in enum order. */
	int p;
	int idx[ASPH_FIT_N_DOF];        /* solver index -> DOF */
	double full[ASPH_FIT_N_DOF];

	/* Per point. */
	double *r_foot;     /* signed meridian foot, the next Newton start */
	double *slope;      /* dZ/dr there (NaN: no foot; 0 on a freeform) */
	/* freeform: the foot with S and its gradient there, the next start */
	struct fit_surface_point *foot;
	double *resid;      /* residual, mm (unweighted) */
	double *weight;     /* robust weight */
	double *scratch;    /* n, for f evaluations the solver does not own */
	double *left;       /* n, robust fit: residual minus its Zernike fit */
	uint8_t *status;

	/* Solver coordinates: x = xref + T y, T upper triangular. */
	double xref[ASPH_FIT_N_DOF];
	double T[ASPH_FIT_N_DOF][ASPH_FIT_N_DOF];

	/* The solver parameters y the stored feet belong to; scratch holds
	 * the weighted residual there when scratch_is_f. */
	double cached_y[ASPH_FIT_N_DOF];
	int cache_valid;
	int scratch_is_f;
	/* J^T f and J^T J with that evaluation, f where it was written */
	struct fit_sums sums;
	const double *sums_f;
	size_t sums_fs;

	gsl_multilarge_nlinear_workspace *solver;
	gsl_multilarge_nlinear_fdf fdf;
	gsl_vector *x0;
	gsl_matrix *covar;

	enum fit_phase phase;
	int pass, iter, total_iter;
	double chi2;                /* after the previous iteration */
	int converged;
	int n_changes;              /* passes started by exclusions */
	char reason[96];
	size_t n_outside;
	size_t n_status_changes;    /* in or out of the aperture, last check */
	size_t n_downweighted;      /* Tukey weight < 1/2 before hardening */
	int robust_done;            /* opt.robust cleared for the last pass */
};

/* Evaluates every point at the current parameters into resid[] (NaN for
 * those without a foot inside the aperture), refreshes the feet and the
 * statuses, and counts the changes in or out. Returns the number outside. */
size_t fit_evaluate_all(struct asph_fit *w);

/* The foot of point i in the part frame at the current parameters (the
 * point's own x, y for sag residuals; fit-foot.c). */
void fit_point_foot(const struct asph_fit *w, size_t i, double xy[2]);

/* That foot in polar coordinates over the disk that holds the aperture
 * about its centre (for a centred circle, the aperture itself): rho in
 * [0, 1] inside, theta from +x. */
void fit_point_polar(const struct asph_fit *w, size_t i, double *rho,
		     double *theta);

/* left[i] = resid[i] minus the weighted Zernike fit of the residual (NaN
 * for points outside): what a smooth form error cannot explain. */
int fit_smooth_residual(struct asph_fit *w, double *left,
			struct asph_error *err);

/* Form quantities, slope, radius deviation, uncertainties and verdict
 * (lib/fit/fit-form.c), after fit_fill_statistics(). */
int fit_fill_form(struct asph_fit *w, struct asph_fit_result *out,
		  struct asph_error *err);

int fit_fill_statistics(struct asph_fit *w, struct asph_fit_result *out,
			struct asph_error *err);

#endif
