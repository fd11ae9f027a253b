/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Incremental insertion into the half-edge mesh (see delaunay-internal.h).
 *
 * Points arrive sorted by distance from the sweep centre c, so almost every
 * new point lies outside the current boundary.
 *
 * Star mode (c strictly inside the seed triangle, the usual case): the
 * boundary is kept star-shaped about c, every boundary edge having c
 * strictly on its left. A new point p is joined to the boundary edge a->b
 * whose angular sector about c holds it; nothing else of the mesh lies in
 * that sector beyond a->b, so the triangle (a, p, b) overlaps nothing.
 * Then the reflex boundary vertices next to p whose angle is below 90
 * degrees are filled with a triangle (a reflex vertex v of a star polygon
 * always can be: the triangle (prev, v, next) lies in the sector of v's two
 * edges, outside the polygon, and c stays left of prev->next). The boundary
 * thus follows the points closely and a new point meets short edges only,
 * whatever the layout (rings, spirals, grids). mesh_finish() fills the
 * remaining reflex vertices, which leaves the convex hull.
 *
 * Convex mode (fallback when no double lies strictly inside the seed
 * triangle): the boundary is the convex hull; p is joined to every hull
 * edge it sees.
 *
 * A point that is not outside the boundary (ties or rounding in the sort
 * key, points nearer to c than the seed, duplicates) is located by a walk
 * and splits its triangle or edge. Every new or changed triangle has its
 * edges legalized by Lawson flips with the exact in-circle test, so the end
 * result has every interior edge locally Delaunay: it is a Delaunay
 * triangulation of the convex hull, whatever the order of insertion.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "delaunay-internal.h"
#include "predicates.h"

static inline const double *pt(const struct asph_delaunay *w, uint32_t v)
{
	return w->xy + 2 * (size_t)v;
}

/* Monotone in the angle of (dx, dy) about the centre, in [0, 1]. */
static size_t hash_key(const struct asph_delaunay *w, const double *p)
{
	double dx = p[0] - w->cx, dy = p[1] - w->cy;
	double s = fabs(dx) + fabs(dy);
	double r = s > 0 ? dx / s : 0.0;
	double a = (dy > 0 ? 3.0 - r : 1.0 + r) * 0.25;
	size_t k = (size_t)(a * (double)w->hash_size);

	return k < w->hash_size ? k : w->hash_size - 1;
}

static inline void hash_put(struct asph_delaunay *w, uint32_t v)
{
	w->hash[hash_key(w, pt(w, v))] = v;
}

/* Links half-edges a and b as twins; a NONE b makes a a hull edge. */
static inline void link(struct asph_delaunay *w, uint32_t a, uint32_t b)
{
	w->adj[a] = b;
	if (b != NONE)
		w->adj[b] = a;
	else
		w->hull_tri[w->tri[a]] = a;
}

static uint32_t new_triangle(struct asph_delaunay *w, uint32_t a, uint32_t b,
			     uint32_t c)
{
	uint32_t h = (uint32_t)(3 * w->n_tri++);

	w->tri[h] = a;
	w->tri[h + 1] = b;
	w->tri[h + 2] = c;
	return h;
}

void mesh_init(struct asph_delaunay *w, int star)
{
	w->n_tri = 0;
	w->star = star;
	w->n_hull = 3;
	w->stack_failed = 0;
	new_triangle(w, 0, 1, 2);
	for (uint32_t v = 0; v < 3; v++) {
		w->adj[v] = NONE;
		w->hull_next[v] = (v + 1) % 3;
		w->hull_prev[v] = (v + 2) % 3;
		w->hull_tri[v] = v;
	}
	for (size_t k = 0; k < w->hash_size; k++)
		w->hash[k] = NONE;
	for (uint32_t v = 0; v < 3; v++)
		hash_put(w, v);
	w->hull_start = 0;
}

static void push(struct asph_delaunay *w, size_t *top, uint32_t h)
{
	if (*top == w->stack_cap) {
		/* stack_cap starts at 32 (asph_delaunay_alloc), so cap > 0. */
		size_t cap = 2 * w->stack_cap;
		uint32_t *st = realloc(w->stack, cap * sizeof(*st)); // NOLINT(clang-analyzer-optin.portability.UnixAPI)
		if (!st) {
			w->stack_failed = -ENOMEM;
			return;
		}
		w->stack = st;
		w->stack_cap = cap;
	}
	w->stack[(*top)++] = h;
}

