/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The CVT plan: a centroidal Voronoi tessellation restricted to the surface
 * (docs/sampling-plans.md, "cvt"), started from the OT plan.
 *
 * The restricted Voronoi diagram is computed exactly on a fine mesh of the
 * surface, as Yan, Levy, Liu, Sun and Wang do (Comput. Graph. Forum 28
 * (2009) 1445): the Delaunay triangulation of the starting sites in the x-y
 * plane, each triangle split into CVT_SUBDIV^2 and its vertices lifted onto
 * the surface. The starting sites follow the surface's area (OT), so the
 * mesh does too, on the steep flank as at the centre. A flat triangle of the
 * mesh meets a site's cell (the points nearer to it in 3-D than to any
 * other site) in a convex polygon, cut out by the bisector planes; its area,
 * centroid and second moment are exact. Cells and centroids are therefore
 * continuous functions of the sites, and so is the CVT energy
 *
 *     F = sum_i integral over cell i of |x - s_i|^2 dA,
 *
 * whose gradient is 2 m_i (s_i - c_i) (cell mass m_i, centroid c_i). F is
 * minimised over the sites' (x, y) by L-BFGS (Liu, Wang, Levy, Sun, Yan,
 * Lu, Yang, ACM Trans. Graph. 28 (2009) 101), preconditioned so that its
 * plain step is Lloyd's (each site to its cell's centroid, taken back onto
 * the surface to first order). The sites on the aperture's edge stay: they
 * take part in the cells but do not move, so the plan keeps its outline.
 * The order of the sites is the OT plan's (the disk grid's spiral scan
 * order).
 */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "asph/delaunay.h"
#include "asph/plan.h"
#include "plan-aperture.h"
#include "plan-cvt.h"
#include "util-mem.h"

/* Each triangle of the sites' x-y Delaunay mesh is split into this many
 * squared flat triangles of the surface (about 8 per site; splitting into
 * 9 changes q > 0.9 and the IQR of A_i/mean of 900-point plans by at most
 * 0.004 and costs a third more). */
#define CVT_SUBDIV 2
/* At most this many L-BFGS iterations (each with its line search). */
#define CVT_MAX_ITER ASPH_PLAN_CVT_MAX_ITERATIONS
/* Stop when every moving site is within this fraction of the spacing
 * sqrt(area / n) of its cell's centroid. */
#define CVT_TOL 1e-3
/* L-BFGS: the number of past steps kept. */
#define CVT_HISTORY 8
/* The largest polygon a clipped triangle can become: every cut adds at
 * most one vertex, and a cell's piece of a small triangle has few sides. */
#define CVT_POLY_MAX 64

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_delaunay *, asph_delaunay_free)

/* Sites bucketed on a square grid of the x-y plane. */
struct buckets {
	double x0, y0, cell;
	int nx, ny;
	size_t *start, *index;  /* CSR: the sites of bucket b are index[start[b]..start[b+1]) */
};

static void buckets_clear(struct buckets *b)
{
	free(b->start);
	free(b->index);
	memset(b, 0, sizeof(*b));
}

static int bucket_of(const struct buckets *b, double v, double v0, int n)
{
	int k = (int)floor((v - v0) / b->cell);

	return k < 0 ? 0 : k >= n ? n - 1 : k;
}

static size_t bucket_index(const struct buckets *b, const double *q)
{
	return (size_t)bucket_of(b, q[1], b->y0, b->ny) * (size_t)b->nx +
	       (size_t)bucket_of(b, q[0], b->x0, b->nx);
}

static int buckets_fill(struct buckets *b, const double box[4], double cell, const double *xyz,
			size_t n)
{
	buckets_clear(b);
	b->x0 = box[0];
	b->y0 = box[2];
	b->cell = cell;
	b->nx = (int)ceil((box[1] - box[0]) / cell) + 1;
	b->ny = (int)ceil((box[3] - box[2]) / cell) + 1;
	size_t nb = (size_t)b->nx * (size_t)b->ny;
	b->start = calloc(nb + 1, sizeof(size_t));
	b->index = malloc(n * sizeof(size_t));
	if (!b->start || !b->index)
		return -ENOMEM;
	for (size_t i = 0; i < n; i++)
		b->start[bucket_index(b, xyz + 3 * i) + 1]++;
	for (size_t k = 0; k < nb; k++)
		b->start[k + 1] += b->start[k];
	_cleanup_free_ size_t *fill = malloc(nb * sizeof(size_t));
	if (!fill)
		return -ENOMEM;
	memcpy(fill, b->start, nb * sizeof(size_t));
	for (size_t i = 0; i < n; i++)
		b->index[fill[bucket_index(b, xyz + 3 * i)]++] = i;
	return 0;
}

