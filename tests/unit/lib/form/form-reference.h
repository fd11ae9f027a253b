/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * An independent computation of the ISO 14999-4 quantities for the tests:
 * GSL's SVD least squares (gsl_multifit_linear) on another basis of the
 * same spaces (Chebyshev polynomials T_k(2 rho^2 - 1) for the rotationally
 * symmetric terms, where the library uses Legendre ones and Cholesky on
 * the normal equations), and PV and RMS straight from the residuals.
 */
#ifndef FORM_REFERENCE_H
#define FORM_REFERENCE_H

#include <math.h>
#include <stdlib.h>

#include <gsl/gsl_multifit.h>

struct form_reference {
	double A, B, C, rms_t, rms_i, rms_a;
};

static void reference_row(double rho, double theta, int p, double *row)
{
	double x = 2 * rho * rho - 1;

	row[0] = 1;
	row[1] = rho * cos(theta);
	row[2] = rho * sin(theta);
	row[3] = x;   /* spans rho^2 with the constant */
	for (int k = 2; k + 2 < p; k++)
		row[k + 2] = cos(k * acos(fmax(-1, fmin(1, x))));
}

/* Coefficients of the first p terms, and the fitted values at each point. */
static void reference_fit(const double *rho, const double *theta, const double *v,
			  size_t n, int p, double *coef, double *fitted)
{
	gsl_matrix *X = gsl_matrix_alloc(n, (size_t)p), *cov = gsl_matrix_alloc((size_t)p, (size_t)p);
	gsl_vector *y = gsl_vector_alloc(n), *c = gsl_vector_alloc((size_t)p);
	gsl_multifit_linear_workspace *w = gsl_multifit_linear_alloc(n, (size_t)p);
	double chi2, row[32];

	for (size_t i = 0; i < n; i++) {
		reference_row(rho[i], theta[i], p, row);
		for (int k = 0; k < p; k++)
			gsl_matrix_set(X, i, (size_t)k, row[k]);
		gsl_vector_set(y, i, v[i]);
	}
	gsl_multifit_linear(X, y, c, cov, &chi2, w);
	for (size_t i = 0; i < n; i++) {
		double f = 0;
		for (int k = 0; k < p; k++)
			f += gsl_matrix_get(X, i, (size_t)k) * gsl_vector_get(c, (size_t)k);
		fitted[i] = f;
	}
	for (int k = 0; k < p; k++)
		coef[k] = gsl_vector_get(c, (size_t)k);
	gsl_multifit_linear_free(w);
	gsl_matrix_free(X);
	gsl_matrix_free(cov);
	gsl_vector_free(y);
	gsl_vector_free(c);
}

/* order: radial order of the rotationally symmetric fit (20 by default). */
static void form_reference(const double *rho, const double *theta, const double *v,
			   size_t n, int order, struct form_reference *out)
{
	int p = 4 + order / 2 - 1;
	double *ft = malloc(n * sizeof(double)), *fs = malloc(n * sizeof(double));
	double *fa = malloc(n * sizeof(double)), cs[32], ca[32];
	double t2 = 0, i2 = 0, a2 = 0, blo = INFINITY, bhi = -INFINITY;
	double clo = INFINITY, chi = -INFINITY;

	reference_fit(rho, theta, v, n, 3, cs, ft);
	reference_fit(rho, theta, v, n, 4, cs, fs);
	reference_fit(rho, theta, v, n, p, ca, fa);
	for (size_t i = 0; i < n; i++) {
		double irr = v[i] - fs[i], row[32], rsi = 0;
		t2 += (v[i] - ft[i]) * (v[i] - ft[i]);
		i2 += irr * irr;
		a2 += (v[i] - fa[i]) * (v[i] - fa[i]);
		blo = fmin(blo, irr);
		bhi = fmax(bhi, irr);
		/* The rotationally symmetric part of asphere minus sphere. */
		reference_row(rho[i], theta[i], p, row);
		rsi = (ca[3] - cs[3]) * row[3];
		for (int k = 4; k < p; k++)
			rsi += ca[k] * row[k];
		clo = fmin(clo, rsi);
		chi = fmax(chi, rsi);
	}
	/* row[3] = 2 rho^2 - 1: the power from centre to edge is 2 c3. */
	out->A = 2 * cs[3];
	out->B = bhi - blo;
	out->C = chi - clo;
	out->rms_t = sqrt(t2 / (double)n);
	out->rms_i = sqrt(i2 / (double)n);
	out->rms_a = sqrt(a2 / (double)n);
	free(ft);
	free(fs);
	free(fa);
}

#endif
