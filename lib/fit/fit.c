/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Best fit of measured points to the nominal surface: Levenberg-Marquardt
 * (GSL's trust-region solver) on the residuals, in passes: a pass runs the
 * solver to convergence; between passes points whose foot left the aperture
 * are excluded and, for a robust fit, the Tukey weights are renewed.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <stdio.h>

#include <gsl/gsl_blas.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_linalg.h>
#include <gsl/gsl_statistics_double.h>

#include "asph/areal.h"
#include "asph/fit.h"
#include "fit-internal.h"
#include "util-mem.h"

#define DEFAULT_MAX_ITER 200
#define DEFAULT_XTOL 1e-9
#define DEFAULT_APERTURE_TOL 1e-3
#define DEFAULT_MAX_OUTSIDE 0.5
/* Step test: |dx_k| <= xtol (|x_k| + XSCALE); see docs/characterization.md. */
#define XSCALE 1e-3
/* Cost test: a step that lowers chi^2 by less than this fraction, or the
 * prediction that the next one would (the Gauss-Newton decrement
 * g^T (J^T J)^-1 g, g = J^T f), with the step itself small (LOOSE_XTOL),
 * ends a pass. At that point the parameters are within about
 * sqrt(COST_TOL) of their statistical uncertainty of the optimum: further
 * iterations only move rounding. */
#define COST_TOL 1e-10
#define LOOSE_XTOL 1e-4
#define MAX_EXCLUSION_PASSES 5
#define MAX_ROBUST_PASSES 30
#define TUKEY_C 4.685
#define MAD_TO_SIGMA 1.482602218505602
/* A MAD scale below this (mm) is rounding, not noise. */
#define MIN_ROBUST_SCALE 1e-9
#define ROBUST_WEIGHT_TOL 1e-3
/* Below this reciprocal condition number of the DOF's correlation matrix
 * the fitted values would be noise: refused. */
#define MIN_RCOND 1e-12

/* The pose as cosines and sines, computed once per evaluation. */
struct frame {
	double t[3];
	double cx, sx, cy, sy, cz, sz;
	int clocked;             /* rz != 0 */
	double R[3][3];          /* Ry(ry) Rx(rx) Rz(rz) */
};

static void frame_init(struct frame *fr, const double *full)
{
	memcpy(fr->t, full, 3 * sizeof(double));
	fr->cx = cos(full[ASPH_FIT_RX]);
	fr->sx = sin(full[ASPH_FIT_RX]);
	fr->cy = cos(full[ASPH_FIT_RY]);
	fr->sy = sin(full[ASPH_FIT_RY]);
	/* Columns are Ry Rx e_k. */
	double m[3][3] = {
		{ fr->cy, fr->sy * fr->sx, fr->sy * fr->cx },
		{ 0, fr->cx, -fr->sx },
		{ -fr->sy, fr->cy * fr->sx, fr->cy * fr->cx },
	};
	memcpy(fr->R, m, sizeof(m));
	fr->clocked = full[ASPH_FIT_RZ] != 0;
	fr->cz = cos(full[ASPH_FIT_RZ]);
	fr->sz = sin(full[ASPH_FIT_RZ]);
	if (fr->clocked)
		for (int k = 0; k < 3; k++) {
			fr->R[k][0] = fr->cz * m[k][0] + fr->sz * m[k][1];
			fr->R[k][1] = -fr->sz * m[k][0] + fr->cz * m[k][1];
		}
}

/* q = Rx(-rx) Ry(-ry) (p - t); w = Ry(-ry) (p - t) on the way. */
static void frame_to_part(const struct frame *fr, const double *p,
			  double q[3], double wv[3])
{
	double u0 = p[0] - fr->t[0], u1 = p[1] - fr->t[1], u2 = p[2] - fr->t[2];

	wv[0] = fr->cy * u0 - fr->sy * u2;
	wv[1] = u1;
	wv[2] = fr->sy * u0 + fr->cy * u2;
	q[0] = wv[0];
	q[1] = fr->cx * wv[1] + fr->sx * wv[2];
	q[2] = -fr->sx * wv[1] + fr->cx * wv[2];
	if (fr->clocked) {
		double q0 = q[0];
		q[0] = fr->cz * q0 + fr->sz * q[1];
		q[1] = -fr->sz * q0 + fr->cz * q[1];
	}
}

/* The solver works on y, whitened coordinates: x = xref + T y (see
 * whiten()). */
static void set_full_from_y(struct asph_fit *w, const double *y)
{
	for (int k = 0; k < w->p; k++) {
		double v = w->xref[k];
		for (int j = 0; j < w->p; j++)
			v += w->T[k][j] * y[j];
		w->full[w->idx[k]] = v;
	}
	fit_model_set_conic(&w->model, w->full[ASPH_FIT_R], w->full[ASPH_FIT_K]);
}

static void set_full_from_vector(struct asph_fit *w, const gsl_vector *y)
{
	double yy[ASPH_FIT_N_DOF];

	for (int k = 0; k < w->p; k++)
		yy[k] = gsl_vector_get(y, (size_t)k);
	set_full_from_y(w, yy);
}

/* point_eval() on a freeform: the foot in (x, y), the aperture by shape. */
static int point_eval_xy(struct asph_fit *w, const double q[3], size_t i, double *res)
{
	struct fit_surface_point *f = &w->foot[i];
	const double tol = w->opt.aperture_tolerance;
	int it;

	if (w->opt.residual == ASPH_FIT_RESIDUAL_SAG) {
		double g[3];
		asph_surface_sag_grad_xy(w->model.s, q[0], q[1], g);
		*res = q[2] - g[0];
		*f = (struct fit_surface_point){ q[0], q[1], g[0], g[1], g[2], NAN };
		w->slope[i] = isfinite(*res) ? 0.0 : NAN;
		if (!isfinite(*res))
			return -1;
		return !asph_surface_contains(w->model.s, q[0], q[1], tol);
	}
	if (fit_foot_xy(&w->model, q, FIT_FOOT_TOL * (1.0 + w->model.a), f, res, &it) < 0) {
		*f = FIT_NO_POINT;
		w->slope[i] = NAN;
		*res = NAN;
		return -1;
	}
	w->slope[i] = 0.0;
	return !asph_surface_contains(w->model.s, f->x, f->y, tol);
}

/* Whether a foot at the signed meridian coordinate r along the azimuth of
 * q lies past the aperture (grown by the tolerance): on a disk about the
 * axis by its radius, else by the aperture's shape. */
static int past_aperture(const struct asph_fit *w, const double q[3], double r)
{
	double rho = hypot(q[0], q[1]);

	if (w->model.centred)
		return fabs(r) > w->model.a + w->opt.aperture_tolerance;
	double xy[2] = { rho > 0 ? r * q[0] / rho : r, rho > 0 ? r * q[1] / rho : 0 };
	fit_frame_to_part(w, xy);
	return !asph_surface_contains(w->model.s, xy[0], xy[1], w->opt.aperture_tolerance);
}

/*
 * Residual of point i, at q in the part frame; refreshes its foot.
 * Returns 0 inside, 1 when the foot is past the aperture, -1 when there is
 * no foot.
 */
static int point_eval(struct asph_fit *w, const double q[3], size_t i, double *res)
{
	if (!w->model.rotational)
		return point_eval_xy(w, q, i, res);
	if (w->opt.residual == ASPH_FIT_RESIDUAL_SAG) {
		double rho = sqrt(q[0] * q[0] + q[1] * q[1]), d[3];
		fit_model_derivs(&w->model, rho, d);
		*res = q[2] - d[0];
		w->r_foot[i] = rho;
		w->slope[i] = d[1];
		if (!isfinite(*res))
			return -1;
		return past_aperture(w, q, rho);
	}
	struct fit_foot f;
	if (fit_foot(&w->model, q, w->r_foot[i], &f) < 0) {
		w->slope[i] = NAN;
		*res = NAN;
		return -1;
	}
	w->r_foot[i] = f.r;
	w->slope[i] = f.slope;
	*res = f.dist;
	return past_aperture(w, q, f.r);
}

static int point_counts(const struct asph_fit *w, size_t i)
{
	return w->status[i] != ASPH_FIT_POINT_OUTSIDE && w->weight[i] > 0;
}

/*
 * One row of the Jacobian. v is the normal at the foot (normal residuals)
 * or the unnormalized gradient (-Z' u, 1) of q_z - Z at q (sag residuals),
 * vz its z component, rr the radius where the conic partials are taken.
 *   d/dt  = -R v               (dq/dt = -R^T)
 *   d/drx = v_y q_z - v_z q_y  (dq/drx = -e_x x q)
 *   d/dry = -((Rx v)_x w_z - (Rx v)_z w_x)   (dq/dry = -Rx(-rx) (e_y x w))
 *   d/dc  = -vz dZ/dc,  d/dk = -vz dZ/dk     (the surface moves along z;
 *                                            the R column is c's)
 */
static void jacobian_row(const struct asph_fit *w, const struct frame *fr, size_t i,
			 const double q[3], const double wv[3], double sw, double *row)
{
	double v[3], d[ASPH_FIT_N_DOF], rr, vz, dzc = 0, dzk = 0;
	double s = w->slope[i], rho;

	rho = sqrt(q[0] * q[0] + q[1] * q[1]);
	double ux = rho > 0 ? q[0] / rho : 1.0, uy = rho > 0 ? q[1] / rho : 0.0;
	double inv = w->opt.residual == ASPH_FIT_RESIDUAL_SAG ? 1.0 : 1.0 / sqrt(1.0 + s * s);
	v[0] = -s * ux * inv;
	v[1] = -s * uy * inv;
	v[2] = vz = inv;
	rr = fabs(w->r_foot[i]);
	for (int k = 0; k < 3; k++)
		d[k] = -(fr->R[k][0] * v[0] + fr->R[k][1] * v[1] + fr->R[k][2] * v[2]);
	d[ASPH_FIT_RX] = v[1] * q[2] - v[2] * q[1];
	double mx = v[0], mz = fr->sx * v[1] + fr->cx * v[2];
	d[ASPH_FIT_RY] = -(mx * wv[2] - mz * wv[0]);
	if (w->opt.dof & (ASPH_FIT_DOF_BIT(ASPH_FIT_R) | ASPH_FIT_DOF_BIT(ASPH_FIT_K)))
		fit_model_conic_partials(&w->model, rr, &dzc, &dzk);
	d[ASPH_FIT_R] = -vz * dzc;
	d[ASPH_FIT_K] = -vz * dzk;
	for (int k = 0; k < w->p; k++)
		row[k] = sw * d[w->idx[k]];
}

/*
 * jacobian_row() on a freeform, with clocking: v the normal at the foot (or
 * (-S_x, -S_y, 1) for sag residuals) and c = q x v; a rotation by theta
 * about an axis that is a in the part frame moves q by -a x q, so
 *   d/drx = -a_x . c,  a_x = Rz(-rz) e_x
 *   d/dry = -a_y . c,  a_y = Rz(-rz) Rx(-rx) e_y
 *   d/drz = -c_z
 */
static void jacobian_row_xy(const struct asph_fit *w, const struct frame *fr, size_t i,
			    const double q[3], double sw, double *row)
{
	const struct fit_surface_point *f = &w->foot[i];
	double v[3], c[3], d[ASPH_FIT_N_DOF] = { 0 };
	double inv = w->opt.residual == ASPH_FIT_RESIDUAL_SAG ? 1.0 : f->nz;

	v[0] = -f->zx * inv;
	v[1] = -f->zy * inv;
	v[2] = inv;
	for (int k = 0; k < 3; k++)
		d[k] = -(fr->R[k][0] * v[0] + fr->R[k][1] * v[1] + fr->R[k][2] * v[2]);
	c[0] = q[1] * v[2] - q[2] * v[1];
	c[1] = q[2] * v[0] - q[0] * v[2];
	c[2] = q[0] * v[1] - q[1] * v[0];
	d[ASPH_FIT_RX] = -(fr->cz * c[0] - fr->sz * c[1]);
	d[ASPH_FIT_RY] = -(fr->sz * fr->cx * c[0] + fr->cz * fr->cx * c[1] - fr->sx * c[2]);
	d[ASPH_FIT_RZ] = -c[2];
	for (int k = 0; k < w->p; k++)
		row[k] = sw * d[w->idx[k]];
}

/* Row of dr/dy = (dr/dx) T (T upper triangular) for point i at q, its
 * weight's square root sw applied. */
static void solver_row(const struct asph_fit *w, const struct frame *fr, size_t i,
		       const double q[3], const double wv[3], double sw, double *ry)
{
	double rx[ASPH_FIT_N_DOF];

	if (w->model.rotational)
		jacobian_row(w, fr, i, q, wv, sw, rx);
	else
		jacobian_row_xy(w, fr, i, q, sw, rx);
	for (int j = 0; j < w->p; j++) {
		double v = 0;
		for (int k = 0; k <= j; k++)
			v += rx[k] * w->T[k][j];
		ry[j] = v;
	}
}

/* The square root of point i's weight (1 outside robust fits). */
static double sqrt_weight(const struct asph_fit *w, size_t i)
{
	return w->weight[i] == 1.0 ? 1.0 : sqrt(w->weight[i]);
}

/* The sums over x (T = I) carried over to y: J_y = J_x T, so
 * J_y^T u = T^T J_x^T u and J_y^T J_y = T^T (J_x^T J_x) T. */
static void sums_to_solver(struct asph_fit *w)
{
	struct fit_sums x = w->sums, y = { 0 };
	const int p = w->p;

	for (int k = 0; k < p; k++)
		for (int j = k + 1; j < p; j++)
			x.jtj[k][j] = x.jtj[j][k];
	for (int a = 0; a < p; a++) {
		for (int k = 0; k <= a; k++)
			y.jtu[a] += w->T[k][a] * x.jtu[k];
		for (int b = 0; b <= a; b++)
			for (int k = 0; k <= a; k++)
				for (int j = 0; j <= b; j++)
					y.jtj[a][b] += w->T[k][a] * x.jtj[k][j] * w->T[j][b];
	}
	w->sums = y;
}

/* sums->jtu += row u, sums->jtj += row row^T (its lower triangle). */
static void sums_add(struct fit_sums *sums, int p, const double *row, double u)
{
	for (int k = 0; k < p; k++) {
		sums->jtu[k] += row[k] * u;
		for (int j = 0; j <= k; j++)
			sums->jtj[k][j] += row[k] * row[j];
	}
}

/*
 * Weighted residuals into f (stride fs) at the current parameters, which
 * are y in the solver's coordinates; and in the same pass, from the feet
 * just found, J^T f and J^T J there (w->sums), which the solver asks for
 * next when it takes the step.
 */
static void eval_weighted(struct asph_fit *w, const double *y, double *f,
			  size_t fs)
{
	struct frame fr;
	double row[ASPH_FIT_N_DOF];

	frame_init(&fr, w->full);
	memset(&w->sums, 0, sizeof(w->sums));
	for (size_t i = 0; i < w->n; i++) {
		double res = 0, q[3], wv[3], sw;
		if (!point_counts(w, i)) {
			f[i * fs] = 0.0;
			continue;
		}
		frame_to_part(&fr, w->xyz + 3 * i, q, wv);
		if (point_eval(w, q, i, &res) < 0)
			res = 0;    /* lost its foot in a trial step */
		sw = sqrt_weight(w, i);
		f[i * fs] = sw * res;
		if (!isfinite(w->slope[i]))
			continue;
		solver_row(w, &fr, i, q, wv, sw, row);
		sums_add(&w->sums, w->p, row, sw * res);
	}
	memcpy(w->cached_y, y, (size_t)w->p * sizeof(double));
	w->cache_valid = 1;
	w->scratch_is_f = (f == w->scratch);
	w->sums_f = f;
	w->sums_fs = fs;
}

static int y_matches_cache(const struct asph_fit *w, const gsl_vector *y)
{
	if (!w->cache_valid)
		return 0;
	for (int k = 0; k < w->p; k++)
		if (gsl_vector_get(y, (size_t)k) != w->cached_y[k])
			return 0;
	return 1;
}

static void vector_to_array(const struct asph_fit *w, const gsl_vector *y,
			    double *a)
{
	for (int k = 0; k < w->p; k++)
		a[k] = gsl_vector_get(y, (size_t)k);
}

static int cb_f(const gsl_vector *y, void *params, gsl_vector *f)
{
	struct asph_fit *w = params;
	double ya[ASPH_FIT_N_DOF];

	set_full_from_vector(w, y);
	/* After whiten() the residual at the start is already in scratch. */
	if (y_matches_cache(w, y) && w->scratch_is_f) {
		for (size_t i = 0; i < w->n; i++)
			gsl_vector_set(f, i, w->scratch[i]);
		return GSL_SUCCESS;
	}
	vector_to_array(w, y, ya);
	eval_weighted(w, ya, f->data, f->stride);
	return GSL_SUCCESS;
}

/* Whether u holds the weighted residuals the last evaluation wrote. */
static int is_last_f(const struct asph_fit *w, const gsl_vector *u)
{
	for (size_t i = 0; i < w->n; i++)
		if (gsl_vector_get(u, i) != w->sums_f[i * w->sums_fs])
			return 0;
	return 1;
}

/*
 * v = J^T u (or J u), and J^T J into JTJ when it is not NULL, at y. The
 * solver asks for J^T f and J^T J where it last evaluated f: those sums
 * came with that evaluation. Anything else takes a pass over the points
 * that builds each row of J from the stored foot. J itself is never
 * stored, nor read again to form J^T J.
 */
static int cb_df(CBLAS_TRANSPOSE_t trans, const gsl_vector *y, const gsl_vector *u,
		 void *params, gsl_vector *v, gsl_matrix *JTJ)
{
	struct asph_fit *w = params;
	struct fit_sums sums = { 0 };
	struct frame fr;
	double row[ASPH_FIT_N_DOF], ya[ASPH_FIT_N_DOF];
	const int p = w->p;

	set_full_from_vector(w, y);
	if (!y_matches_cache(w, y)) {
		vector_to_array(w, y, ya);
		eval_weighted(w, ya, w->scratch, 1);
	}
	if (trans == CblasTrans && is_last_f(w, u)) {
		sums = w->sums;
	} else {
		frame_init(&fr, w->full);
		for (size_t i = 0; i < w->n; i++) {
			double q[3], wv[3], s = 0;
			if (point_counts(w, i) && isfinite(w->slope[i])) {
				frame_to_part(&fr, w->xyz + 3 * i, q, wv);
				solver_row(w, &fr, i, q, wv, sqrt_weight(w, i), row);
				if (trans == CblasTrans) {
					sums_add(&sums, p, row, gsl_vector_get(u, i));
					continue;
				}
				for (int k = 0; k < p; k++)
					s += row[k] * gsl_vector_get(u, (size_t)k);
			}
			if (trans == CblasNoTrans)
				gsl_vector_set(v, i, s);
		}
	}
	for (int k = 0; k < p && trans == CblasTrans; k++)
		gsl_vector_set(v, (size_t)k, sums.jtu[k]);
	for (int k = 0; k < p && JTJ; k++)
		for (int j = 0; j <= k; j++) {
			gsl_matrix_set(JTJ, (size_t)k, (size_t)j, sums.jtj[k][j]);
			gsl_matrix_set(JTJ, (size_t)j, (size_t)k, sums.jtj[k][j]);
		}
	return GSL_SUCCESS;
}

size_t fit_evaluate_all(struct asph_fit *w)
{
	struct frame fr;
	size_t bad = 0;

	frame_init(&fr, w->full);
	w->n_status_changes = 0;
	for (size_t i = 0; i < w->n; i++) {
		double q[3], wv[3];
		frame_to_part(&fr, w->xyz + 3 * i, q, wv);
		int st = point_eval(w, q, i, &w->resid[i]);
		w->n_status_changes += (st != 0) != (w->status[i] == ASPH_FIT_POINT_OUTSIDE);
		if (st != 0) {
			w->status[i] = ASPH_FIT_POINT_OUTSIDE;
			w->resid[i] = NAN;
			bad++;
		} else {
			w->status[i] = w->weight[i] > 0 ? ASPH_FIT_POINT_USED
							: ASPH_FIT_POINT_OUTLIER;
		}
	}
	w->cache_valid = 0;
	return bad;
}

/* --- Options and workspace --------------------------------------------- */

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_fit *, asph_fit_free)