static double dot3(const double *a, const double *b)
{
	return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double dist2(const double *a, const double *b)
{
	double d[3] = { a[0] - b[0], a[1] - b[1], a[2] - b[2] };

	return dot3(d, d);
}

/* The site nearest to q in 3-D. The x-y distance bounds the 3-D one from
 * below, so the rings of buckets are searched until the next ring is
 * farther in x-y than the best site in 3-D. */
static size_t nearest_site(const struct buckets *b, const double *xyz, const double q[3],
			   double *d2)
{
	int cx = bucket_of(b, q[0], b->x0, b->nx), cy = bucket_of(b, q[1], b->y0, b->ny);
	size_t best = SIZE_MAX;
	double bd = INFINITY;
	int rmax = b->nx > b->ny ? b->nx : b->ny;

	for (int ring = 0; ring <= rmax; ring++) {
		double reach = (ring - 1) * b->cell;
		if (best != SIZE_MAX && reach > 0 && reach * reach > bd)
			break;
		for (int j = cy - ring; j <= cy + ring; j++) {
			if (j < 0 || j >= b->ny)
				continue;
			bool edge_row = j == cy - ring || j == cy + ring;
			for (int i = cx - ring; i <= cx + ring; i += edge_row ? 1 : 2 * ring) {
				if (i >= 0 && i < b->nx) {
					size_t k = (size_t)j * (size_t)b->nx + (size_t)i;
					for (size_t m = b->start[k]; m < b->start[k + 1]; m++) {
						double d = dist2(xyz + 3 * b->index[m], q);
						if (d < bd) {
							bd = d;
							best = b->index[m];
						}
					}
				}
				if (ring == 0)
					break;
			}
		}
	}
	*d2 = bd;
	return best;
}

/* The surface as flat triangles. */
struct rvd_mesh {
	double *v;      /* 3 nv: vertices on the surface */
	uint32_t *t;    /* 3 nt */
	size_t nv, nt;
};

static void rvd_mesh_clear(struct rvd_mesh *m)
{
	free(m->v);
	free(m->t);
	memset(m, 0, sizeof(*m));
}

/* Vertex (i, j) of the split of a triangle, i + j <= k: its barycentric
 * coordinates are ((k - i - j) / k, i / k, j / k). The vertices on an edge
 * are shared with the neighbour across it: the triangle that meets the edge
 * first creates them (edge_base, in the direction of its own edge). */
static uint32_t split_vertex(const uint32_t *tri, const uint32_t *edge_base,
			     const uint32_t *edge_owner_dir, size_t t, const uint32_t *inner,
			     int i, int j)
{
	const int k = CVT_SUBDIV;
	int e = -1, m = 0;

	if (i == 0 && j == 0)
		return tri[3 * t];
	if (i == k)
		return tri[3 * t + 1];
	if (j == k)
		return tri[3 * t + 2];
	if (j == 0)
		e = 0, m = i;           /* vertex 0 to 1 */
	else if (i + j == k)
		e = 1, m = j;           /* vertex 1 to 2 */
	else if (i == 0)
		e = 2, m = k - j;       /* vertex 2 to 0 */
	if (e < 0) {
		/* inner vertices, row by row */
		int idx = 0;
		for (int jj = 1; jj < j; jj++)
			idx += k - 1 - jj;
		return inner[t] + (uint32_t)(idx + i - 1);
	}
	return edge_base[3 * t + e] + (uint32_t)(edge_owner_dir[3 * t + e] ? m - 1 : k - m - 1);
}

static int rvd_mesh_build(const struct asph_surface *s, const double *xyz, size_t n,
			  struct rvd_mesh *mesh, struct asph_error *err)
{
	const int k = CVT_SUBDIV;
	_cleanup_(asph_delaunay_freep) struct asph_delaunay *w = asph_delaunay_alloc(n);
	_cleanup_free_ double *xy = malloc(2 * n * sizeof(double));
	_cleanup_free_ uint32_t *tri = NULL, *nb = NULL, *edge_base = NULL, *dir = NULL,
				*inner = NULL;
	size_t nt = 0;
	int r;

	if (!w || !xy)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = xyz[3 * i];
		xy[2 * i + 1] = xyz[3 * i + 1];
	}
	r = asph_delaunay_triangulate(w, xy, n, &tri, &nt, err);
	if (r < 0)
		return r;
	r = asph_delaunay_neighbors(w, &nb, err);
	if (r < 0)
		return r;
	size_t n_inner = (size_t)((k - 1) * (k - 2) / 2);
	size_t nv_max = n + 3 * nt * (size_t)(k - 1) + nt * n_inner;
	if (nv_max >= UINT32_MAX)
		return asph_error_set(err, -E2BIG, "cvt: %zu points are too many", n);
	edge_base = malloc(3 * nt * sizeof(uint32_t));
	dir = malloc(3 * nt * sizeof(uint32_t));
	inner = malloc(nt * sizeof(uint32_t));
	mesh->v = malloc(3 * nv_max * sizeof(double));
	mesh->t = malloc(3 * nt * (size_t)(k * k) * sizeof(uint32_t));
	if (!edge_base || !dir || !inner || !mesh->v || !mesh->t)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	memcpy(mesh->v, xyz, 3 * n * sizeof(double));
	size_t nv = n;
	for (size_t t = 0; t < nt; t++) {
		uint32_t ids[CVT_SUBDIV + 1][CVT_SUBDIV + 1];
		const double *A = xy + 2 * tri[3 * t], *B = xy + 2 * tri[3 * t + 1],
			     *C = xy + 2 * tri[3 * t + 2];
		/* the edges: made here unless the neighbour across made them */
		for (int e = 0; e < 3; e++) {
			uint32_t o = nb[3 * t + e];
			dir[3 * t + e] = 1;
			if (o != UINT32_MAX && o < t) {
				uint32_t a = tri[3 * t + e];
				for (int f = 0; f < 3; f++)
					if (tri[3 * o + (f + 1) % 3] == a) {
						edge_base[3 * t + e] = edge_base[3 * o + f];
						dir[3 * t + e] = 0;
					}
				continue;
			}
			edge_base[3 * t + e] = (uint32_t)nv;
			nv += (size_t)(k - 1);
		}
		inner[t] = (uint32_t)nv;
		nv += n_inner;
		for (int j = 0; j <= k; j++)
			for (int i = 0; i + j <= k; i++) {
				ids[i][j] = split_vertex(tri, edge_base, dir, t, inner, i, j);
				double l1 = (double)i / k, l2 = (double)j / k, l0 = 1 - l1 - l2;
				double *v = mesh->v + 3 * ids[i][j];
				if (ids[i][j] < n)
					continue;
				v[0] = l0 * A[0] + l1 * B[0] + l2 * C[0];
				v[1] = l0 * A[1] + l1 * B[1] + l2 * C[1];
				v[2] = asph_surface_sag_xy(s, v[0], v[1]);
			}
		uint32_t *out = mesh->t + 3 * mesh->nt;
		for (int j = 0; j < k; j++)
			for (int i = 0; i + j < k; i++) {
				*out++ = ids[i][j];
				*out++ = ids[i + 1][j];
				*out++ = ids[i][j + 1];
				if (i + j + 1 < k) {
					*out++ = ids[i + 1][j];
					*out++ = ids[i + 1][j + 1];
					*out++ = ids[i][j + 1];
				}
			}
		mesh->nt = (size_t)(out - mesh->t) / 3;
	}
	mesh->nv = nv;
	return 0;
}