/*
 * Lawson flips: a stacked edge whose far vertex is inside the circle of the
 * near triangle is flipped, and the edges of the two new triangles are
 * checked in turn. With `all` unset every stacked edge lies opposite the
 * vertex just inserted, and only the two edges facing it are rechecked
 * (the edges at a new vertex are Delaunay, the classic insertion lemma);
 * with `all` set the four outer edges are.
 */
static void legalize(struct asph_delaunay *w, size_t top, int all)
{
	uint32_t *tri = w->tri, *adj = w->adj;

	while (top > 0) {
		uint32_t e = w->stack[--top];
		uint32_t o = adj[e];

		if (o == NONE)
			continue;
		uint32_t e1 = he_next(e), e2 = he_prev(e);
		uint32_t o1 = he_next(o), o2 = he_prev(o);
		uint32_t a = tri[e], b = tri[e1], p = tri[e2], q = tri[o2];

		if (incircle(pt(w, a), pt(w, b), pt(w, p), pt(w, q)) <= 0)
			continue;
		/* (a, b, p) + (b, a, q) -> (p, a, q) + (p, q, b); the half-edges
		 * p->a and q->b keep their slots. */
		uint32_t across_aq = adj[o1], across_bp = adj[e1];

		tri[e1] = q;
		tri[o1] = p;
		link(w, e, across_aq);
		link(w, o, across_bp);
		link(w, e1, o1);
		push(w, &top, e);
		push(w, &top, o2);
		if (all) {
			push(w, &top, e2);
			push(w, &top, o);
		}
	}
}

/* A hull vertex near p in angle, from the hash. */
static uint32_t hull_vertex_near(const struct asph_delaunay *w, const double *p)
{
	size_t k = hash_key(w, p);

	for (size_t j = 0; j < w->hash_size; j++) {
		uint32_t v = w->hash[(k + j) % w->hash_size];
		if (v != NONE && w->hull_next[v] != NONE)
			return v;
	}
	return w->hull_start;
}

static inline int sees(const struct asph_delaunay *w, uint32_t a, uint32_t b,
		       const double *p)
{
	return orient2d(pt(w, a), pt(w, b), p) < 0;
}

/* A hull vertex whose outgoing hull edge p sees, or NONE. */
static uint32_t find_visible(const struct asph_delaunay *w, uint32_t start,
			     const double *p)
{
	uint32_t e = w->hull_prev[start];
	uint32_t first = e;

	while (!sees(w, e, w->hull_next[e], p)) {
		e = w->hull_next[e];
		if (e == first)
			return NONE;
	}
	return e;
}

/* Joins p (outside the hull) to the chain of hull edges it sees, one of
 * which starts at e. */
static void add_outside(struct asph_delaunay *w, uint32_t p, uint32_t e)
{
	const double *pp = pt(w, p);
	size_t top = 0;

	while (sees(w, w->hull_prev[e], e, pp))
		e = w->hull_prev[e];
	uint32_t first = e, prev_h = NONE;
	do {
		uint32_t n = w->hull_next[e];
		uint32_t h = new_triangle(w, e, p, n);

		link(w, h + 2, w->hull_tri[e]);
		link(w, h, prev_h);
		prev_h = h + 1;
		push(w, &top, h + 2);
		if (e != first)
			w->hull_next[e] = NONE;
		e = n;
	} while (sees(w, e, w->hull_next[e], pp));
	link(w, prev_h, NONE);
	w->hull_next[first] = p;
	w->hull_prev[p] = first;
	w->hull_next[p] = e;
	w->hull_prev[e] = p;
	hash_put(w, p);
	hash_put(w, first);
	w->hull_start = p;
	legalize(w, top, w->star);
}

/* Splits triangle t by p inside it. */
static void split_triangle(struct asph_delaunay *w, uint32_t t, uint32_t p)
{
	uint32_t h = 3 * t;
	uint32_t a = w->tri[h], b = w->tri[h + 1], c = w->tri[h + 2];
	uint32_t across_bc = w->adj[h + 1], across_ca = w->adj[h + 2];
	uint32_t g = new_triangle(w, b, c, p);
	uint32_t f = new_triangle(w, c, a, p);
	size_t top = 0;

	w->tri[h + 2] = p;      /* (a, b, p) */
	link(w, g, across_bc);
	link(w, f, across_ca);
	link(w, h + 1, g + 2);  /* b->p / p->b */
	link(w, g + 1, f + 2);  /* c->p / p->c */
	link(w, f + 1, h + 2);  /* a->p / p->a */
	push(w, &top, h);
	push(w, &top, g);
	push(w, &top, f);
	if (w->star) {
		/* the edges at p too: in star mode every changed edge is checked */
		push(w, &top, h + 1);
		push(w, &top, g + 1);
		push(w, &top, f + 1);
	}
	legalize(w, top, w->star);
}

