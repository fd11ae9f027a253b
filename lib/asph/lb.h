/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_LB_H
#define ASPH_LB_H

#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The Laplace-Beltrami map of the paper's section 5.3, Eq. (6): the harmonic
 * map S from the surface domain U (the aperture disk, radius a) onto the
 * computational disk Q of the same radius, with S(x) = x on the rim.
 *
 * For a surface of revolution S is radial, S(x) = rho(|x|) x / |x|, where
 * rho solves (r rho' / w)' = w rho / r, w = sqrt(1 + Z'(r)^2), rho(0) = 0,
 * rho(a) = a. Its regular solution is rho(r) = r exp(-int_r^a (w - 1)/t dt),
 * so rho' = w rho / r > 0: rho is increasing and S is one-to-one. rho is also
 * the radius of the surface's conformal (isothermal) polar chart.
 * docs/laplace-beltrami.md has the derivation.
 *
 * The map is tabulated once (quintic Hermite pieces on uniform grids,
 * relative accuracy ~1e-14); every evaluation afterwards is an O(1) table
 * look-up and one exp().
 */
struct asph_lb_map;

/* The map keeps a pointer to s: free the map before the surface. */
int asph_lb_map_alloc(const struct asph_surface *s, struct asph_lb_map **out,
		      struct asph_error *err);
void asph_lb_map_free(struct asph_lb_map *m);

/* The aperture radius a the map was built for. */
double asph_lb_map_aperture_radius(const struct asph_lb_map *m);

/* S: surface-domain radius r -> computational radius rho(r), 0 <= r <= a
 * (|r| is used; NaN beyond a (1 + 1e-9)). */
double asph_lb_map_rho(const struct asph_lb_map *m, double r);

/* rho'(r) = w(r) rho(r) / r (the limit rho(a)/a exp(...) at r = 0). */
double asph_lb_map_rho_deriv(const struct asph_lb_map *m, double r);

/* T = S^-1: computational radius rho -> surface-domain radius r,
 * 0 <= rho <= a (|rho| is used; NaN beyond a (1 + 1e-9)). */
double asph_lb_map_radius(const struct asph_lb_map *m, double rho);

/*
 * The general finite-element solver of Eq. (6) for a graph surface
 * z = Z(x, y) over a triangulated planar domain: P1 elements, the metric of
 * F(x, y) = (x, y, Z(x, y)) evaluated at each triangle's centroid, the
 * sparse symmetric positive definite system (GSL sparse matrix) solved by
 * Jacobi-preconditioned conjugate gradients to a relative residual 1e-13.
 *
 * xy: 2 n node coordinates; tri: 3 ntri node indices (either orientation).
 * Boundary nodes are the ends of edges that belong to one triangle only;
 * they get the Dirichlet value S(x) = x, so the mesh boundary must lie on
 * the rim of the domain. S_out receives 2 n values (S_1, S_2 per node).
 *
 * Errors: -EINVAL for an index out of range, a degenerate triangle, n or
 * ntri zero; -ENOMEM; -ERANGE when the iterative solver does not reach its
 * tolerance.
 */
typedef void (*asph_lb_gradient_fn)(void *ctx, double x, double y,
				    double grad[2]);

int asph_lb_fem_solve_graph(asph_lb_gradient_fn gradient, void *ctx,
			    const double *xy, size_t n, const uint32_t *tri,
			    size_t ntri, double *S_out, struct asph_error *err);

/*
 * The same with other Dirichlet values: boundary(bctx, x, y, S) gives the
 * value S[2] of the map at a boundary node (x, y); NULL is S(x) = x. The
 * map is harmonic for the surface's metric inside and takes these values on
 * the boundary (a known harmonic map, such as the development of a
 * cylinder onto the plane, is reproduced to the accuracy of P1 elements).
 */
typedef void (*asph_lb_boundary_fn)(void *bctx, double x, double y, double S[2]);

int asph_lb_fem_solve_graph_dirichlet(asph_lb_gradient_fn gradient, void *ctx,
				      asph_lb_boundary_fn boundary, void *bctx,
				      const double *xy, size_t n, const uint32_t *tri,
				      size_t ntri, double *S_out, struct asph_error *err);

/* The same for the rotationally symmetric surface s: grad Z = Z'(r) x / r. */
int asph_lb_fem_solve(const struct asph_surface *s, const double *xy,
		      size_t n, const uint32_t *tri, size_t ntri,
		      double *S_out, struct asph_error *err);

/*
 * The harmonic chart of a freeform: the P1 solution S of Eq. (6) (above)
 * on the Delaunay mesh of the aperture's disk grid at the given pitch (mm),
 * with the aperture's edge fixed, interpolated linearly in its triangles.
 * On a surface of revolution over a centred circle it is the conformal
 * chart rho(r) (x, y) / r scaled by a / rho(a), to O(pitch^2); over another
 * aperture it is harmonic, not conformal (the edge is held in place). The
 * LB plan on a freeform is its inverse; asph_quality_compute() triangulates
 * a freeform plan in it.
 *
 * -EINVAL for a pitch that is not > 0; -ERANGE when the discrete map folds
 * a triangle; -ENOMEM. The chart keeps a pointer to s.
 */
struct asph_lb_chart;

int asph_lb_chart_alloc(const struct asph_surface *s, double pitch,
			struct asph_lb_chart **out, struct asph_error *err);
void asph_lb_chart_free(struct asph_lb_chart *c);

/* S(x, y) into uv; between a curved edge and the mesh, the nearby edge
 * triangle's linear map extended. -ENOENT for a point outside the aperture.
 * Not const: the chart remembers the last triangle, where the next search
 * starts (nearby queries are O(1)). */
int asph_lb_chart_map(struct asph_lb_chart *c, double x, double y, double uv[2]);

#ifdef __cplusplus
}
#endif

#endif