/* What the cells integrate to: per site its mass and first moment, and the
 * energy F. */
struct cells {
	double *m, *mom;        /* n, 3 n */
	double energy;
	uint32_t *near;         /* per mesh vertex: its nearest site */
	double *dnear;          /* and the distance to it */
	size_t *cand;           /* candidates of a clipped triangle */
	size_t cand_cap;
};

static void cells_clear(struct cells *c)
{
	free(c->m);
	free(c->mom);
	free(c->near);
	free(c->dnear);
	free(c->cand);
	memset(c, 0, sizeof(*c));
}

/* Adds the planar polygon P (np vertices) to site i's cell. */
static void add_polygon(struct cells *c, const double *s, size_t i, const double (*P)[3],
			int np)
{
	for (int q = 1; q + 1 < np; q++) {
		const double *a = P[0], *b = P[q], *d = P[q + 1];
		double u[3], v[3], x[3], ra[3], rb[3], rd[3];
		for (int e = 0; e < 3; e++) {
			u[e] = b[e] - a[e];
			v[e] = d[e] - a[e];
			ra[e] = a[e] - s[e];
			rb[e] = b[e] - s[e];
			rd[e] = d[e] - s[e];
		}
		x[0] = u[1] * v[2] - u[2] * v[1];
		x[1] = u[2] * v[0] - u[0] * v[2];
		x[2] = u[0] * v[1] - u[1] * v[0];
		double A = 0.5 * sqrt(dot3(x, x));
		c->m[i] += A;
		for (int e = 0; e < 3; e++)
			c->mom[3 * i + e] += A * (a[e] + b[e] + d[e]) / 3;
		/* integral of |x - s|^2 over the triangle */
		c->energy += A / 6 *
			     (dot3(ra, ra) + dot3(rb, rb) + dot3(rd, rd) + dot3(ra, rb) +
			      dot3(rb, rd) + dot3(rd, ra));
	}
}

/* Cuts P down to the side of the bisector plane of s_i and s_j nearer s_i
 * (Sutherland-Hodgman). Returns the new vertex count. */
static int clip_bisector(double (*P)[3], int np, const double *si, const double *sj)
{
	double Q[CVT_POLY_MAX][3], f[CVT_POLY_MAX], d[3];
	int nq = 0;
	bool all_in = true;

	for (int e = 0; e < 3; e++)
		d[e] = sj[e] - si[e];
	double half = 0.5 * dot3(d, d);
	for (int a = 0; a < np; a++) {
		double r[3] = { P[a][0] - si[0], P[a][1] - si[1], P[a][2] - si[2] };
		f[a] = dot3(r, d) - half;
		all_in = all_in && f[a] <= 0;
	}
	if (all_in)
		return np;
	for (int a = 0; a < np && nq + 2 <= CVT_POLY_MAX; a++) {
		int b = (a + 1) % np;
		if (f[a] <= 0)
			memcpy(Q[nq++], P[a], sizeof(Q[0]));
		if ((f[a] < 0 && f[b] > 0) || (f[a] > 0 && f[b] < 0)) {
			double t = f[a] / (f[a] - f[b]);
			for (int e = 0; e < 3; e++)
				Q[nq][e] = P[a][e] + t * (P[b][e] - P[a][e]);
			nq++;
		}
	}
	memcpy(P, Q, (size_t)nq * sizeof(Q[0]));
	return nq;
}

/* The sites within 3-D distance R of q, into c->cand. */
static int sites_within(struct cells *c, const struct buckets *b, const double *xyz,
			const double q[3], double R, size_t *nc)
{
	int i0 = bucket_of(b, q[0] - R, b->x0, b->nx), i1 = bucket_of(b, q[0] + R, b->x0, b->nx);
	int j0 = bucket_of(b, q[1] - R, b->y0, b->ny), j1 = bucket_of(b, q[1] + R, b->y0, b->ny);

	*nc = 0;
	for (int j = j0; j <= j1; j++)
		for (int i = i0; i <= i1; i++) {
			size_t k = (size_t)j * (size_t)b->nx + (size_t)i;
			for (size_t m = b->start[k]; m < b->start[k + 1]; m++) {
				size_t site = b->index[m];
				if (dist2(xyz + 3 * site, q) > R * R)
					continue;
				if (*nc == c->cand_cap) {
					size_t cap = c->cand_cap ? 2 * c->cand_cap : 64;
					size_t *p = realloc(c->cand, cap * sizeof(size_t));
					if (!p)
						return -ENOMEM;
					c->cand = p;
					c->cand_cap = cap;
				}
				c->cand[(*nc)++] = site;
			}
		}
	return 0;
}

/* The triangle (a, b, d) of the mesh cut into the cells of the sites. Its
 * cells are convex polygons; all three vertices in one cell put it whole in
 * that cell. Otherwise, with g its centroid, r its largest distance from g
 * and D the distance of g from the nearest of its vertices' sites, a site
 * farther than D + 2 r from g is farther from every point of the triangle
 * than that site is: the candidates are the sites within D + 2 r, sorted by
 * their distance from g, each cut by the nearer ones first. */
