/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The circle involute on any surface z = S(x, y), by geodesics integrated on
 * the smooth surface (docs/circle-involute.md, "On any surface"). */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>

#include <gsl/gsl_errno.h>
#include <gsl/gsl_integration.h>
#include <gsl/gsl_odeiv2.h>

#include "asph/involute.h"
#include "util-mem.h"

/*
 * A string of length u unwound from a closed curve C (3-D length L, here
 * a small circle about the aperture's centre) leaves C tangentially at
 * C(u mod L) and runs back along a geodesic; its end traces the involute.
 * The strings leaving one point of C are one geodesic, so the family is
 * indexed by the point theta of C, and turn k of the involute is the
 * family's geodesics at lengths u(theta) + k L. Each geodesic carries the
 * Jacobi field j of the family, whose size is the involute's speed
 * |dP/du| (j(0) = 0, j'(0) = -kappa_g(C)): the arc length along a turn is
 * then a quadrature over theta, with no differencing. theta runs over
 * panels of N_NODES Gauss-Legendre nodes: every function of a turn (x, y,
 * speed) is the polynomial through its nodes on each panel. The panels
 * start at MIN_PANELS and double, the plan started anew, while a turn's
 * polynomials are not resolved: the last Legendre coefficient of x, y (or
 * of the arc length over the panel) above TAIL spacings.
 */
#define MIN_PANELS 12
#define MAX_PANELS 768
#define N_NODES 12
#define TAIL 1e-9
#define GL_C 20                 /* Gauss-Legendre order for C's length */
/* Step control of the geodesics, per step: position to TOL spacings,
 * direction and the Jacobi field to TOL relative. */
#define TOL 1e-12
#define MIN_STEP_FRACTION 1e-9

enum { Y_X, Y_Y, Y_P, Y_Q, Y_J, Y_DJ, N_Y };

struct geodesic {
	double theta, u, cspeed;        /* on C: parameter, length to it, |C'| */
	double s, h;                    /* length integrated, next step */
	double y[N_Y];
};

struct involute {
	const struct asph_surface *surf;
	double centre[2], R, spacing, rho, L;
	double gx[N_NODES], gw[N_NODES];        /* nodes, weights on [-1, 1] */
	double fit[N_NODES][N_NODES];           /* build_fit() */
	int np;                                 /* panels */
	struct geodesic *g;                     /* np * N_NODES */
	double tail[N_NODES];                   /* the last Legendre coefficient */
	gsl_odeiv2_step *step;
	gsl_odeiv2_system sys;
	double *xyz;
	size_t n, cap, max_points;
};

/* The geodesic equations of the graph z = S(x, y) in arc length, with the
 * Jacobi equation j'' + K j = 0 (K the Gaussian curvature): the
 * Christoffel symbols are S_k S_ij / (1 + |grad S|^2). */
static int geodesic_rhs(double t, const double y[], double f[], void *ctx)
{
	struct asph_sag d;

	(void)t;
	asph_surface_derivs_xy(ctx, y[Y_X], y[Y_Y], &d);
	double W = 1 + d.zx * d.zx + d.zy * d.zy;
	double Q = d.zxx * y[Y_P] * y[Y_P] + 2 * d.zxy * y[Y_P] * y[Y_Q] +
		   d.zyy * y[Y_Q] * y[Y_Q];
	double K = (d.zxx * d.zyy - d.zxy * d.zxy) / (W * W);

	f[Y_X] = y[Y_P];
	f[Y_Y] = y[Y_Q];
	f[Y_P] = -d.zx * Q / W;
	f[Y_Q] = -d.zy * Q / W;
	f[Y_J] = y[Y_DJ];
	f[Y_DJ] = -K * y[Y_J];
	for (int k = 0; k < N_Y; k++)
		if (!isfinite(f[k]))
			return GSL_EBADFUNC;
	return GSL_SUCCESS;
}

static double error_norm(const struct involute *w, const double y[], const double e[])
{
	double sc[N_Y] = { w->spacing, w->spacing, 1, 1, 1 + fabs(y[Y_J]), 1 + fabs(y[Y_DJ]) };
	double worst = 0;

	for (int k = 0; k < N_Y; k++) {
		double r = fabs(e[k]) / (TOL * sc[k]);
		if (!(r <= worst))
			worst = isnan(r) ? INFINITY : r;
	}
	return worst;
}

/* Integrates g on to length s_end: Prince-Dormand 8(9) steps under an
 * error control of our own (so that no GSL error handler is involved).
 * -EDOM when it reaches where the surface is not defined. */
