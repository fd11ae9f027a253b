/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What the fit leaves: residual statistics, the Zernike decomposition, PVr,
 * slope error, and the uncertainties of the fitted values. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_blas.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_linalg.h>
#include <gsl/gsl_matrix.h>

#include "asph/fit.h"
#include "asph/zernike.h"
#include "fit-internal.h"
#include "util-mem.h"

static void count_points(const struct asph_fit *w, struct asph_fit_result *out)
{
	out->n_points = w->n;
	out->n_used = out->n_outside_aperture = out->n_outliers = 0;
	out->n_downweighted = 0;
	for (size_t i = 0; i < w->n; i++) {
		switch (w->status[i]) {
		case ASPH_FIT_POINT_USED:
			out->n_used++;
			break;
		case ASPH_FIT_POINT_OUTSIDE:
			out->n_outside_aperture++;
			continue;
		default:
			out->n_outliers++;
			break;
		}
	}
	out->n_downweighted = w->n_downweighted;
}

/* Standard uncertainties: sqrt(diag((J^T J)^-1) s^2), J and the residual
 * weighted as in the last pass, s^2 = chi^2 / (points counted - DOF). */
static void uncertainties(struct asph_fit *w, struct asph_fit_result *out)
{
	gsl_vector *f = gsl_multilarge_nlinear_residual(w->solver);
	size_t counted = 0;
	double chi2 = 0, s2;

	for (size_t i = 0; i < w->n; i++)
		if (w->status[i] != ASPH_FIT_POINT_OUTSIDE && w->weight[i] > 0)
			counted++;
	gsl_blas_ddot(f, f, &chi2);
	s2 = counted > (size_t)w->p ? chi2 / (double)(counted - (size_t)w->p) : NAN;
	out->sigma_mm = sqrt(s2);
	/* J is over the solver's y = T^-1 (x - xref): Cov(x) = T Cov(y) T^T.
	 * Cov(y) = (J^T J)^-1 from the solver's J^T J (its lower triangle),
	 * inverted here rather than by gsl_multilarge_nlinear_covar(), which
	 * swaps GSL's process-wide error handler around its factorization:
	 * fits run in parallel threads (the Monte Carlo) must not write it. */
	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		out->uncertainty[d] = 0.0;
	gsl_matrix_tricpy(CblasLower, CblasNonUnit, w->covar, w->solver->JTJ);
	if (gsl_linalg_cholesky_decomp1(w->covar) != GSL_SUCCESS ||
	    gsl_linalg_cholesky_invert(w->covar) != GSL_SUCCESS) {
		/* J^T J singular: the DOF are not determined */
		for (int k = 0; k < w->p; k++)
			out->uncertainty[w->idx[k]] = NAN;
		return;
	}
	for (int k = 0; k < w->p; k++) {
		double v = 0;
		for (int i = 0; i < w->p; i++)
			for (int j = 0; j < w->p; j++)
				v += w->T[k][i] * w->T[k][j] *
				     gsl_matrix_get(w->covar, (size_t)i, (size_t)j);
		out->uncertainty[w->idx[k]] = sqrt(v * s2);
	}
}

/* The fit varies c = 1/R: R and u(R) = u(c) / c^2 from it, both NaN when
 * c = 0 lies within U(c) = 2 u(c) (docs/characterization.md). */
static void radius_from_curvature(const struct asph_fit *w, struct asph_fit_result *out)
{
	double c = w->full[ASPH_FIT_R], uc = out->uncertainty[ASPH_FIT_R];

	out->curvature_nominal = w->model.c0;
	out->curvature = out->u_curvature = NAN;
	out->value[ASPH_FIT_R] = 1.0 / c;
	if (!(w->opt.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_R)))
		return;
	out->curvature = c;
	out->u_curvature = uc;
	out->uncertainty[ASPH_FIT_R] = uc / (c * c);
	/* (an unknown u(c) decides nothing: R stands) */
	if (c == 0 || fabs(c) <= 2 * uc)
		out->value[ASPH_FIT_R] = out->uncertainty[ASPH_FIT_R] = NAN;
}

struct field {
	double *rho, *theta, *val, *mask;
};

static void field_free(struct field *f)
{
	free(f->rho);
	free(f->theta);
	free(f->val);
	free(f->mask);
}