/* Splits the edge h (a->b) by p on it, and its twin if there is one. */
static void split_edge(struct asph_delaunay *w, uint32_t h, uint32_t p)
{
	uint32_t h1 = he_next(h), h2 = he_prev(h), o = w->adj[h];
	uint32_t a = w->tri[h], b = w->tri[h1], c = w->tri[h2];
	uint32_t across_bc = w->adj[h1];
	uint32_t g = new_triangle(w, p, b, c);
	size_t top = 0;

	w->tri[h1] = p;         /* (a, p, c) */
	link(w, g + 1, across_bc);
	link(w, g + 2, h1);
	push(w, &top, h2);
	push(w, &top, g + 1);
	if (o == NONE) {
		link(w, h, NONE);
		link(w, g, NONE);
		w->hull_next[a] = p;
		w->hull_prev[p] = a;
		w->hull_next[p] = b;
		w->hull_prev[b] = p;
		w->n_hull++;
		hash_put(w, p);
	} else {
		uint32_t o1 = he_next(o), o2 = he_prev(o);
		uint32_t d = w->tri[o2];
		uint32_t across_ad = w->adj[o1];
		uint32_t f = new_triangle(w, p, a, d);

		w->tri[o1] = p;         /* (b, p, d) */
		link(w, f + 1, across_ad);
		link(w, f + 2, o1);
		link(w, h, f);
		link(w, g, o);
		push(w, &top, o2);
		push(w, &top, f + 1);
		if (w->star) {
			push(w, &top, h);
			push(w, &top, g);
			push(w, &top, o1);
		}
	}
	if (w->star)
		push(w, &top, h1);
	legalize(w, top, w->star);
}

/* The triangle containing p (closed), by a visibility walk from triangle
 * t; NONE if the walk leaves the mesh or does not end. */
static uint32_t locate(const struct asph_delaunay *w, uint32_t t,
		       const double *p)
{
	unsigned rot = 0;

	for (size_t step = 0; step <= w->n_tri; step++) {
		uint32_t next = t;
		for (unsigned i = 0; i < 3; i++) {
			uint32_t h = 3 * t + (i + rot) % 3;
			if (sees(w, w->tri[h], w->tri[he_next(h)], p)) {
				if (w->adj[h] == NONE)
					return NONE;
				next = w->adj[h] / 3;
				break;
			}
		}
		if (next == t)
			return t;
		t = next;
		rot = (rot + 1) % 3;    /* varying the edge order avoids cycles */
	}
	return NONE;
}

static uint32_t locate_by_scan(const struct asph_delaunay *w, const double *p)
{
	for (uint32_t t = 0; t < w->n_tri; t++) {
		uint32_t h = 3 * t;
		if (!sees(w, w->tri[h], w->tri[h + 1], p) &&
		    !sees(w, w->tri[h + 1], w->tri[h + 2], p) &&
		    !sees(w, w->tri[h + 2], w->tri[h], p))
			return t;
	}
	return NONE;
}

/* p is inside the hull or on it: split what contains it. */
static int insert_inside(struct asph_delaunay *w, uint32_t p, uint32_t near)
{
	const double *pp = pt(w, p);
	uint32_t t = locate(w, w->hull_tri[near] / 3, pp);

	if (t == NONE)
		t = locate_by_scan(w, pp);
	if (t == NONE)
		return -EIO;
	uint32_t on_edge = NONE;
	int zeros = 0;
	for (uint32_t h = 3 * t; h < 3 * t + 3; h++) {
		if (orient2d(pt(w, w->tri[h]), pt(w, w->tri[he_next(h)]), pp) == 0) {
			on_edge = h;
			zeros++;
		}
	}
	if (zeros >= 2)
		return 1;
	if (zeros == 1)
		split_edge(w, on_edge, p);
	else
		split_triangle(w, t, p);
	return 0;
}

static int insert_convex(struct asph_delaunay *w, uint32_t p)
{
	const double *pp = pt(w, p);
	uint32_t near = hull_vertex_near(w, pp);
	uint32_t e = find_visible(w, near, pp);

	if (e == NONE)
		return insert_inside(w, p, near);
	add_outside(w, p, e);
	return 0;
}

/* ---- star mode ---- */

