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

/* Runs of consecutive points on one line, while the traces are sought. */
#define FIT_MAX_RUNS 256

/* Sums over points in x-y (about a reference point): their least-squares
 * line. */
struct fit_line_sums {
	double n, sx, sy, sxx, sxy, syy;
};

struct fit_trace {
	struct fit_line_sums sums;
	double u[2];                /* unit direction, azimuth in (-pi/2, pi/2] */
	double azimuth, offset, length;
	size_t n;
};

/* The line profiles the points are (n 0: they are not). */
struct fit_traces {
	int n;
	int single;                 /* one trace: the fit runs in its frame */
	double ca, sa;              /* cos, sin of that frame's azimuth; 1, 0
				       in the machine frame */
	double ref[2];              /* x-y origin of the sums */
	struct fit_trace t[ASPH_FIT_MAX_PROFILES];
};

struct fit_run {
	size_t first, n;
	struct fit_line_sums sums;
	int trace;
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
	const double *xyz;          /* the points fitted (a single profile's in
				       its trace's frame) */
	/* The DOF asked for (opt.dof is the set fitted), and whether the
	 * options left them to the default. */
	unsigned dof_asked;
	int dof_default;
	struct fit_traces traces;
	uint8_t *trace_of;          /* n_max: each point's trace */
	double *xyz_frame;          /* 3 n_max when a single profile needs it */
	struct fit_run runs[FIT_MAX_RUNS];

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
	/* The interpolant of the residual map the slope was computed on (the
	 * map's tilt removed from its values), kept for
	 * asph_fit_residual_scatter() to hand on with the map's own values:
	 * a triangulation depends on x, y alone, so one serves both. */
	struct asph_scatter *slope_scatter;

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

/* The form quantities, slope and their uncertainties of an areal
 * measurement (lib/fit/fit-form.c); fit_profile_fill() for profiles. */
int fit_areal_form(struct asph_fit *w, struct asph_fit_result *out, struct asph_error *err);

int fit_fill_statistics(struct asph_fit *w, struct asph_fit_result *out,
			struct asph_error *err);

/* Fits only the degrees of freedom of mask (solver index -> DOF). */
int fit_select_dof(struct asph_fit *w, unsigned mask, struct asph_error *err);

/* --- Line profiles (lib/fit/fit-profile.c) ------------------------------ */

/* Finds whether the points are line profiles (w->traces), chooses their
 * DOF and, for a single profile, turns the points into its trace's frame;
 * *pts: the points to fit. */
int fit_profile_setup(struct asph_fit *w, const double *xyz, size_t n,
		      const double **pts, struct asph_error *err);

/* A foot (x, y) of the fit's frame in the part's, whose azimuths are the
 * machine's. */
void fit_frame_to_part(const struct asph_fit *w, double xy[2]);

/* left[i] = resid[i] minus each trace's smooth (polynomial) fit of it,
 * NaN for points outside; *terms: the coefficients fitted in all. */
void fit_profile_smooth(const struct asph_fit *w, double *left, size_t *terms);

/* The profiles' statistics, form quantities, slope along the traces and
 * the machine-frame pose, after fit_fill_statistics(). */
int fit_profile_fill(struct asph_fit *w, struct asph_fit_result *out,
		     struct asph_error *err);

/* The fitted pose in the machine frame. */
void fit_machine_pose(const struct asph_fit *w, struct asph_pose *pose);

/* The form quantities of the residual at (rho, theta) over the disk, the
 * noise and wavelength given (fit-form.c); one_line for a profile. */
int fit_form_quantities(const double *rho, const double *theta, const double *val,
			size_t m, double wavelength, double noise, int one_line,
			struct asph_fit_result *out, struct asph_error *err);

/* The slope of an unavailable map: NaN values of length. */
void fit_slope_invalid(struct asph_slope *s, double length);

/* The options' wavelength and slope length, else the tolerance's, else
 * the defaults. */
void fit_form_lengths(const struct asph_fit *w, double *wavelength, double *length);

#endif