static int options_resolve(struct asph_fit_options *o, struct asph_error *err)
{
	if (o->dof == 0)
		o->dof = ASPH_FIT_DOF_RIGID;
	if (o->dof >> ASPH_FIT_N_DOF)
		return asph_error_set(err, -EINVAL, "unknown degree of freedom in mask 0x%x", o->dof);
	if (o->max_iterations == 0)
		o->max_iterations = DEFAULT_MAX_ITER;
	if (o->xtol == 0)
		o->xtol = DEFAULT_XTOL;
	if (o->aperture_tolerance == 0)
		o->aperture_tolerance = DEFAULT_APERTURE_TOL;
	else if (o->aperture_tolerance < 0)
		o->aperture_tolerance = 0;
	if (o->max_outside_fraction == 0)
		o->max_outside_fraction = DEFAULT_MAX_OUTSIDE;
	if (o->n_zernike == 0)
		o->n_zernike = ASPH_FIT_DEFAULT_ZERNIKE;
	if (o->max_iterations < 0 || !(o->xtol > 0) || !isfinite(o->xtol) ||
	    !isfinite(o->aperture_tolerance))
		return asph_error_set(err, -EINVAL,
				      "fit options: max_iterations, xtol or aperture_tolerance out of range");
	if (!(o->max_outside_fraction > 0 && o->max_outside_fraction <= 1))
		return asph_error_set(err, -EINVAL, "fit options: max_outside_fraction must be in (0, 1]");
	if (o->n_zernike < 1 || o->n_zernike > ASPH_FIT_MAX_ZERNIKE)
		return asph_error_set(err, -EINVAL, "fit options: %d Zernike terms (1..%d)",
				      o->n_zernike, ASPH_FIT_MAX_ZERNIKE);
	if (!isfinite(o->wavelength_nm) || o->wavelength_nm < 0 ||
	    !isfinite(o->slope_length_mm) || o->slope_length_mm < 0)
		return asph_error_set(err, -EINVAL,
				      "fit options: wavelength and slope length must be positive");
	if ((unsigned)o->residual > ASPH_FIT_RESIDUAL_SAG)
		return asph_error_set(err, -EINVAL, "fit options: unknown residual kind %d", (int)o->residual);
	for (int k = 0; k < 3; k++)
		if (!isfinite(o->start.t[k]))
			return asph_error_set(err, -EINVAL, "fit options: start pose is not finite");
	if (!isfinite(o->start.rx) || !isfinite(o->start.ry) || !isfinite(o->start.rz))
		return asph_error_set(err, -EINVAL, "fit options: start pose is not finite");
	return 0;
}

