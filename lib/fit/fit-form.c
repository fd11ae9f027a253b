/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The fit's residual as a form deviation: ISO 14999-4 quantities, slope
 * deviation, radius deviation, their uncertainties and the verdict. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "asph/areal.h"
#include "asph/fit.h"
#include "asph/form.h"
#include "fit-internal.h"
#include "util-mem.h"

#define DEFAULT_SLOPE_LENGTH_MM 1.0

size_t asph_fit_residual_map(const struct asph_fit *w, double *xy,
			     double *value_nm)
{
	size_t m = 0;

	for (size_t i = 0; i < w->n; i++) {
		double rho, theta;
		if (w->status[i] != ASPH_FIT_POINT_USED)
			continue;
		if (w->model.centred) {
			fit_point_polar(w, i, &rho, &theta);
			xy[2 * m] = rho * w->model.a * cos(theta);
			xy[2 * m + 1] = rho * w->model.a * sin(theta);
		} else {
			fit_point_foot(w, i, xy + 2 * m);
		}
		value_nm[m++] = asph_nm_from_mm(w->resid[i]).v;
	}
	return m;
}

int asph_fit_residual_scatter(struct asph_fit *w, struct asph_scatter **out,
			      struct asph_error *err)
{
	_cleanup_free_ double *xy = NULL;
	_cleanup_free_ double *v = NULL;
	struct asph_scatter *s = w->slope_scatter;
	size_t m = 0;
	int r;

	for (size_t i = 0; i < w->n; i++)
		m += w->status[i] == ASPH_FIT_POINT_USED;
	xy = malloc(2 * m * sizeof(double) + 1);
	v = malloc(m * sizeof(double) + 1);
	if (!xy || !v)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(xy, 2 * m * sizeof(double));
	mem_advise_huge(v, m * sizeof(double));
	m = asph_fit_residual_map(w, xy, v);
	/* the slope's triangulation, when it is of these very points */
	if (s && asph_scatter_n_points(s) == m &&
	    memcmp(asph_scatter_xy(s), xy, 2 * m * sizeof(double)) == 0) {
		r = asph_scatter_set_values(s, v, err);
		if (r == 0)
			*out = steal_ptr(w->slope_scatter);
		return r;
	}
	return asph_scatter_alloc(xy, v, m, NULL, out, err);
}

/* The point-to-point noise: what the Zernike fit leaves, with its degrees
 * of freedom (docs/characterization.md); the fit's sigma without one. */
static double noise_nm(const struct asph_fit_result *r)
{
	if (r->n_zernike > 0 && r->n_used > (size_t)r->n_zernike)
		return r->zernike_fit_rms_left.v *
		       sqrt((double)r->n_used / (double)(r->n_used - (size_t)r->n_zernike));
	return asph_nm_from_mm(r->sigma_mm).v;
}

static void form_invalid(struct asph_form *f, double wavelength)
{
	f->wavelength_nm = wavelength;
	f->A.v = f->B.v = f->C.v = NAN;
	f->A_fringes = f->B_fringes = f->C_fringes = NAN;
	f->rms_t.v = f->rms_i.v = f->rms_a.v = NAN;
}

int fit_form_quantities(const double *rho, const double *theta, const double *val,
			size_t m, double wavelength, double noise, int one_line,
			struct asph_fit_result *out, struct asph_error *err)
{
	struct asph_form_options fo = { .wavelength_nm = wavelength, .noise_nm = noise,
					.one_line = one_line };
	int r = asph_form_compute(rho, theta, val, m, &fo, &out->form, &out->uncertainty_k2, err);

	if (r == -EDOM) {
		asph_error_clear(err);
		form_invalid(&out->form, wavelength);
		return 0;
	}
	out->form_valid = r == 0;
	return r;
}

/* The form quantities over the disk of radius a about centre. */
static int compute_form(const double *xy, const double *val, size_t m, const double centre[2],
			double a, double wavelength, double noise, struct asph_fit_result *out,
			struct asph_error *err)
{
	_cleanup_free_ double *rho = malloc(m * sizeof(double) + 1);
	_cleanup_free_ double *theta = malloc(m * sizeof(double) + 1);

	if (!rho || !theta)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(rho, m * sizeof(double));
	mem_advise_huge(theta, m * sizeof(double));
	for (size_t k = 0; k < m; k++) {
		rho[k] = hypot(xy[2 * k] - centre[0], xy[2 * k + 1] - centre[1]) / a;
		theta[k] = atan2(xy[2 * k + 1] - centre[1], xy[2 * k] - centre[0]);
	}
	return fit_form_quantities(rho, theta, val, m, wavelength, noise, 0, out, err);
}

