/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The vertex-plane patterns over a freeform's aperture of any shape. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "plan-aperture.h"
#include "plan-patterns.h"
#include "util-mem.h"

int plan_points_push(struct plan_points *pp, double x, double y, double z)
{
	if (pp->n == pp->cap) {
		size_t cap = pp->cap ? 2 * pp->cap : 1024;
		double *v = realloc(pp->xyz, 3 * cap * sizeof(*v));
		if (!v)
			return -ENOMEM;
		pp->xyz = v;
		pp->cap = cap;
	}
	pp->xyz[3 * pp->n] = x;
	pp->xyz[3 * pp->n + 1] = y;
	pp->xyz[3 * pp->n + 2] = z;
	pp->n++;
	return 0;
}

void plan_points_clear(struct plan_points *pp)
{
	free(pp->xyz);
	*pp = (struct plan_points){ 0 };
}

void plan_aperture_nudge_in(const struct asph_surface *s, double *x, double *y)
{
	struct asph_aperture ap;

	asph_surface_aperture(s, &ap);
	for (int i = 0; i < 64 && !asph_surface_contains(s, *x, *y, 0); i++) {
		*x = nextafter(*x, ap.offset[0]);
		*y = nextafter(*y, ap.offset[1]);
	}
}

/* ---- the edge -------------------------------------------------------------- */

static size_t steps_of(double len, double p)
{
	double m = ceil(len / p - 1e-9);
	return m < 1 ? 1 : (size_t)m;
}

/* Arc length of an ellipse's edge over t in [lo, hi]: 8-point
 * Gauss-Legendre, which is exact to rounding on the short panels used. */
static const double gl8_x[4] = {
	0.1834346424956498049394761, 0.5255324099163289858177390,
	0.7966664774136267395915539, 0.9602898564975362316835609,
};
static const double gl8_w[4] = {
	0.3626837833783619829651504, 0.3137066458778872873379622,
	0.2223810344533744705443560, 0.1012285362903762591525314,
};

static double edge_speed(const struct asph_surface *s, double t)
{
	double p[2], dp[2];

	asph_surface_aperture_edge(s, t, p, dp);
	return hypot(dp[0], dp[1]);
}

static double edge_arc(const struct asph_surface *s, double lo, double hi)
{
	double mid = 0.5 * (lo + hi), half = 0.5 * (hi - lo), sum = 0;

	for (int i = 0; i < 4; i++)
		sum += gl8_w[i] * (edge_speed(s, mid - half * gl8_x[i]) +
				   edge_speed(s, mid + half * gl8_x[i]));
	return sum * half;
}

#define ELLIPSE_PANELS 128

/* t of the ellipse's edge at equal arc length: the panel sums, then
 * Newton's method inside the panel. */
struct ellipse_edge {
	double cum[ELLIPSE_PANELS + 1];
};

static void ellipse_edge_init(const struct asph_surface *s, struct ellipse_edge *e)
{
	e->cum[0] = 0;
	for (int k = 0; k < ELLIPSE_PANELS; k++)
		e->cum[k + 1] = e->cum[k] + edge_arc(s, (double)k / ELLIPSE_PANELS,
						     (double)(k + 1) / ELLIPSE_PANELS);
}

static double ellipse_edge_t(const struct asph_surface *s, const struct ellipse_edge *e,
			     double arc)
{
	int k = 0;

	while (k < ELLIPSE_PANELS - 1 && e->cum[k + 1] <= arc)
		k++;
	double lo = (double)k / ELLIPSE_PANELS, t = lo;
	for (int it = 0; it < 30; it++) {
		double step = (e->cum[k] + edge_arc(s, lo, t) - arc) / edge_speed(s, t);
		t -= step;
		if (fabs(step) < 1e-15)
			break;
	}
	return t;
}

