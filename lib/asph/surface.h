/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_SURFACE_H
#define ASPH_SURFACE_H

#include <stddef.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The nominal surface of a rotationally symmetric lens, z = Z(r).
 *
 * Every surface type answers through the same functions (sag and its first
 * two radial derivatives, normal, meridian arc length, area), so that plans,
 * quality metrics and fitting never look at the type.
 *
 * Units: mm and radians. The z axis points from the vertex into the part
 * (sag is positive for a convex-up surface with R > 0, as in the paper).
 */

enum asph_surface_type {
	ASPH_SURFACE_EVEN_ASPHERE = 0,
	ASPH_SURFACE_QBFS,          /* Forbes best-fit-sphere Q polynomials */
	ASPH_SURFACE_QCON,          /* conic plus Forbes Q^con polynomials */
	ASPH_SURFACE_ODD_ASPHERE,   /* conic plus all powers r^1 .. r^20 */
};

#define ASPH_SURFACE_MAX_POWER 20
/* Highest Q polynomial order m (a_0 .. a_30). */
#define ASPH_SURFACE_MAX_Q 30

/*
 * A prescription as the user wrote it; validated by asph_surface_alloc().
 * docs/prescriptions.md gives each type's formula and sign conventions:
 *   even/odd asphere: conic(R, k) + sum A_i r^i
 *   Qbfs: sphere(R) + u^2 (1 - u^2) / sqrt(1 - r^2/R^2) sum a_m Q_m^bfs(u^2)
 *   Qcon: conic(R, k) + u^4 sum a_m Q_m^con(u^2),   u = r / norm_radius
 */
struct asph_prescription {
	enum asph_surface_type type;
	char name[64];          /* preset name or file stem, for display */
	double R;               /* vertex radius of curvature, mm; != 0 */
	double k;               /* conic constant */
	/* A[i] multiplies r^i (mm^(1-i)); the even asphere uses i = 2,4,..,20,
	 * the odd asphere i = 1..20; 0 for the Q types. */
	double A[ASPH_SURFACE_MAX_POWER + 1];
	double aperture_diameter; /* mm, > 0 */
	/* Q types only (0 otherwise): the normalization radius rho_max (mm,
	 * > 0) and the coefficients a_m (mm) of Q_m, m = 0..ASPH_SURFACE_MAX_Q. */
	double norm_radius;
	double Q[ASPH_SURFACE_MAX_Q + 1];
};

struct asph_surface;

/* The checks asph_surface_alloc() makes, without building anything. */
int asph_prescription_check(const struct asph_prescription *p,
			    struct asph_error *err);

/*
 * Validates p and builds the surface with its arc-length and area tables.
 * Refused (-EINVAL, err names the field and, where it applies, the radius):
 * R = 0, a non-finite value, an aperture that is missing or not positive, a
 * conic square root that goes negative (or reaches zero) inside the aperture.
 */
int asph_surface_alloc(const struct asph_prescription *p,
		       struct asph_surface **out, struct asph_error *err);
void asph_surface_free(struct asph_surface *s);

const struct asph_prescription *
asph_surface_prescription(const struct asph_surface *s);
const char *asph_surface_type_name(enum asph_surface_type type);

/* Parses a type name ("even_asphere", "qbfs", "qcon", "odd_asphere");
 * -EINVAL if unknown. */
int asph_surface_type_from_name(const char *name, enum asph_surface_type *out);

/* Whether the type has a free conic constant k (all but Qbfs, whose base
 * is a sphere). */
int asph_surface_type_has_conic(enum asph_surface_type type);

/* Radius of the clear aperture a = aperture_diameter / 2. */
double asph_surface_aperture_radius(const struct asph_surface *s);

/* Z(r). Defined for 0 <= r while the conic root stays real; NaN past that. */
double asph_surface_sag(const struct asph_surface *s, double r);

/* d[0] = Z(r), d[1] = Z'(r), d[2] = Z''(r), all analytic. */
void asph_surface_sag_derivs(const struct asph_surface *s, double r,
			     double d[3]);

/* Unit normal at (x, y, Z(r)), oriented with n[2] > 0:
 * (-Z' x/r, -Z' y/r, 1) / sqrt(1 + Z'^2). */
void asph_surface_normal(const struct asph_surface *s, double x, double y,
			 double n[3]);

/* Meridian arc length s(r) = int_0^r sqrt(1 + Z'(t)^2) dt, and its inverse.
 * Computed once by composite Gauss-Legendre quadrature, then interpolated
 * (piecewise Chebyshev) to a relative accuracy of 1e-14 or better, so each
 * evaluation, forward or inverse, costs about as much as one sag. */
double asph_surface_arc_length(const struct asph_surface *s, double r);
double asph_surface_radius_at_arc_length(const struct asph_surface *s,
					 double arc);

/* Surface area inside radius r: 2 pi int_0^r t sqrt(1 + Z'(t)^2) dt,
 * and its inverse. */
double asph_surface_area(const struct asph_surface *s, double r);
double asph_surface_radius_at_area(const struct asph_surface *s, double area);

/* Largest |Z'| over [0, a]; *r_at (if not NULL) gets where it occurs. */
double asph_surface_max_slope(const struct asph_surface *s, double *r_at);

/* gamma = area inside the aperture / (pi a^2): the paper's Eq. (10). */
double asph_surface_gamma(const struct asph_surface *s);

#ifdef __cplusplus
}
#endif

#endif
