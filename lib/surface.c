/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_integration.h>

#include "asph/surface.h"
#include "chebyshev.h"
#include "util-mem.h"

/*
 * Arc length and area are integrals of the sag's slope. They are computed
 * exactly once (composite Gauss-Legendre, checked by panel doubling) at the
 * nodes of piecewise Chebyshev interpolants; afterwards every evaluation,
 * forward or inverse, costs one interpolant evaluation. The interpolated
 * quantities are ratios that tend to 1 at the vertex (s/r, A/(pi r^2),
 * r/s, r/sqrt(A/pi)), so relative precision holds down to r = 0.
 */
#define GL_ORDER 20
/* Relative accuracy of the interpolants: a few tens of ulp, the level at
 * which the integrands themselves are known for steep prescriptions (the
 * slope of the turning-point lens is a difference of terms ~30 times
 * larger than itself). */
#define INTERP_TOL 1e-14
#define INTERP_MAX_PANELS 128

struct asph_surface {
	struct asph_prescription p;
	double a;                 /* aperture radius */
	double c;                 /* vertex curvature 1/R */
	int max_power;            /* highest i with A[i] != 0 */
	gsl_integration_glfixed_table *gl;
	size_t quad_panels;       /* panels over [0, a] for exact integrals */
	double *prefix_arc;       /* integrals up to each panel boundary */
	double *prefix_area;
	struct cheb_table arc_ratio;      /* s(r)/r over [0, a] */
	struct cheb_table area_ratio;     /* A(r)/(pi r^2) over [0, a] */
	struct cheb_table arc_inv_ratio;  /* r(s)/s over [0, s(a)] */
	struct cheb_table area_inv_ratio; /* r(q)/q, q = sqrt(A/pi), [0, q(a)] */
	double arc_a, area_a;
	double max_slope, r_max_slope;
};

const char *asph_surface_type_name(enum asph_surface_type type)
{
	switch (type) {
	case ASPH_SURFACE_EVEN_ASPHERE:
		return "even_asphere";
	}
	return "unknown";
}

void asph_surface_sag_derivs(const struct asph_surface *s, double r,
			     double d[3])
{
	const double c = s->c, k = s->p.k;
	r = fabs(r);
	double u = 1.0 - (1.0 + k) * c * c * r * r;
	double root = sqrt(u);
	/* c r^2 / (1 + root) has no cancellation for any sign of 1 + k. */
	double z = c * r * r / (1.0 + root);
	double dz = c * r / root;
	double d2z = c / (u * root);

	/* Horner for sum A_i r^i and its first two derivatives. */
	double p0 = 0, p1 = 0, p2 = 0;
	for (int i = s->max_power; i >= 1; i--) {
		p2 = p2 * r + 2.0 * p1;
		p1 = p1 * r + p0;
		p0 = p0 * r + s->p.A[i];
	}
	/* p0 now holds sum A_i r^(i-1); one more step multiplies by r. */
	p2 = p2 * r + 2.0 * p1;
	p1 = p1 * r + p0;
	p0 = p0 * r;
	d[0] = z + p0;
	d[1] = dz + p1;
	d[2] = d2z + p2;
}

double asph_surface_sag(const struct asph_surface *s, double r)
{
	double d[3];

	asph_surface_sag_derivs(s, r, d);
	return d[0];
}

void asph_surface_normal(const struct asph_surface *s, double x, double y,
			 double n[3])
{
	double r = hypot(x, y), d[3];

	asph_surface_sag_derivs(s, r, d);
	double inv = 1.0 / sqrt(1.0 + d[1] * d[1]);
	if (r > 0) {
		n[0] = -d[1] * (x / r) * inv;
		n[1] = -d[1] * (y / r) * inv;
	} else {
		n[0] = n[1] = 0;
	}
	n[2] = inv;
}

static double slope_factor(const struct asph_surface *s, double r)
{
	double d[3];

	asph_surface_sag_derivs(s, r, d);
	return sqrt(1.0 + d[1] * d[1]);
}

static double gl_panel(const struct asph_surface *s, double lo, double hi,
		       int power)
{
	double part = 0;

	for (size_t j = 0; j < GL_ORDER; j++) {
		double x, w;
		gsl_integration_glfixed_point(lo, hi, j, &x, &w, s->gl);
		part += w * (power ? x : 1.0) * slope_factor(s, x);
	}
	return part;
}

/* int_0^r t^power sqrt(1 + Z'(t)^2) dt, composite Gauss-Legendre on
 * quad_panels equal panels over [0, a]; past a, panels of the same width. */