static int advance(struct involute *w, struct geodesic *g, double s_end)
{
	double y[N_Y], e[N_Y];

	while (g->s < s_end) {
		double h = fmin(g->h, s_end - g->s);
		if (s_end - (g->s + h) < 1e-12 * w->L)
			h = s_end - g->s;
		for (int k = 0; k < N_Y; k++)
			y[k] = g->y[k];
		gsl_odeiv2_step_reset(w->step);
		int st = gsl_odeiv2_step_apply(w->step, g->s, h, y, e, NULL, NULL, &w->sys);
		double err = st == GSL_SUCCESS ? error_norm(w, y, e) : INFINITY;
		if (err <= 1) {
			g->s = h == s_end - g->s ? s_end : g->s + h;
			for (int k = 0; k < N_Y; k++)
				g->y[k] = y[k];
			g->h = h * fmin(4, 0.9 * pow(fmax(err, 1e-12), -1.0 / 9));
			continue;
		}
		g->h = h * (isfinite(err) ? fmax(0.2, 0.9 * pow(err, -1.0 / 9)) : 0.25);
		if (g->h < MIN_STEP_FRACTION * w->L)
			return -EDOM;
	}
	return 0;
}

/* C(theta) = centre + rho (cos, sin) lifted: the point, C' and C'' in 3-D,
 * and the unit normal. */
static void curve(const struct involute *w, double rho, double th, double P[3], double d1[3],
		  double d2[3], double nrm[3])
{
	double c = cos(th), s = sin(th);
	struct asph_sag d;

	P[0] = w->centre[0] + rho * c;
	P[1] = w->centre[1] + rho * s;
	asph_surface_derivs_xy(w->surf, P[0], P[1], &d);
	P[2] = d.z;
	d1[0] = -rho * s;
	d1[1] = rho * c;
	d1[2] = d.zx * d1[0] + d.zy * d1[1];
	d2[0] = -rho * c;
	d2[1] = -rho * s;
	d2[2] = d.zx * d2[0] + d.zy * d2[1] +
		d.zxx * d1[0] * d1[0] + 2 * d.zxy * d1[0] * d1[1] + d.zyy * d1[1] * d1[1];
	double nn = sqrt(1 + d.zx * d.zx + d.zy * d.zy);
	nrm[0] = -d.zx / nn;
	nrm[1] = -d.zy / nn;
	nrm[2] = 1 / nn;
}

static double curve_speed(const struct involute *w, double rho, double th)
{
	double P[3], d1[3], d2[3], n[3];

	curve(w, rho, th, P, d1, d2, n);
	return sqrt(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]);
}

/* Length of C from theta a to b (Gauss-Legendre, C is smooth). */
static double curve_length(const struct involute *w, const gsl_integration_glfixed_table *t,
			   double rho, double a, double b)
{
	double sum = 0;

	for (size_t i = 0; i < GL_C; i++) {
		double x, wt;
		gsl_integration_glfixed_point(a, b, i, &x, &wt, t);
		sum += wt * curve_speed(w, rho, x);
	}
	return sum;
}

static double panel_width(const struct involute *w)
{
	return 2 * M_PI / w->np;
}

static double node_theta(const struct involute *w, int p, int i)
{
	return panel_width(w) * (p + 0.5 * (w->gx[i] + 1));
}

/* The circle about the centre whose 3-D length is the spacing (on a
 * surface of revolution about that centre: the parallel of radius
 * spacing / 2 pi), its length u at every node, and the geodesics' start:
 * tangent to C, heading against the unwinding, with j = 0 and
 * j' = -kappa_g. */
