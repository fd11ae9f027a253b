/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_integration.h>

#include "asph/surface.h"
#include "aperture.h"
#include "chebyshev.h"
#include "freeform.h"
#include "numeric/newton.h"
#include "qpoly.h"
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
	int n_q;                  /* Q types: 1 + highest m with a_m != 0 */
	double inv_rho2;          /* Q types: 1 / norm_radius^2 */
	struct qbfs_coef qbfs;    /* Qbfs recurrence coefficients */
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
	int radial;                       /* Z(r): a rotationally symmetric type */
	int rotational;                   /* radial over a centred circle */
	struct asph_aperture ap;          /* resolved */
	double total_area;
	struct asph_surface_extent extent;
	struct freeform ff;               /* freeform types */
};

static const char *const type_names[] = {
	[ASPH_SURFACE_EVEN_ASPHERE] = "even_asphere",
	[ASPH_SURFACE_QBFS] = "qbfs",
	[ASPH_SURFACE_QCON] = "qcon",
	[ASPH_SURFACE_ODD_ASPHERE] = "odd_asphere",
	[ASPH_SURFACE_BICONIC] = "biconic",
	[ASPH_SURFACE_TOROIDAL] = "toroidal",
	[ASPH_SURFACE_XY_POLYNOMIAL] = "xy_polynomial",
	[ASPH_SURFACE_ZERNIKE_SAG] = "zernike_sag",
	[ASPH_SURFACE_Q2D] = "q2d",
};

const char *asph_surface_type_name(enum asph_surface_type type)
{
	if ((unsigned)type < ARRAY_SIZE(type_names))
		return type_names[type];
	return "unknown";
}

int asph_surface_type_from_name(const char *name, enum asph_surface_type *out)
{
	for (size_t i = 0; i < ARRAY_SIZE(type_names); i++) {
		if (strcmp(name, type_names[i]))
			continue;
		*out = (enum asph_surface_type)i;
		return 0;
	}
	return -EINVAL;
}

int asph_surface_type_has_conic(enum asph_surface_type type)
{
	return type != ASPH_SURFACE_Q2D && type != ASPH_SURFACE_BICONIC;
}

int asph_surface_type_is_rotational(enum asph_surface_type type)
{
	return type == ASPH_SURFACE_EVEN_ASPHERE || type == ASPH_SURFACE_QBFS ||
	       type == ASPH_SURFACE_QCON || type == ASPH_SURFACE_ODD_ASPHERE;
}

int asph_surface_is_rotational(const struct asph_surface *s)
{
	return s->rotational;
}

int asph_surface_is_radial(const struct asph_surface *s)
{
	return s->radial;
}

static int is_q_type(enum asph_surface_type type)
{
	return type == ASPH_SURFACE_QBFS || type == ASPH_SURFACE_QCON;
}

/* The conic c r^2 / (1 + sqrt(1 - K c^2 r^2)), K = 1 + k, and its first two
 * derivatives; it has no cancellation for any sign of K. */
static void conic_derivs(double c, double K, double r, double d[3])
{
	double u = 1.0 - K * c * c * r * r;
	double root = sqrt(u);

	d[0] = c * r * r / (1.0 + root);
	d[1] = c * r / root;
	d[2] = c / (u * root);
}

/* Horner for sum A_i r^i and its first two derivatives. */
static void power_series(const struct asph_surface *s, double r, double d[3])
{
	double p0 = 0, p1 = 0, p2 = 0;

	for (int i = s->max_power; i >= 1; i--) {
		p2 = p2 * r + 2.0 * p1;
		p1 = p1 * r + p0;
		p0 = p0 * r + s->p.A[i];
	}
	/* p0 now holds sum A_i r^(i-1); one more step multiplies by r. */
	d[2] = p2 * r + 2.0 * p1;
	d[1] = p1 * r + p0;
	d[0] = p0 * r;
}

/*
 * Qbfs measures its departure along the normal of the base conic; its
 * sag is the departure times the secant of the normal's angle,
 * g = sqrt(1 + Z_conic'^2) = sqrt(N / D), N = 1 - k c^2 r^2,
 * D = 1 - (1 + k) c^2 r^2 (1 / sqrt(1 - c^2 r^2) on a sphere, Forbes'
 * form), with g' = g L and g'' = g (L^2 + L'), L = (ln g)'.
 */