/* The per-point arrays of asph_fit_alloc(), on huge pages where the kernel
 * gives them. */
static void advise_huge_arrays(struct asph_fit *w)
{
	size_t n = w->n_max * sizeof(double);

	mem_advise_huge(w->r_foot, n);
	mem_advise_huge(w->slope, n);
	mem_advise_huge(w->resid, n);
	mem_advise_huge(w->weight, n);
	mem_advise_huge(w->scratch, n);
	mem_advise_huge(w->status, w->n_max);
	mem_advise_huge(w->trace_of, w->n_max);
	mem_advise_huge(w->left, w->left ? n : 0);
	mem_advise_huge(w->foot, w->foot ? w->n_max * sizeof(*w->foot) : 0);
}

int asph_fit_alloc(const struct asph_surface *s, size_t n_max,
		   const struct asph_fit_options *opts, struct asph_fit **out,
		   struct asph_error *err)
{
	_cleanup_(asph_fit_freep) struct asph_fit *w = calloc(1, sizeof(*w));
	int r;

	if (!w)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (opts)
		w->opt = *opts;
	w->dof_default = w->opt.dof == 0;
	r = options_resolve(&w->opt, err);
	if (r < 0)
		return r;
	/* R is the base sphere's or conic's radius for every type; a surface
	 * without a conic constant has no k to fit. */
	enum asph_surface_type type = asph_surface_prescription(s)->type;
	if ((w->opt.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_K)) && !asph_surface_type_has_conic(type))
		return asph_error_set(err, -EINVAL,
				      "a %s surface has no conic constant: k cannot be fitted (R can)",
				      asph_surface_type_name(type));
	/* the sag's symmetry, whatever the aperture: an off-axis segment of a
	 * rotationally symmetric parent looks the same clocked about the axis */
	int rotational = asph_surface_is_radial(s);
	if ((w->opt.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_RZ)) && rotational)
		return asph_error_set(err, -EINVAL,
				      "surface type %s is rotationally symmetric: it looks the same "
				      "clocked, so rz cannot be fitted",
				      asph_surface_type_name(type));
	if ((w->opt.dof & (ASPH_FIT_DOF_BIT(ASPH_FIT_R) | ASPH_FIT_DOF_BIT(ASPH_FIT_K))) && !rotational)
		return asph_error_set(err, -EINVAL,
				      "R and k are fitted on rotationally symmetric surfaces only; "
				      "surface type %s takes the rigid motions tx, ty, tz, rx, ry, rz",
				      asph_surface_type_name(type));
	/* A plane base takes R (its curvature c, from 0); a conic constant
	 * changes nothing there, whatever the curvature it starts from. */
	if ((w->opt.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_K)) && isinf(asph_surface_prescription(s)->R))
		return asph_error_set(err, -EINVAL,
				      "the base of this %s is a plane (curvature 0): a conic constant "
				      "k does nothing there; fit R (the curvature c) without k",
				      asph_surface_type_name(type));
	if (rotational && w->opt.start.rz != 0)
		return asph_error_set(err, -EINVAL, "fit options: a start rz on a rotationally "
				      "symmetric surface");
	fit_model_init(&w->model, s);
	w->dof_asked = w->opt.dof;
	if (fit_select_dof(w, w->opt.dof, err) < 0)
		return -ENOMEM;
	w->n_max = n_max;
	w->r_foot = malloc(n_max * sizeof(double) + 1);
	w->slope = malloc(n_max * sizeof(double) + 1);
	w->resid = malloc(n_max * sizeof(double) + 1);
	w->weight = malloc(n_max * sizeof(double) + 1);
	w->scratch = malloc(n_max * sizeof(double) + 1);
	w->status = calloc(n_max + 1, 1);
	w->trace_of = malloc(n_max + 1);
	w->left = w->opt.robust ? malloc(n_max * sizeof(double) + 1) : NULL;
	if (!rotational) {
		w->foot = malloc(n_max * sizeof(*w->foot) + 1);
		if (!w->foot)
			return asph_error_set(err, -ENOMEM, "out of memory for %zu points", n_max);
	}
	if (!w->r_foot || !w->slope || !w->resid || !w->weight || !w->scratch ||
	    !w->status || !w->trace_of || (w->opt.robust && !w->left))
		return asph_error_set(err, -ENOMEM, "out of memory for %zu points", n_max);
	advise_huge_arrays(w);
	*out = steal_ptr(w);
	return 0;
}