static int start_geodesics(struct involute *w, struct asph_error *err)
{
	gsl_integration_glfixed_table *t = gsl_integration_glfixed_table_alloc(GL_C);
	double rho = w->spacing / (2 * M_PI), L = 0;

	if (!t)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (int it = 0; it < 60; it++) {
		L = 0;
		for (int p = 0; p < w->np; p++)
			L += curve_length(w, t, rho, p * panel_width(w), (p + 1) * panel_width(w));
		if (!isfinite(L))
			break;
		if (fabs(L - w->spacing) <= 1e-15 * w->spacing)
			break;
		rho *= w->spacing / L;
	}
	if (!isfinite(L) || !(fabs(L - w->spacing) <= 1e-13 * w->spacing)) {
		gsl_integration_glfixed_table_free(t);
		return asph_error_set(err, -ERANGE,
				      "the involute's generating circle (3-D length %g mm) "
				      "cannot be laid on the surface at the aperture's centre",
				      w->spacing);
	}
	w->rho = rho;
	w->L = L;
	double u0 = 0;
	for (int p = 0; p < w->np; p++) {
		double a = p * panel_width(w);
		for (int i = 0; i < N_NODES; i++) {
			struct geodesic *g = &w->g[p * N_NODES + i];
			double P[3], d1[3], d2[3], n[3];
			g->theta = node_theta(w, p, i);
			g->u = u0 + curve_length(w, t, rho, a, g->theta);
			curve(w, rho, g->theta, P, d1, d2, n);
			double sp = sqrt(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2]);
			/* kappa_g = (C' x C'') . n / |C'|^3 */
			double kg = ((d1[1] * d2[2] - d1[2] * d2[1]) * n[0] +
				     (d1[2] * d2[0] - d1[0] * d2[2]) * n[1] +
				     (d1[0] * d2[1] - d1[1] * d2[0]) * n[2]) / (sp * sp * sp);
			g->cspeed = sp;
			g->s = 0;
			g->h = 0.25 * w->spacing;
			g->y[Y_X] = P[0];
			g->y[Y_Y] = P[1];
			g->y[Y_P] = -d1[0] / sp;
			g->y[Y_Q] = -d1[1] / sp;
			g->y[Y_J] = 0;
			g->y[Y_DJ] = -kg;
		}
		u0 += curve_length(w, t, rho, a, a + panel_width(w));
	}
	gsl_integration_glfixed_table_free(t);
	return 0;
}

/* The recurrence (n + 1) P_n+1 = (2 n + 1) x P_n - n P_n-1. */
static void legendre_at(double x, double P[N_NODES])
{
	P[0] = 1;
	P[1] = x;
	for (int n = 1; n + 1 < N_NODES; n++)
		P[n + 1] = ((2 * n + 1) * x * P[n] - n * P[n - 1]) / (n + 1);
}

/* fit[k][i]: the monomial coefficient of x^k in the Legendre series
 * through the nodes (exact for degree < N_NODES), per unit value at node
 * i: Gauss-Legendre projection onto P_0 .. P_11, then each P_n's monomial
 * coefficients. The series are smooth over [-1, 1], so their monomial form
 * loses a few bits only, and Horner's rule is what the resampling needs. */
static void build_fit(struct involute *w)
{
	double mono[N_NODES][N_NODES] = { { 0 } }, P[N_NODES];

	mono[0][0] = 1;
	mono[1][1] = 1;
	for (int n = 1; n + 1 < N_NODES; n++)
		for (int k = 0; k < N_NODES; k++)
			mono[n + 1][k] = ((2 * n + 1) * (k ? mono[n][k - 1] : 0) -
					  n * mono[n - 1][k]) / (n + 1);
	for (int k = 0; k < N_NODES; k++)
		for (int i = 0; i < N_NODES; i++)
			w->fit[k][i] = 0;
	for (int i = 0; i < N_NODES; i++) {
		legendre_at(w->gx[i], P);
		w->tail[i] = 0.5 * (2 * N_NODES - 1) * w->gw[i] * P[N_NODES - 1];
		for (int n = 0; n < N_NODES; n++)
			for (int k = 0; k <= n; k++)
				w->fit[k][i] += mono[n][k] * 0.5 * (2 * n + 1) * w->gw[i] * P[n];
	}
}

static double tail(const struct involute *w, const double f[N_NODES])
{
	double sum = 0;

	for (int i = 0; i < N_NODES; i++)
		sum += w->tail[i] * f[i];
	return fabs(sum);
}

/* The polynomial (monomial coefficients) through the values f at the
 * nodes. */
static void fit_poly(const struct involute *w, const double f[N_NODES], double m[N_NODES])
{
	for (int k = 0; k < N_NODES; k++) {
		double sum = 0;
		for (int i = 0; i < N_NODES; i++)
			sum += w->fit[k][i] * f[i];
		m[k] = sum;
	}
}

static double horner(const double *m, int n, double x)
{
	double v = m[n - 1];

	for (int k = n - 2; k >= 0; k--)
		v = v * x + m[k];
	return v;
}

/* F = int_-1^x of the polynomial m. */
static void antiderivative(const double m[N_NODES], double F[N_NODES + 1])
{
	double at_minus1 = 0;

	for (int k = 0; k < N_NODES; k++) {
		F[k + 1] = m[k] / (k + 1);
		at_minus1 += (k % 2 ? F[k + 1] : -F[k + 1]);
	}
	F[0] = -at_minus1;
}