static void normal_secant(double c, double k, double r, double g[3])
{
	double c2 = c * c, N = 1.0 - k * c2 * r * r, D = 1.0 - (1.0 + k) * c2 * r * r;
	double L = -k * c2 * r / N + (1.0 + k) * c2 * r / D;
	double Lp = -k * c2 / N - 2.0 * k * k * c2 * c2 * r * r / (N * N) + (1.0 + k) * c2 / D +
		    2.0 * (1.0 + k) * (1.0 + k) * c2 * c2 * r * r / (D * D);

	g[0] = sqrt(N / D);
	g[1] = g[0] * L;
	g[2] = g[0] * (L * L + Lp);
}

/*
 * The Q departures as functions of r: T(x) with x = r^2 / rho^2, where
 * T = x (1 - x) S(x) for Qbfs and x^2 S(x) for Qcon, S = sum a_m Q_m.
 * Qbfs then multiplies by the secant of the base's normal.
 */
static void q_departure(const struct asph_surface *s, double r, double d[3])
{
	double x = r * r * s->inv_rho2, sum[3], t[3];

	if (s->p.type == ASPH_SURFACE_QBFS) {
		qbfs_sum(&s->qbfs, s->p.Q, s->n_q, x, sum);
		t[0] = x * (1.0 - x) * sum[0];
		t[1] = (1.0 - 2.0 * x) * sum[0] + x * (1.0 - x) * sum[1];
		t[2] = -2.0 * sum[0] + 2.0 * (1.0 - 2.0 * x) * sum[1] +
		       x * (1.0 - x) * sum[2];
	} else {
		qcon_sum(s->p.Q, s->n_q, x, sum);
		t[0] = x * x * sum[0];
		t[1] = 2.0 * x * sum[0] + x * x * sum[1];
		t[2] = 2.0 * sum[0] + 4.0 * x * sum[1] + x * x * sum[2];
	}
	double dx = 2.0 * r * s->inv_rho2;
	d[0] = t[0];
	d[1] = t[1] * dx;
	d[2] = t[2] * dx * dx + t[1] * 2.0 * s->inv_rho2;
	if (s->p.type != ASPH_SURFACE_QBFS)
		return;
	double g[3], d0 = d[0], d1 = d[1];
	normal_secant(s->c, s->p.k, r, g);
	d[0] = g[0] * d0;
	d[1] = g[1] * d0 + g[0] * d1;
	d[2] = g[2] * d0 + 2.0 * g[1] * d1 + g[0] * d[2];
}

void asph_surface_sag_derivs(const struct asph_surface *s, double r,
			     double d[3])
{
	double dep[3] = { 0, 0, 0 };

	if (!s->radial) {
		d[0] = d[1] = d[2] = NAN;
		return;
	}
	r = fabs(r);
	conic_derivs(s->c, 1.0 + s->p.k, r, d);
	if (is_q_type(s->p.type)) {
		if (s->n_q > 0)
			q_departure(s, r, dep);
	} else {
		power_series(s, r, dep);
	}
	for (int i = 0; i < 3; i++)
		d[i] += dep[i];
}

double asph_surface_sag(const struct asph_surface *s, double r)
{
	double d[3];

	asph_surface_sag_derivs(s, r, d);
	return d[0];
}

/* The graph of Z(r): the gradient Z' (x, y)/r and the Hessian
 * Z'' u u^T + (Z'/r) (I - u u^T), u = (x, y)/r; at r = 0, Z''(0) I. */
static void rotational_derivs_xy(const struct asph_surface *s, double x, double y,
				 struct asph_sag *o)
{
	double r = sqrt(x * x + y * y), d[3];

	asph_surface_sag_derivs(s, r, d);
	o->z = d[0];
	if (!(r > 0)) {
		o->zx = o->zy = o->zxy = 0;
		o->zxx = o->zyy = d[2];
		return;
	}
	double ux = x / r, uy = y / r, t = d[1] / r;
	o->zx = d[1] * ux;
	o->zy = d[1] * uy;
	o->zxx = d[2] * ux * ux + t * uy * uy;
	o->zxy = (d[2] - t) * ux * uy;
	o->zyy = d[2] * uy * uy + t * ux * ux;
}

void asph_surface_derivs_xy(const struct asph_surface *s, double x, double y,
			    struct asph_sag *out)
{
	if (s->radial)
		rotational_derivs_xy(s, x, y, out);
	else
		freeform_eval(&s->ff, x, y, out);
}