size_t plan_outline_count(const struct asph_surface *s, double p)
{
	struct asph_aperture ap;

	asph_surface_aperture(s, &ap);
	if (ap.shape == ASPH_APERTURE_RECTANGULAR)
		return 2 * (steps_of(ap.width, p) + steps_of(ap.height, p));
	if (ap.shape == ASPH_APERTURE_CIRCULAR || ap.width == ap.height) {
		size_t m = steps_of(M_PI * ap.width, p);
		return m < 3 ? 3 : m;
	}
	struct ellipse_edge e;
	ellipse_edge_init(s, &e);
	size_t m = steps_of(e.cum[ELLIPSE_PANELS], p);
	return m < 3 ? 3 : m;
}

/* The edge's samples in order, t of each in ts (n of them). */
static int outline_params(const struct asph_surface *s, double p, double *ts, size_t n)
{
	struct asph_aperture ap;

	asph_surface_aperture(s, &ap);
	if (ap.shape == ASPH_APERTURE_RECTANGULAR) {
		size_t nw = steps_of(ap.width, p), nh = steps_of(ap.height, p), k = 0;
		size_t per_side[4] = { nw, nh, nw, nh };
		for (int side = 0; side < 4; side++)
			for (size_t j = 0; j < per_side[side]; j++)
				ts[k++] = 0.25 * ((double)side + (double)j / (double)per_side[side]);
		return 0;
	}
	if (ap.shape == ASPH_APERTURE_CIRCULAR || ap.width == ap.height) {
		for (size_t k = 0; k < n; k++)
			ts[k] = (double)k / (double)n;
		return 0;
	}
	struct ellipse_edge e;
	ellipse_edge_init(s, &e);
	for (size_t k = 0; k < n; k++)
		ts[k] = ellipse_edge_t(s, &e, e.cum[ELLIPSE_PANELS] * (double)k / (double)n);
	return 0;
}

int plan_outline_append(const struct asph_surface *s, double p, double x0, double y0,
			struct plan_points *pp)
{
	size_t n = plan_outline_count(s, p), start = 0;
	_cleanup_free_ double *ts = malloc(n * sizeof(*ts));
	_cleanup_free_ double *xy = malloc(2 * n * sizeof(*xy));
	double best = INFINITY, dp[2];

	if (!ts || !xy)
		return -ENOMEM;
	outline_params(s, p, ts, n);
	for (size_t k = 0; k < n; k++) {
		asph_surface_aperture_edge(s, ts[k], xy + 2 * k, dp);
		plan_aperture_nudge_in(s, xy + 2 * k, xy + 2 * k + 1);
		double d = hypot(xy[2 * k] - x0, xy[2 * k + 1] - y0);
		if (d < best) {
			best = d;
			start = k;
		}
	}
	for (size_t q = 0; q < n; q++) {
		const double *v = xy + 2 * ((start + q) % n);
		if (plan_points_push(pp, v[0], v[1], 0) < 0)
			return -ENOMEM;
	}
	return 0;
}

/* ---- patterns -------------------------------------------------------------- */

static int planar_fill(const struct plan_pattern *pat, double a, double p,
		       double **xyr, size_t *n)
{
	*n = pat->count(a, p);
	*xyr = malloc(3 * *n * sizeof(double));
	if (!*xyr || pat->fill(a, p, *xyr) < 0)
		return -ENOMEM;
	return 0;
}

/* A circle: the pattern of the circle, moved to its centre. */
static int circle_pattern(const struct asph_surface *s, const struct plan_pattern *pat,
			  double p, struct plan_points *pp)
{
	struct asph_aperture ap;
	_cleanup_free_ double *xyr = NULL;
	size_t n;

	asph_surface_aperture(s, &ap);
	if (planar_fill(pat, 0.5 * ap.width, p, &xyr, &n) < 0)
		return -ENOMEM;
	for (size_t i = 0; i < n; i++) {
		double x = xyr[3 * i] + ap.offset[0], y = xyr[3 * i + 1] + ap.offset[1];
		plan_aperture_nudge_in(s, &x, &y);
		if (plan_points_push(pp, x, y, 0) < 0)
			return -ENOMEM;
	}
	return 0;
}

/* A rectangle or an ellipse: the pattern over the disk about the centre,
 * the points at least p/2 inside, then the outline. */
