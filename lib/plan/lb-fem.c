/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_errno.h>
#include <gsl/gsl_blas.h>
#include <gsl/gsl_spblas.h>
#include <gsl/gsl_spmatrix.h>
#include <gsl/gsl_vector.h>

#include "asph/lb.h"
#include "util-mem.h"

/*
 * P1 finite elements for Eq. (6): each S_k minimises
 * int_U grad S_k . (sqrt(g) g^-1) grad S_k dx. For the graph
 * F = (x, y, Z(x, y)) with gradient G: g = I + G G^T, sqrt(g) = w =
 * sqrt(1 + |G|^2), sqrt(g) g^-1 = w I - G G^T / w. The coefficient is taken
 * at the centroid, which keeps the O(h^2) nodal accuracy of P1 elements.
 *
 * Nodes on the mesh boundary are Dirichlet nodes; the interior block is
 * symmetric positive definite for every graph surface (w I - G G^T / w
 * has eigenvalues w and 1/w), so conjugate gradients is the Krylov method
 * of choice; restarted GMRES (GSL splinalg) stalls on it as the mesh is
 * refined. The block is scaled symmetrically by its diagonal
 * (D^-1/2 K D^-1/2, a Jacobi preconditioner that evens out the
 * coefficient's range on steep flanks), stored as a GSL sparse matrix (CSR)
 * and solved for both right-hand sides.
 */
#define CG_TOL 1e-13
#define CG_MAX_ITER_FACTOR 4

DEFINE_TRIVIAL_CLEANUP_FUNC(gsl_spmatrix *, gsl_spmatrix_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(gsl_vector *, gsl_vector_free)

struct element {
	double area;            /* unsigned */
	double k[3][3];         /* local stiffness */
};

static int cmp_u64(const void *a, const void *b)
{
	uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
	return (x > y) - (x < y);
}

static uint64_t edge_key(uint32_t i, uint32_t j)
{
	return i < j ? ((uint64_t)i << 32) | j : ((uint64_t)j << 32) | i;
}

/* fixed[i] = 1 for boundary nodes and for nodes no triangle uses. */
static int mark_fixed(const uint32_t *tri, size_t ntri, size_t n,
		      uint8_t *fixed)
{
	_cleanup_free_ uint64_t *e = malloc(3 * ntri * sizeof(*e));
	_cleanup_free_ uint8_t *used = calloc(n, 1);

	if (!e || !used)
		return -ENOMEM;
	for (size_t t = 0; t < ntri; t++)
		for (int c = 0; c < 3; c++) {
			e[3 * t + c] = edge_key(tri[3 * t + c],
						tri[3 * t + (c + 1) % 3]);
			used[tri[3 * t + c]] = 1;
		}
	qsort(e, 3 * ntri, sizeof(*e), cmp_u64);
	for (size_t i = 0; i < n; i++)
		fixed[i] = !used[i];
	for (size_t i = 0; i < 3 * ntri;) {
		size_t j = i + 1;
		while (j < 3 * ntri && e[j] == e[i])
			j++;
		if (j - i == 1) {
			fixed[e[i] >> 32] = 1;
			fixed[e[i] & 0xffffffffu] = 1;
		}
		i = j;
	}
	return 0;
}

/* Twice the signed area of triangle v. */
static double area2(const double *xy, const uint32_t *v)
{
	const double *p0 = xy + 2 * v[0], *p1 = xy + 2 * v[1], *p2 = xy + 2 * v[2];

	return (p1[0] - p0[0]) * (p2[1] - p0[1]) -
	       (p2[0] - p0[0]) * (p1[1] - p0[1]);
}

/* Degenerate: area below 1e-12 of the square of its longest side. */
static int degenerate(const double *xy, const uint32_t *v)
{
	double longest = 0;

	for (int c = 0; c < 3; c++) {
		const double *p = xy + 2 * v[c], *q = xy + 2 * v[(c + 1) % 3];
		longest = fmax(longest, hypot(q[0] - p[0], q[1] - p[1]));
	}
	return !(fabs(area2(xy, v)) > 1e-12 * longest * longest);
}

static void element_stiffness(asph_lb_gradient_fn gradient, void *ctx,
			      const double *xy, const uint32_t *v,
			      struct element *el)
{
	const double *p0 = xy + 2 * v[0], *p1 = xy + 2 * v[1], *p2 = xy + 2 * v[2];
	double a2 = area2(xy, v);
	double g[3][2] = {
		{ (p1[1] - p2[1]) / a2, (p2[0] - p1[0]) / a2 },
		{ (p2[1] - p0[1]) / a2, (p0[0] - p2[0]) / a2 },
		{ (p0[1] - p1[1]) / a2, (p1[0] - p0[0]) / a2 },
	};
	double G[2];
	gradient(ctx, (p0[0] + p1[0] + p2[0]) / 3.0,
		 (p0[1] + p1[1] + p2[1]) / 3.0, G);
	double w = sqrt(1.0 + G[0] * G[0] + G[1] * G[1]);
	double M[2][2] = {
		{ w - G[0] * G[0] / w, -G[0] * G[1] / w },
		{ -G[0] * G[1] / w, w - G[1] * G[1] / w },
	};
	el->area = 0.5 * fabs(a2);
	for (int i = 0; i < 3; i++)
		for (int j = 0; j < 3; j++) {
			double mg0 = M[0][0] * g[j][0] + M[0][1] * g[j][1];
			double mg1 = M[1][0] * g[j][0] + M[1][1] * g[j][1];
			el->k[i][j] = el->area * (g[i][0] * mg0 + g[i][1] * mg1);
		}
}

struct system {
	size_t n_free;
	size_t *index;          /* node -> free index, or SIZE_MAX */
	double *dscale;         /* 1 / sqrt(K_ii) per free index */
	gsl_spmatrix *k;        /* scaled interior block, CSR */
	double *rhs;            /* 2 n_free: scaled right-hand sides */
};

static int assemble(asph_lb_gradient_fn gradient, void *ctx, const double *xy,
		    const double *S_fixed, const uint32_t *tri, size_t ntri,
		    struct system *sys, struct asph_error *err)
{
	_cleanup_(gsl_spmatrix_freep) gsl_spmatrix *coo = NULL;
	_cleanup_free_ double *diag = calloc(sys->n_free, sizeof(double));
	_cleanup_free_ struct element *el = malloc(ntri * sizeof(*el));

	if (!diag || !el)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t t = 0; t < ntri; t++) {
		element_stiffness(gradient, ctx, xy, tri + 3 * t, &el[t]);
		for (int c = 0; c < 3; c++) {
			size_t fi = sys->index[tri[3 * t + c]];
			if (fi != SIZE_MAX)
				diag[fi] += el[t].k[c][c];
		}
	}
	for (size_t i = 0; i < sys->n_free; i++)
		sys->dscale[i] = 1.0 / sqrt(diag[i]);

	coo = gsl_spmatrix_alloc_nzmax(sys->n_free, sys->n_free,
				       7 * sys->n_free, GSL_SPMATRIX_COO);
	if (!coo)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t t = 0; t < ntri; t++) {
		const uint32_t *v = tri + 3 * t;
		for (int i = 0; i < 3; i++) {
			size_t fi = sys->index[v[i]];
			if (fi == SIZE_MAX)
				continue;
			for (int j = 0; j < 3; j++) {
				size_t fj = sys->index[v[j]];
				double kij = el[t].k[i][j] * sys->dscale[fi];
				if (fj == SIZE_MAX) {
					sys->rhs[2 * fi] -= kij * S_fixed[2 * v[j]];
					sys->rhs[2 * fi + 1] -= kij * S_fixed[2 * v[j] + 1];
					continue;
				}
				kij *= sys->dscale[fj];
				double *slot = gsl_spmatrix_ptr(coo, fi, fj);
				if (slot)
					*slot += kij;
				else if (gsl_spmatrix_set(coo, fi, fj, kij) != GSL_SUCCESS)
					return asph_error_set(err, -ENOMEM,
							      "out of memory");
			}
		}
	}
	sys->k = gsl_spmatrix_compress(coo, GSL_SPMATRIX_CSR);
	if (!sys->k)
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}