static double integrate_exact(const struct asph_surface *s, double r,
			      int power)
{
	const double *prefix = power ? s->prefix_area : s->prefix_arc;
	double h = s->a / (double)s->quad_panels;

	if (r <= 0)
		return 0;
	if (prefix && r <= s->a) {
		size_t i = (size_t)(r / h);
		if (i >= s->quad_panels)
			i = s->quad_panels - 1;
		return prefix[i] + gl_panel(s, h * (double)i, r, power);
	}
	size_t m = (size_t)ceil(r / h);
	double sum = 0;
	for (size_t i = 0; i < m; i++) {
		double lo = h * (double)i, hi = fmin(lo + h, r);
		sum += gl_panel(s, lo, hi, power);
	}
	return sum;
}

static int build_prefix(struct asph_surface *s)
{
	size_t n = s->quad_panels;
	double h = s->a / (double)n;

	s->prefix_arc = malloc((n + 1) * sizeof(double));
	s->prefix_area = malloc((n + 1) * sizeof(double));
	if (!s->prefix_arc || !s->prefix_area)
		return -ENOMEM;
	s->prefix_arc[0] = s->prefix_area[0] = 0;
	for (size_t i = 0; i < n; i++) {
		double lo = h * (double)i, hi = (i + 1 == n) ? s->a : lo + h;
		s->prefix_arc[i + 1] = s->prefix_arc[i] + gl_panel(s, lo, hi, 0);
		s->prefix_area[i + 1] = s->prefix_area[i] + gl_panel(s, lo, hi, 1);
	}
	return 0;
}

static double arc_exact(const struct asph_surface *s, double r)
{
	return integrate_exact(s, r, 0);
}

static double area_exact(const struct asph_surface *s, double r)
{
	return 2.0 * M_PI * integrate_exact(s, r, 1);
}

/* Doubles the panel count until the integrals over the aperture settle. */
static void choose_quad_panels(struct asph_surface *s)
{
	double prev_arc, prev_area;

	s->quad_panels = 16;
	prev_arc = arc_exact(s, s->a);
	prev_area = area_exact(s, s->a);
	while (s->quad_panels < 8192) {
		s->quad_panels *= 2;
		double arc = arc_exact(s, s->a), area = area_exact(s, s->a);
		int settled = fabs(arc - prev_arc) <= 1e-15 * arc &&
			      fabs(area - prev_area) <= 1e-15 * area;
		prev_arc = arc;
		prev_area = area;
		if (settled)
			break;
	}
}

static double arc_ratio_fn(double r, void *ctx)
{
	const struct asph_surface *s = ctx;
	return r > 0 ? arc_exact(s, r) / r : 1.0;
}

static double area_ratio_fn(double r, void *ctx)
{
	const struct asph_surface *s = ctx;
	return r > 0 ? area_exact(s, r) / (M_PI * r * r) : 1.0;
}

/* Newton on a monotone forward map g(r) = target with g' = dg, safeguarded
 * by the bracket [0, hi]. Stops when the step drops to rounding level of r,
 * since g itself carries rounding noise of a few ulp. */
static double invert_monotone(const struct asph_surface *s, double target,
			      double hi, double (*g)(const struct asph_surface *, double),
			      double (*dg)(const struct asph_surface *, double))
{
	double lo = 0, r = fmin(target, hi * 0.5);

	if (target <= 0)
		return 0;
	for (int it = 0; it < 60; it++) {
		double f = g(s, r) - target;
		if (f == 0)
			return r;
		if (f > 0)
			hi = r;
		else
			lo = r;
		double next = r - f / dg(s, r);
		if (!(next > lo && next < hi))
			next = 0.5 * (lo + hi);
		if (fabs(next - r) <= 2e-16 * r)
			return next;
		r = next;
	}
	return r;
}

static double arc_fwd(const struct asph_surface *s, double r)
{
	return arc_exact(s, r);
}

static double arc_deriv(const struct asph_surface *s, double r)
{
	return slope_factor(s, r);
}

/* q(r) = sqrt(A(r)/pi): smooth and ~r at the vertex. */
static double q_fwd(const struct asph_surface *s, double r)
{
	return sqrt(area_exact(s, r) / M_PI);
}

static double q_deriv(const struct asph_surface *s, double r)
{
	double q = q_fwd(s, r);
	if (q <= 0)
		return 1.0;
	return r * slope_factor(s, r) / q;
}

