/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_SURFACE_H
#define ASPH_SURFACE_H

#include <stddef.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The nominal surface of a lens: a graph z = S(x, y) over its aperture.
 *
 * Every surface type answers the same functions of (x, y): sag, gradient
 * and Hessian (all analytic), normal, area element, aperture membership and
 * bounds, area. The rotationally symmetric types (asph_surface_is_radial())
 * are z = Z(r), r = sqrt(x^2 + y^2), and answer the (x, y) functions and
 * Z(r) with its radial derivatives through r. Over a centred circular
 * aperture (asph_surface_is_rotational()) they also answer the radial
 * functions of the whole part (meridian arc length, area inside a radius
 * and their inverses) on which the paper's sampling plans rest. Freeform
 * types answer NaN to the radial functions; a rotationally symmetric
 * parent over an off-centre or non-circular aperture (an off-axis
 * segment) answers Z(r) but NaN to the arc length and area functions, and
 * is sampled as the freeforms are.
 *
 * Units: mm and radians. The z axis points from the vertex into the part
 * (sag is positive for a convex-up surface with R > 0, as in the paper).
 */

enum asph_surface_type {
	ASPH_SURFACE_EVEN_ASPHERE = 0,
	ASPH_SURFACE_QBFS,          /* Forbes best-fit-sphere Q polynomials */
	ASPH_SURFACE_QCON,          /* conic plus Forbes Q^con polynomials */
	ASPH_SURFACE_ODD_ASPHERE,   /* conic plus all powers r^1 .. r^20 */
	/* Freeforms: not rotationally symmetric. */
	ASPH_SURFACE_BICONIC,       /* Rx, kx, Ry, ky plus even powers of r */
	ASPH_SURFACE_TOROIDAL,      /* y-z conic asphere rotated about an axis */
	ASPH_SURFACE_XY_POLYNOMIAL, /* conic plus sum c_ij (x/rho)^i (y/rho)^j */
	ASPH_SURFACE_ZERNIKE_SAG,   /* conic plus powers of r plus Zernike terms */
	ASPH_SURFACE_Q2D,           /* Forbes freeform Q polynomials */
};

#define ASPH_SURFACE_MAX_POWER 20
/* Highest Q polynomial order m (a_0 .. a_30). */
#define ASPH_SURFACE_MAX_Q 30
/* xy_polynomial: highest total degree i + j, and the number of monomials
 * x^i y^j with 0 <= i + j <= 20 (the constant, index 0, is not allowed). */
#define ASPH_SURFACE_XY_MAX_DEGREE 20
#define ASPH_SURFACE_XY_TERMS 231
/* zernike_sag: Noll indices 1 .. 231 (radial order 20). */
#define ASPH_SURFACE_MAX_ZERNIKE 231
/* q2d: azimuthal orders m = 1 .. 20 and radial orders n = 0 .. 20 of the
 * a_n^m (cos) and b_n^m (sin) terms; m = 0 is the Qbfs part in Q[]. */
#define ASPH_SURFACE_Q2D_MAX_M 20
#define ASPH_SURFACE_Q2D_MAX_N 20

/* Index of the monomial x^i y^j in asph_prescription.C: the monomials come
 * by total degree, and within a degree by falling power of x (x, y, x^2,
 * x y, y^2, x^3, ...), so that index t is OpticStudio's extended polynomial
 * term t. */
static inline int asph_xy_index(int i, int j)
{
	return (i + j) * (i + j + 1) / 2 + j;
}

/*
 * The clear aperture, in the part's own x-y frame. A shape of 0 means the
 * prescription gives aperture_diameter (a centred circle); the other shapes
 * give any type a circle, a rectangle or an ellipse, off-centre when offset
 * is not 0 (an off-axis segment of a rotationally symmetric parent).
 * width and height are full sizes along x and y (a circle's diameter is
 * both); offset moves the centre.
 */
enum asph_aperture_shape {
	ASPH_APERTURE_FROM_DIAMETER = 0,
	ASPH_APERTURE_CIRCULAR,
	ASPH_APERTURE_RECTANGULAR,
	ASPH_APERTURE_ELLIPTICAL,
};