void asph_fit_free(struct asph_fit *w)
{
	if (!w)
		return;
	if (w->solver)
		gsl_multilarge_nlinear_free(w->solver);
	gsl_vector_free(w->x0);
	gsl_matrix_free(w->covar);
	free(w->r_foot);
	free(w->slope);
	free(w->resid);
	free(w->weight);
	free(w->scratch);
	free(w->left);
	free(w->foot);
	free(w->status);
	asph_scatter_free(w->slope_scatter);
	free(w->trace_of);
	free(w->xyz_frame);
	free(w);
}

/* --- Input checks ------------------------------------------------------- */

static int check_points(const struct asph_fit *w, const double *xyz, size_t n,
			struct asph_error *err)
{
	if (n > w->n_max)
		return asph_error_set(err, -EINVAL, "%zu points, workspace holds %zu", n, w->n_max);
	if (n == 0)
		return asph_error_set(err, -EINVAL, "no points to fit");
	for (size_t i = 0; i < 3 * n; i++)
		if (!isfinite(xyz[i]))
			return asph_error_set(err, -EINVAL, "point %zu: coordinate %c is not finite",
					      i / 3 + 1, "xyz"[i % 3]);
	return 0;
}

/* Enough points for the DOF fitted. */
static int check_count(const struct asph_fit *w, size_t n, struct asph_error *err)
{
	char names[64] = "";

	if (n >= (size_t)w->p + 1)
		return 0;
	if (!w->traces.n)
		return asph_error_set(err, -EINVAL,
				      "%zu points cannot determine %d degrees of freedom (need at least %d)",
				      n, w->p, w->p + 1);
	for (int k = 0; k < w->p; k++)
		snprintf(names + strlen(names), sizeof(names) - strlen(names), "%s%s", k ? ", " : "",
			 asph_fit_dof_name((enum asph_fit_dof)w->idx[k]));
	return asph_error_set(err, -EINVAL,
			      "a line profile of %zu points cannot determine %d degrees of freedom "
			      "(%s): it needs at least %d", n, w->p, names, w->p + 1);
}