static double arc_inv_ratio_fn(double arc, void *ctx)
{
	const struct asph_surface *s = ctx;
	if (arc <= 0)
		return 1.0;
	return invert_monotone(s, arc, s->a * 1.0000001, arc_fwd, arc_deriv) / arc;
}

static double area_inv_ratio_fn(double q, void *ctx)
{
	const struct asph_surface *s = ctx;
	if (q <= 0)
		return 1.0;
	return invert_monotone(s, q, s->a * 1.0000001, q_fwd, q_deriv) / q;
}

static void find_max_slope(struct asph_surface *s)
{
	const int n = 4096;
	double best = -1, best_r = 0;

	for (int i = 0; i <= n; i++) {
		double r = s->a * i / n, d[3];
		asph_surface_sag_derivs(s, r, d);
		if (fabs(d[1]) > best) {
			best = fabs(d[1]);
			best_r = r;
		}
	}
	/* Refine an interior maximum: |Z'| is extremal where Z'' = 0. */
	double lo = fmax(0, best_r - s->a / n), hi = fmin(s->a, best_r + s->a / n);
	double dlo[3], dhi[3];
	asph_surface_sag_derivs(s, lo, dlo);
	asph_surface_sag_derivs(s, hi, dhi);
	if (best_r > 0 && best_r < s->a && dlo[2] * dhi[2] < 0) {
		for (int it = 0; it < 200 && hi - lo > 1e-15 * s->a; it++) {
			double mid = 0.5 * (lo + hi), dm[3];
			asph_surface_sag_derivs(s, mid, dm);
			if ((dm[2] < 0) == (dlo[2] < 0))
				lo = mid;
			else
				hi = mid;
		}
		best_r = 0.5 * (lo + hi);
		double d[3];
		asph_surface_sag_derivs(s, best_r, d);
		best = fmax(best, fabs(d[1]));
	}
	s->max_slope = best;
	s->r_max_slope = best_r;
}

int asph_prescription_check(const struct asph_prescription *p,
			    struct asph_error *err)
{
	if (p->type != ASPH_SURFACE_EVEN_ASPHERE) {
		asph_error_locate(err, NULL, 0, 0, "type");
		return asph_error_set(err, -EINVAL, "unknown surface type %d",
				      (int)p->type);
	}
	if (!isfinite(p->R)) {
		asph_error_locate(err, NULL, 0, 0, "R");
		return asph_error_set(err, -EINVAL, "R must be a finite number");
	}
	if (p->R == 0) {
		asph_error_locate(err, NULL, 0, 0, "R");
		return asph_error_set(err, -EINVAL,
				      "R = 0 is not a radius of curvature");
	}
	if (!isfinite(p->k)) {
		asph_error_locate(err, NULL, 0, 0, "k");
		return asph_error_set(err, -EINVAL, "k must be a finite number");
	}
	for (int i = 0; i <= ASPH_SURFACE_MAX_POWER; i++) {
		if (isfinite(p->A[i]))
			continue;
		char field[16];
		snprintf(field, sizeof(field), "A.%d", i);
		asph_error_locate(err, NULL, 0, 0, field);
		return asph_error_set(err, -EINVAL, "coefficient A%d is not finite", i);
	}
	if (p->A[0] != 0 || p->A[1] != 0) {
		asph_error_locate(err, NULL, 0, 0, p->A[0] != 0 ? "A.0" : "A.1");
		return asph_error_set(err, -EINVAL,
				      "an even asphere has coefficients A2..A20 only");
	}
	for (int i = 3; i <= ASPH_SURFACE_MAX_POWER; i += 2) {
		if (p->A[i] == 0)
			continue;
		char field[16];
		snprintf(field, sizeof(field), "A.%d", i);
		asph_error_locate(err, NULL, 0, 0, field);
		return asph_error_set(err, -EINVAL,
				      "an even asphere has even powers only (A%d given)", i);
	}
	if (!(p->aperture_diameter > 0) || !isfinite(p->aperture_diameter)) {
		asph_error_locate(err, NULL, 0, 0, "aperture_diameter");
		return asph_error_set(err, -EINVAL,
				      "aperture_diameter must be a positive number of mm");
	}
	double a = 0.5 * p->aperture_diameter;
	double c = 1.0 / p->R;
	if ((1.0 + p->k) * c * c * a * a >= 1.0) {
		double r_fail = fabs(p->R) / sqrt(1.0 + p->k);
		asph_error_locate(err, NULL, 0, 0, "k");
		return asph_error_set(err, -EINVAL,
			"the conic square root 1 - (1+k) r^2/R^2 reaches zero at r = %.6g mm, "
			"inside the aperture radius %.6g mm (R = %g, k = %g)",
			r_fail, a, p->R, p->k);
	}
	return 0;
}