/* x in [-1, 1] where scale * F(x) = len (F increasing, F' = m), from the
 * guess x: Newton, kept in a shrinking bracket, until the length is met to
 * tol (or the step is below rounding). */
static double solve_length(const double m[N_NODES], const double F[N_NODES + 1], double scale,
			   double len, double tol, double x)
{
	double lo = -1, hi = 1;

	if (!(x > -1))
		x = -1;
	if (x > 1)
		x = 1;
	for (int it = 0; it < 100; it++) {
		double f = scale * horner(F, N_NODES + 1, x) - len;
		if (fabs(f) <= tol)
			break;
		if (f > 0)
			hi = x;
		else
			lo = x;
		double next = x - f / (scale * horner(m, N_NODES, x));
		if (!(next > lo && next < hi))
			next = 0.5 * (lo + hi);
		/* the polynomial's rounding: below that, steps wander */
		if (fabs(next - x) <= 1e-13)
			return next;
		x = next;
	}
	return x;
}

static int emit(struct involute *w, double x, double y, struct asph_error *err)
{
	if (w->max_points && w->n == w->max_points)
		return asph_error_set(err, -E2BIG,
				      "spacing %g mm gives more than the limit of %zu points",
				      w->spacing, w->max_points);
	if (w->n == w->cap) {
		size_t cap = w->cap ? 2 * w->cap : 1024;
		double *grown = realloc(w->xyz, 3 * cap * sizeof(double));
		if (!grown)
			return asph_error_set(err, -ENOMEM, "out of memory (%zu points)", cap);
		w->xyz = grown;
		w->cap = cap;
	}
	w->xyz[3 * w->n] = x;
	w->xyz[3 * w->n + 1] = y;
	w->xyz[3 * w->n + 2] = asph_surface_sag_xy(w->surf, x, y);
	w->n++;
	return 0;
}

/* Samples one turn, whose geodesics stand at its points: the points of
 * arc length next * spacing that fall on it, kept inside the aperture.
 * *len is the arc length at the turn's start, then at its end. -EAGAIN
 * when the panels do not resolve the turn. */
/* Whether a panel of a turn lies wholly outside the aperture: every node
 * farther out than twice the largest gap between nodes (the curve between
 * them, and out to the panel's ends, is within that), so that its points
 * need not be found. */
static bool panel_outside(const struct involute *w, const double fx[N_NODES],
			  const double fy[N_NODES])
{
	double gap = 0;

	for (int i = 0; i + 1 < N_NODES; i++)
		gap = fmax(gap, hypot(fx[i + 1] - fx[i], fy[i + 1] - fy[i]));
	for (int i = 0; i < N_NODES; i++)
		if (asph_surface_contains(w->surf, fx[i], fy[i], 2 * gap))
			return false;
	return true;
}

static int sample_turn(struct involute *w, double *len, size_t *next, struct asph_error *err)
{
	const double scale = 0.5 * panel_width(w);

	for (int p = 0; p < w->np; p++) {
		double fx[N_NODES], fy[N_NODES], fs[N_NODES];
		double mx[N_NODES], my[N_NODES], ms[N_NODES], F[N_NODES + 1];
		for (int i = 0; i < N_NODES; i++) {
			const struct geodesic *g = &w->g[p * N_NODES + i];
			fx[i] = g->y[Y_X];
			fy[i] = g->y[Y_Y];
			fs[i] = fabs(g->y[Y_J]) * g->cspeed;
		}
		if (tail(w, fx) > TAIL * w->spacing || tail(w, fy) > TAIL * w->spacing ||
		    scale * tail(w, fs) > TAIL * w->spacing)
			return -EAGAIN;
		fit_poly(w, fs, ms);
		antiderivative(ms, F);
		double end = *len + scale * horner(F, N_NODES + 1, 1), x = -1, speed = 0;
		if (panel_outside(w, fx, fy)) {
			*next = (size_t)floor(end / w->spacing) + 1;
			*len = end;
			continue;
		}
		fit_poly(w, fx, mx);
		fit_poly(w, fy, my);
		for (; (double)*next * w->spacing <= end; ++*next) {
			double target = (double)*next * w->spacing - *len;
			/* from the last point, a step of spacing at its speed */
			double guess = speed > 0 ? x + w->spacing / (scale * speed)
						 : -1 + 2 * target / (end - *len);
			/* 1e-12 spacings: well above the rounding of a panel's
			 * length (up to ~100 spacings), far below the plan's 1e-6 */
			x = solve_length(ms, F, scale, target, 1e-12 * w->spacing, guess);
			speed = horner(ms, N_NODES, x);
			double px = horner(mx, N_NODES, x), py = horner(my, N_NODES, x);
			if (!asph_surface_contains(w->surf, px, py, 0))
				continue;
			int r = emit(w, px, py, err);
			if (r < 0)
				return r;
		}
		*len = end;
	}
	return 0;
}