static int inset_pattern(const struct asph_surface *s, const struct plan_pattern *pat,
			 double p, struct plan_points *pp, size_t *n_edge)
{
	double c[2], R;
	_cleanup_free_ double *xyr = NULL;
	size_t n, first = pp->n;

	asph_surface_aperture_disk(s, c, &R);
	if (planar_fill(pat, R, p, &xyr, &n) < 0)
		return -ENOMEM;
	for (size_t i = 0; i < n; i++) {
		double x = xyr[3 * i] + c[0], y = xyr[3 * i + 1] + c[1];
		if (asph_surface_contains(s, x, y, -0.5 * p) && plan_points_push(pp, x, y, 0) < 0)
			return -ENOMEM;
	}
	double x0 = c[0] + R, y0 = c[1];
	if (pp->n > first) {
		x0 = pp->xyz[3 * (pp->n - 1)];
		y0 = pp->xyz[3 * (pp->n - 1) + 1];
	}
	size_t before = pp->n;
	if (plan_outline_append(s, p, x0, y0, pp) < 0)
		return -ENOMEM;
	if (n_edge)
		*n_edge = pp->n - before;
	return 0;
}

/* One row y of a raster over the chord [xc - c, xc + c], serpentine. */
static int raster_row(const struct asph_surface *s, double xc, double c, double y,
		      double p, int reverse, struct plan_points *pp)
{
	size_t cnt = plan_raster_row_count(c, p);
	long cols = plan_raster_cols(c, p);

	if (cnt == 1)
		return plan_points_push(pp, xc, y, 0);
	for (size_t q = 0; q < cnt; q++) {
		size_t i = reverse ? cnt - 1 - q : q;
		double x;
		if (i == 0 || i == cnt - 1) {
			x = xc + (i == 0 ? -c : c);
			double yy = y;
			plan_aperture_nudge_in(s, &x, &yy);
			if (plan_points_push(pp, x, yy, 0) < 0)
				return -ENOMEM;
			continue;
		}
		x = xc + (double)((long)i - 1 - cols) * p;
		if (plan_points_push(pp, x, y, 0) < 0)
			return -ENOMEM;
	}
	return 0;
}

/* Rows from the bottom up: a rectangle's rows divide its height equally, so
 * that its bottom and top sides are rows; an ellipse's are y = yc + j p as
 * on a circle. Each row ends on the edge. */
static int aperture_raster(const struct asph_surface *s, double p, struct plan_points *pp)
{
	struct asph_aperture ap;
	double hx, hy;

	asph_surface_aperture(s, &ap);
	hx = 0.5 * ap.width;
	hy = 0.5 * ap.height;
	if (ap.shape == ASPH_APERTURE_RECTANGULAR) {
		size_t m = steps_of(ap.height, p);
		for (size_t j = 0; j <= m; j++) {
			double y = j == m ? ap.offset[1] + hy
					  : ap.offset[1] - hy + ap.height * (double)j / (double)m;
			if (raster_row(s, ap.offset[0], hx, y, p, (int)(j % 2), pp) < 0)
				return -ENOMEM;
		}
		return 0;
	}
	long rows = (long)floor(hy / p + 1e-12);
	for (long j = -rows; j <= rows; j++) {
		double v = (double)j * p / hy, c = hx * sqrt(fmax(0, (1 - v) * (1 + v)));
		if (raster_row(s, ap.offset[0], c, ap.offset[1] + (double)j * p, p,
			       (int)((j + rows) % 2), pp) < 0)
			return -ENOMEM;
	}
	return 0;
}

int plan_aperture_pattern(const struct asph_surface *s, const struct plan_pattern *pat,
			  double p, struct plan_points *pp, size_t *n_edge)
{
	struct asph_aperture ap;

	asph_surface_aperture(s, &ap);
	if (n_edge)
		*n_edge = 0;
	if (ap.shape == ASPH_APERTURE_CIRCULAR) {
		int r = circle_pattern(s, pat, p, pp);
		if (r == 0 && pat->rim_count && n_edge)
			*n_edge = pat->rim_count(0.5 * ap.width, p);
		return r;
	}
	if (pat->rows)
		return aperture_raster(s, p, pp);
	return inset_pattern(s, pat, p, pp, n_edge);
}
