/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include <gsl/gsl_integration.h>

#include "asph/involute.h"
#include "hermite.h"
#include "involute-profile.h"
#include "util-mem.h"

/*
 * The geodesic that leaves the parallel r = r0 tangentially, parameterised
 * by v = sqrt(r - r0) (which removes the square-root singularity of
 * Clairaut's relation at the start), carries three integrals:
 *   phi(v)   = t / r0, t its length (the unwound angle),
 *   Theta(v) = how far it turns back around the axis,
 *   L(v)     = arc length of the involute up to radius r.
 * With r = r0 + v^2, w = sqrt(1 + Z'(r)^2) their integrands are
 *   phi'   = 2 w r / (r0 sqrt(r + r0)),
 *   Theta' = 2 r0 w / (r sqrt(r + r0)),
 *   L'     = 2 w r v / r0,
 * all smooth in v. They are tabulated once, as quintic Hermite pieces
 * (values from Gauss-Legendre sums, first and second derivatives exact)
 * on panels bisected until the interpolant matches the quadrature at the
 * panel midpoint. The involute point at arc length l is then
 * r = r0 + v^2, theta = phi(v) - Theta(v), with L(v) = l: the points are
 * produced in order, so a moving cursor finds each panel in O(1).
 */
#define GL_ORDER 20
#define N_FUNC 3
#define TOL 1e-15
/* Bounds on the bisection, should rounding keep a panel from passing. */
#define MIN_PANEL_FRACTION 1e-7
#define MAX_PANELS (1u << 18)
#define INITIAL_PANELS 8

enum { F_PHI = 0, F_THETA = 1, F_LEN = 2 };

struct panel {
	double v0, h;
	double c[N_FUNC][6];    /* p(s) = sum c[k] s^k, s = (v - v0) / h */
	double len1;            /* L at the panel's right end */
};

struct table {
	const struct involute_profile *prof;
	double r0, vmax;
	gsl_integration_glfixed_table *gl;
	struct panel *panels;
	size_t n, cap;
};

/* Integrands f and their v-derivatives df at v. */
static void integrands(const struct table *t, double v, double f[N_FUNC],
		       double df[N_FUNC])
{
	const double r0 = t->r0, r = r0 + v * v;
	double d[3];

	t->prof->derivs(t->prof->ctx, r, d);
	double w = sqrt(1.0 + d[1] * d[1]), dw = d[1] * d[2] / w;
	double q = sqrt(r + r0), dq = 0.5 / q;      /* d/dr of q */
	double drdv = 2.0 * v;

	f[F_PHI] = 2.0 * w * r / (r0 * q);
	df[F_PHI] = drdv * 2.0 / r0 *
		    ((dw * r + w) / q - w * r * dq / (q * q));
	f[F_THETA] = 2.0 * r0 * w / (r * q);
	df[F_THETA] = drdv * 2.0 * r0 *
		      (dw / (r * q) - w / (r * r * q) - w * dq / (r * q * q));
	f[F_LEN] = 2.0 * w * r * v / r0;
	df[F_LEN] = 2.0 / r0 * (w * r + v * drdv * (dw * r + w));
}

static void gl_integrals(const struct table *t, double lo, double hi,
			 double out[N_FUNC])
{
	double f[N_FUNC], df[N_FUNC];

	for (int k = 0; k < N_FUNC; k++)
		out[k] = 0;
	for (size_t j = 0; j < GL_ORDER; j++) {
		double x, wt;
		gsl_integration_glfixed_point(lo, hi, j, &x, &wt, t->gl);
		integrands(t, x, f, df);
		for (int k = 0; k < N_FUNC; k++)
			out[k] += wt * f[k];
	}
}

static int push_panel(struct table *t, const struct panel *p)
{
	if (t->n == t->cap) {
		size_t cap = t->cap ? 2 * t->cap : 256;
		struct panel *grown = realloc(t->panels, cap * sizeof(*grown));
		if (!grown)
			return -ENOMEM;
		t->panels = grown;
		t->cap = cap;
	}
	t->panels[t->n++] = *p;
	return 0;
}

/* Left end state of the panel being fitted. */
struct node {
	double v, F[N_FUNC], f[N_FUNC], df[N_FUNC];
};

static double tolerance(const struct table *t, int k, double value)
{
	return TOL * (fabs(value) + (k == F_LEN ? t->r0 : 1.0));
}

/*
 * Fits [left->v, hi]; returns 1 when accepted (left advanced to hi and the
 * panel stored), 0 when the interval must be split, < 0 on ENOMEM.
 */
static int try_panel(struct table *t, struct node *left, double hi)
{
	const double lo = left->v, h = hi - lo, mid = lo + 0.5 * h;
	struct node right = { .v = hi };
	double whole[N_FUNC], a[N_FUNC], b[N_FUNC];
	struct panel p = { .v0 = lo, .h = h };
	int good = 1;

	integrands(t, hi, right.f, right.df);
	gl_integrals(t, lo, hi, whole);
	gl_integrals(t, lo, mid, a);
	gl_integrals(t, mid, hi, b);
	for (int k = 0; k < N_FUNC; k++) {
		right.F[k] = left->F[k] + (a[k] + b[k]);
		double y0[3] = { left->F[k], left->f[k], left->df[k] };
		double y1[3] = { right.F[k], right.f[k], right.df[k] };
		hermite5(y0, y1, h, p.c[k]);
		double at_mid = left->F[k] + a[k];
		double tol = tolerance(t, k, at_mid);
		if (fabs(whole[k] - (a[k] + b[k])) > tol ||
		    fabs(poly5(p.c[k], 0.5) - at_mid) > tol)
			good = 0;
	}
	if (!good && h > MIN_PANEL_FRACTION * t->vmax && t->n < MAX_PANELS)
		return 0;
	p.len1 = right.F[F_LEN];
	if (push_panel(t, &p) < 0)
		return -ENOMEM;
	*left = right;
	return 1;
}