/* The residual in nm at the used points (mask 1), 0 with mask 0 elsewhere. */
static int field_build(const struct asph_fit *w, struct field *f,
		       struct asph_error *err)
{
	f->rho = malloc(w->n * sizeof(double) + 1);
	f->theta = malloc(w->n * sizeof(double) + 1);
	f->val = malloc(w->n * sizeof(double) + 1);
	f->mask = malloc(w->n * sizeof(double) + 1);
	if (!f->rho || !f->theta || !f->val || !f->mask)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(f->rho, w->n * sizeof(double));
	mem_advise_huge(f->theta, w->n * sizeof(double));
	mem_advise_huge(f->val, w->n * sizeof(double));
	mem_advise_huge(f->mask, w->n * sizeof(double));
	for (size_t i = 0; i < w->n; i++) {
		int used = w->status[i] == ASPH_FIT_POINT_USED;
		fit_point_polar(w, i, &f->rho[i], &f->theta[i]);
		f->val[i] = used ? asph_nm_from_mm(w->resid[i]).v : 0.0;
		f->mask[i] = used;
	}
	return 0;
}

int fit_smooth_residual(struct asph_fit *w, double *left,
			struct asph_error *err)
{
	struct field f = { 0 };
	double coef[ASPH_FIT_MAX_ZERNIKE];
	int n_z = w->opt.n_zernike, r;
	size_t terms;

	if (w->traces.n) {
		fit_profile_smooth(w, left, &terms);
		return 0;
	}
	r = field_build(w, &f, err);
	for (size_t i = 0; r == 0 && i < w->n; i++) {
		int inside = w->status[i] != ASPH_FIT_POINT_OUTSIDE;
		f.val[i] = inside ? asph_nm_from_mm(w->resid[i]).v : 0.0;
		f.mask[i] = inside ? w->weight[i] : 0.0;
	}
	if (r == 0)
		r = asph_zernike_decompose(f.rho, f.theta, f.val, f.mask, w->n,
					   n_z, coef, err);
	if (r == -EDOM) {
		/* Too few points for the terms: the scale then comes from the
		 * residual itself. */
		memset(coef, 0, sizeof(coef));
		asph_error_clear(err);
		r = 0;
	}
	if (r == 0)   /* the fit in nm, into val */
		asph_zernike_series_many(coef, n_z, f.rho, f.theta, w->n, f.val, NULL);
	for (size_t i = 0; r == 0 && i < w->n; i++)
		left[i] = w->status[i] == ASPH_FIT_POINT_OUTSIDE ? NAN :
			  w->resid[i] - asph_nm_to_mm((asph_nm){ f.val[i] });
	field_free(&f);
	return r;
}

static void basic_stats(const struct field *f, size_t n,
			struct asph_fit_result *out)
{
	double sum = 0, sum2 = 0, lo = INFINITY, hi = -INFINITY, mean;
	size_t m = 0;

	for (size_t i = 0; i < n; i++) {
		if (!f->mask[i])
			continue;
		sum += f->val[i];
		lo = fmin(lo, f->val[i]);
		hi = fmax(hi, f->val[i]);
		m++;
	}
	mean = sum / (double)m;
	for (size_t i = 0; i < n; i++)
		if (f->mask[i])
			sum2 += (f->val[i] - mean) * (f->val[i] - mean);
	out->rms.v = sqrt(sum2 / (double)m);
	out->pv.v = hi - lo;
}

/* PVr (Evans 2009) and the RMS slope of the Zernike fit. */
static int zernike_stats(const struct asph_fit *w, const struct field *f,
			 const double *coef, struct asph_fit_result *out,
			 struct asph_error *err)
{
	_cleanup_free_ double *zf = malloc(w->n * sizeof(double) + 1);
	_cleanup_free_ double *g = malloc(2 * w->n * sizeof(double) + 1);
	double lo = INFINITY, hi = -INFINITY, left2 = 0, slope2 = 0, centre[2], disk_r;
	size_t m = 0;