void asph_surface_sag_grad_xy(const struct asph_surface *s, double x, double y,
			      double g[3])
{
	double r = sqrt(x * x + y * y), d[3];

	if (!s->radial) {
		freeform_sag_grad(&s->ff, x, y, g);
		return;
	}
	asph_surface_sag_derivs(s, r, d);
	g[0] = d[0];
	g[1] = r > 0 ? d[1] * x / r : 0;
	g[2] = r > 0 ? d[1] * y / r : 0;
}

double asph_surface_sag_xy(const struct asph_surface *s, double x, double y)
{
	if (s->radial)
		return asph_surface_sag(s, sqrt(x * x + y * y));
	return freeform_sag(&s->ff, x, y);
}

double asph_surface_area_element(const struct asph_surface *s, double x, double y)
{
	struct asph_sag d;

	asph_surface_derivs_xy(s, x, y, &d);
	return sqrt(1.0 + d.zx * d.zx + d.zy * d.zy);
}

void asph_surface_normal(const struct asph_surface *s, double x, double y,
			 double n[3])
{
	double r = hypot(x, y), d[3];

	if (!s->radial) {
		struct asph_sag g;
		freeform_eval(&s->ff, x, y, &g);
		double inv = 1.0 / sqrt(1.0 + g.zx * g.zx + g.zy * g.zy);
		n[0] = -g.zx * inv;
		n[1] = -g.zy * inv;
		n[2] = inv;
		return;
	}
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
		double next = newton_bracketed_step(r, f, dg(s, r), &lo, &hi);
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

/* The lowest and highest Z over [0, a], on the +x meridian: sampled, then
 * an interior extremum refined by bisection on Z' = 0. */
static double refine_sag_extremum(const struct asph_surface *s, double r, double h)
{
	double lo = fmax(0, r - h), hi = fmin(s->a, r + h), dlo[3], dhi[3];

	asph_surface_sag_derivs(s, lo, dlo);
	asph_surface_sag_derivs(s, hi, dhi);
	if (!(r > 0 && r < s->a && dlo[1] * dhi[1] < 0))
		return r;
	for (int it = 0; it < 200 && hi - lo > 1e-15 * s->a; it++) {
		double mid = 0.5 * (lo + hi), dm[3];
		asph_surface_sag_derivs(s, mid, dm);
		if ((dm[1] < 0) == (dlo[1] < 0))
			lo = mid;
		else
			hi = mid;
	}
	return 0.5 * (lo + hi);
}

static void rotational_extent(struct asph_surface *s)
{
	const int n = 4096;
	struct asph_surface_extent *e = &s->extent;
	double r_lo = 0, r_hi = 0, z_lo = INFINITY, z_hi = -INFINITY;

	for (int i = 0; i <= n; i++) {
		double r = s->a * i / n, z = asph_surface_sag(s, r);
		if (z < z_lo)
			z_lo = z, r_lo = r;
		if (z > z_hi)
			z_hi = z, r_hi = r;
	}
	r_lo = refine_sag_extremum(s, r_lo, s->a / n);
	r_hi = refine_sag_extremum(s, r_hi, s->a / n);
	e->sag_min = fmin(z_lo, asph_surface_sag(s, r_lo));
	e->sag_max = fmax(z_hi, asph_surface_sag(s, r_hi));
	e->sag_min_at[0] = r_lo;
	e->sag_max_at[0] = r_hi;
	e->sag_min_at[1] = e->sag_max_at[1] = 0;
	e->max_slope = s->max_slope;
	e->max_slope_at[0] = s->r_max_slope;
	e->max_slope_at[1] = 0;
}

/* The power coefficients a type allows: none (Q types), A2..A20 even
 * (even asphere), A1..A20 (odd asphere). A0 would move the vertex. */
static int check_powers(const struct asph_prescription *p,
			struct asph_error *err)
{
	const char *name = asph_surface_type_name(p->type);
	char field[16];

	for (int i = 0; i <= ASPH_SURFACE_MAX_POWER; i++) {
		snprintf(field, sizeof(field), "A.%d", i);
		if (!isfinite(p->A[i]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "coefficient A%d is not finite", i);
		if (p->A[i] == 0)
			continue;
		if (is_q_type(p->type))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "a %s surface has Q coefficients \"a\", not powers of r (A%d given)",
						 name, i);
		if (i == 0 || (i == 1 && p->type == ASPH_SURFACE_EVEN_ASPHERE))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "an %s asphere has coefficients A%d..A20 only",
						 p->type == ASPH_SURFACE_EVEN_ASPHERE ? "even" : "odd",
						 p->type == ASPH_SURFACE_EVEN_ASPHERE ? 2 : 1);
		if (p->type == ASPH_SURFACE_EVEN_ASPHERE && i % 2)
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "an even asphere has even powers only (A%d given)",
						 i);
	}
	return 0;
}

