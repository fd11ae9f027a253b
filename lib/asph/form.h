/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_FORM_H
#define ASPH_FORM_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/units.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The surface form quantities of ISO 10110-5 as ISO 14999-4 evaluates them,
 * from a surface form deviation F sampled at points of the test region
 * (docs/characterization.md, "Form deviation quantities"):
 *
 *   F_tilt  least-squares fit of {1, u, v}            (piston and tilt)
 *   F_sph   least-squares fit of {1, u, v, rho^2}     (approximating sphere)
 *   F_asp   least-squares fit of {1, u, v, rho^2} and the rotationally
 *           symmetric Zernike radial polynomials R_4 .. R_order
 *                                                      (approximating asphere)
 *   A     = the power term of F_sph from the centre to the edge of the test
 *           region (signed: positive when the edge stands higher, on +z)
 *   B     = PV(F - F_sph)                    irregularity
 *   C     = PV(F_rsi), F_rsi the rotationally symmetric part of F_asp - F_sph
 *   RMSt  = RMS(F - F_tilt), RMSi = RMS(F - F_sph), RMSa = RMS(F - F_asp)
 *
 * u = rho cos(theta), v = rho sin(theta), rho = r / (radius of the test
 * region). PV and RMS are over the points. A, B, C also in fringes of the
 * test wavelength: one fringe is lambda / 2 of height.
 */

#define ASPH_FORM_DEFAULT_WAVELENGTH_NM 546.07
/* Radial order of the rotationally symmetric fit (R_4 .. R_20). */
#define ASPH_FORM_DEFAULT_RSI_ORDER 20
#define ASPH_FORM_MAX_RSI_ORDER 40

struct asph_form_options {
	double wavelength_nm;    /* 0 = ASPH_FORM_DEFAULT_WAVELENGTH_NM */
	int rsi_order;           /* even, 4..40; 0 = default */
	double noise_nm;         /* standard deviation of independent noise on
				    F, for the uncertainties (NaN: none) */
	/* The points lie on one line along u (a line profile, theta 0 or pi
	 * about a centre on it, or a parallel line): v is not fitted, and C
	 * and RMSa, which need the azimuthal average, are NaN. */
	int one_line;
};

struct asph_form {
	double wavelength_nm;
	asph_nm A, B, C;
	double A_fringes, B_fringes, C_fringes;
	asph_nm rms_t, rms_i, rms_a;
	size_t n;                /* points evaluated */
};

/*
 * Expanded uncertainties (k = 2) of the reported quantities, the same
 * names as the values they cover. method says where they come from; a
 * quantity without an estimate is NaN.
 */
enum asph_uncertainty_method {
	ASPH_UNCERTAINTY_NONE = 0,
	ASPH_UNCERTAINTY_COVARIANCE,    /* linear propagation of the noise and
					   the fit's covariance */
	ASPH_UNCERTAINTY_MONTE_CARLO,   /* GUM Supplement 1 on the instrument
					   model */
};

/* "none", "covariance", "monte-carlo" */
const char *asph_uncertainty_method_name(enum asph_uncertainty_method m);

struct asph_uncertainty_k2 {
	enum asph_uncertainty_method method;
	asph_nm A, B, C;
	double A_fringes, B_fringes, C_fringes;
	asph_nm rms_t, rms_i, rms_a;
	asph_urad slope_rms, slope_max;
	double R_mm;             /* of the fitted R and of its deviation */
	double c_per_mm;         /* of the fitted curvature c = 1/R */
};

/* All members NaN, method NONE. */
void asph_uncertainty_k2_clear(struct asph_uncertainty_k2 *u);

/*
 * The quantities of F (nm) at n points (rho_i, theta_i), rho in [0, 1].
 * With opts->noise_nm >= 0, u (may be NULL) receives the expanded
 * uncertainties of A, B, C and the RMS values propagated from that noise
 * (docs/characterization.md), its other members untouched.
 * -EINVAL: bad options, a non-finite input; -EDOM: the points cannot
 * determine the fits (too few, or all at few radii); -ENOMEM.
 */
int asph_form_compute(const double *rho, const double *theta,
		      const double *value_nm, size_t n,
		      const struct asph_form_options *opts,
		      struct asph_form *out, struct asph_uncertainty_k2 *u,
		      struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
