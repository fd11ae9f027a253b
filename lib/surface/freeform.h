/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The freeform surface types as graphs z = S(x, y): their validity checks
 * and their evaluation with gradient and Hessian, all analytic. Internal
 * to lib/surface (and its tests).
 */
#ifndef ASPH_FREEFORM_H
#define ASPH_FREEFORM_H

#include <gsl/gsl_integration.h>

#include "asph/error.h"
#include "asph/surface.h"
#include "qpoly.h"

/* A polynomial sum c[i][j] u^i v^j, i + j <= deg (deg -1: zero). */
struct bipoly {
	int deg;
	double c[ASPH_SURFACE_XY_MAX_DEGREE + 1][ASPH_SURFACE_XY_MAX_DEGREE + 1];
};

/* Zernike terms as sum_m {Re, Im}(u + i v)^m c[m][cos 0, sin 1](X),
 * X = u^2 + v^2, the c polynomials of degree deg[m]. */
struct zseries {
	int m_max;
	int deg[ASPH_SURFACE_XY_MAX_DEGREE + 1];
	double c[ASPH_SURFACE_XY_MAX_DEGREE + 1][2][ASPH_SURFACE_XY_MAX_DEGREE / 2 + 1];
};

/* Adds w Z_j (Noll, over the unit disk). j in 1 .. ASPH_SURFACE_MAX_ZERNIKE. */
void zseries_add(struct zseries *z, int j, double w);

struct freeform {
	enum asph_surface_type type;
	double c, K;              /* base conic (sphere for q2d; y-z curve of a toroid) */
	double cx, cy, Kx, Ky;    /* biconic */
	double cr;                /* toroid: 1 / R_rotation */
	double A[ASPH_SURFACE_MAX_POWER + 1]; /* even powers of r (of y for a toroid) */
	int max_power;
	double inv_norm;          /* 1 / norm_radius */
	double decenter[2];       /* zernike_sag */
	struct bipoly poly;       /* xy_polynomial */
	struct zseries zern;      /* zernike_sag; a toroid's optional terms */
	int has_zernike;
	/* q2d */
	struct qbfs_coef qbfs;
	int n0;                   /* m = 0 terms */
	double q0[ASPH_SURFACE_MAX_Q + 1];
	int m_max;
	int count[ASPH_SURFACE_Q2D_MAX_M];  /* terms n < count for m - 1 */
	struct q2d_coef q2d[ASPH_SURFACE_Q2D_MAX_M];
	double qa[ASPH_SURFACE_Q2D_MAX_M][ASPH_SURFACE_Q2D_MAX_N + 1];
	double qb[ASPH_SURFACE_Q2D_MAX_M][ASPH_SURFACE_Q2D_MAX_N + 1];
};

/* A radius of curvature: finite and non-zero, or infinite (flat); never
 * NaN. field names it in err. */
int radius_check(double R, const char *field, struct asph_error *err);

/* The checks of a freeform prescription (the fields its type uses and
 * leaves alone, the roots of its conics over the aperture); err names the
 * field, and type the type (asph_surface_type_name()). */
int freeform_check(const struct asph_prescription *p, const char *type, struct asph_error *err);

/* Prepares f for p, which passed freeform_check(). */
void freeform_init(struct freeform *f, const struct asph_prescription *p);

/* S and its derivatives at (x, y); NaN past a conic's root. */
void freeform_eval(const struct freeform *f, double x, double y, struct asph_sag *o);

/* S and its gradient, g = { S, S_x, S_y }: freeform_eval() without the
 * work of the Hessian. */
void freeform_sag_grad(const struct freeform *f, double x, double y, double g[3]);

/* S alone. */
double freeform_sag(const struct freeform *f, double x, double y);

/* A surface as the numerics over an aperture see it: its sag and slopes at
 * (x, y), whichever surface data is. */
struct sag_sampler {
	void (*derivs)(const void *data, double x, double y, struct asph_sag *d);
	const void *data;
};

/* The sag range and steepest slope of s over the aperture, and the area
 * (freeform-extent.c; for the surfaces without the radial tables). */
void extent_over_aperture(const struct sag_sampler *s, const struct asph_aperture *ap,
			  struct asph_surface_extent *e);
double area_over_aperture(const struct sag_sampler *s, const struct asph_aperture *ap,
			  const gsl_integration_glfixed_table *gl);

#endif
