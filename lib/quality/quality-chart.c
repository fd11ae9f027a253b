/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The conformal (isothermal) chart of a surface of revolution; the
 * derivation is in docs/conformal-chart.md. In short: the metric
 * w^2 dr^2 + r^2 dtheta^2 equals (r/rho)^2 (drho^2 + rho^2 dtheta^2) when
 * d(log rho)/dr = w / r, so rho(r) = r exp(I(r)) with
 * I(r) = int_0^r (w(t) - 1) / t dt, which is regular at 0 (the integrand
 * tends to t / (2 R^2)).
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "asph/quality.h"

/* Panels of the table of I; each evaluation integrates one partial panel
 * with 8-point Gauss-Legendre, exact to rounding for the smooth integrands
 * of lens prescriptions at this panel width. Near a slope singularity just
 * outside the aperture (a cap close to a hemisphere) the panel is bisected
 * until the halves agree with the whole. */
#define CHART_PANELS 512
#define MAX_BISECTIONS 20

struct asph_conformal_chart {
	const struct asph_surface *s;
	double a, h;
	double I[CHART_PANELS + 1];
};

static const double gl_x[4] = {
	0.1834346424956498049394761, 0.5255324099163289858177390,
	0.7966664774136267395915539, 0.9602898564975362316835609,
};
static const double gl_w[4] = {
	0.3626837833783619829651504, 0.3137066458778872873379622,
	0.2223810344533744705443560, 0.1012285362903762591525314,
};

/* (w - 1) / t written without the cancellation of w - 1 near the axis. */
static double integrand(const struct asph_surface *s, double t)
{
	double d[3], w;

	asph_surface_sag_derivs(s, t, d);
	w = sqrt(1 + d[1] * d[1]);
	return d[1] * d[1] / ((w + 1) * t);
}

static double gl_rule(const struct asph_surface *s, double lo, double hi)
{
	double mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo), sum = 0;

	if (half <= 0)
		return 0;
	for (int i = 0; i < 4; i++)
		sum += gl_w[i] * (integrand(s, mid - half * gl_x[i]) +
				  integrand(s, mid + half * gl_x[i]));
	return sum * half;
}

/*
 * The error of I, not of one panel, is what matters (it is the relative
 * error of rho), so each panel may err by its share of 1e-15 over the
 * aperture a, or by 1e-12 of its own value: on a steep flank the sag's
 * slope itself is only that accurate (1 - r^2/R^2 cancels), and asking for
 * more would bisect rounding noise.
 */
static double gl_adaptive(const struct asph_surface *s, double lo, double hi,
			  double whole, double a, int depth)
{
	double mid = 0.5 * (lo + hi);
	double left = gl_rule(s, lo, mid), right = gl_rule(s, mid, hi);
	double tol = fmax(1e-15 * (hi - lo) / a, 1e-12 * fabs(left + right));

	if (depth >= MAX_BISECTIONS || !(fabs(whole - left - right) > tol))
		return left + right;
	return gl_adaptive(s, lo, mid, left, a, depth + 1) +
	       gl_adaptive(s, mid, hi, right, a, depth + 1);
}

static double gl_panel(const struct asph_surface *s, double lo, double hi,
		       double a)
{
	if (!(hi > lo))
		return 0;
	return gl_adaptive(s, lo, hi, gl_rule(s, lo, hi), a, 0);
}

int asph_conformal_chart_alloc(const struct asph_surface *s,
			       struct asph_conformal_chart **out,
			       struct asph_error *err)
{
	struct asph_conformal_chart *c;

	if (!s || !out)
		return asph_error_set(err, -EINVAL, "conformal chart: no surface");
	c = calloc(1, sizeof(*c));
	if (!c)
		return asph_error_set(err, -ENOMEM, "conformal chart: out of memory");
	c->s = s;
	c->a = asph_surface_aperture_radius(s);
	c->h = c->a / CHART_PANELS;
	c->I[0] = 0;
	for (int k = 0; k < CHART_PANELS; k++) {
		c->I[k + 1] = c->I[k] + gl_panel(s, k * c->h, (k + 1) * c->h, c->a);
		if (!isfinite(c->I[k + 1])) {
			double r = (k + 1) * c->h;
			free(c);
			return asph_error_set(err, -EINVAL,
					      "conformal chart: the surface slope is not finite near r = %g mm",
					      r);
		}
	}
	*out = c;
	return 0;
}

void asph_conformal_chart_free(struct asph_conformal_chart *c)
{
	free(c);
}

static double log_scale(const struct asph_conformal_chart *c, double r)
{
	size_t k = (size_t)(r / c->h);
	double I, lo;

	if (k > CHART_PANELS)
		k = CHART_PANELS;
	I = c->I[k];
	lo = (double)k * c->h;
	/* Past the aperture, whole panels first, then the remainder. Rounding
	 * in lo only moves where the last panel starts: [lo, r] still closes
	 * the range. */
	for (; r - lo > c->h; lo += c->h) // NOLINT(cert-flp30-c)
		I += gl_panel(c->s, lo, lo + c->h, c->a);
	return I + gl_panel(c->s, lo, r, c->a);
}

double asph_conformal_chart_rho(const struct asph_conformal_chart *c,
				double r)
{
	if (!(r >= 0) || !isfinite(r))
		return NAN;
	if (r == 0)
		return 0;
	return r * exp(log_scale(c, r));
}

void asph_conformal_chart_map(const struct asph_conformal_chart *c, double x,
			      double y, double uv[2])
{
	double r = hypot(x, y), f;

	if (!isfinite(r)) {
		uv[0] = uv[1] = NAN;
		return;
	}
	f = r > 0 ? exp(log_scale(c, r)) : 1.0;
	uv[0] = f * x;
	uv[1] = f * y;
}

static const char *const chart_names[] = {
	[ASPH_CHART_CONFORMAL] = "conformal",
	[ASPH_CHART_VERTEX_PLANE] = "vertex-plane",
	[ASPH_CHART_PLAN_MESH] = "plan-mesh",
};

const char *asph_quality_chart_name(enum asph_quality_chart c)
{
	if ((unsigned)c >= sizeof(chart_names) / sizeof(chart_names[0]))
		return "unknown";
	return chart_names[c];
}

int asph_quality_chart_from_name(const char *name,
				 enum asph_quality_chart *out)
{
	if (!name)
		return -EINVAL;
	if (!strcmp(name, "xy")) {
		*out = ASPH_CHART_VERTEX_PLANE;
		return 0;
	}
	for (size_t i = 0; i < sizeof(chart_names) / sizeof(chart_names[0]); i++)
		if (!strcmp(name, chart_names[i])) {
			*out = (enum asph_quality_chart)i;
			return 0;
		}
	return -EINVAL;
}
