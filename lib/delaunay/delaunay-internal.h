/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The triangulation shared by lib/delaunay.c (API, seeding, ordering) and
 * lib/delaunay-mesh.c (insertion and edge flips). Internal header.
 *
 * Triangles are stored as half-edges: half-edge h belongs to triangle h / 3
 * and runs from vertex tri[h] to tri[next(h)]; adj[h] is the opposite
 * half-edge in the neighbouring triangle, or NONE on the hull. Vertices are
 * numbered in insertion order; ids[] maps them back to the caller's indices.
 * The boundary ("hull") is a counter-clockwise doubly linked list of
 * vertices; hull_tri[v] is the half-edge from v to hull_next[v], and a
 * vertex not on it has hull_next[v] == NONE. During the sweep the boundary
 * is either the convex hull or, in star mode, a polygon star-shaped about
 * the sweep centre; mesh_finish() makes it the convex hull.
 */
#ifndef ASPH_DELAUNAY_INTERNAL_H
#define ASPH_DELAUNAY_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#define NONE UINT32_MAX

struct asph_delaunay {
	size_t max_points;
	size_t n_points;        /* points of the last call (internal order) */
	size_t n_tri;
	int valid;              /* the last call succeeded */
	double *xy;             /* 2 max_points, insertion order */
	uint32_t *ids;          /* caller's index of each vertex */
	uint64_t *sort_a, *sort_b;      /* (key << 32 | index) pairs */
	uint32_t *tri, *adj;    /* 3 max_tri half-edges */
	uint32_t *hull_next, *hull_prev, *hull_tri;
	uint32_t *hash;         /* hull vertices by pseudo-angle about c */
	size_t hash_size, hash_cap;     /* buckets in use, allocated */
	uint32_t hull_start;    /* some vertex on the hull */
	size_t n_hull;          /* vertices on the hull (star mode) */
	uint32_t *stack;        /* half-edges waiting to be legalized */
	size_t stack_cap;
	int stack_failed;       /* -ENOMEM when the stack could not grow */
	int star;               /* the hull is a star polygon about c */
	double cx, cy;          /* centre of the radial sweep */
	unsigned debug_flags;   /* enum delaunay_debug_flags, 0 in use */
};

/* For tests: take the insertion paths that sorting makes rare. */
enum delaunay_debug_flags {
	DELAUNAY_KEEP_ORDER = 1u << 0,  /* insert in input order, unsorted */
	DELAUNAY_CONVEX = 1u << 1,      /* convex mode even when star works */
};

static inline uint32_t he_next(uint32_t h)
{
	return h % 3 == 2 ? h - 2 : h + 1;
}

static inline uint32_t he_prev(uint32_t h)
{
	return h % 3 == 0 ? h + 2 : h - 1;
}

/* Makes the triangle (0, 1, 2) (counter-clockwise) the whole mesh. With
 * star set, c must lie strictly inside it (see delaunay-mesh.c). */
void mesh_init(struct asph_delaunay *w, int star);

/* Inserts vertex p. Returns 0, 1 when p duplicates a vertex (it is left
 * out), -ENOMEM, or -EIO if the mesh is found inconsistent. */
int mesh_insert(struct asph_delaunay *w, uint32_t p);

/* After the last insertion: completes the mesh to the convex hull. */
int mesh_finish(struct asph_delaunay *w);

#endif