void fit_slope_invalid(struct asph_slope *s, double length)
{
	memset(s, 0, sizeof(*s));
	s->length_mm = length;
	s->rms.v = s->max.v = NAN;
	s->rms_radial.v = s->max_radial.v = NAN;
	s->rms_azimuthal.v = s->max_azimuthal.v = NAN;
	s->u_rms.v = s->u_max.v = NAN;
}

/* The slope of the residual with its tilt plane (least squares, over the
 * points) removed, as ISO 14999-4 removes tilt before any quantity. */
static int compute_slope(struct asph_fit *w, double *xy, double *val, size_t m, double a,
			 double length, double noise, struct asph_fit_result *out,
			 struct asph_error *err)
{
	struct asph_scatter *s;
	double spacing;
	int r;

	r = asph_scatter_alloc(xy, val, m, NULL, &w->slope_scatter, err);
	s = w->slope_scatter;
	if (r == 0) {
		/* Positions about as dense as the points, never more than
		 * 400 x 400 of them. */
		spacing = fmax(asph_scatter_median_edge(s), 2 * a / 400);
		r = asph_slope_compute(s, a, length, spacing, noise, &out->slope, err);
	}
	if (r == -EDOM || r == -EINVAL) {
		/* Too few points, or a length the aperture cannot hold: the
		 * slope is left out, the rest stands. */
		asph_error_clear(err);
		fit_slope_invalid(&out->slope, length);
		return 0;
	}
	if (r < 0)
		return r;
	out->slope_valid = 1;
	out->uncertainty_k2.slope_rms = out->slope.u_rms;
	out->uncertainty_k2.slope_max = out->slope.u_max;
	return 0;
}

static void remove_tilt(const double *xy, double *val, size_t m)
{
	double M[3][3] = { { 0 } }, b[3] = { 0 }, c[3];

	for (size_t k = 0; k < m; k++) {
		double row[3] = { 1, xy[2 * k], xy[2 * k + 1] };
		for (int i = 0; i < 3; i++) {
			b[i] += row[i] * val[k];
			for (int j = 0; j < 3; j++)
				M[i][j] += row[i] * row[j];
		}
	}
	/* Cramer's rule: a 3 x 3 system of a fit already known to be
	 * determined (the form fits succeeded on these points). */
	double det = M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1]) -
		     M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0]) +
		     M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0]);
	if (!(fabs(det) > 0))
		return;
	for (int col = 0; col < 3; col++) {
		double A[3][3];
		memcpy(A, M, sizeof(A));
		for (int i = 0; i < 3; i++)
			A[i][col] = b[i];
		c[col] = (A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1]) -
			  A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0]) +
			  A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0])) / det;
	}
	for (size_t k = 0; k < m; k++)
		val[k] -= c[0] + c[1] * xy[2 * k] + c[2] * xy[2 * k + 1];
}

void fit_form_lengths(const struct asph_fit *w, double *wavelength, double *length)
{
	const struct asph_tolerance *t = w->opt.tolerance;

	*wavelength = w->opt.wavelength_nm;
	*length = w->opt.slope_length_mm;
	if (*wavelength == 0)
		*wavelength = t ? t->wavelength_nm : ASPH_FORM_DEFAULT_WAVELENGTH_NM;
	if (*length == 0)
		*length = t && !isnan(t->slope_length_mm) ? t->slope_length_mm
							  : DEFAULT_SLOPE_LENGTH_MM;
}

/* The form quantities, slope and their uncertainties of an areal
 * measurement. */
int fit_areal_form(struct asph_fit *w, struct asph_fit_result *out, struct asph_error *err)
{
	_cleanup_free_ double *xy = malloc(2 * w->n * sizeof(double) + 1);
	_cleanup_free_ double *val = malloc(w->n * sizeof(double) + 1);
	double wavelength, length, a = w->model.a, noise = noise_nm(out), centre[2], disk_r;
	size_t m;
	int r;

	if (!xy || !val)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(xy, 2 * w->n * sizeof(double));
	mem_advise_huge(val, w->n * sizeof(double));
	fit_form_lengths(w, &wavelength, &length);
	asph_surface_aperture_disk(w->model.s, centre, &disk_r);
	asph_scatter_free(w->slope_scatter);
	w->slope_scatter = NULL;
	m = asph_fit_residual_map(w, xy, val);
	r = compute_form(xy, val, m, centre, disk_r, wavelength, noise, out, err);
	if (r == 0 && out->form_valid) {
		remove_tilt(xy, val, m);
		r = compute_slope(w, xy, val, m, a, length, noise, out, err);
	} else if (r == 0) {
		out->slope.length_mm = length;
		out->slope.rms.v = out->slope.max.v = NAN;
	}
	return r;
}