static int cut_triangle(struct cells *c, const struct buckets *b, const double *xyz,
			const struct rvd_mesh *mesh, const uint32_t *t)
{
	const double *V[3] = { mesh->v + 3 * t[0], mesh->v + 3 * t[1], mesh->v + 3 * t[2] };
	double P[CVT_POLY_MAX][3];
	size_t nc;

	if (c->near[t[0]] == c->near[t[1]] && c->near[t[1]] == c->near[t[2]]) {
		memcpy(P, V[0], sizeof(P[0]));
		memcpy(P[1], V[1], sizeof(P[0]));
		memcpy(P[2], V[2], sizeof(P[0]));
		add_polygon(c, xyz + 3 * c->near[t[0]], c->near[t[0]], (const double (*)[3])P, 3);
		return 0;
	}
	double g[3], rad = 0, D = INFINITY;
	for (int e = 0; e < 3; e++)
		g[e] = (V[0][e] + V[1][e] + V[2][e]) / 3;
	for (int e = 0; e < 3; e++) {
		rad = fmax(rad, sqrt(dist2(V[e], g)));
		D = fmin(D, sqrt(dist2(xyz + 3 * c->near[t[e]], g)));
	}
	int r = sites_within(c, b, xyz, g, D + 2 * rad, &nc);
	if (r < 0)
		return r;
	/* insertion sort by the distance from g (few candidates) */
	for (size_t k = 1; k < nc; k++) {
		size_t site = c->cand[k], m = k;
		double key = dist2(xyz + 3 * site, g);
		while (m > 0 && dist2(xyz + 3 * c->cand[m - 1], g) > key) {
			c->cand[m] = c->cand[m - 1];
			m--;
		}
		c->cand[m] = site;
	}
	for (size_t ci = 0; ci < nc; ci++) {
		size_t i = c->cand[ci];
		int np = 3;
		memcpy(P, V[0], sizeof(P[0]));
		memcpy(P[1], V[1], sizeof(P[0]));
		memcpy(P[2], V[2], sizeof(P[0]));
		for (size_t cj = 0; cj < nc && np >= 3; cj++)
			if (cj != ci)
				np = clip_bisector(P, np, xyz + 3 * i, xyz + 3 * c->cand[cj]);
		if (np >= 3)
			add_polygon(c, xyz + 3 * i, i, (const double (*)[3])P, np);
	}
	return 0;
}

/* The restricted Voronoi cells of the n sites on the mesh. */
static int cells_compute(struct cells *c, const struct rvd_mesh *mesh, const double box[4],
			 double cell, const double *xyz, size_t n)
{
	_cleanup_(buckets_clear) struct buckets b = { 0 };
	int r = buckets_fill(&b, box, cell, xyz, n);

	if (r < 0)
		return r;
	memset(c->m, 0, n * sizeof(double));
	memset(c->mom, 0, 3 * n * sizeof(double));
	c->energy = 0;
	for (size_t v = 0; v < mesh->nv; v++) {
		double d2;
		c->near[v] = (uint32_t)nearest_site(&b, xyz, mesh->v + 3 * v, &d2);
		c->dnear[v] = sqrt(d2);
	}
	for (size_t t = 0; t < mesh->nt; t++)
		if ((r = cut_triangle(c, &b, xyz, mesh, mesh->t + 3 * t)) < 0)
			return r;
	return 0;
}

/* The state of the minimisation over the free sites' (x, y). */
struct cvt_state {
	const struct asph_surface *s;
	const struct rvd_mesh *mesh;
	double box[4], cell;
	double edge_tol;        /* the aperture grown by rounding */
	double pin_tol;         /* a site this close to the edge is held by it */
	double *xyz;            /* all sites */
	size_t n, nf;
	const size_t *free_site; /* nf */
	struct cells *c;
};

/* Puts the free sites at u (2 nf) on the surface and computes F, its
 * gradient g over u, the preconditioner (per site the inverse of the 2x2
 * matrix 2 m J^T J, J = the tangents (1, 0, S_x), (0, 1, S_y); stored as
 * a, b, d) and the largest distance of a free site from its cell's
 * centroid, the sites held at the edge left out. -ERANGE when a site
 * leaves the aperture, -ENOMEM. */
static int cvt_eval(struct cvt_state *st, const double *u, double *F, double *g, double *hinv,
		    double *worst)
{
	for (size_t f = 0; f < st->nf; f++) {
		double *q = st->xyz + 3 * st->free_site[f];
		if (!asph_surface_contains(st->s, u[2 * f], u[2 * f + 1], st->edge_tol))
			return -ERANGE;
		q[0] = u[2 * f];
		q[1] = u[2 * f + 1];
		q[2] = asph_surface_sag_xy(st->s, q[0], q[1]);
	}
	int r = cells_compute(st->c, st->mesh, st->box, st->cell, st->xyz, st->n);
	if (r < 0)
		return r;
	*F = st->c->energy;
	*worst = 0;
	for (size_t f = 0; f < st->nf; f++) {
		size_t i = st->free_site[f];
		const double *q = st->xyz + 3 * i;
		double m = st->c->m[i], gr[3], sg[3];
		if (!(m > 0)) {
			/* a site nearest to no point of the surface: F does
			 * not depend on it */
			g[2 * f] = g[2 * f + 1] = 0;
			hinv[3 * f] = hinv[3 * f + 2] = 1;
			hinv[3 * f + 1] = 0;
			continue;
		}
		for (int e = 0; e < 3; e++)
			gr[e] = 2 * (m * q[e] - st->c->mom[3 * i + e]);
		/* a site the edge holds (its centroid lies outward) does not
		 * count for convergence */
		if (asph_surface_contains(st->s, q[0], q[1], -st->pin_tol))
			*worst = fmax(*worst, sqrt(dot3(gr, gr)) / (2 * m));
		asph_surface_sag_grad_xy(st->s, q[0], q[1], sg);
		g[2 * f] = gr[0] + sg[1] * gr[2];
		g[2 * f + 1] = gr[1] + sg[2] * gr[2];
		double a = 2 * m * (1 + sg[1] * sg[1]), b = 2 * m * sg[1] * sg[2],
		       d = 2 * m * (1 + sg[2] * sg[2]), det = a * d - b * b;
		hinv[3 * f] = d / det;
		hinv[3 * f + 1] = -b / det;
		hinv[3 * f + 2] = a / det;
	}
	return 0;
}