/* --- Passes ------------------------------------------------------------- */

static double chi2_now(const struct asph_fit *w)
{
	double c;

	gsl_blas_ddot(w->solver->f, w->solver->f, &c);
	return c;
}

/*
 * Whitening: at the start of a pass, A = J^T J (J over x) is factored as
 * D L L^T D with D = sqrt(diag A), and the solver runs on y with
 * x = xref + D^-1 L^-T y, where J^T J is the identity. Levenberg-Marquardt's
 * damping then acts alike in every direction: strongly correlated DOF (a
 * decentre and a tilt on a near-spherical part) converge as fast as the
 * others, in about Gauss-Newton's few steps.
 */
static int whiten(struct asph_fit *w, struct asph_error *err)
{
	double y0[ASPH_FIT_N_DOF] = { 0 }, dinv[ASPH_FIT_N_DOF];
	gsl_matrix_view L = gsl_matrix_submatrix(w->covar, 0, 0, (size_t)w->p, (size_t)w->p);
	int p = w->p;

	memset(w->T, 0, sizeof(w->T));
	for (int k = 0; k < p; k++) {
		w->xref[k] = w->full[w->idx[k]];
		w->T[k][k] = 1.0;
	}
	set_full_from_y(w, y0);
	/* with T = I the evaluation's J^T J is A, over x */
	eval_weighted(w, y0, w->scratch, 1);
	double (*A)[ASPH_FIT_N_DOF] = w->sums.jtj;
	for (int k = 0; k < p; k++) {
		if (!(A[k][k] > 0) || !isfinite(A[k][k]))
			return asph_error_set(err, -EDOM,
					      "the points do not determine the degree of freedom '%s'",
					      asph_fit_dof_name((enum asph_fit_dof)w->idx[k]));
		dinv[k] = 1.0 / sqrt(A[k][k]);
	}
	for (int k = 0; k < p; k++)
		for (int j = 0; j < p; j++)
			gsl_matrix_set(&L.matrix, (size_t)k, (size_t)j,
				       (j <= k ? A[k][j] : A[j][k]) * dinv[k] * dinv[j]);
	/* A correlation matrix that is singular to working precision means
	 * that the points cannot tell some DOF apart (e.g. all at one radius:
	 * a decentre and a tilt do the same there). */
	double rcond = 0, work[3 * ASPH_FIT_N_DOF];
	gsl_vector_view wv = gsl_vector_view_array(work, 3 * (size_t)p);
	if (gsl_linalg_cholesky_decomp1(&L.matrix) != 0 ||
	    gsl_linalg_cholesky_rcond(&L.matrix, &rcond, &wv.vector) != 0 ||
	    !(rcond > MIN_RCOND))
		return asph_error_set(err, -EDOM,
				      "the points cannot tell the degrees of freedom apart (reciprocal condition number %.2g)",
				      rcond);
	gsl_linalg_tri_invert(CblasLower, CblasNonUnit, &L.matrix);
	/* T = D^-1 L^-T, with L^-1 in the lower triangle of L. */
	for (int k = 0; k < p; k++)
		for (int j = k; j < p; j++)
			w->T[k][j] = dinv[k] * gsl_matrix_get(&L.matrix, (size_t)j, (size_t)k);
	sums_to_solver(w);
	return 0;
}

