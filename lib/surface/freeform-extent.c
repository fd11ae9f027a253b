/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What a surface spans over an aperture that is not a centred disk (a
 * freeform, an off-axis segment): sag range, steepest slope, area. */
#include <math.h>

#include <gsl/gsl_integration.h>

#include "aperture.h"
#include "freeform.h"

#define GRID 96
#define EDGE 768
#define ZOOM_STEPS 12
#define ZOOM_POINTS 7   /* each side of the centre */

enum quantity { SAG_MIN, SAG_MAX, SLOPE, N_QUANTITIES };

/* The quantity to maximize: -S, S or |grad S|^2. */
static double objective(enum quantity q, const struct asph_sag *d)
{
	return q == SAG_MAX ? d->z : q == SAG_MIN ? -d->z : d->zx * d->zx + d->zy * d->zy;
}

struct best {
	double v, x, y;
};

/* One evaluation at (x, y) for all the quantities (or only q when q is
 * not N_QUANTITIES). */
static void consider(const struct sag_sampler *f, const struct asph_aperture *ap, enum quantity q,
		     double x, double y, struct best *b)
{
	struct asph_sag d;

	if (!aperture_contains(ap, x, y, 0))
		return;
	f->derivs(f->data, x, y, &d);
	for (int k = 0; k < N_QUANTITIES; k++) {
		if (q != N_QUANTITIES && k != (int)q)
			continue;
		double v = objective((enum quantity)k, &d);
		if (v > b[k].v || (isnan(b[k].v) && !isnan(v)))
			b[k] = (struct best){ v, x, y };
	}
}

/* A grid over the bounding box and samples along the edge, then for each
 * quantity a grid of 15 x 15 points around its best, shrinking sevenfold
 * each step: interior or edge, each extremum is found to about 1e-11 of the
 * aperture size. */
static void search(const struct sag_sampler *f, const struct asph_aperture *ap, struct best *b)
{
	double box[4], pt[2], dp[2];

	aperture_bounds(ap, box);
	for (int k = 0; k < N_QUANTITIES; k++)
		b[k] = (struct best){ NAN, ap->offset[0], ap->offset[1] };
	double hx = (box[1] - box[0]) / GRID, hy = (box[3] - box[2]) / GRID;
	for (int i = 0; i <= GRID; i++)
		for (int j = 0; j <= GRID; j++)
			consider(f, ap, N_QUANTITIES, box[0] + i * hx, box[2] + j * hy, b);
	for (int i = 0; i < EDGE; i++) {
		aperture_boundary(ap, (double)i / EDGE, pt, dp);
		/* exactly on the edge, the containment test may round either way */
		double in = aperture_contains(ap, pt[0], pt[1], 0) ? 1 : 1 - 1e-15;
		consider(f, ap, N_QUANTITIES, ap->offset[0] + in * (pt[0] - ap->offset[0]),
			 ap->offset[1] + in * (pt[1] - ap->offset[1]), b);
	}
	for (int k = 0; k < N_QUANTITIES; k++) {
		double sx = hx, sy = hy;
		for (int step = 0; step < ZOOM_STEPS; step++) {
			double cx = b[k].x, cy = b[k].y;
			for (int i = -ZOOM_POINTS; i <= ZOOM_POINTS; i++)
				for (int j = -ZOOM_POINTS; j <= ZOOM_POINTS; j++)
					consider(f, ap, (enum quantity)k, cx + i * sx / ZOOM_POINTS,
						 cy + j * sy / ZOOM_POINTS, b);
			sx /= ZOOM_POINTS;
			sy /= ZOOM_POINTS;
		}
	}
}

void extent_over_aperture(const struct sag_sampler *f, const struct asph_aperture *ap,
			  struct asph_surface_extent *e)
{
	struct best b[N_QUANTITIES];

	search(f, ap, b);
	e->sag_min = -b[SAG_MIN].v;
	e->sag_min_at[0] = b[SAG_MIN].x, e->sag_min_at[1] = b[SAG_MIN].y;
	e->sag_max = b[SAG_MAX].v;
	e->sag_max_at[0] = b[SAG_MAX].x, e->sag_max_at[1] = b[SAG_MAX].y;
	e->max_slope = sqrt(b[SLOPE].v);
	e->max_slope_at[0] = b[SLOPE].x, e->max_slope_at[1] = b[SLOPE].y;
}

/* Gauss-Legendre on p x p equal panels of the unit square mapped onto the
 * aperture (affinely for a rectangle, in polar coordinates otherwise). */
static double area_panels(const struct sag_sampler *f, const struct asph_aperture *ap,
			  const gsl_integration_glfixed_table *gl, int p)
{
	double sum = 0;

	for (int pi = 0; pi < p; pi++)
		for (int pj = 0; pj < p; pj++)
			for (size_t i = 0; i < gl->n; i++)
				for (size_t j = 0; j < gl->n; j++) {
					double s, t, ws, wt, xy[2], jac;
					struct asph_sag d;
					gsl_integration_glfixed_point((double)pi / p, (pi + 1.0) / p, i,
								      &s, &ws, gl);
					gsl_integration_glfixed_point((double)pj / p, (pj + 1.0) / p, j,
								      &t, &wt, gl);
					aperture_map(ap, s, t, xy, &jac);
					f->derivs(f->data, xy[0], xy[1], &d);
					sum += ws * wt * jac * sqrt(1.0 + d.zx * d.zx + d.zy * d.zy);
				}
	return sum;
}

double area_over_aperture(const struct sag_sampler *f, const struct asph_aperture *ap,
			  const gsl_integration_glfixed_table *gl)
{
	double prev = area_panels(f, ap, gl, 1), area = prev;

	/* a smooth integrand: 20-point rules on 2 x 2 panels usually agree
	 * with 1 x 1 already */
	for (int p = 2; p <= 32; p *= 2) {
		area = area_panels(f, ap, gl, p);
		if (fabs(area - prev) <= 1e-13 * area)
			break;
		prev = area;
	}
	return area;
}