static double dot(const double *a, const double *b, size_t n)
{
	double s = 0;

	for (size_t i = 0; i < n; i++)
		s += a[i] * b[i];
	return s;
}

static void precondition(const double *hinv, const double *v, double *out, size_t nf)
{
	for (size_t f = 0; f < nf; f++) {
		double a = v[2 * f], b = v[2 * f + 1];
		out[2 * f] = hinv[3 * f] * a + hinv[3 * f + 1] * b;
		out[2 * f + 1] = hinv[3 * f + 1] * a + hinv[3 * f + 2] * b;
	}
}

/* The L-BFGS direction d = -H g (the two-loop recursion, with the
 * preconditioner as H0). S, Y: the last nh steps and gradient changes,
 * newest at (head - 1) mod CVT_HISTORY. */
static void lbfgs_direction(const double *g, const double *hinv, double *const *S,
			    double *const *Y, const double *rho, int nh, int head, double *d,
			    double *tmp, size_t N)
{
	double alpha[CVT_HISTORY];

	memcpy(tmp, g, N * sizeof(double));
	for (int k = 0; k < nh; k++) {
		int h = (head - 1 - k + 2 * CVT_HISTORY) % CVT_HISTORY;
		alpha[k] = rho[h] * dot(S[h], tmp, N);
		for (size_t i = 0; i < N; i++)
			tmp[i] -= alpha[k] * Y[h][i];
	}
	precondition(hinv, tmp, d, N / 2);
	for (int k = nh - 1; k >= 0; k--) {
		int h = (head - 1 - k + 2 * CVT_HISTORY) % CVT_HISTORY;
		double beta = rho[h] * dot(Y[h], d, N);
		for (size_t i = 0; i < N; i++)
			d[i] += (alpha[k] - beta) * S[h][i];
	}
	for (size_t i = 0; i < N; i++)
		d[i] = -d[i];
}

/* ut = u + alpha d, except that a site whose step would leave the
 * aperture stops short of the edge (the largest fraction of its step that
 * stays inside, to 2^-30): the edge is a constraint of the minimisation. */
static void trial_sites(const struct asph_surface *s, double tol, const double *u,
			const double *d, double alpha, double *ut, size_t nf)
{
	for (size_t f = 0; f < nf; f++) {
		double x = u[2 * f] + alpha * d[2 * f], y = u[2 * f + 1] + alpha * d[2 * f + 1];
		if (!asph_surface_contains(s, x, y, tol)) {
			double lo = 0, hi = 1;
			for (int k = 0; k < 30; k++) {
				double t = 0.5 * (lo + hi);
				if (asph_surface_contains(s, u[2 * f] + t * alpha * d[2 * f],
							  u[2 * f + 1] + t * alpha * d[2 * f + 1], tol))
					lo = t;
				else
					hi = t;
			}
			x = u[2 * f] + lo * alpha * d[2 * f];
			y = u[2 * f + 1] + lo * alpha * d[2 * f + 1];
		}
		ut[2 * f] = x;
		ut[2 * f + 1] = y;
	}
}

/* The L-BFGS iterations from the sites in st (u, their (x, y)): at most
 * CVT_MAX_ITER, until every free site is within CVT_TOL e of its cell's
 * centroid, or until the energy stops falling at its rounding. Leaves the
 * sites at the last accepted step. */
static int cvt_minimise(struct cvt_state *st, double *u, double e,
			const struct asph_progress *progress, struct plan_cvt_info *info)
{
	size_t N = 2 * st->nf;
	_cleanup_free_ double *g = malloc(N * sizeof(double)), *d = malloc(N * sizeof(double));
	_cleanup_free_ double *ut = malloc(N * sizeof(double)), *gt = malloc(N * sizeof(double));
	_cleanup_free_ double *tmp = malloc(N * sizeof(double));
	_cleanup_free_ double *hinv = malloc(3 * st->nf * sizeof(double));
	_cleanup_free_ double *hinvt = malloc(3 * st->nf * sizeof(double));
	_cleanup_free_ double *hist = malloc(2 * CVT_HISTORY * N * sizeof(double));
	double *S[CVT_HISTORY], *Y[CVT_HISTORY], rho[CVT_HISTORY], F, worst;
	int nh = 0, head = 0, it, r;

	if (!g || !d || !ut || !gt || !tmp || !hinv || !hinvt || !hist)
		return -ENOMEM;
	for (int k = 0; k < CVT_HISTORY; k++) {
		S[k] = hist + 2 * (size_t)k * N;
		Y[k] = S[k] + N;
	}
	if ((r = cvt_eval(st, u, &F, g, hinv, &worst)) < 0)
		return r;
	for (it = 0; it < CVT_MAX_ITER && worst > CVT_TOL * e && N; it++) {
		if (progress && progress->fn && progress->fn(progress->data, (size_t)it, CVT_MAX_ITER))
			return -ECANCELED;
		lbfgs_direction(g, hinv, S, Y, rho, nh, head, d, tmp, N);
		double slope = dot(g, d, N);
		if (!(slope < 0)) {
			nh = 0;
			lbfgs_direction(g, hinv, S, Y, rho, 0, head, d, tmp, N);
			slope = dot(g, d, N);
		}
		double alpha = 1, Ft = 0, worst_t = 0;
		bool ok = false;
		for (int ls = 0; ls < 30 && !ok; ls++) {
			trial_sites(st->s, st->edge_tol, u, d, alpha, ut, st->nf);
			r = cvt_eval(st, ut, &Ft, gt, hinvt, &worst_t);
			if (r == -ENOMEM)
				return r;
			double decrease = 0;
			for (size_t i = 0; i < N; i++)
				decrease += g[i] * (ut[i] - u[i]);
			ok = r == 0 && Ft <= F + 1e-4 * decrease;
			if (!ok)
				alpha *= 0.5;
		}
		if (!ok) {
			/* back to the last accepted sites; then a plain
			 * (Lloyd) step, unless this was one: no decrease is
			 * left above the energy's rounding */
			if ((r = cvt_eval(st, u, &F, g, hinv, &worst)) < 0)
				return r;
			if (nh == 0)
				break;
			nh = 0;
			continue;
		}
		double *sk = S[head], *yk = Y[head];
		for (size_t i = 0; i < N; i++) {
			sk[i] = ut[i] - u[i];
			yk[i] = gt[i] - g[i];
		}
		double sy = dot(sk, yk, N);
		if (sy > 0) {
			rho[head] = 1 / sy;
			head = (head + 1) % CVT_HISTORY;
			nh = nh < CVT_HISTORY ? nh + 1 : CVT_HISTORY;
		}
		memcpy(u, ut, N * sizeof(double));
		memcpy(g, gt, N * sizeof(double));
		memcpy(hinv, hinvt, 3 * st->nf * sizeof(double));
		F = Ft;
		worst = worst_t;
	}
	/* settled: the scan order is what is left */
	if (it > 0 && progress && progress->fn && progress->fn(progress->data, (size_t)it, (size_t)it))
		return -ECANCELED;
	if (info)
		*info = (struct plan_cvt_info){ .iterations = it, .last_move = worst / e,
						.triangles = st->mesh->nt };
	return 0;
}