struct asph_aperture {
	enum asph_aperture_shape shape;
	double width, height;     /* mm, > 0 */
	double offset[2];         /* centre, mm */
};

/*
 * A prescription as the user wrote it; validated by asph_surface_alloc().
 * docs/prescriptions.md gives each type's formula and sign conventions:
 *   even/odd asphere: conic(R, k) + sum A_i r^i
 *   Qbfs: sphere(R) + u^2 (1 - u^2) / sqrt(1 - r^2/R^2) sum a_m Q_m^bfs(u^2)
 *   Qcon: conic(R, k) + u^4 sum a_m Q_m^con(u^2),   u = r / norm_radius
 *   biconic: (cx x^2 + cy y^2) / (1 + sqrt(1 - (1+kx) cx^2 x^2
 *            - (1+ky) cy^2 y^2)) + sum A_i r^i,   cx = 1/Rx, cy = 1/Ry
 *   toroidal: the y-z curve conic(R, k)(y) + sum A_i y^i rotated about
 *            the axis parallel to y at z = R_rotation, plus optional
 *            Zernike terms sum Z_j Zernike_j(r / norm_radius, theta)
 *   xy_polynomial: conic(R, k) + sum C_ij (x/rho)^i (y/rho)^j
 *   zernike_sag: conic(R, k) + sum A_i r^i + sum Z_j Zernike_j
 *   q2d: sphere(R) + [u^2 (1 - u^2) sum a_n^0 Q_n^0(u^2) + sum_m u^m
 *        sum_n (a_n^m cos m theta + b_n^m sin m theta) Q_n^m(u^2)]
 *        / sqrt(1 - r^2/R^2)
 * Qbfs with a conic (k != 0) measures its departure along the normal of
 * the base conic: the factor 1 / sqrt(1 - c^2 r^2) becomes
 * sqrt((1 - k c^2 r^2) / (1 - (1 + k) c^2 r^2)), as OpticStudio's Q-type
 * asphere has it. Every type with a base curvature (R, and biconic's Rx,
 * Ry) takes R = INFINITY for a flat base (curvature 0).
 */
struct asph_prescription {
	enum asph_surface_type type;
	char name[64];          /* preset name or file stem, for display */
	/* free text kept with the prescription, e.g. what an import converted */
	char note[256];
	double R;               /* vertex radius of curvature, mm; != 0;
				   INFINITY (either sign) for a flat base */
	double k;               /* conic constant */
	/* A[i] multiplies r^i (mm^(1-i)); the even asphere uses i = 2,4,..,20,
	 * the odd asphere i = 1..20; 0 for the Q types. */
	double A[ASPH_SURFACE_MAX_POWER + 1];
	double aperture_diameter; /* mm, > 0 */
	/* Q types only (0 otherwise): the normalization radius rho_max (mm,
	 * > 0) and the coefficients a_m (mm) of Q_m, m = 0..ASPH_SURFACE_MAX_Q. */
	double norm_radius;
	double Q[ASPH_SURFACE_MAX_Q + 1];