static int run(struct involute *w, struct asph_error *err)
{
	double len = 0, slope = asph_surface_max_slope(w->surf, NULL);
	size_t next = 0;
	/* The turns stand spacing apart along geodesics, so the one past the
	 * aperture's disk comes within its geodesic radius / spacing turns. */
	double max_turns = 4 + 2 * w->R * sqrt(1 + slope * slope) / w->spacing;

	for (size_t k = 0;; k++) {
		if ((double)k > max_turns)
			return asph_error_set(err, -ERANGE,
					      "the involute does not leave the aperture after "
					      "%zu turns", k);
		bool out = true;
		for (int i = 0; i < w->np * N_NODES; i++) {
			struct geodesic *g = &w->g[i];
			if (advance(w, g, g->u + (double)k * w->L) < 0)
				return asph_error_set(err, -ERANGE,
						      "turn %zu of the involute leaves the domain "
						      "where the surface is defined, near (%.6g, %.6g)",
						      k, g->y[Y_X], g->y[Y_Y]);
			out = out && hypot(g->y[Y_X] - w->centre[0],
					   g->y[Y_Y] - w->centre[1]) > w->R;
		}
		int r = sample_turn(w, &len, &next, err);
		if (r < 0 || out)
			return r;
	}
}

/* The plan, with panels doubled until every turn is resolved. */
static int panels_as_needed(struct involute *w, struct asph_error *err)
{
	for (w->np = MIN_PANELS;; w->np *= 2) {
		free(w->g);
		w->g = malloc((size_t)w->np * N_NODES * sizeof(*w->g));
		if (!w->g)
			return asph_error_set(err, -ENOMEM, "out of memory");
		w->n = 0;
		int r = start_geodesics(w, err);
		if (r == 0)
			r = run(w, err);
		if (r != -EAGAIN)
			return r;
		if (2 * w->np > MAX_PANELS)
			return asph_error_set(err, -ERANGE,
					      "the involute's turns vary too fast around the "
					      "centre to be resolved by %d panels of %d geodesics",
					      w->np, N_NODES);
	}
}

int asph_involute_points_geodesic(const struct asph_surface *s, double spacing_mm,
				  size_t max_points, double **xyz, size_t *n,
				  struct asph_error *err)
{
	_cleanup_free_ struct involute *w = calloc(1, sizeof(*w));
	gsl_integration_glfixed_table *t = gsl_integration_glfixed_table_alloc(N_NODES);
	int r = 0;

	if (!w || !t) {
		gsl_integration_glfixed_table_free(t);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	w->surf = s;
	w->spacing = spacing_mm;
	w->max_points = max_points;
	asph_surface_aperture_disk(s, w->centre, &w->R);
	if (!isfinite(spacing_mm) || !(spacing_mm > 0))
		r = asph_error_set(err, -EINVAL,
				   "spacing must be a positive number of mm (got %g)", spacing_mm);
	else if (!(spacing_mm / (2 * M_PI) < w->R))
		r = asph_error_set(err, -EINVAL,
				   "spacing %g mm is too coarse: the generating circle "
				   "(3-D length spacing) must lie inside the aperture's "
				   "disk of radius %g mm", spacing_mm, w->R);
	for (int i = 0; i < N_NODES; i++)
		gsl_integration_glfixed_point(-1, 1, (size_t)i, &w->gx[i], &w->gw[i], t);
	build_fit(w);
	gsl_integration_glfixed_table_free(t);
	w->sys = (gsl_odeiv2_system){ geodesic_rhs, NULL, N_Y, (void *)s };
	if (r == 0 && !(w->step = gsl_odeiv2_step_alloc(gsl_odeiv2_step_rk8pd, N_Y)))
		r = asph_error_set(err, -ENOMEM, "out of memory");
	if (r == 0)
		r = panels_as_needed(w, err);
	if (w->step)
		gsl_odeiv2_step_free(w->step);
	free(w->g);
	if (r < 0) {
		free(w->xyz);
		return r;
	}
	*xyz = w->xyz;
	*n = w->n;
	return 0;
}