int plan_cvt_relax(const struct asph_surface *s, double p, double *xyz, size_t n,
		   const struct asph_progress *progress, struct plan_cvt_info *info,
		   struct asph_error *err)
{
	_cleanup_(rvd_mesh_clear) struct rvd_mesh mesh = { 0 };
	_cleanup_(cells_clear) struct cells c = { 0 };
	_cleanup_free_ size_t *free_site = NULL;
	_cleanup_free_ double *u = NULL;
	struct cvt_state st = { .s = s, .n = n, .xyz = xyz, .c = &c, .cell = p };
	double centre[2], R, area = 0;
	int r;

	if (!(p > 0) || n < 3)
		return asph_error_set(err, -EINVAL, "cvt: pitch %g, %zu points", p, n);
	if ((r = rvd_mesh_build(s, xyz, n, &mesh, err)) < 0)
		return r;
	st.mesh = &mesh;
	asph_surface_bounds(s, st.box);
	asph_surface_aperture_disk(s, centre, &R);
	st.edge_tol = 1e-12 * R;
	st.pin_tol = 1e-7 * R;
	free_site = malloc(n * sizeof(size_t));
	u = malloc(2 * n * sizeof(double));
	c.m = malloc(n * sizeof(double));
	c.mom = malloc(3 * n * sizeof(double));
	c.near = malloc(mesh.nv * sizeof(uint32_t));
	c.dnear = malloc(mesh.nv * sizeof(double));
	if (!free_site || !u || !c.m || !c.mom || !c.near || !c.dnear)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	for (size_t i = 0; i < n; i++)
		if (asph_surface_contains(s, xyz[3 * i], xyz[3 * i + 1], -1e-9 * R)) {
			u[2 * st.nf] = xyz[3 * i];
			u[2 * st.nf + 1] = xyz[3 * i + 1];
			free_site[st.nf++] = i;
		}
	st.free_site = free_site;
	for (size_t t = 0; t < mesh.nt; t++) {
		const uint32_t *tr = mesh.t + 3 * t;
		double a[3], b[3], x[3];
		for (int k = 0; k < 3; k++) {
			a[k] = mesh.v[3 * tr[1] + k] - mesh.v[3 * tr[0] + k];
			b[k] = mesh.v[3 * tr[2] + k] - mesh.v[3 * tr[0] + k];
		}
		x[0] = a[1] * b[2] - a[2] * b[1];
		x[1] = a[2] * b[0] - a[0] * b[2];
		x[2] = a[0] * b[1] - a[1] * b[0];
		area += 0.5 * sqrt(dot3(x, x));
	}
	r = cvt_minimise(&st, u, sqrt(area / (double)n), progress, info);
	if (r < 0)
		return asph_error_set(err, r, "cvt: %s", r == -ENOMEM ? "out of memory" :
							 r == -ECANCELED ? "cancelled" :
							 "a site left the aperture");
	return 0;
}

/* ---- the starting sites --------------------------------------------------- */

/* The aperture's outline as a fine closed polygon: its length in x-y and
 * lifted onto the surface. The edge's
 * parameter puts a rectangle's corners at multiples of 1/4, which the
 * polygon has as vertices. */
#define CVT_OUTLINE_STEPS 4096

static void outline_measure(const struct asph_surface *s, double *len_xy, double *len_3d)
{
	double p[2], q[2], dp[2], zp, zq;

	*len_xy = *len_3d = 0;
	asph_surface_aperture_edge(s, 0, p, dp);
	zp = asph_surface_sag_xy(s, p[0], p[1]);
	for (int k = 1; k <= CVT_OUTLINE_STEPS; k++) {
		asph_surface_aperture_edge(s, (double)(k % CVT_OUTLINE_STEPS) / CVT_OUTLINE_STEPS,
					   q, dp);
		zq = asph_surface_sag_xy(s, q[0], q[1]);
		*len_xy += hypot(q[0] - p[0], q[1] - p[1]);
		*len_3d += sqrt(pow(q[0] - p[0], 2) + pow(q[1] - p[1], 2) + pow(zq - zp, 2));
		p[0] = q[0];
		p[1] = q[1];
		zp = zq;
	}
}

