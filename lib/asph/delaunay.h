/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_DELAUNAY_H
#define ASPH_DELAUNAY_H

#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Delaunay triangulation of points in the plane (sweep-hull with exact
 * orientation and in-circle predicates; see docs/triangulation.md).
 *
 * The workspace holds every array the triangulation needs for up to
 * max_points points, so repeated calls allocate nothing but their output.
 *
 * Degeneracies:
 * - Exact duplicates: only one point of each set of equal points enters the
 *   triangulation (which one is unspecified); the others appear in no
 *   triangle and not on the hull.
 * - Collinear points on the boundary are kept: they are hull vertices with a
 *   straight angle, and every distinct input point is a vertex of some
 *   triangle, so n_triangles = 2 n_distinct - 2 - n_hull.
 * - Four or more cocircular points: any of the valid Delaunay
 *   triangulations is returned (all triangles have an empty circumcircle).
 *
 * Coordinates must be finite with magnitude at most 1e60; the predicates are
 * exact as long as no product underflows, which holds for all coordinates of
 * magnitude above 1e-60 (or zero).
 */
struct asph_delaunay;

/* Largest max_points accepted (indices are 32-bit). */
#define ASPH_DELAUNAY_MAX_POINTS ((size_t)1 << 29)

/* A workspace for up to max_points points. NULL when out of memory (or,
 * with errno = E2BIG, when max_points exceeds ASPH_DELAUNAY_MAX_POINTS). */
struct asph_delaunay *asph_delaunay_alloc(size_t max_points);
void asph_delaunay_free(struct asph_delaunay *w);

/*
 * Triangulates the n points xy[2i], xy[2i+1]. On success *triangles holds
 * 3 *n_triangles point indices (malloc'd, the caller frees it), every
 * triangle counter-clockwise.
 *
 * Errors: -E2BIG when n > max_points of the workspace; -EINVAL when a
 * coordinate is not finite or too large, or when there are fewer than three
 * distinct non-collinear points (no triangle exists); -ENOMEM.
 */
int asph_delaunay_triangulate(struct asph_delaunay *w, const double *xy,
			      size_t n, uint32_t **triangles,
			      size_t *n_triangles, struct asph_error *err);

/*
 * After a successful asph_delaunay_triangulate(), the neighbours of its
 * triangles: (*neighbors)[3t + k] is the triangle across the edge from
 * vertex k to vertex (k + 1) % 3 of triangle t, or UINT32_MAX on the convex
 * hull. 3 n_triangles entries, malloc'd, the caller frees them.
 * -EINVAL when the last triangulation failed or none was made; -ENOMEM.
 */
int asph_delaunay_neighbors(const struct asph_delaunay *w,
			    uint32_t **neighbors, struct asph_error *err);

/*
 * After a successful asph_delaunay_triangulate(), the convex hull of its
 * points as point indices in counter-clockwise order, including points that
 * lie on a hull edge. Malloc'd, the caller frees it. Errors as above.
 */
int asph_delaunay_hull(const struct asph_delaunay *w, uint32_t **hull,
		       size_t *n_hull, struct asph_error *err);

/*
 * Point location in a triangle mesh: any counter-clockwise mesh of the
 * points xy with the adjacency of asph_delaunay_neighbors() (nb[3t + k] the
 * triangle across the edge from vertex k to vertex k + 1, UINT32_MAX on
 * the boundary), Delaunay or not. Walks from triangle *t (a good guess
 * makes it short: the triangle of a neighbouring query) to the triangle
 * that holds q, sets *t to it and bary to q's barycentric coordinates in it
 * (each >= -1e-12). -ENOENT when q is outside the mesh (*t is then a
 * boundary triangle near it).
 */
int asph_mesh_locate(const double *xy, const uint32_t *tri, const uint32_t *nb,
		     size_t ntri, uint32_t *t, const double q[2], double bary[3]);

#ifdef __cplusplus
}
#endif

#endif