static int build_table(struct table *t)
{
	size_t cap = 64, sp = 0;
	_cleanup_free_ double *stack = malloc(cap * sizeof(double));
	struct node left = { .v = 0 };

	if (!stack)
		return -ENOMEM;
	integrands(t, 0, left.f, left.df);
	/* Right ends still to reach, nearest on top. */
	for (int i = INITIAL_PANELS; i >= 1; i--)
		stack[sp++] = t->vmax * i / INITIAL_PANELS;
	while (sp > 0) {
		double hi = stack[sp - 1];
		int r = try_panel(t, &left, hi);
		if (r < 0)
			return r;
		if (r == 1) {
			sp--;
			continue;
		}
		if (sp == cap) {
			double *grown = realloc(stack, 2 * cap * sizeof(double));
			if (!grown)
				return -ENOMEM;
			stack = grown;
			cap *= 2;
		}
		stack[sp++] = 0.5 * (left.v + hi);
	}
	return 0;
}

/* s in [0, 1] with L(v0 + s h) = len on panel p (L increasing). */
static double solve_len(const struct panel *p, double len0, double len)
{
	double lo = 0, hi = 1;
	double s = (len - len0) / (p->len1 - len0);

	if (!(s > 0))
		s = 0;
	if (s > 1)
		s = 1;
	for (int it = 0; it < 60; it++) {
		double f = poly5(p->c[F_LEN], s) - len;
		if (f == 0)
			return s;
		if (f > 0)
			hi = s;
		else
			lo = s;
		double next = s - f / poly5_deriv(p->c[F_LEN], s);
		if (!(next >= lo && next <= hi))
			next = 0.5 * (lo + hi);
		if (fabs(next - s) <= 4e-16)
			return next;
		s = next;
	}
	return s;
}

static void emit_points(const struct table *t, size_t n, double spacing,
			double *xyz)
{
	size_t i = 0;

	for (size_t k = 0; k < n; k++) {
		double len = spacing * (double)k, d[3];
		while (i + 1 < t->n && t->panels[i].len1 < len)
			i++;
		const struct panel *p = &t->panels[i];
		double s = k == 0 ? 0 : solve_len(p, p->c[F_LEN][0], len);
		double v = p->v0 + s * p->h, r = t->r0 + v * v;
		double theta = poly5(p->c[F_PHI], s) - poly5(p->c[F_THETA], s);
		t->prof->derivs(t->prof->ctx, r, d);
		xyz[3 * k] = r * cos(theta);
		xyz[3 * k + 1] = r * sin(theta);
		xyz[3 * k + 2] = d[0];
	}
}

static int count_points(const struct table *t, double spacing,
			size_t max_points, size_t *n, struct asph_error *err)
{
	double total = t->panels[t->n - 1].len1;
	double count = floor(total / spacing) + 1;

	if (!(count < (double)(SIZE_MAX / (3 * sizeof(double)))))
		return asph_error_set(err, -E2BIG,
			"spacing %g mm gives too many points (%.3g)", spacing, count);
	*n = (size_t)count;
	if (max_points && *n > max_points)
		return asph_error_set(err, -E2BIG,
			"spacing %g mm gives %zu points, more than the limit of %zu",
			spacing, *n, max_points);
	return 0;
}

int involute_points_profile(const struct involute_profile *prof,
			    double spacing_mm, size_t max_points,
			    double **xyz, size_t *n, struct asph_error *err)
{
	struct table t = { .prof = prof };
	int r;

	if (!isfinite(spacing_mm) || !(spacing_mm > 0))
		return asph_error_set(err, -EINVAL,
			"spacing must be a positive number of mm (got %g)", spacing_mm);
	t.r0 = spacing_mm / (2.0 * M_PI);
	if (!(t.r0 < prof->a))
		return asph_error_set(err, -EINVAL,
			"spacing %g mm is too coarse: the generating circle "
			"(radius spacing / 2 pi = %g mm) must lie inside the "
			"aperture radius %g mm", spacing_mm, t.r0, prof->a);
	t.vmax = sqrt(prof->a - t.r0);
	t.gl = gsl_integration_glfixed_table_alloc(GL_ORDER);
	if (!t.gl)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = build_table(&t);
	if (r < 0)
		r = asph_error_set(err, r, "out of memory");
	if (r == 0)
		r = count_points(&t, spacing_mm, max_points, n, err);
	if (r == 0) {
		*xyz = malloc(3 * *n * sizeof(double));
		if (!*xyz)
			r = asph_error_set(err, -ENOMEM, "out of memory");
		else
			emit_points(&t, *n, spacing_mm, *xyz);
	}
	free(t.panels);
	gsl_integration_glfixed_table_free(t.gl);
	return r;
}

static void surface_derivs(const void *ctx, double r, double d[3])
{
	asph_surface_sag_derivs(ctx, r, d);
}

int asph_involute_points(const struct asph_surface *s, double spacing_mm,
			 size_t max_points, double **xyz, size_t *n,
			 struct asph_error *err)
{
	struct involute_profile prof = {
		.derivs = surface_derivs,
		.ctx = s,
		.a = asph_surface_aperture_radius(s),
	};
	return involute_points_profile(&prof, spacing_mm, max_points, xyz, n, err);
}
