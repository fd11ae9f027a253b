/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * ISO 14999-4 form quantities of a surface form deviation: three nested
 * least-squares fits (tilt, sphere, asphere), whose bases are prefixes of
 * one another, so one set of normal equations serves all three.
 */
#include <errno.h>
#include <math.h>
#include <string.h>

#include <gsl/gsl_errno.h>
#include <gsl/gsl_linalg.h>

#include "asph/form.h"

#define N_TILT 3
#define N_SPH 4
#define TERM_V 2
#define MAX_TERMS (N_SPH + ASPH_FORM_MAX_RSI_ORDER / 2 - 1)
/* Below this reciprocal condition number a fit is not determined. */
#define MIN_RCOND 1e-12

const char *asph_uncertainty_method_name(enum asph_uncertainty_method m)
{
	switch (m) {
	case ASPH_UNCERTAINTY_COVARIANCE:
		return "covariance";
	case ASPH_UNCERTAINTY_MONTE_CARLO:
		return "monte-carlo";
	default:
		return "none";
	}
}

void asph_uncertainty_k2_clear(struct asph_uncertainty_k2 *u)
{
	u->method = ASPH_UNCERTAINTY_NONE;
	u->A.v = u->B.v = u->C.v = NAN;
	u->A_fringes = u->B_fringes = u->C_fringes = NAN;
	u->rms_t.v = u->rms_i.v = u->rms_a.v = NAN;
	u->slope_rms.v = u->slope_max.v = NAN;
	u->R_mm = NAN;
	u->c_per_mm = NAN;
}

/*
 * The asphere basis at one point: 1, u, v, rho^2, then the Zernike radial
 * polynomials R_n^0(rho) = P_{n/2}(2 rho^2 - 1) (Legendre) for n = 4, 6, ...
 * Their orthogonality over the disk keeps the normal equations well
 * conditioned up to high orders.
 */
static void basis_row(double rho, double theta, int n_terms, double *row)
{
	double x = 2 * rho * rho - 1, p0 = 1, p1 = x;

	row[0] = 1;
	row[1] = rho * cos(theta);
	row[2] = rho * sin(theta);
	row[3] = rho * rho;
	for (int k = 2, i = N_SPH; i < n_terms; k++, i++) {
		double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
		row[i] = p2;
		p0 = p1;
		p1 = p2;
	}
}

struct fit {
	int p;                      /* basis terms */
	int m;                      /* of them fitted (all but v on one line) */
	int idx[MAX_TERMS];         /* fitted term -> basis term */
	gsl_matrix_view L;          /* Cholesky factor of the normal matrix */
	double store[MAX_TERMS * MAX_TERMS];
	double coef[MAX_TERMS];     /* per basis term; 0 for one not fitted */
};

/* The fit over the first p basis terms (without v when one_line) from
 * the full normal equations. */
static int fit_solve(struct fit *f, int p, const double *M, int ld,
		     const double *b, int one_line, struct asph_error *err)
{
	double rcond = 0, work[3 * MAX_TERMS], br[MAX_TERMS], x[MAX_TERMS];
	gsl_vector_view wv, bv, xv;

	f->p = p;
	f->m = 0;
	for (int i = 0; i < p; i++)
		if (!(one_line && i == TERM_V))
			f->idx[f->m++] = i;
	for (int i = 0; i < f->m; i++) {
		br[i] = b[f->idx[i]];
		for (int j = 0; j < f->m; j++)
			f->store[i * f->m + j] = M[f->idx[i] * ld + f->idx[j]];
	}
	wv = gsl_vector_view_array(work, 3 * (size_t)f->m);
	bv = gsl_vector_view_array(br, (size_t)f->m);
	xv = gsl_vector_view_array(x, (size_t)f->m);
	f->L = gsl_matrix_view_array(f->store, (size_t)f->m, (size_t)f->m);
	if (gsl_linalg_cholesky_decomp1(&f->L.matrix) != GSL_SUCCESS ||
	    gsl_linalg_cholesky_rcond(&f->L.matrix, &rcond, &wv.vector) != GSL_SUCCESS ||
	    !(rcond > MIN_RCOND))
		return asph_error_set(err, -EDOM,
				      "the points do not determine a fit of %d terms "
				      "(too few, or at too few radii)", f->m);
	gsl_linalg_cholesky_solve(&f->L.matrix, &bv.vector, &xv.vector);
	memset(f->coef, 0, sizeof(f->coef));
	for (int i = 0; i < f->m; i++)
		f->coef[f->idx[i]] = x[i];
	return 0;
}

