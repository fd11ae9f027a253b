/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The surface model the fit works on, and the closest-point kernel.
 * Internal to lib/fit*.c. */
#ifndef ASPH_FIT_MODEL_H
#define ASPH_FIT_MODEL_H

#include "asph/fit.h"
#include "asph/surface.h"

/*
 * The nominal surface, optionally with its base conic changed:
 *   Z(r) = Z_nominal(r) + conic(r; c, K) - conic(r; c0, K0),
 * conic(r; c, K) = c r^2 / (1 + sqrt(1 - K c^2 r^2)), c = 1/R, K = 1 + k.
 * For an even asphere this is exactly the prescription with R, k replaced;
 * for any surface type it is "the same surface with another base conic".
 */
struct fit_model {
	const struct asph_surface *s;
	int rotational;         /* Z(r): the meridian kernel and the conic change;
				   else a freeform: the (x, y) kernel */
	int centred;            /* the aperture is a disk about the axis; else a
				   point's foot is tested against its shape */
	double a;               /* aperture radius (farthest aperture point) */
	int conic_changed;
	double c0, K0;          /* nominal */
	double c, K;            /* current */
};

void fit_model_init(struct fit_model *m, const struct asph_surface *s);
/* The base conic's curvature c = 1/R (0: a plane) and conic constant. */
void fit_model_set_conic(struct fit_model *m, double c, double k);

/* d[0..2] = Z, Z', Z'' at |r| (Z' for |r|: the caller applies parity). */
void fit_model_derivs(const struct fit_model *m, double r, double d[3]);

/* dZ/dc and dZ/dk of the current conic at |r|. */
void fit_model_conic_partials(const struct fit_model *m, double r,
			      double *dz_dc, double *dz_dk);

/* Foot of q in its meridian plane. r is the signed meridian coordinate
 * along the azimuth of q, i.e. (q_x, q_y) / rho (negative: across the
 * axis; +x when rho = 0). */
struct fit_foot {
	double r;
	double rho;             /* |q_xy| */
	double z;               /* Z(|r|) */
	double slope;           /* dZ/dr at the signed r */
	double dist;            /* signed normal distance */
	int iterations;
};

/* r0: a start for r (the previous foot), or NaN to start from the sag at
 * q's radius. Returns 0, or -EDOM when there is no foot. */
int fit_foot(const struct fit_model *m, const double q[3], double r0,
	     struct fit_foot *f);

/* A point of a freeform surface with the gradient of S there: where the
 * search for a foot stands. nz = 1 / sqrt(1 + |grad S|^2), the unit
 * normal's z component, where known (else NaN). */
struct fit_surface_point {
	double x, y, z;
	double zx, zy;
	double nz;
};
#define FIT_NO_POINT ((struct fit_surface_point){ NAN, NAN, NAN, NAN, NAN, NAN })

/* The fit's tolerance on the foot, mm: fit_foot_xy() with this (times
 * 1 + a) leaves the distance off by less than 1e-13 mm. */
#define FIT_FOOT_TOL 1e-7

/*
 * Foot of q on a freeform, found in (x, y). at: in, the start (the
 * previous foot: with its z and gradient it costs no evaluation; with only
 * x and y finite it is evaluated there; x NaN starts below q); out, the
 * foot, a point of the surface within about tol (mm) of the exact foot.
 * *dist is the signed distance along the normal there. Returns 0, or
 * -EDOM when there is no foot.
 */
int fit_foot_xy(const struct fit_model *m, const double q[3], double tol,
		struct fit_surface_point *at, double *dist, int *iterations);

/* Unit normal at the foot of q, n_z > 0. */
void fit_foot_normal(const struct fit_foot *f, const double q[3], double n[3]);

#endif