/*
 * Conjugate gradients on the scaled block A y = b (A has unit diagonal);
 * y holds the initial guess. Stops at ||b - A y|| <= CG_TOL ||b||.
 */
static int conjugate_gradients(const gsl_spmatrix *A, const gsl_vector *b,
			       gsl_vector *y, struct asph_error *err)
{
	const size_t n = b->size;
	_cleanup_(gsl_vector_freep) gsl_vector *res = gsl_vector_alloc(n);
	_cleanup_(gsl_vector_freep) gsl_vector *dir = gsl_vector_alloc(n);
	_cleanup_(gsl_vector_freep) gsl_vector *ad = gsl_vector_alloc(n);

	if (!res || !dir || !ad)
		return asph_error_set(err, -ENOMEM, "out of memory");
	double bnorm = gsl_blas_dnrm2(b);
	gsl_vector_memcpy(res, b);
	gsl_spblas_dgemv(CblasNoTrans, -1.0, A, y, 1.0, res);
	gsl_vector_memcpy(dir, res);
	double rr = gsl_blas_dnrm2(res);
	rr *= rr;
	for (size_t it = 0; it < CG_MAX_ITER_FACTOR * n + 100; it++) {
		if (sqrt(rr) <= CG_TOL * bnorm)
			return 0;
		gsl_spblas_dgemv(CblasNoTrans, 1.0, A, dir, 0.0, ad);
		double dad;
		gsl_blas_ddot(dir, ad, &dad);
		double alpha = rr / dad;
		gsl_blas_daxpy(alpha, dir, y);
		gsl_blas_daxpy(-alpha, ad, res);
		double rr_new = gsl_blas_dnrm2(res);
		rr_new *= rr_new;
		gsl_vector_scale(dir, rr_new / rr);
		gsl_vector_add(dir, res);
		rr = rr_new;
	}
	return asph_error_set(err, -ERANGE,
			      "conjugate gradients did not converge "
			      "(relative residual %g)", sqrt(rr) / bnorm);
}

