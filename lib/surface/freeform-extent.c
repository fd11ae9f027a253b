/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What a freeform spans over its aperture: sag range, steepest slope, area. */
#include <math.h>

#include <gsl/gsl_integration.h>

#include "aperture.h"
#include "freeform.h"

#define GRID 128
#define ZOOM_STEPS 10
#define ZOOM_POINTS 10   /* each side of the centre */

enum quantity { SAG_MIN, SAG_MAX, SLOPE };

/* The quantity to maximize at (x, y): -S, S or |grad S|^2. */
static double objective(const struct freeform *f, enum quantity q, double x, double y)
{
	struct asph_sag d;

	if (q != SLOPE) {
		double z = freeform_sag(f, x, y);
		return q == SAG_MAX ? z : -z;
	}
	freeform_eval(f, x, y, &d);
	return d.zx * d.zx + d.zy * d.zy;
}

struct best {
	double v, x, y;
};

static void consider(const struct freeform *f, const struct asph_aperture *ap, enum quantity q,
		     double x, double y, struct best *b)
{
	if (!aperture_contains(ap, x, y, 0))
		return;
	double v = objective(f, q, x, y);
	if (v > b->v || (isnan(b->v) && !isnan(v)))
		*b = (struct best){ v, x, y };
}

/* A grid over the bounding box and samples along the edge, then a grid of
 * 21 x 21 points around the best, shrinking tenfold each step: interior or
 * edge, the extremum is found to about 1e-10 of the aperture size. */
static void search(const struct freeform *f, const struct asph_aperture *ap, enum quantity q,
		   struct best *b)
{
	double box[4], pt[2], dp[2];

	aperture_bounds(ap, box);
	*b = (struct best){ NAN, ap->offset[0], ap->offset[1] };
	double hx = (box[1] - box[0]) / GRID, hy = (box[3] - box[2]) / GRID;
	for (int i = 0; i <= GRID; i++)
		for (int j = 0; j <= GRID; j++)
			consider(f, ap, q, box[0] + i * hx, box[2] + j * hy, b);
	for (int i = 0; i < 8 * GRID; i++) {
		aperture_boundary(ap, (double)i / (8 * GRID), pt, dp);
		/* exactly on the edge, the containment test may round either way */
		double in = aperture_contains(ap, pt[0], pt[1], 0) ? 1 : 1 - 1e-15;
		consider(f, ap, q, ap->offset[0] + in * (pt[0] - ap->offset[0]),
			 ap->offset[1] + in * (pt[1] - ap->offset[1]), b);
	}
	for (int step = 0; step < ZOOM_STEPS; step++) {
		double cx = b->x, cy = b->y;
		for (int i = -ZOOM_POINTS; i <= ZOOM_POINTS; i++)
			for (int j = -ZOOM_POINTS; j <= ZOOM_POINTS; j++)
				consider(f, ap, q, cx + i * hx / ZOOM_POINTS, cy + j * hy / ZOOM_POINTS, b);
		hx /= ZOOM_POINTS;
		hy /= ZOOM_POINTS;
	}
}

void freeform_extent(const struct freeform *f, const struct asph_aperture *ap,
		     struct asph_surface_extent *e)
{
	struct best b;

	search(f, ap, SAG_MIN, &b);
	e->sag_min = -b.v;
	e->sag_min_at[0] = b.x, e->sag_min_at[1] = b.y;
	search(f, ap, SAG_MAX, &b);
	e->sag_max = b.v;
	e->sag_max_at[0] = b.x, e->sag_max_at[1] = b.y;
	search(f, ap, SLOPE, &b);
	e->max_slope = sqrt(b.v);
	e->max_slope_at[0] = b.x, e->max_slope_at[1] = b.y;
}

/* Gauss-Legendre on p x p equal panels of the unit square mapped onto the
 * aperture (affinely for a rectangle, in polar coordinates otherwise). */
static double area_panels(const struct freeform *f, const struct asph_aperture *ap,
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
					freeform_eval(f, xy[0], xy[1], &d);
					sum += ws * wt * jac * sqrt(1.0 + d.zx * d.zx + d.zy * d.zy);
				}
	return sum;
}

double freeform_area(const struct freeform *f, const struct asph_aperture *ap,
		     const gsl_integration_glfixed_table *gl)
{
	double prev = area_panels(f, ap, gl, 1), area = prev;

	for (int p = 2; p <= 32; p *= 2) {
		area = area_panels(f, ap, gl, p);
		if (fabs(area - prev) <= 1e-14 * area)
			break;
		prev = area;
	}
	return area;
}