	/* Freeform types (0 for the others; docs/prescriptions.md):
	 * biconic: radii (mm; INFINITY for flat) and conic constants along x
	 * and y, plus the even powers A[2..20] of r. */
	double Rx, Ry, kx, ky;
	/* toroidal: the y-z curve is R, k and the even powers A[i] of y; it is
	 * rotated about an axis parallel to y at z = R_rotation (mm; INFINITY
	 * for a cylinder). */
	double R_rotation;
	/* xy_polynomial: C[asph_xy_index(i, j)] (mm) multiplies
	 * (x/norm_radius)^i (y/norm_radius)^j; the base is the conic R, k. */
	double C[ASPH_SURFACE_XY_TERMS];
	/* zernike_sag: Zernike[j - 1] (mm) multiplies Noll's Z_j(rho, theta),
	 * rho = |(x, y) - zernike_decenter| / norm_radius; the base is the
	 * conic R, k plus the even powers A[i] of r. A toroidal surface may
	 * add the same terms, centred (zernike_decenter 0). */
	double Zernike[ASPH_SURFACE_MAX_ZERNIKE];
	double zernike_decenter[2];
	/* q2d: Forbes' a_n^m (cos m theta) and b_n^m (sin m theta), mm, at
	 * [m - 1][n], over the best-fit sphere R; the m = 0 terms are Q[]. */
	double q2d_a[ASPH_SURFACE_Q2D_MAX_M][ASPH_SURFACE_Q2D_MAX_N + 1];
	double q2d_b[ASPH_SURFACE_Q2D_MAX_M][ASPH_SURFACE_Q2D_MAX_N + 1];
	/* A non-circular or off-centre aperture, with aperture_diameter 0
	 * (shape 0: aperture_diameter gives a centred circle). */
	struct asph_aperture aperture;
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

/* Parses a type name ("even_asphere", "qbfs", "qcon", "odd_asphere",
 * "biconic", "toroidal", "xy_polynomial", "zernike_sag", "q2d");
 * -EINVAL if unknown. */
int asph_surface_type_from_name(const char *name, enum asph_surface_type *out);

/* Whether the type has a single free conic constant k: the even and odd
 * aspheres, Qcon, xy_polynomial, zernike_sag and toroidal (not Qbfs and
 * q2d, whose base is a sphere, nor biconic, which has kx and ky). */
int asph_surface_type_has_conic(enum asph_surface_type type);

/* Whether surfaces of the type are rotationally symmetric about z. */
int asph_surface_type_is_rotational(enum asph_surface_type type);

/* Whether the sag is a function Z(r) of the distance from the axis alone
 * (a rotationally symmetric type), whatever the aperture. */
int asph_surface_is_radial(const struct asph_surface *s);

/* Whether the part is rotationally symmetric: Z(r) over a circular
 * aperture centred on the axis, so that the radial functions below
 * describe all of it. */
int asph_surface_is_rotational(const struct asph_surface *s);

/* ---- the graph z = S(x, y): every type ---------------------------------- */

/* S and its first and second partial derivatives at one point. */
struct asph_sag {
	double z;               /* mm */
	double zx, zy;          /* dS/dx, dS/dy */
	double zxx, zxy, zyy;   /* 1/mm */
};

/* S(x, y); NaN where the surface is not defined (past a conic's root). */
double asph_surface_sag_xy(const struct asph_surface *s, double x, double y);

/* S, its gradient and its Hessian, all analytic. A rotationally symmetric
 * surface gives them from Z, Z', Z'' at r (at r = 0 the Hessian is
 * Z''(0) I; an odd asphere with A1 != 0 has a cone point there). */
void asph_surface_derivs_xy(const struct asph_surface *s, double x, double y,
			    struct asph_sag *out);

/* S and its gradient, g = { S, S_x, S_y }: asph_surface_derivs_xy()
 * without the work of the Hessian, for the closest point and anything
 * else that needs no curvature. */
void asph_surface_sag_grad_xy(const struct asph_surface *s, double x, double y,
			      double g[3]);

/* Unit normal at (x, y, S(x, y)), oriented with n[2] > 0:
 * (-S_x, -S_y, 1) / sqrt(1 + S_x^2 + S_y^2). */
void asph_surface_normal(const struct asph_surface *s, double x, double y,
			 double n[3]);

/* The area element sqrt(1 + S_x^2 + S_y^2): surface area per unit of
 * projected area at (x, y). */
double asph_surface_area_element(const struct asph_surface *s, double x,
				 double y);

/* The clear aperture with its shape resolved (never FROM_DIAMETER). */
void asph_surface_aperture(const struct asph_surface *s,
			   struct asph_aperture *out);

/* Whether (x, y) lies in the aperture grown by tol mm along its outward
 * normal (a circle's radius, a rectangle's half sizes, an ellipse's
 * semi-axes each grow by tol). A negative tol shrinks the aperture the same
 * way (an inset: for a circle or a rectangle, the points at least -tol from
 * the edge); while it is more than minus the smallest half size. */
int asph_surface_contains(const struct asph_surface *s, double x, double y,
			  double tol);

/* The aperture's edge as a closed curve of t in [0, 1): the point p and
 * dp = dp/dt. Counter-clockwise seen from +z. A circle or an ellipse is
 * (centre + (w/2 cos 2 pi t, h/2 sin 2 pi t)); a rectangle is traced side
 * by side from its (+x, +y) corner, with its corners at t = 0, 1/4, 1/2,
 * 3/4 and t linear along each side. */
void asph_surface_aperture_edge(const struct asph_surface *s, double t,
				double p[2], double dp[2]);

/* The aperture's bounding box: box = { x_min, x_max, y_min, y_max }, mm. */
void asph_surface_bounds(const struct asph_surface *s, double box[4]);

/* Radius of the clear aperture a = aperture_diameter / 2; for a
 * non-circular or off-centre aperture, the largest distance of an aperture
 * point from the z axis (the radius of the smallest centred disk that holds
 * the aperture). */
double asph_surface_aperture_radius(const struct asph_surface *s);

/* The smallest disk centred at the aperture's centre that holds the
 * aperture: the domain of the Zernike terms of form errors and residuals
 * (for a centred circle, the aperture itself). */
void asph_surface_aperture_disk(const struct asph_surface *s, double centre[2],
				double *radius);

/* Area of the aperture in the x-y plane, mm^2. */
double asph_surface_projected_area(const struct asph_surface *s);

/* Surface area over the whole aperture, mm^2: the integral of the area
 * element (for a rotationally symmetric surface, the integral that
 * asph_surface_area(s, a) interpolates). */
double asph_surface_total_area(const struct asph_surface *s);

/* What the surface spans over its aperture, computed when it was built:
 * the lowest and highest sag, the steepest slope |grad S| and where each
 * occurs. The values are found by sampling refined by Newton's method
 * (exact to rounding at interior extrema, to 1e-9 of the aperture size on
 * its edge). */
struct asph_surface_extent {
	double sag_min, sag_max;             /* mm */
	double sag_min_at[2], sag_max_at[2]; /* (x, y), mm */
	double max_slope;                    /* |grad S| */
	double max_slope_at[2];
};
void asph_surface_extent(const struct asph_surface *s,
			 struct asph_surface_extent *out);

/* ---- rotationally symmetric types: Z(r) ------------------------------- */

/* Z(r). Defined for 0 <= r while the conic root stays real; NaN past that
 * and for freeform types (asph_surface_is_radial() is 0). */
double asph_surface_sag(const struct asph_surface *s, double r);

/* d[0] = Z(r), d[1] = Z'(r), d[2] = Z''(r), all analytic (NaN for freeform
 * types). */
void asph_surface_sag_derivs(const struct asph_surface *s, double r,
			     double d[3]);

/* Meridian arc length s(r) = int_0^r sqrt(1 + Z'(t)^2) dt, and its inverse
 * (asph_surface_is_rotational(); NaN otherwise).
 * Computed once by composite Gauss-Legendre quadrature, then interpolated
 * (piecewise Chebyshev) to a relative accuracy of 1e-14 or better, so each
 * evaluation, forward or inverse, costs about as much as one sag. */
double asph_surface_arc_length(const struct asph_surface *s, double r);
double asph_surface_radius_at_arc_length(const struct asph_surface *s,
					 double arc);

/* Surface area inside radius r: 2 pi int_0^r t sqrt(1 + Z'(t)^2) dt,
 * and its inverse (asph_surface_is_rotational(); NaN otherwise). */
double asph_surface_area(const struct asph_surface *s, double r);
double asph_surface_radius_at_area(const struct asph_surface *s, double area);

/* Largest |Z'| over [0, a]; *r_at (if not NULL) gets where it occurs. For
 * a freeform or an off-axis segment, the largest |grad S| over the
 * aperture and the distance from the axis of where it occurs
 * (asph_surface_extent() has the point). */
double asph_surface_max_slope(const struct asph_surface *s, double *r_at);

/* gamma = area inside the aperture / (pi a^2): the paper's Eq. (10); for
 * any aperture, the surface area over the projected area. */
double asph_surface_gamma(const struct asph_surface *s);

#ifdef __cplusplus
}
#endif

#endif
