/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_OT_H
#define ASPH_OT_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The optimal transport map of a surface's aperture onto itself that makes
 * area uniform on the surface: T = grad phi, phi convex, carries the
 * uniform measure of the aperture (projected area) to the surface's area,
 * i.e. it solves the Monge-Ampere equation
 *
 *     det D^2 phi(x) = gamma / w(grad phi(x)),   w = sqrt(1 + |grad S|^2),
 *
 * with the second boundary condition grad phi(aperture) = aperture, and
 * gamma = surface area / projected area. For a surface of revolution over a
 * centred circle it is the paper's radial map of Eq. (9).
 *
 * Method (docs/sampling-plans.md, "Freeform surfaces"): damped
 * Newton iterations on a spectral collocation of the equation, as
 * Benamou, Froese and Oberman do on finite differences (J. Comput. Phys.
 * 260 (2014) 107). A circle or an ellipse is the unit disk stretched by its
 * semi-axes, collocated in polar coordinates (Chebyshev in r over the whole
 * diameter, Fourier in theta); the boundary condition is |T| = 1 there. A
 * rectangle is collocated on a Chebyshev tensor grid, where the map keeps
 * each side on itself (a Neumann condition per side). The resolution grows
 * until the Jacobian equation holds to the tolerance between the nodes.
 *
 * The map is decomposed for stepping: asph_ot_map_alloc() sets the problem
 * up, asph_ot_map_iterate() takes one step (a Newton step, or a change of
 * resolution), asph_ot_map_test() says whether it is done.
 */
struct asph_ot_map;

struct asph_ot_options {
	/* Largest |det DT w(T) / gamma - 1| allowed between the collocation
	 * nodes; 0 = 1e-6. */
	double tolerance;
	/* Largest resolution: polar radial nodes (the angles are twice as
	 * many), or Chebyshev points per side of a rectangle; 0 = 28 and 40. */
	int max_nodes;
};

/* The map keeps a pointer to s: free the map first. -EINVAL for a bad
 * option; -ENOMEM. */
int asph_ot_map_alloc(const struct asph_surface *s, const struct asph_ot_options *opts,
		      struct asph_ot_map **out, struct asph_error *err);
void asph_ot_map_free(struct asph_ot_map *m);

/* One step. -ERANGE (err says what was reached) when the largest
 * resolution cannot meet the tolerance or Newton's method fails there. */
int asph_ot_map_iterate(struct asph_ot_map *m, struct asph_error *err);

/* 1 when the map meets the tolerance (and can be applied), else 0. */
int asph_ot_map_test(const struct asph_ot_map *m);

/* alloc, then iterate until test. */
int asph_ot_map_solve(const struct asph_surface *s, const struct asph_ot_options *opts,
		      struct asph_ot_map **out, struct asph_error *err);

/*
 * T(x, y) for a point of the aperture (a little outside is extrapolated);
 * jac (may be NULL) gets DT = { dT1/dx, dT1/dy, dT2/dx, dT2/dy }. From
 * tables of the solution (bicubic, accurate to ~1e-9 of the aperture);
 * O(1) per point.
 */
void asph_ot_map_apply(const struct asph_ot_map *m, double x, double y, double T[2],
		       double jac[4]);

struct asph_ot_map_info {
	int nodes[2];            /* radial x angular, or per side x per side */
	int newton_steps;        /* over all resolutions */
	double residual;         /* largest collocation residual */
	double jacobian_error;   /* largest |det DT w(T) / gamma - 1| between nodes */
	double gamma;            /* the discrete mass ratio (-> surface / projected area) */
};

void asph_ot_map_info(const struct asph_ot_map *m, struct asph_ot_map_info *out);

#ifdef __cplusplus
}
#endif

#endif