static int check_q(const struct asph_prescription *p, struct asph_error *err)
{
	char field[16];

	for (int m = 0; m <= ASPH_SURFACE_MAX_Q; m++) {
		snprintf(field, sizeof(field), "a.[%d]", m);
		if (!isfinite(p->Q[m]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "coefficient a%d is not finite", m);
		if (p->Q[m] != 0 && !is_q_type(p->type))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "only the qbfs and qcon types have Q coefficients (a%d given)",
						 m);
	}
	if (!is_q_type(p->type)) {
		if (p->norm_radius != 0)
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "norm_radius",
						 "only the qbfs and qcon types have a normalization radius");
		return 0;
	}
	if (!(p->norm_radius > 0) || !isfinite(p->norm_radius))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "norm_radius",
					 "norm_radius must be a positive number of mm");
	return 0;
}

/* The conic's square root 1 - (1 + k) c^2 r^2 stays positive out to the
 * farthest point of the aperture (Qbfs's secant needs no more). */
static int check_conic_root(const struct asph_prescription *p, struct asph_error *err)
{
	struct asph_aperture ap;

	aperture_resolve(p, &ap);
	double a = aperture_max_radius(&ap), c = isinf(p->R) ? 0.0 : 1.0 / p->R;
	if (!((1.0 + p->k) * c * c * a * a >= 1.0))
		return 0;
	return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "k",
				 "the conic square root 1 - (1+k) r^2/R^2 reaches zero at r = %.6g mm, "
				 "inside the aperture, which reaches r = %.6g mm (R = %g, k = %g)",
				 fabs(p->R) / sqrt(1.0 + p->k), a, p->R, p->k);
}

int asph_prescription_check(const struct asph_prescription *p,
			    struct asph_error *err)
{
	int r;

	if ((unsigned)p->type >= ARRAY_SIZE(type_names) || !type_names[p->type])
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "type",
					 "unknown surface type %d", (int)p->type);
	if (!asph_surface_type_is_rotational(p->type))
		return freeform_check(p, asph_surface_type_name(p->type), err);
	if ((r = radius_check(p->R, "R", err)) < 0)
		return r;
	if (!isfinite(p->k))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "k",
					 "k must be a finite number");
	if ((r = check_powers(p, err)) < 0 || (r = check_q(p, err)) < 0 ||
	    (r = aperture_check(p, err)) < 0)
		return r;
	return check_conic_root(p, err);
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
	/* A slope whose square overflows makes the integrals infinite; the
	 * tables below would grow to their largest size in vain (seconds). */
	if (!isfinite(s->arc_a) || !isfinite(s->area_a))
		return -EDOM;
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

/* asph_surface_derivs_xy() as the numerics over an aperture call it. */
static void derivs_at(const void *data, double x, double y, struct asph_sag *d)
{
	asph_surface_derivs_xy(data, x, y, d);
}

/* A freeform, or a segment of a rotationally symmetric parent, has no
 * radial tables: its area is a 2-D integral, its extent a search over the
 * aperture. */