double plan_cvt_edge_step(const struct asph_surface *s, size_t n)
{
	double len_xy, len_3d;
	double step = sqrt(2.0 * asph_surface_total_area(s) / (sqrt(3.0) * (double)n));

	outline_measure(s, &len_xy, &len_3d);
	double m = fmax(3.0, round(len_3d / step));
	/* the x-y step that divides the outline into m samples, a hair
	 * longer than the exact quotient so that rounding cannot add one;
	 * longer still where so few sites would leave none inside */
	double edge_step = len_xy / m * (1 + 1e-12);
	while (plan_outline_count(s, edge_step) + 1 > n && plan_outline_count(s, edge_step) > 4)
		edge_step *= 1.01;
	return edge_step;
}

/* A hexagonal lattice point (x, y) with its depth inside the aperture
 * (found to 1e-6 of the step) and its place on the spiral. */
struct seed_point {
	double x, y, depth, key;
};

static int by_depth(const void *a, const void *b)
{
	const struct seed_point *u = a, *v = b;

	if (u->depth != v->depth)
		return u->depth > v->depth ? -1 : 1;
	return u->key < v->key ? -1 : u->key > v->key;
}

static int by_key(const void *a, const void *b)
{
	const struct seed_point *u = a, *v = b;

	return u->key < v->key ? -1 : u->key > v->key;
}

static double depth_inside(const struct asph_surface *s, double x, double y, double reach,
			   double resolution)
{
	double lo = 0, hi = reach;

	if (!asph_surface_contains(s, x, y, 0))
		return -1;
	while (hi - lo > resolution) {
		double mid = 0.5 * (lo + hi);
		if (asph_surface_contains(s, x, y, -mid))
			lo = mid;
		else
			hi = mid;
	}
	return lo;
}

/* The position of (x, y) along the Archimedean spiral of turn spacing
 * `turn` about c: the turn it lies in, plus the fraction of a turn. */
static double spiral_key(double x, double y, const double c[2], double turn)
{
	double th = atan2(y - c[1], x - c[0]);
	double f = (th < 0 ? th + 2 * M_PI : th) / (2 * M_PI);

	return floor(hypot(x - c[0], y - c[1]) / turn - f + 0.5) + f;
}

int plan_cvt_seed(const struct asph_surface *s, size_t n, double *xyz, struct asph_error *err)
{
	double c[2], R, box[4], area_xy = asph_surface_projected_area(s);
	double edge_step = plan_cvt_edge_step(s, n);
	size_t n_edge = plan_outline_count(s, edge_step);

	asph_surface_aperture_disk(s, c, &R);
	asph_surface_bounds(s, box);
	if (n_edge + 1 > n)
		return asph_error_set(err, -EINVAL, "cvt: %zu points do not fill the aperture", n);
	/* the lattice of the OT map's source: one site per (sqrt 3 / 2) h^2 */
	double h = sqrt(2.0 * area_xy / (sqrt(3.0) * (double)n)), row = 0.5 * sqrt(3.0) * h;
	long nj = (long)ceil((box[3] - box[2]) / (2 * row)) + 1;
	long ni = (long)ceil((box[1] - box[0]) / (2 * h)) + 2;
	size_t cap = (size_t)(2 * ni + 1) * (size_t)(2 * nj + 1), m = 0;
	_cleanup_free_ struct seed_point *pts = malloc(cap * sizeof(*pts));
	struct plan_points edge = { 0 };

	if (!pts)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	for (long j = -nj; j <= nj; j++)
		for (long i = -ni; i <= ni; i++) {
			/* rows alternate by half a step, so that the site at the
			 * aperture's centre has six neighbours at h */
			double x = c[0] + ((double)i + 0.5 * (double)(j & 1)) * h;
			double y = c[1] + (double)j * row;
			double d = depth_inside(s, x, y, R, 1e-6 * h);
			if (d < 0)
				continue;
			pts[m++] = (struct seed_point){ x, y, d, spiral_key(x, y, c, row) };
		}
	if (m < n - n_edge)
		return asph_error_set(err, -EINVAL, "cvt: %zu points do not fill the aperture", n);
	/* the deepest sites inside, then the outline at the lattice's step */
	qsort(pts, m, sizeof(*pts), by_depth);
	qsort(pts, n - n_edge, sizeof(*pts), by_key);
	for (size_t k = 0; k < n - n_edge; k++) {
		xyz[3 * k] = pts[k].x;
		xyz[3 * k + 1] = pts[k].y;
		xyz[3 * k + 2] = hypot(pts[k].x - c[0], pts[k].y - c[1]);
	}
	const double *last = xyz + 3 * (n - n_edge - 1);
	if (plan_outline_append(s, edge_step, last[0], last[1], &edge) < 0 || edge.n != n_edge) {
		plan_points_clear(&edge);
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	}
	for (size_t k = 0; k < n_edge; k++) {
		double *q = xyz + 3 * (n - n_edge + k);
		q[0] = edge.xyz[3 * k];
		q[1] = edge.xyz[3 * k + 1];
		q[2] = R;
	}
	plan_points_clear(&edge);
	return 0;
}

/* The distance from the aperture's centre on the surface: along the
 * meridian on a surface of revolution, the 3-D chord from the point above
 * the centre on a freeform. */
static double surface_radius(const struct asph_surface *s, const double c[3], const double *q)
{
	if (asph_surface_is_rotational(s))
		return asph_surface_arc_length(s, hypot(q[0], q[1]));
	return sqrt(dist2(c, q));
}

/* The cheapest place for site p in the list (next/prev, SIZE_MAX at the
 * ends) beside one of its listed neighbours; SIZE_MAX if it has none.
 * *before: p goes before the site returned, else after it. */