static int solve(struct system *sys, const double *xy, const double *S_fixed, size_t n,
		 double *S_out, struct asph_error *err)
{
	_cleanup_(gsl_vector_freep) gsl_vector *y = gsl_vector_alloc(sys->n_free);
	_cleanup_(gsl_vector_freep) gsl_vector *b = gsl_vector_alloc(sys->n_free);

	if (!y || !b)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (int comp = 0; comp < 2; comp++) {
		/* Start from the identity map, S(x) = x, in scaled unknowns. */
		for (size_t i = 0; i < n; i++) {
			size_t fi = sys->index[i];
			if (fi == SIZE_MAX)
				continue;
			gsl_vector_set(y, fi, xy[2 * i + comp] / sys->dscale[fi]);
			gsl_vector_set(b, fi, sys->rhs[2 * fi + comp]);
		}
		int r = conjugate_gradients(sys->k, b, y, err);
		if (r < 0)
			return r;
		for (size_t i = 0; i < n; i++) {
			size_t fi = sys->index[i];
			S_out[2 * i + comp] = fi == SIZE_MAX ? S_fixed[2 * i + comp] :
				gsl_vector_get(y, fi) * sys->dscale[fi];
		}
	}
	return 0;
}

static int check_mesh(const double *xy, size_t n, const uint32_t *tri,
		      size_t ntri, struct asph_error *err)
{
	if (n == 0 || ntri == 0)
		return asph_error_set(err, -EINVAL,
				      "the mesh needs nodes and triangles");
	if (n > UINT32_MAX)
		return asph_error_set(err, -EINVAL, "too many nodes (%zu)", n);
	for (size_t t = 0; t < 3 * ntri; t++)
		if (tri[t] >= n)
			return asph_error_set(err, -EINVAL,
				"triangle %zu refers to node %u of %zu",
				t / 3, (unsigned)tri[t], n);
	for (size_t t = 0; t < ntri; t++)
		if (degenerate(xy, tri + 3 * t))
			return asph_error_set(err, -EINVAL,
					      "triangle %zu is degenerate", t);
	return 0;
}

int asph_lb_fem_solve_graph(asph_lb_gradient_fn gradient, void *ctx,
			    const double *xy, size_t n, const uint32_t *tri,
			    size_t ntri, double *S_out, struct asph_error *err)
{
	return asph_lb_fem_solve_graph_dirichlet(gradient, ctx, NULL, NULL, xy, n, tri, ntri,
						 S_out, err);
}

int asph_lb_fem_solve_graph_dirichlet(asph_lb_gradient_fn gradient, void *ctx,
				      asph_lb_boundary_fn boundary, void *bctx,
				      const double *xy, size_t n, const uint32_t *tri,
				      size_t ntri, double *S_out, struct asph_error *err)
{
	int r = check_mesh(xy, n, tri, ntri, err);
	if (r < 0)
		return r;

	_cleanup_free_ uint8_t *fixed = malloc(n);
	_cleanup_free_ size_t *index = malloc(n * sizeof(size_t));
	_cleanup_free_ double *S_fixed = malloc(2 * n * sizeof(double));
	if (!fixed || !index || !S_fixed)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (mark_fixed(tri, ntri, n, fixed) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");

	struct system sys = { .index = index };
	for (size_t i = 0; i < n; i++) {
		index[i] = fixed[i] ? SIZE_MAX : sys.n_free++;
		S_fixed[2 * i] = xy[2 * i];
		S_fixed[2 * i + 1] = xy[2 * i + 1];
		if (fixed[i] && boundary)
			boundary(bctx, xy[2 * i], xy[2 * i + 1], S_fixed + 2 * i);
	}
	if (sys.n_free == 0) {
		memcpy(S_out, S_fixed, 2 * n * sizeof(double));
		return 0;
	}
	_cleanup_free_ double *dscale = malloc(sys.n_free * sizeof(double));
	_cleanup_free_ double *rhs = calloc(2 * sys.n_free, sizeof(double));
	if (!dscale || !rhs)
		return asph_error_set(err, -ENOMEM, "out of memory");
	sys.dscale = dscale;
	sys.rhs = rhs;
	r = assemble(gradient, ctx, xy, S_fixed, tri, ntri, &sys, err);
	if (r == 0)
		r = solve(&sys, xy, S_fixed, n, S_out, err);
	if (sys.k)
		gsl_spmatrix_free(sys.k);
	return r;
}

static void radial_gradient(void *ctx, double x, double y, double grad[2])
{
	const struct asph_surface *s = ctx;
	double r = hypot(x, y), d[3];

	if (r == 0) {
		grad[0] = grad[1] = 0;
		return;
	}
	asph_surface_sag_derivs(s, r, d);
	grad[0] = d[1] * x / r;
	grad[1] = d[1] * y / r;
}

int asph_lb_fem_solve(const struct asph_surface *s, const double *xy,
		      size_t n, const uint32_t *tri, size_t ntri,
		      double *S_out, struct asph_error *err)
{
	return asph_lb_fem_solve_graph(radial_gradient, (void *)s, xy, n, tri,
				       ntri, S_out, err);
}