	asph_surface_aperture_disk(w->model.s, centre, &disk_r);
	if (!zf || !g)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(zf, w->n * sizeof(double));
	mem_advise_huge(g, 2 * w->n * sizeof(double));
	asph_zernike_series_many(coef, out->n_zernike, f->rho, f->theta, w->n, zf, g);
	for (size_t i = 0; i < w->n; i++) {
		if (!f->mask[i])
			continue;
		lo = fmin(lo, zf[i]);
		hi = fmax(hi, zf[i]);
		left2 += (f->val[i] - zf[i]) * (f->val[i] - zf[i]);
		/* nm per unit rho -> mm per mm of the disk's radius */
		slope2 += (g[2 * i] * g[2 * i] + g[2 * i + 1] * g[2 * i + 1]) * 1e-12 /
			  (disk_r * disk_r);
		m++;
	}
	out->zernike_fit_rms_left.v = sqrt(left2 / (double)m);
	out->pvr.v = (hi - lo) + 3.0 * out->zernike_fit_rms_left.v;
	out->slope_rms = asph_urad_from_rad(sqrt(slope2 / (double)m));
	return 0;
}

int fit_fill_statistics(struct asph_fit *w, struct asph_fit_result *out,
			struct asph_error *err)
{
	struct field f = { 0 };
	double coef[ASPH_FIT_MAX_ZERNIKE];
	int r;

	out->n_zernike = w->opt.n_zernike;
	r = field_build(w, &f, err);
	if (r == 0)
		basic_stats(&f, w->n, out);
	if (r == 0 && w->traces.n)
		r = -EDOM;      /* on lines the Zernike terms alias: none */
	else if (r == 0)
		r = asph_zernike_decompose(f.rho, f.theta, f.val, f.mask, w->n,
					   out->n_zernike, coef, err);
	if (r == 0) {
		for (int j = 0; j < out->n_zernike; j++)
			out->zernike[j].v = coef[j];
		r = zernike_stats(w, &f, coef, out, err);
	} else if (r == -EDOM) {
		/* The fit stands; only the decomposition needs more points. */
		out->n_zernike = 0;
		out->pvr.v = out->slope_rms.v = out->zernike_fit_rms_left.v = NAN;
		asph_error_clear(err);
		r = 0;
	}
	field_free(&f);
	return r;
}

/* R = 1/c and its deviation from the nominal, with U. */
static void radius(const struct asph_fit *w, struct asph_fit_result *out)
{
	out->R_nominal_mm = w->model.c0 != 0 ? 1.0 / w->model.c0 : INFINITY;
	out->R_deviation_mm = NAN;
	if (w->opt.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_R)) {
		out->R_deviation_mm = out->value[ASPH_FIT_R] - out->R_nominal_mm;
		out->uncertainty_k2.R_mm = 2 * out->uncertainty[ASPH_FIT_R];
		out->uncertainty_k2.c_per_mm = 2 * out->u_curvature;
	}
}

static int fill_form(struct asph_fit *w, struct asph_fit_result *out, struct asph_error *err)
{
	const struct asph_tolerance *t = w->opt.tolerance;
	int r;

	asph_uncertainty_k2_clear(&out->uncertainty_k2);
	r = w->traces.n ? fit_profile_fill(w, out, err) : fit_areal_form(w, out, err);
	if (r < 0)
		return r;
	radius(w, out);
	memset(&out->verdict, 0, sizeof(out->verdict));
	if (t)
		asph_verdict_evaluate(t, out->form_valid ? &out->form : NULL,
				      out->slope_valid ? &out->slope : NULL, out->R_deviation_mm,
				      &out->uncertainty_k2, &out->verdict);
	return 0;
}

void asph_fit_release_solver(struct asph_fit *w)
{
	if (w && w->solver) {
		gsl_multilarge_nlinear_free(w->solver);
		w->solver = NULL;
	}
}

int asph_fit_get_result(struct asph_fit *w, struct asph_fit_result *out,
			struct asph_error *err)
{
	if (w->phase != FIT_PHASE_DONE)
		return asph_error_set(err, -EINVAL, "fit not finished");
	if (!w->solver)
		return asph_error_set(err, -EINVAL, "fit: the solver was released, the result already taken");
	memset(out, 0, sizeof(*out));
	count_points(w, out);
	out->dof = w->opt.dof;
	out->residual = w->opt.residual;
	memcpy(out->value, w->full, sizeof(out->value));
	out->iterations = w->total_iter;
	out->passes = w->pass;
	out->converged = w->converged;
	snprintf(out->reason, sizeof(out->reason), "%s", w->reason);
	uncertainties(w, out);
	if (w->opt.release_solver)
		asph_fit_release_solver(w);
	radius_from_curvature(w, out);
	fit_machine_pose(w, &out->pose);
	int r = fit_fill_statistics(w, out, err);
	return r < 0 ? r : fill_form(w, out, err);
}