static size_t cheapest_place(const struct buckets *b, const double *xyz, const size_t *next,
			     const size_t *prev, const bool *listed, size_t p, double reach,
			     bool *before)
{
	const double *q = xyz + 3 * p;
	int cx = bucket_of(b, q[0], b->x0, b->nx), cy = bucket_of(b, q[1], b->y0, b->ny);
	size_t best = SIZE_MAX;
	double cost = INFINITY;

	for (int j = cy - 2; j <= cy + 2; j++)
		for (int i = cx - 2; i <= cx + 2; i++) {
			if (i < 0 || j < 0 || i >= b->nx || j >= b->ny)
				continue;
			size_t bk = (size_t)j * (size_t)b->nx + (size_t)i;
			for (size_t t = b->start[bk]; t < b->start[bk + 1]; t++) {
				size_t k = b->index[t];
				if (!listed[k] || dist2(q, xyz + 3 * k) > 4 * reach * reach)
					continue;
				double dk = sqrt(dist2(q, xyz + 3 * k));
				for (int side = 0; side < 2; side++) {
					size_t o = side ? prev[k] : next[k];
					/* the path grows at its tail, so that it ends
					 * where the spiral does */
					double c = o == SIZE_MAX ? (side ? dk : dk - reach) :
						   dk + sqrt(dist2(q, xyz + 3 * o)) -
						   sqrt(dist2(xyz + 3 * k, xyz + 3 * o));
					if (c < cost) {
						cost = c;
						best = k;
						*before = side;
					}
				}
			}
		}
	return best;
}

/* The path through the n sites taken in the order given (walk, which it
 * overwrites), each put where it lengthens the path least beside one of
 * its neighbours already on it, or after the last. */
static int path_by_insertion(const struct buckets *b, const double *xyz, size_t *walk, size_t n,
			     double reach)
{
	_cleanup_free_ size_t *next = malloc(n * sizeof(size_t)), *prev = malloc(n * sizeof(size_t));
	_cleanup_free_ bool *listed = calloc(n, sizeof(bool));
	size_t head = walk[0], tail = walk[0];

	if (!next || !prev || !listed)
		return -ENOMEM;
	next[head] = prev[head] = SIZE_MAX;
	listed[head] = true;
	for (size_t k = 1; k < n; k++) {
		size_t p = walk[k];
		bool before = false;
		size_t at = cheapest_place(b, xyz, next, prev, listed, p, reach, &before);
		if (at == SIZE_MAX)
			at = tail, before = false;
		size_t a = before ? prev[at] : at, c = before ? at : next[at];
		prev[p] = a;
		next[p] = c;
		if (a == SIZE_MAX)
			head = p;
		else
			next[a] = p;
		if (c == SIZE_MAX)
			tail = p;
		else
			prev[c] = p;
		listed[p] = true;
	}
	for (size_t m = 0, v = head; m < n; m++, v = next[v])
		walk[m] = v;
	return 0;
}

/* A site's neighbours in the relaxed lattice lie within this many of its
 * steps (a hexagonal lattice's second ring is sqrt 3 steps away). */
#define CVT_ORDER_REACH 1.6

int plan_cvt_order(const struct asph_surface *s, double *xyz, size_t n, struct asph_error *err)
{
	size_t n_edge = plan_outline_count(s, plan_cvt_edge_step(s, n)), n_in = n - n_edge;
	double c[3], R, box[4];
	_cleanup_free_ struct seed_point *pts = malloc(n_in * sizeof(*pts));
	_cleanup_free_ double *copy = malloc(3 * n * sizeof(double));
	_cleanup_free_ size_t *walk = malloc((n_in + 1) * sizeof(size_t));
	_cleanup_(buckets_clear) struct buckets b = { 0 };

	if (!pts || !copy || !walk)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	asph_surface_aperture_disk(s, c, &R);
	asph_surface_bounds(s, box);
	c[2] = asph_surface_sag_xy(s, c[0], c[1]);
	double step = sqrt(2.0 * asph_surface_total_area(s) / (sqrt(3.0) * (double)n));
	double row = 0.5 * sqrt(3.0) * step;
	for (size_t k = 0; k < n_in; k++) {
		const double *q = xyz + 3 * k;
		double th = atan2(q[1] - c[1], q[0] - c[0]);
		double f = (th < 0 ? th + 2 * M_PI : th) / (2 * M_PI);
		/* the spiral's turns one row of the lattice apart */
		pts[k] = (struct seed_point){ .x = (double)k,
					      .key = floor(surface_radius(s, c, q) / row - f + 0.5) + f };
	}
	qsort(pts, n_in, sizeof(*pts), by_key);
	if (n_in && buckets_fill(&b, box, CVT_ORDER_REACH * step, xyz, n_in) < 0)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	/* A spiral's band of one row crosses the lattice's rows at a slant
	 * and leaves gaps in places; the sites taken in the spiral's order
	 * and each put in the path where it costs least close them. */
	for (size_t m = 0; m < n_in; m++)
		walk[m] = (size_t)pts[m].x;
	if (n_in && path_by_insertion(&b, xyz, walk, n_in, CVT_ORDER_REACH * step) < 0)
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	memcpy(copy, xyz, 3 * n * sizeof(double));
	for (size_t k = 0; k < n_in; k++)
		memcpy(xyz + 3 * k, copy + 3 * walk[k], 3 * sizeof(double));
	/* the outline from its sample nearest to the last inner site on */
	size_t start = 0;
	double best = INFINITY;
	for (size_t k = 0; k < n_edge && n_in; k++) {
		double d = dist2(xyz + 3 * (n_in - 1), copy + 3 * (n_in + k));
		if (d < best) {
			best = d;
			start = k;
		}
	}
	for (size_t k = 0; k < n_edge; k++)
		memcpy(xyz + 3 * (n_in + k), copy + 3 * (n_in + (start + k) % n_edge),
		       3 * sizeof(double));
	return 0;
}