static int start_pass(struct asph_fit *w, struct asph_error *err)
{
	int st = whiten(w, err);

	if (st < 0)
		return st;
	gsl_vector_set_zero(w->x0);
	st = gsl_multilarge_nlinear_init(w->x0, &w->fdf, w->solver);
	if (st)
		return asph_error_set(err, -ERANGE, "fit: solver init failed: %s", gsl_strerror(st));
	w->pass++;
	w->iter = 0;
	w->chi2 = chi2_now(w);
	return 0;
}

static int solver_setup(struct asph_fit *w, size_t n, struct asph_error *err)
{
	gsl_multilarge_nlinear_parameters par = gsl_multilarge_nlinear_default_parameters();

	if (w->solver && w->solver->n == n && w->solver->p == (size_t)w->p)
		return 0;
	if (w->solver)
		gsl_multilarge_nlinear_free(w->solver);
	par.trs = gsl_multilarge_nlinear_trs_lm;
	/* Normal equations: p is at most 7 and the columns are scaled. The
	 * solver for large systems takes J^T J from cb_df() and never holds J. */
	par.solver = gsl_multilarge_nlinear_solver_cholesky;
	/* Near the optimum the problem is almost linear: let the damping fall
	 * fast so that the steps become Gauss-Newton's. */
	par.factor_down = 10.0;
	w->solver = gsl_multilarge_nlinear_alloc(gsl_multilarge_nlinear_trust, &par, n, (size_t)w->p);
	if (!w->solver)
		return asph_error_set(err, -ENOMEM, "out of memory for the solver (%zu points)", n);
	/* its residual vector, written at every point at every step */
	mem_advise_huge(gsl_multilarge_nlinear_residual(w->solver)->data, n * sizeof(double));
	return 0;
}

