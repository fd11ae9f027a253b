/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The geometry of a clear aperture (circle, rectangle, ellipse, each
 * possibly off-centre): membership, bounds, area, farthest point from the
 * axis, and its boundary as a closed curve. Internal to lib/surface.
 */
#ifndef ASPH_APERTURE_H
#define ASPH_APERTURE_H

#include "asph/error.h"
#include "asph/surface.h"

/* The aperture of p with its shape resolved (a centred circle of
 * aperture_diameter when p gives no shape). */
void aperture_resolve(const struct asph_prescription *p, struct asph_aperture *out);

/* The aperture members of p: aperture_diameter, or an aperture of a known
 * shape with positive finite sizes (a circle's two equal) and a finite
 * offset, never both; err names the member. */
int aperture_check(const struct asph_prescription *p, struct asph_error *err);

/* Whether the aperture is a circle centred on the axis. */
int aperture_is_centred_circle(const struct asph_aperture *ap);

int aperture_contains(const struct asph_aperture *ap, double x, double y, double tol);
void aperture_bounds(const struct asph_aperture *ap, double box[4]);
double aperture_area(const struct asph_aperture *ap);

/* The largest distance of an aperture point from the origin. */
double aperture_max_radius(const struct asph_aperture *ap);

/* The boundary as a closed curve of t in [0, 1): the point and the
 * derivative d/dt of the point. A rectangle is traced edge by edge from
 * its (+x, +y) corner, counter-clockwise (its corners at t = k/4). */
void aperture_boundary(const struct asph_aperture *ap, double t, double p[2],
		       double dp[2]);

/* Maps the unit square [0, 1]^2 onto the aperture: (s, t) -> (x, y), with
 * the Jacobian determinant in *jac. A rectangle maps affinely; a circle or
 * ellipse by polar coordinates (s the radius fraction, t the angle). */
void aperture_map(const struct asph_aperture *ap, double s, double t, double xy[2],
		  double *jac);

#endif