static int aperture_surface_alloc(struct asph_surface *s, struct asph_surface **out,
				  struct asph_error *err)
{
	if (!s->radial)
		freeform_init(&s->ff, &s->p);
	s->a = aperture_max_radius(&s->ap);
	s->gl = gsl_integration_glfixed_table_alloc(GL_ORDER);
	if (!s->gl) {
		asph_surface_free(s);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	const struct sag_sampler sampler = { derivs_at, s };
	s->total_area = area_over_aperture(&sampler, &s->ap, s->gl);
	if (!isfinite(s->total_area)) {
		asph_surface_free(s);
		return asph_error_set(err, -EINVAL, "the surface is too steep to sample: its "
				      "area over the aperture overflows");
	}
	extent_over_aperture(&sampler, &s->ap, &s->extent);
	s->max_slope = s->extent.max_slope;
	s->r_max_slope = hypot(s->extent.max_slope_at[0], s->extent.max_slope_at[1]);
	s->arc_a = s->area_a = NAN;
	*out = s;
	return 0;
}

/* Z(r)'s coefficients as the evaluation takes them. */
static void radial_init(struct asph_surface *s)
{
	const struct asph_prescription *p = &s->p;

	s->c = isinf(p->R) ? 0.0 : 1.0 / p->R;
	for (int i = 1; i <= ASPH_SURFACE_MAX_POWER; i++)
		if (p->A[i] != 0)
			s->max_power = i;
	for (int m = 0; m <= ASPH_SURFACE_MAX_Q; m++)
		if (p->Q[m] != 0)
			s->n_q = m + 1;
	if (is_q_type(p->type)) {
		s->inv_rho2 = 1.0 / (p->norm_radius * p->norm_radius);
		qbfs_coef_init(&s->qbfs);
	}
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
	s->radial = asph_surface_type_is_rotational(p->type);
	aperture_resolve(p, &s->ap);
	s->rotational = s->radial && aperture_is_centred_circle(&s->ap);
	if (s->radial)
		radial_init(s);
	if (!s->rotational)
		return aperture_surface_alloc(s, out, err);
	s->a = 0.5 * s->ap.width;
	s->gl = gsl_integration_glfixed_table_alloc(GL_ORDER);
	if (!s->gl) {
		asph_surface_free(s);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	r = build_tables(s);
	if (r == -EDOM) {
		asph_surface_free(s);
		return asph_error_set(err, -EINVAL, "the surface is too steep to sample: its "
				      "area over the aperture overflows");
	}
	if (r < 0) {
		asph_surface_free(s);
		return asph_error_set(err, r, "out of memory");
	}
	find_max_slope(s);
	s->total_area = s->area_a;
	rotational_extent(s);
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
	if (!s->rotational)
		return NAN;
	r = fabs(r);
	if (r > s->a)
		return s->arc_a + (arc_exact(s, r) - arc_exact(s, s->a));
	return r * cheb_table_eval(&s->arc_ratio, r);
}

double asph_surface_radius_at_arc_length(const struct asph_surface *s,
					 double arc)
{
	if (!s->rotational)
		return NAN;
	if (arc <= 0)
		return 0;
	if (arc > s->arc_a)
		return invert_monotone(s, arc, 4 * s->a + arc, arc_fwd, arc_deriv);
	return arc * cheb_table_eval(&s->arc_inv_ratio, arc);
}

double asph_surface_area(const struct asph_surface *s, double r)
{
	if (!s->rotational)
		return NAN;
	r = fabs(r);
	if (r > s->a)
		return area_exact(s, r);
	return M_PI * r * r * cheb_table_eval(&s->area_ratio, r);
}

double asph_surface_radius_at_area(const struct asph_surface *s, double area)
{
	if (!s->rotational)
		return NAN;
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
	if (s->rotational)
		return s->area_a / (M_PI * s->a * s->a);
	return s->total_area / aperture_area(&s->ap);
}

void asph_surface_aperture(const struct asph_surface *s, struct asph_aperture *out)
{
	*out = s->ap;
}

int asph_surface_contains(const struct asph_surface *s, double x, double y, double tol)
{
	return aperture_contains(&s->ap, x, y, tol);
}

void asph_surface_aperture_edge(const struct asph_surface *s, double t, double p[2],
				double dp[2])
{
	aperture_boundary(&s->ap, t, p, dp);
}

void asph_surface_bounds(const struct asph_surface *s, double box[4])
{
	aperture_bounds(&s->ap, box);
}

double asph_surface_projected_area(const struct asph_surface *s)
{
	return aperture_area(&s->ap);
}

double asph_surface_total_area(const struct asph_surface *s)
{
	return s->total_area;
}

void asph_surface_extent(const struct asph_surface *s, struct asph_surface_extent *out)
{
	*out = s->extent;
}

void asph_surface_aperture_disk(const struct asph_surface *s, double centre[2], double *radius)
{
	centre[0] = s->ap.offset[0];
	centre[1] = s->ap.offset[1];
	if (s->ap.shape == ASPH_APERTURE_RECTANGULAR)
		*radius = 0.5 * hypot(s->ap.width, s->ap.height);
	else
		*radius = 0.5 * fmax(s->ap.width, s->ap.height);
}
