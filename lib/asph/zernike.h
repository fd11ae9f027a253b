/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_ZERNIKE_H
#define ASPH_ZERNIKE_H

#include <stddef.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Zernike polynomials in Noll's order and normalization (j >= 1; each has
 * RMS 1 over the unit disk): Z_1 piston, Z_2 x-tilt, Z_3 y-tilt, Z_4 defocus,
 * ... rho in [0, 1], theta in radians from +x.
 *
 * Noll, "Zernike polynomials and atmospheric turbulence", J. Opt. Soc. Am.
 * 66, 207 (1976): Z_j = sqrt(n+1) R_n^0(rho) for m = 0, and
 * sqrt(2(n+1)) R_n^|m|(rho) cos(m theta) (j even) or sin(|m| theta) (j odd).
 */

/* Largest Noll index the functions below accept (radial order 20). */
#define ASPH_ZERNIKE_MAX_J 231

/* (n, m) of Noll index j; m signed (cos for m > 0, sin for m < 0).
 * Outside 1..ASPH_ZERNIKE_MAX_J: n = m = -1. */
void asph_zernike_noll_to_nm(int j, int *n, int *m);

/* Noll index of (n, m) (m signed as above); 0 if there is none. */
int asph_zernike_nm_to_noll(int n, int m);

/* Z_j(rho, theta); NaN for j outside 1..ASPH_ZERNIKE_MAX_J. */
double asph_zernike_noll(int j, double rho, double theta);

/* Cartesian gradient (dZ_j/du, dZ_j/dv) over the unit disk, where
 * u = rho cos theta, v = rho sin theta. Exact, also at rho = 0. */
void asph_zernike_noll_gradient(int j, double rho, double theta,
				double grad[2]);

/* Z_1 .. Z_n_terms at one point, into values[0 .. n_terms-1]. */
void asph_zernike_noll_all(int n_terms, double rho, double theta,
			   double *values);

/* sum_j coef[j-1] Z_j(rho, theta), and its Cartesian gradient (grad may be
 * NULL). */
double asph_zernike_series(const double *coef, int n_terms, double rho,
			   double theta, double grad[2]);

/* The series at n points: value[i], and grad[2i], grad[2i+1] unless grad is
 * NULL. Faster than n calls of asph_zernike_series(). */
void asph_zernike_series_many(const double *coef, int n_terms,
			      const double *rho, const double *theta, size_t n,
			      double *value, double *grad);

/*
 * Least-squares decomposition of values sampled at (rho_i, theta_i):
 * coef minimizes sum_i w_i (value_i - sum_j coef_j Z_j)^2 (w = NULL: all 1;
 * points with w_i = 0 do not count). Solved with GSL by Cholesky on the
 * normal equations (the terms are orthonormal over the disk, so for points
 * spread over it the system is close to diagonal), or, when that system is
 * not safely conditioned, by Householder QR; both streamed over blocks of
 * points, so memory does not grow with n.
 *
 * GSL reports the ill-conditioned case through its error handler, which a
 * program turns off (gsl_set_error_handler_off()) as the tools do.
 *
 * -EINVAL: n_terms outside 1..ASPH_ZERNIKE_MAX_J, a non-finite input.
 * -EDOM: the points do not determine the coefficients (fewer weighted points
 * than terms, or points that leave the system rank deficient, e.g. all on one
 * line). -ENOMEM.
 */
int asph_zernike_decompose(const double *rho, const double *theta,
			   const double *value, const double *w, size_t n,
			   int n_terms, double *coef, struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