int asph_fit_init(struct asph_fit *w, const double *xyz, size_t n,
		  struct asph_error *err)
{
	const struct asph_prescription *pr = asph_surface_prescription(w->model.s);
	const double *pts = xyz;
	int r = check_points(w, xyz, n, err);

	w->phase = FIT_PHASE_IDLE;
	asph_scatter_free(w->slope_scatter);
	w->slope_scatter = NULL;
	if (r == 0)
		r = fit_profile_setup(w, xyz, n, &pts, err);
	if (r == 0)
		r = check_count(w, n, err);
	if (r == 0)
		r = solver_setup(w, n, err);
	if (r < 0)
		return r;
	w->xyz = pts;
	w->n = n;
	memcpy(w->full, w->opt.start.t, 3 * sizeof(double));
	w->full[ASPH_FIT_RX] = w->opt.start.rx;
	w->full[ASPH_FIT_RY] = w->opt.start.ry;
	w->full[ASPH_FIT_RZ] = w->opt.start.rz;
	/* the fit varies the curvature c = 1/R (0 for a plane base) */
	w->full[ASPH_FIT_R] = w->model.c0;
	w->full[ASPH_FIT_K] = pr->k;
	fit_model_set_conic(&w->model, w->model.c0, pr->k);
	for (size_t i = 0; i < n && w->foot; i++)
		w->foot[i] = FIT_NO_POINT;
	for (size_t i = 0; i < n; i++) {
		w->r_foot[i] = NAN;
		w->slope[i] = NAN;
		w->resid[i] = NAN;
		w->weight[i] = 1.0;
		w->status[i] = ASPH_FIT_POINT_USED;
	}
	w->fdf = (gsl_multilarge_nlinear_fdf){
		.f = cb_f, .df = cb_df, .fvv = NULL, .n = n, .p = (size_t)w->p, .params = w,
	};
	if (w->robust_done)
		w->opt.robust = 1;
	w->robust_done = 0;
	w->n_downweighted = 0;
	w->pass = w->total_iter = w->n_changes = 0;
	w->converged = 0;
	w->n_outside = 0;
	w->reason[0] = '\0';
	w->phase = FIT_PHASE_RUNNING;
	return start_pass(w, err);
}

/* The last step, back in x: |dx_k| <= xtol (|x_k| + XSCALE) for all k. */
static int step_below(const struct asph_fit *w, double xtol)
{
	const gsl_vector *dy = w->solver->dx;

	for (int k = 0; k < w->p; k++) {
		double dx = 0;
		for (int j = k; j < w->p; j++)
			dx += w->T[k][j] * gsl_vector_get(dy, (size_t)j);
		if (fabs(dx) > xtol * (fabs(w->full[w->idx[k]]) + XSCALE))
			return 0;
	}
	return 1;
}

/* What a Gauss-Newton step from here would take off chi^2:
 * g^T (J^T J)^-1 g at the solver's current point; infinite when J^T J is
 * not positive definite. */
static double gauss_newton_decrement(const struct asph_fit *w)
{
	double a[ASPH_FIT_N_DOF * ASPH_FIT_N_DOF], z[ASPH_FIT_N_DOF], dec = 0;
	const size_t p = (size_t)w->p;
	gsl_matrix_view A = gsl_matrix_view_array(a, p, p);
	gsl_vector_view Z = gsl_vector_view_array(z, p);

	gsl_matrix_memcpy(&A.matrix, w->solver->JTJ);
	if (gsl_linalg_cholesky_decomp1(&A.matrix) != 0 ||
	    gsl_linalg_cholesky_solve(&A.matrix, w->solver->g, &Z.vector) != 0)
		return INFINITY;
	gsl_blas_ddot(w->solver->g, &Z.vector, &dec);
	return dec;
}

/*
 * Tukey biweight on the MAD scale of what the Zernike fit of the residual
 * leaves: a smooth form error of any size is not an outlier, a point that
 * no smooth surface explains is. Returns the largest change of a weight in
 * *change.
 */
static int reweight(struct asph_fit *w, double *change, struct asph_error *err)
{
	size_t m = 0;
	double med, mad, c;
	int r = fit_smooth_residual(w, w->left, err);

	*change = 0;
	if (r < 0)
		return r;
	for (size_t i = 0; i < w->n; i++)
		if (w->status[i] != ASPH_FIT_POINT_OUTSIDE)
			w->scratch[m++] = w->left[i];
	med = gsl_stats_median(w->scratch, 1, m);
	m = 0;
	for (size_t i = 0; i < w->n; i++)
		if (w->status[i] != ASPH_FIT_POINT_OUTSIDE)
			w->scratch[m++] = fabs(w->left[i] - med);
	mad = gsl_stats_median(w->scratch, 1, m);
	c = TUKEY_C * fmax(MAD_TO_SIGMA * mad, MIN_ROBUST_SCALE);
	for (size_t i = 0; i < w->n; i++) {
		double u = (w->left[i] - med) / c, wn;
		if (w->status[i] == ASPH_FIT_POINT_OUTSIDE)
			continue;
		wn = fabs(u) < 1 ? (1 - u * u) * (1 - u * u) : 0.0;
		*change = fmax(*change, fabs(wn - w->weight[i]));
		w->weight[i] = wn;
		w->status[i] = wn > 0 ? ASPH_FIT_POINT_USED : ASPH_FIT_POINT_OUTLIER;
	}
	return 0;
}

