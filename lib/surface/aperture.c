/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>

#include "aperture.h"

void aperture_resolve(const struct asph_prescription *p, struct asph_aperture *out)
{
	if (p->aperture.shape != ASPH_APERTURE_FROM_DIAMETER) {
		*out = p->aperture;
		return;
	}
	*out = (struct asph_aperture){
		.shape = ASPH_APERTURE_CIRCULAR,
		.width = p->aperture_diameter,
		.height = p->aperture_diameter,
	};
}

int aperture_contains(const struct asph_aperture *ap, double x, double y, double tol)
{
	double hx = 0.5 * ap->width + tol, hy = 0.5 * ap->height + tol;
	double u = x - ap->offset[0], v = y - ap->offset[1];

	if (ap->shape == ASPH_APERTURE_RECTANGULAR)
		return fabs(u) <= hx && fabs(v) <= hy;
	/* Circle and ellipse: (u/hx)^2 + (v/hy)^2 <= 1, written without the
	 * division so that a point on the edge of a circle is inside. */
	return u * u * hy * hy + v * v * hx * hx <= hx * hx * hy * hy;
}

void aperture_bounds(const struct asph_aperture *ap, double box[4])
{
	box[0] = ap->offset[0] - 0.5 * ap->width;
	box[1] = ap->offset[0] + 0.5 * ap->width;
	box[2] = ap->offset[1] - 0.5 * ap->height;
	box[3] = ap->offset[1] + 0.5 * ap->height;
}

double aperture_area(const struct asph_aperture *ap)
{
	if (ap->shape == ASPH_APERTURE_RECTANGULAR)
		return ap->width * ap->height;
	return 0.25 * M_PI * ap->width * ap->height;
}

void aperture_boundary(const struct asph_aperture *ap, double t, double p[2],
		       double dp[2])
{
	double hx = 0.5 * ap->width, hy = 0.5 * ap->height;

	t -= floor(t);
	if (ap->shape != ASPH_APERTURE_RECTANGULAR) {
		double a = 2.0 * M_PI * t;
		p[0] = ap->offset[0] + hx * cos(a);
		p[1] = ap->offset[1] + hy * sin(a);
		dp[0] = -2.0 * M_PI * hx * sin(a);
		dp[1] = 2.0 * M_PI * hy * cos(a);
		return;
	}
	/* Four edges of a quarter of t each, counter-clockwise from (+, +). */
	static const double from[4][2] = { { 1, 1 }, { -1, 1 }, { -1, -1 }, { 1, -1 } };
	static const double dir[4][2] = { { -2, 0 }, { 0, -2 }, { 2, 0 }, { 0, 2 } };
	int e = (int)(4.0 * t);
	if (e > 3)
		e = 3;
	double f = 4.0 * t - e;
	p[0] = ap->offset[0] + hx * (from[e][0] + f * dir[e][0]);
	p[1] = ap->offset[1] + hy * (from[e][1] + f * dir[e][1]);
	dp[0] = 4.0 * hx * dir[e][0];
	dp[1] = 4.0 * hy * dir[e][1];
}

/* Squared distance from the origin along the boundary, maximized by
 * sampling and golden-section refinement of the best sample's bracket. */
static double boundary_r2(const struct asph_aperture *ap, double t)
{
	double p[2], dp[2];

	aperture_boundary(ap, t, p, dp);
	return p[0] * p[0] + p[1] * p[1];
}

double aperture_max_radius(const struct asph_aperture *ap)
{
	double hx = 0.5 * ap->width, hy = 0.5 * ap->height;

	if (ap->shape == ASPH_APERTURE_RECTANGULAR)
		return hypot(fabs(ap->offset[0]) + hx, fabs(ap->offset[1]) + hy);
	if (ap->shape == ASPH_APERTURE_CIRCULAR || hx == hy)
		return hypot(ap->offset[0], ap->offset[1]) + hx;
	const int n = 1024;
	double best = -1, t_best = 0;
	for (int i = 0; i < n; i++) {
		double v = boundary_r2(ap, (double)i / n);
		if (v > best) {
			best = v;
			t_best = (double)i / n;
		}
	}
	double lo = t_best - 1.0 / n, hi = t_best + 1.0 / n;
	const double g = 0.5 * (sqrt(5.0) - 1.0);
	for (int it = 0; it < 80; it++) {
		double a = hi - g * (hi - lo), b = lo + g * (hi - lo);
		if (boundary_r2(ap, a) > boundary_r2(ap, b))
			hi = b;
		else
			lo = a;
	}
	return sqrt(fmax(best, boundary_r2(ap, 0.5 * (lo + hi))));
}

void aperture_map(const struct asph_aperture *ap, double s, double t, double xy[2],
		  double *jac)
{
	double hx = 0.5 * ap->width, hy = 0.5 * ap->height;

	if (ap->shape == ASPH_APERTURE_RECTANGULAR) {
		xy[0] = ap->offset[0] + hx * (2.0 * s - 1.0);
		xy[1] = ap->offset[1] + hy * (2.0 * t - 1.0);
		*jac = 4.0 * hx * hy;
		return;
	}
	double a = 2.0 * M_PI * t;
	xy[0] = ap->offset[0] + hx * s * cos(a);
	xy[1] = ap->offset[1] + hy * s * sin(a);
	*jac = 2.0 * M_PI * hx * hy * s;
}

int aperture_check(const struct asph_prescription *p, struct asph_error *err)
{
	const struct asph_aperture *ap = &p->aperture;

	if (ap->shape == ASPH_APERTURE_FROM_DIAMETER) {
		if (!(p->aperture_diameter > 0) || !isfinite(p->aperture_diameter))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture_diameter",
						 "aperture_diameter (or aperture) must give a positive size in mm");
		return 0;
	}
	if ((unsigned)ap->shape > ASPH_APERTURE_ELLIPTICAL)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture.shape",
					 "unknown aperture shape %d", (int)ap->shape);
	if (p->aperture_diameter != 0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture_diameter",
					 "give either aperture_diameter or aperture, not both");
	if (!(ap->width > 0) || !isfinite(ap->width))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0,
					 ap->shape == ASPH_APERTURE_CIRCULAR ? "aperture.diameter"
									     : "aperture.width",
					 "the aperture's size must be a positive number of mm");
	if (!(ap->height > 0) || !isfinite(ap->height))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture.height",
					 "the aperture's height must be a positive number of mm");
	if (ap->shape == ASPH_APERTURE_CIRCULAR && ap->width != ap->height)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture",
					 "a circular aperture has one diameter");
	if (!isfinite(ap->offset[0]) || !isfinite(ap->offset[1]))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture.offset",
					 "the aperture's offset must be finite");
	return 0;
}

int aperture_is_centred_circle(const struct asph_aperture *ap)
{
	return ap->shape == ASPH_APERTURE_CIRCULAR && ap->width == ap->height &&
	       ap->offset[0] == 0 && ap->offset[1] == 0;
}