static double fit_value(const struct fit *f, const double *row)
{
	double v = 0;

	for (int i = 0; i < f->p; i++)
		v += f->coef[i] * row[i];
	return v;
}

/* g^T M^-1 g for the fit's normal matrix M (g over the basis terms). */
static double fit_quadratic(const struct fit *f, const double *g)
{
	double x[MAX_TERMS], gr[MAX_TERMS], q = 0;
	gsl_vector_view gv = gsl_vector_view_array(gr, (size_t)f->m);
	gsl_vector_view xv = gsl_vector_view_array(x, (size_t)f->m);

	for (int i = 0; i < f->m; i++)
		gr[i] = g[f->idx[i]];
	gsl_linalg_cholesky_solve(&f->L.matrix, &gv.vector, &xv.vector);
	for (int i = 0; i < f->m; i++)
		q += gr[i] * x[i];
	return q;
}

static int check_input(const double *rho, const double *theta,
		       const double *value, size_t n,
		       const struct asph_form_options *o, struct asph_error *err)
{
	if (o->wavelength_nm < 0 || !isfinite(o->wavelength_nm))
		return asph_error_set(err, -EINVAL, "wavelength %g nm is not a positive number",
				      o->wavelength_nm);
	if (o->rsi_order != 0 && (o->rsi_order < 4 || o->rsi_order > ASPH_FORM_MAX_RSI_ORDER ||
				  o->rsi_order % 2))
		return asph_error_set(err, -EINVAL,
				      "rotationally symmetric order %d is not even in 4..%d",
				      o->rsi_order, ASPH_FORM_MAX_RSI_ORDER);
	for (size_t i = 0; i < n; i++)
		if (!isfinite(rho[i]) || !isfinite(theta[i]) || !isfinite(value[i]) ||
		    rho[i] < 0)
			return asph_error_set(err, -EINVAL,
					      "point %zu: not a finite position and value", i);
	return 0;
}

struct extremes {
	double lo, hi;
	size_t ilo, ihi;
};

static void extremes_add(struct extremes *e, double v, size_t i)
{
	if (v < e->lo) {
		e->lo = v;
		e->ilo = i;
	}
	if (v > e->hi) {
		e->hi = v;
		e->ihi = i;
	}
}

/* The rotationally symmetric part of F_asp - F_sph at one basis row. */
static double rsi_value(const struct fit *asp, const struct fit *sph,
			const double *row)
{
	double v = (asp->coef[3] - sph->coef[3]) * row[3];

	for (int i = N_SPH; i < asp->p; i++)
		v += asp->coef[i] * row[i];
	return v;
}

struct sums {
	double t2, i2, a2;
	struct extremes irr, rsi;
};

static void residual_pass(const double *rho, const double *theta,
			  const double *value, size_t n, const struct fit *f,
			  struct sums *s)
{
	double row[MAX_TERMS];

	memset(s, 0, sizeof(*s));
	s->irr.lo = s->rsi.lo = INFINITY;
	s->irr.hi = s->rsi.hi = -INFINITY;
	for (size_t i = 0; i < n; i++) {
		basis_row(rho[i], theta[i], f[2].p, row);
		double t = value[i] - fit_value(&f[0], row);
		double irr = value[i] - fit_value(&f[1], row);
		double a = value[i] - fit_value(&f[2], row);
		s->t2 += t * t;
		s->i2 += irr * irr;
		s->a2 += a * a;
		extremes_add(&s->irr, irr, i);
		extremes_add(&s->rsi, rsi_value(&f[2], &f[1], row), i);
	}
}