static void harden_weights(struct asph_fit *w)
{
	for (size_t i = 0; i < w->n; i++) {
		w->n_downweighted += w->status[i] != ASPH_FIT_POINT_OUTSIDE && w->weight[i] < 0.5;
		w->weight[i] = w->weight[i] > 0 ? 1.0 : 0.0;
	}
}

static int check_outside(struct asph_fit *w, struct asph_error *err)
{
	size_t usable = w->n - w->n_outside;

	if ((double)w->n_outside > w->opt.max_outside_fraction * (double)w->n)
		return asph_error_set(err, -EDOM,
				      "%zu of %zu points have no foot on the surface inside the aperture (wrong lens, units or pose?)",
				      w->n_outside, w->n);
	if (usable < (size_t)w->p + 1)
		return asph_error_set(err, -EDOM,
				      "only %zu points inside the aperture for %d degrees of freedom",
				      usable, w->p);
	return 0;
}

static int end_pass(struct asph_fit *w, struct asph_error *err)
{
	int r;

	w->n_outside = fit_evaluate_all(w);
	r = check_outside(w, err);
	if (r < 0)
		return r;
	if (w->n_status_changes > 0 && w->n_changes < MAX_EXCLUSION_PASSES) {
		w->n_changes++;
		return start_pass(w, err);
	}
	if (w->opt.robust && w->pass < MAX_ROBUST_PASSES) {
		double change;
		r = reweight(w, &change, err);
		if (r < 0)
			return r;
		if (change > ROBUST_WEIGHT_TOL)
			return start_pass(w, err);
		/* Converged weights: a last plain least-squares pass over the
		 * points kept, so that the fitted values, the uncertainties and
		 * the statistics all describe the same set. */
		harden_weights(w);
		w->opt.robust = 0;
		w->robust_done = 1;
		return start_pass(w, err);
	}
	w->phase = FIT_PHASE_DONE;
	return 0;
}

int asph_fit_iterate(struct asph_fit *w, struct asph_error *err)
{
	double chi2;
	int st, done = 0;

	if (w->phase != FIT_PHASE_RUNNING)
		return w->phase == FIT_PHASE_DONE ? 0 : asph_error_set(err, -EINVAL, "fit not initialized");
	st = gsl_multilarge_nlinear_iterate(w->solver);
	w->iter++;
	w->total_iter++;
	set_full_from_vector(w, w->solver->x);
	chi2 = chi2_now(w);
	if (st == GSL_ENOPROG) {
		done = 1;
		w->converged = 1;
		snprintf(w->reason, sizeof(w->reason), "no further reduction of the residual (rounding level)");
	} else if (st) {
		w->phase = FIT_PHASE_IDLE;
		return asph_error_set(err, -ERANGE, "fit: solver failed: %s", gsl_strerror(st));
	} else if (step_below(w, w->opt.xtol)) {
		done = 1;
		w->converged = 1;
		snprintf(w->reason, sizeof(w->reason), "step below xtol = %g", w->opt.xtol);
	} else if (((w->iter > 1 && w->chi2 - chi2 <= COST_TOL * chi2) ||
		    gauss_newton_decrement(w) <= COST_TOL * chi2) &&
		   step_below(w, LOOSE_XTOL)) {
		done = 1;
		w->converged = 1;
		snprintf(w->reason, sizeof(w->reason),
			 "relative decrease of chi^2, made or predicted, below %g", COST_TOL);
	} else if (w->iter >= w->opt.max_iterations) {
		done = 1;
		w->converged = 0;
		snprintf(w->reason, sizeof(w->reason), "iteration limit (%d) reached", w->opt.max_iterations);
	}
	w->chi2 = chi2;
	return done ? end_pass(w, err) : 0;
}

int asph_fit_test(const struct asph_fit *w)
{
	return w->phase == FIT_PHASE_DONE;
}

void asph_fit_get_progress(const struct asph_fit *w,
			   struct asph_fit_progress *out)
{
	double rms = 0;

	out->pass = w->pass;
	out->iteration = w->iter;
	out->total_iterations = w->total_iter;
	if (w->solver && w->n > 0) {
		double nrm = gsl_blas_dnrm2(gsl_multilarge_nlinear_residual(w->solver));
		rms = nrm / sqrt((double)w->n);
	}
	out->rms_mm = rms;
	memcpy(out->value, w->full, sizeof(out->value));
	out->value[ASPH_FIT_R] = 1.0 / w->full[ASPH_FIT_R];
}

int asph_fit_run(struct asph_fit *w, const double *xyz, size_t n,
		 struct asph_fit_result *out, struct asph_error *err)
{
	const struct asph_progress *pg = &w->opt.progress;
	int r = asph_fit_init(w, xyz, n, err);
	size_t steps = 0;

	while (r == 0 && !asph_fit_test(w)) {
		r = asph_fit_iterate(w, err);
		if (r == 0 && pg->fn && pg->fn(pg->data, ++steps, 0))
			return asph_error_set(err, -ECANCELED, "fit: cancelled");
	}
	if (r < 0)
		return r;
	/* the iterations are over: the statistics (as long again on large
	 * point sets) are what is left */
	if (pg->fn && pg->fn(pg->data, steps, steps))
		return asph_error_set(err, -ECANCELED, "fit: cancelled");
	return asph_fit_get_result(w, out, err);
}

const double *asph_fit_residuals(const struct asph_fit *w)
{
	return w->resid;
}

const uint8_t *asph_fit_point_status(const struct asph_fit *w)
{
	return w->status;
}

const double *asph_fit_weights(const struct asph_fit *w)
{
	return w->weight;
}