static int build_tables(struct asph_surface *s)
{
	int r;

	choose_quad_panels(s);
	r = build_prefix(s);
	if (r < 0)
		return r;
	s->arc_a = arc_exact(s, s->a);
	s->area_a = area_exact(s, s->a);
	/* -ERANGE only means the last bits were not reached; keep going. */
	r = cheb_table_build(&s->arc_ratio, 0, s->a, arc_ratio_fn, s,
			     INTERP_TOL, INTERP_MAX_PANELS);
	if (r == -ENOMEM)
		return r;
	r = cheb_table_build(&s->area_ratio, 0, s->a, area_ratio_fn, s,
			     INTERP_TOL, INTERP_MAX_PANELS);
	if (r == -ENOMEM)
		return r;
	r = cheb_table_build(&s->arc_inv_ratio, 0, s->arc_a, arc_inv_ratio_fn,
			     s, INTERP_TOL, INTERP_MAX_PANELS);
	if (r == -ENOMEM)
		return r;
	r = cheb_table_build(&s->area_inv_ratio, 0, sqrt(s->area_a / M_PI),
			     area_inv_ratio_fn, s, INTERP_TOL, INTERP_MAX_PANELS);
	if (r == -ENOMEM)
		return r;
	return 0;
}

int asph_surface_alloc(const struct asph_prescription *p,
		       struct asph_surface **out, struct asph_error *err)
{
	int r = asph_prescription_check(p, err);
	if (r < 0)
		return r;

	struct asph_surface *s = calloc(1, sizeof(*s));
	if (!s)
		return asph_error_set(err, -ENOMEM, "out of memory");
	s->p = *p;
	s->a = 0.5 * p->aperture_diameter;
	s->c = 1.0 / p->R;
	for (int i = 1; i <= ASPH_SURFACE_MAX_POWER; i++)
		if (p->A[i] != 0)
			s->max_power = i;
	s->gl = gsl_integration_glfixed_table_alloc(GL_ORDER);
	if (!s->gl) {
		asph_surface_free(s);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	r = build_tables(s);
	if (r < 0) {
		asph_surface_free(s);
		return asph_error_set(err, r, "out of memory");
	}
	find_max_slope(s);
	*out = s;
	return 0;
}

void asph_surface_free(struct asph_surface *s)
{
	if (!s)
		return;
	cheb_table_clear(&s->arc_ratio);
	cheb_table_clear(&s->area_ratio);
	cheb_table_clear(&s->arc_inv_ratio);
	cheb_table_clear(&s->area_inv_ratio);
	free(s->prefix_arc);
	free(s->prefix_area);
	if (s->gl)
		gsl_integration_glfixed_table_free(s->gl);
	free(s);
}

const struct asph_prescription *
asph_surface_prescription(const struct asph_surface *s)
{
	return &s->p;
}

double asph_surface_aperture_radius(const struct asph_surface *s)
{
	return s->a;
}

double asph_surface_arc_length(const struct asph_surface *s, double r)
{
	r = fabs(r);
	if (r > s->a)
		return s->arc_a + (arc_exact(s, r) - arc_exact(s, s->a));
	return r * cheb_table_eval(&s->arc_ratio, r);
}

double asph_surface_radius_at_arc_length(const struct asph_surface *s,
					 double arc)
{
	if (arc <= 0)
		return 0;
	if (arc > s->arc_a)
		return invert_monotone(s, arc, 4 * s->a + arc, arc_fwd, arc_deriv);
	return arc * cheb_table_eval(&s->arc_inv_ratio, arc);
}

double asph_surface_area(const struct asph_surface *s, double r)
{
	r = fabs(r);
	if (r > s->a)
		return area_exact(s, r);
	return M_PI * r * r * cheb_table_eval(&s->area_ratio, r);
}

double asph_surface_radius_at_area(const struct asph_surface *s, double area)
{
	if (area <= 0)
		return 0;
	double q = sqrt(area / M_PI);
	if (area > s->area_a)
		return invert_monotone(s, q, 4 * s->a + q, q_fwd, q_deriv);
	return q * cheb_table_eval(&s->area_inv_ratio, q);
}

double asph_surface_max_slope(const struct asph_surface *s, double *r_at)
{
	if (r_at)
		*r_at = s->r_max_slope;
	return s->max_slope;
}

double asph_surface_gamma(const struct asph_surface *s)
{
	return s->area_a / (M_PI * s->a * s->a);
}