/* Linear propagation of independent noise sigma on F (docs). */
static void propagate(const double *rho, const double *theta, size_t n,
		      const struct fit *f, const struct sums *s, double sigma,
		      double fringe, struct asph_uncertainty_k2 *u)
{
	double ra[MAX_TERMS], rb[MAX_TERMS], g[MAX_TERMS], e4[N_SPH] = { 0, 0, 0, 1 };
	int p = f[2].p;

	u->A.v = 2 * sigma * sqrt(fit_quadratic(&f[1], e4));
	/* B: the difference of two residuals of the sphere fit. */
	basis_row(rho[s->irr.ihi], theta[s->irr.ihi], p, ra);
	basis_row(rho[s->irr.ilo], theta[s->irr.ilo], p, rb);
	for (int i = 0; i < N_SPH; i++)
		g[i] = ra[i] - rb[i];
	u->B.v = s->irr.ihi == s->irr.ilo ? 0 :
		 2 * sigma * sqrt(fmax(2 - fit_quadratic(&f[1], g), 0));
	/* C: the radial coefficients of the asphere minus the sphere fit. */
	basis_row(rho[s->rsi.ihi], theta[s->rsi.ihi], p, ra);
	basis_row(rho[s->rsi.ilo], theta[s->rsi.ilo], p, rb);
	for (int i = 0; i < p; i++)
		g[i] = i < N_TILT ? 0 : ra[i] - rb[i];
	u->C.v = 2 * sigma * sqrt(fmax(fit_quadratic(&f[2], g) - fit_quadratic(&f[1], g), 0));
	u->rms_t.v = u->rms_i.v = u->rms_a.v = 2 * sigma / sqrt((double)n);
	u->A_fringes = u->A.v / fringe;
	u->B_fringes = u->B.v / fringe;
	u->C_fringes = u->C.v / fringe;
	u->method = ASPH_UNCERTAINTY_COVARIANCE;
}

int asph_form_compute(const double *rho, const double *theta,
		      const double *value_nm, size_t n,
		      const struct asph_form_options *opts,
		      struct asph_form *out, struct asph_uncertainty_k2 *u,
		      struct asph_error *err)
{
	struct asph_form_options o = { 0 };
	double M[MAX_TERMS * MAX_TERMS] = { 0 }, b[MAX_TERMS] = { 0 }, row[MAX_TERMS];
	struct fit f[3];
	struct sums s;
	int p, r;

	if (opts)
		o = *opts;
	r = check_input(rho, theta, value_nm, n, &o, err);
	if (r < 0)
		return r;
	if (o.wavelength_nm == 0)
		o.wavelength_nm = ASPH_FORM_DEFAULT_WAVELENGTH_NM;
	if (o.rsi_order == 0)
		o.rsi_order = ASPH_FORM_DEFAULT_RSI_ORDER;
	p = N_SPH + o.rsi_order / 2 - 1;
	if (n <= (size_t)p)
		return asph_error_set(err, -EDOM, "%zu points cannot determine a fit of %d terms",
				      n, p);
	for (size_t i = 0; i < n; i++) {
		basis_row(rho[i], theta[i], p, row);
		for (int j = 0; j < p; j++) {
			b[j] += row[j] * value_nm[i];
			for (int k = 0; k <= j; k++)
				M[j * p + k] += row[j] * row[k];
		}
	}
	for (int j = 0; j < p; j++)
		for (int k = j + 1; k < p; k++)
			M[j * p + k] = M[k * p + j];
	if ((r = fit_solve(&f[0], N_TILT, M, p, b, o.one_line, err)) < 0 ||
	    (r = fit_solve(&f[1], N_SPH, M, p, b, o.one_line, err)) < 0 ||
	    (r = fit_solve(&f[2], p, M, p, b, o.one_line, err)) < 0)
		return r;
	residual_pass(rho, theta, value_nm, n, f, &s);

	double fringe = 0.5 * o.wavelength_nm;
	out->wavelength_nm = o.wavelength_nm;
	out->n = n;
	out->A.v = f[1].coef[3];
	out->B.v = s.irr.hi - s.irr.lo;
	out->C.v = s.rsi.hi - s.rsi.lo;
	out->A_fringes = out->A.v / fringe;
	out->B_fringes = out->B.v / fringe;
	out->C_fringes = out->C.v / fringe;
	out->rms_t.v = sqrt(s.t2 / (double)n);
	out->rms_i.v = sqrt(s.i2 / (double)n);
	out->rms_a.v = sqrt(s.a2 / (double)n);
	if (u && o.noise_nm >= 0 && isfinite(o.noise_nm))
		propagate(rho, theta, n, f, &s, o.noise_nm, fringe, u);
	if (o.one_line) {
		/* one diameter cannot tell the rotationally symmetric part
		 * from the even azimuthal terms (astigmatism, ...) */
		out->C.v = out->C_fringes = out->rms_a.v = NAN;
		if (u && u->method == ASPH_UNCERTAINTY_COVARIANCE)
			u->C.v = u->C_fringes = u->rms_a.v = NAN;
	}
	return 0;
}