static inline double orient_c(const struct asph_delaunay *w, uint32_t v,
			      const double *p)
{
	const double c[2] = { w->cx, w->cy };

	return orient2d(c, pt(w, v), p);
}

/* The boundary vertex a such that p lies in the sector about c from a
 * (included) to hull_next[a] (excluded), or NONE (p == c, or a walk longer
 * than the boundary). */
static uint32_t find_sector(const struct asph_delaunay *w, uint32_t v,
			    const double *p)
{
	size_t steps = 0, limit = w->n_hull + 2;

	while (orient_c(w, v, p) < 0) {
		v = w->hull_prev[v];
		if (++steps > limit)
			return NONE;
	}
	while (orient_c(w, w->hull_next[v], p) >= 0) {
		v = w->hull_next[v];
		if (++steps > limit)
			return NONE;
	}
	return v;
}

/* Fills the boundary vertex v (reflex): triangle (v, prev, next). */
static void fill_vertex(struct asph_delaunay *w, uint32_t v, size_t *top)
{
	uint32_t a = w->hull_prev[v], b = w->hull_next[v];
	uint32_t h = new_triangle(w, v, a, b);

	link(w, h, w->hull_tri[a]);
	link(w, h + 2, w->hull_tri[v]);
	link(w, h + 1, NONE);
	w->hull_next[a] = b;
	w->hull_prev[b] = a;
	w->hull_next[v] = NONE;
	w->n_hull--;
	if (w->hull_start == v)
		w->hull_start = a;
	push(w, top, h);
	push(w, top, h + 2);
}

static inline int reflex(const struct asph_delaunay *w, uint32_t v)
{
	return orient2d(pt(w, w->hull_prev[v]), pt(w, v), pt(w, w->hull_next[v])) < 0;
}

/* Reflex and sharper than 90 degrees: worth filling now. */
static int basin(const struct asph_delaunay *w, uint32_t v)
{
	const double *a = pt(w, w->hull_prev[v]), *o = pt(w, v);
	const double *b = pt(w, w->hull_next[v]);
	double dot = (a[0] - o[0]) * (b[0] - o[0]) + (a[1] - o[1]) * (b[1] - o[1]);

	return dot > 0 && reflex(w, v);
}

static void add_star(struct asph_delaunay *w, uint32_t p, uint32_t a)
{
	uint32_t b = w->hull_next[a];
	uint32_t h = new_triangle(w, a, p, b);
	size_t top = 0;

	link(w, h + 2, w->hull_tri[a]);
	link(w, h, NONE);
	link(w, h + 1, NONE);
	w->hull_next[a] = p;
	w->hull_prev[p] = a;
	w->hull_next[p] = b;
	w->hull_prev[b] = p;
	w->n_hull++;
	push(w, &top, h + 2);
	while (w->n_hull > 3 && basin(w, w->hull_next[p]))
		fill_vertex(w, w->hull_next[p], &top);
	while (w->n_hull > 3 && basin(w, w->hull_prev[p]))
		fill_vertex(w, w->hull_prev[p], &top);
	hash_put(w, p);
	w->hull_start = p;
	legalize(w, top, 1);
}

static int insert_star(struct asph_delaunay *w, uint32_t p)
{
	const double *pp = pt(w, p);
	uint32_t near = hull_vertex_near(w, pp);
	uint32_t a = find_sector(w, near, pp);

	if (a == NONE || orient2d(pt(w, a), pt(w, w->hull_next[a]), pp) >= 0)
		return insert_inside(w, p, a == NONE ? near : a);
	add_star(w, p, a);
	return 0;
}

int mesh_insert(struct asph_delaunay *w, uint32_t p)
{
	int r = w->star ? insert_star(w, p) : insert_convex(w, p);

	return w->stack_failed ? w->stack_failed : r;
}

/* Fills every reflex boundary vertex; a vertex with a straight angle stays
 * (a point on a hull edge). Backs up one vertex after each fill, so the
 * walk ends after one full turn without a fill. */
int mesh_finish(struct asph_delaunay *w)
{
	uint32_t v = w->hull_start;
	size_t convex_run = 0;

	if (!w->star)
		return 0;
	while (convex_run < w->n_hull) {
		if (w->n_hull > 3 && reflex(w, v)) {
			size_t top = 0;
			uint32_t back = w->hull_prev[v];
			fill_vertex(w, v, &top);
			legalize(w, top, 1);
			if (w->stack_failed)
				return w->stack_failed;
			v = back;
			convex_run = 0;
		} else {
			v = w->hull_next[v];
			convex_run++;
		}
	}
	return 0;
}
