/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The OT map of a freeform's aperture by Newton's method on a spectral
 * collocation of the Monge-Ampere equation (asph/ot.h).
 *
 * The aperture is x = c + D xi, D = diag(hx, hy), xi in the unit disk (a
 * circle or an ellipse) or the square [-1, 1]^2 (a rectangle). With
 * phi(x) the Brenier potential, u(xi) = phi(c + D xi) - (D c) . xi has
 * grad u = D^2 eta, where T(x) = c + D eta, eta in the same reference
 * domain, so that
 *
 *     T(x) = c + (u_1 / hx, u_2 / hy),
 *     det D^2 phi = det D^2 u / K,   K = hx^2 hy^2,
 *
 * and the equation and boundary conditions read, at the collocation nodes,
 *
 *     F = det D^2 u / K - g / w(T) = 0                  inside,
 *     G = (u_1 / hx^2)^2 + (u_2 / hy^2)^2 - 1 = 0        on |xi| = 1 (disk),
 *     G = u_1 -+ hx^2 = 0 on xi_1 = +-1, u_2 -+ hy^2 = 0 on xi_2 = +-1  (square),
 *
 * with g (the discrete mass ratio, -> gamma) an unknown and u fixed at one
 * node (u is defined up to a constant): as many equations as unknowns.
 * Newton's method starts from the identity, u = (hx^2 xi_1^2 + hy^2 xi_2^2)/2,
 * g = gamma, with a backtracking line search that keeps u convex at the
 * nodes; if it stalls, the density is reached by continuation
 * (w_t = 1 + t (w - 1)). The dense Jacobian is factorized by LU.
 *
 * Disk: nodes r_i > 0 of a Chebyshev grid over the whole diameter [-1, 1]
 * (an even number 2 nr of points, none at the centre) times nt equally
 * spaced angles; a value at -r is the value at r on the opposite angle
 * (Trefethen, Spectral Methods in MATLAB, ch. 11). Square: the Chebyshev
 * tensor grid, boundary included.
 */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_linalg.h>
#include <gsl/gsl_permutation.h>

#include "asph/ot.h"
#include "util-mem.h"

#define DEFAULT_TOLERANCE 1e-6
#define DEFAULT_MAX_DISK 28
#define DEFAULT_MAX_SQUARE 40
#define FIRST_DISK 10
#define FIRST_SQUARE 12
#define NEWTON_TOL 1e-12
/* The residual rounding leaves: the collocated second derivatives lose
 * ~N^4 eps. Where no step length reduces a residual below it, Newton's
 * method has converged (the check between the nodes says how well). */
#define ROUNDING_FLOOR 1e-9
#define MAX_NEWTON 30
#define MAX_HALVINGS 12
/* Table of T for apply(): cells per unit of r (or of xi), angles. */
#define TABLE_R 160
#define TABLE_T 768
#define TABLE_XI 320
#define TABLE_PAD 3

enum geometry { GEOM_DISK, GEOM_SQUARE };

/* The native derivatives: disk (r, t, rr, rt, tt), square (1, 2, 11, 12, 22). */
enum { N_D = 0, T_D, NN_D, NT_D, TT_D, N_DERIV };

struct spectral {
	enum geometry geom;
	int nr, nt;             /* disk: radii, angles; square: points per side, twice */
	size_t n;
	double *x;              /* disk: the 2 nr diameter points; square: nr points */
	double *d1, *d2;        /* Chebyshev differentiation (2 nr or nr square) */
	double *e1, *e2;        /* disk: Fourier differentiation, nt x nt */
	double *bw;             /* barycentric weights of x */
};

struct asph_ot_map {
	const struct asph_surface *s;
	enum geometry geom;
	double c[2], hx, hy, K, gamma;
	double tol;
	int max_nodes, nodes;
	struct spectral sp;
	double *u, *fval, *deriv[N_DERIV];
	double g;               /* discrete mass ratio */
	double t;               /* continuation: the density is 1 + t (w - 1) */
	double t_done;          /* the last t converged at */
	double t_step;          /* the continuation's step */
	int stage_steps;        /* Newton steps at this t and resolution */
	double *u_done;         /* the solution at t_done */
	double g_done;
	int steps;
	double residual, jac_err;
	bool done;
	/* apply(): T on a uniform table (disk: r x angle; square: xi_1 x xi_2) */
	int tr, tt;
	double t0, dr, dt;
	double *T1, *T2;
};

/* ---- the collocation grid --------------------------------------------------- */

static void spectral_clear(struct spectral *sp)
{
	free(sp->x);
	free(sp->d1);
	free(sp->d2);
	free(sp->e1);
	free(sp->e2);
	free(sp->bw);
	memset(sp, 0, sizeof(*sp));
}

/* Chebyshev points x_j = cos(pi j / N), j = 0..N, their differentiation
 * matrices (Trefethen's cheb) and barycentric weights. */
static int chebyshev(int npts, double **x, double **d1, double **d2, double **bw)
{
	int N = npts - 1;
	double *c = malloc((size_t)npts * sizeof(double));

	*x = malloc((size_t)npts * sizeof(double));
	*d1 = calloc((size_t)npts * npts, sizeof(double));
	*d2 = calloc((size_t)npts * npts, sizeof(double));
	*bw = malloc((size_t)npts * sizeof(double));
	if (!c || !*x || !*d1 || !*d2 || !*bw) {
		free(c);
		return -ENOMEM;
	}
	for (int j = 0; j < npts; j++) {
		/* sin form: symmetric to rounding about 0 */
		(*x)[j] = sin(M_PI * (N - 2.0 * j) / (2.0 * N));
		c[j] = (j == 0 || j == N ? 2.0 : 1.0) * (j % 2 ? -1.0 : 1.0);
		(*bw)[j] = (j % 2 ? -1.0 : 1.0) * (j == 0 || j == N ? 0.5 : 1.0);
	}
	for (int i = 0; i < npts; i++) {
		double sum = 0;
		for (int j = 0; j < npts; j++) {
			if (i == j)
				continue;
			double v = (c[i] / c[j]) / ((*x)[i] - (*x)[j]);
			(*d1)[i * npts + j] = v;
			sum += v;
		}
		(*d1)[i * npts + i] = -sum;
	}
	for (int i = 0; i < npts; i++)
		for (int j = 0; j < npts; j++) {
			double v = 0;
			for (int k = 0; k < npts; k++)
				v += (*d1)[i * npts + k] * (*d1)[k * npts + j];
			(*d2)[i * npts + j] = v;
		}
	free(c);
	return 0;
}

/* Fourier differentiation on nt (even) equally spaced angles. */
static int fourier(int nt, double **e1, double **e2)
{
	double h = 2.0 * M_PI / nt;

	*e1 = malloc((size_t)nt * nt * sizeof(double));
	*e2 = malloc((size_t)nt * nt * sizeof(double));
	if (!*e1 || !*e2)
		return -ENOMEM;
	for (int i = 0; i < nt; i++)
		for (int j = 0; j < nt; j++) {
			int k = i - j;
			if (k == 0) {
				(*e1)[i * nt + j] = 0;
				(*e2)[i * nt + j] = -M_PI * M_PI / (3.0 * h * h) - 1.0 / 6.0;
				continue;
			}
			double sgn = k % 2 ? -1.0 : 1.0, half = 0.5 * k * h;
			(*e1)[i * nt + j] = 0.5 * sgn / tan(half);
			(*e2)[i * nt + j] = -0.5 * sgn / (sin(half) * sin(half));
		}
	return 0;
}

static int spectral_init(struct spectral *sp, enum geometry geom, int nodes)
{
	memset(sp, 0, sizeof(*sp));
	sp->geom = geom;
	if (geom == GEOM_DISK) {
		sp->nr = nodes;
		sp->nt = 2 * nodes;
		sp->n = (size_t)sp->nr * (size_t)sp->nt;
		if (chebyshev(2 * sp->nr, &sp->x, &sp->d1, &sp->d2, &sp->bw) < 0 ||
		    fourier(sp->nt, &sp->e1, &sp->e2) < 0)
			return -ENOMEM;
		return 0;
	}
	sp->nr = sp->nt = nodes;
	sp->n = (size_t)nodes * (size_t)nodes;
	return chebyshev(nodes, &sp->x, &sp->d1, &sp->d2, &sp->bw);
}

/* Node index. Disk: radius i (r = x[i], i = 0 on the rim), angle j. Square:
 * xi_1 = x[i], xi_2 = x[j]. */
static size_t node(const struct spectral *sp, int i, int j)
{
	return (size_t)i * (size_t)sp->nt + (size_t)j;
}

static double node_r(const struct spectral *sp, int i)
{
	return sp->x[i];
}

static double node_theta(const struct spectral *sp, int j)
{
	return 2.0 * M_PI * j / sp->nt;
}

static void node_xi(const struct spectral *sp, size_t k, double xi[2])
{
	int i = (int)(k / (size_t)sp->nt), j = (int)(k % (size_t)sp->nt);

	if (sp->geom == GEOM_DISK) {
		xi[0] = node_r(sp, i) * cos(node_theta(sp, j));
		xi[1] = node_r(sp, i) * sin(node_theta(sp, j));
	} else {
		xi[0] = sp->x[i];
		xi[1] = sp->x[j];
	}
}

static bool node_on_boundary(const struct spectral *sp, size_t k)
{
	int i = (int)(k / (size_t)sp->nt), j = (int)(k % (size_t)sp->nt);

	if (sp->geom == GEOM_DISK)
		return i == 0;
	return i == 0 || j == 0 || i == sp->nr - 1 || j == sp->nt - 1;
}

/* d/dr along the diameter through angle j at radius i: the Chebyshev
 * matrix over the 2 nr diameter points, the points at -r being those of
 * the opposite angle (A: same angle, B: opposite). */
static double cheb_a(const struct spectral *sp, const double *d, int i, int k)
{
	return d[(size_t)i * (size_t)(2 * sp->nr) + (size_t)k];
}

static double cheb_b(const struct spectral *sp, const double *d, int i, int k)
{
	return d[(size_t)i * (size_t)(2 * sp->nr) + (size_t)(2 * sp->nr - 1 - k)];
}

/* The native derivatives of u at every node. */
static void spectral_derivs(const struct spectral *sp, const double *u, double **out)
{
	int nr = sp->nr, nt = sp->nt;

	for (int i = 0; i < nr; i++)
		for (int j = 0; j < nt; j++) {
			size_t k0 = node(sp, i, j);
			double v[N_DERIV] = { 0 };
			if (sp->geom == GEOM_DISK) {
				int jo = (j + nt / 2) % nt;
				for (int k = 0; k < nr; k++) {
					double ua = u[node(sp, k, j)], ub = u[node(sp, k, jo)];
					v[N_D] += cheb_a(sp, sp->d1, i, k) * ua + cheb_b(sp, sp->d1, i, k) * ub;
					v[NN_D] += cheb_a(sp, sp->d2, i, k) * ua + cheb_b(sp, sp->d2, i, k) * ub;
				}
				for (int l = 0; l < nt; l++) {
					v[T_D] += sp->e1[j * nt + l] * u[node(sp, i, l)];
					v[TT_D] += sp->e2[j * nt + l] * u[node(sp, i, l)];
				}
				for (int k = 0; k < nr; k++) {
					double ta = 0, tb = 0;
					for (int l = 0; l < nt; l++) {
						ta += sp->e1[j * nt + l] * u[node(sp, k, l)];
						tb += sp->e1[jo * nt + l] * u[node(sp, k, l)];
					}
					v[NT_D] += cheb_a(sp, sp->d1, i, k) * ta + cheb_b(sp, sp->d1, i, k) * tb;
				}
			} else {
				for (int k = 0; k < nr; k++) {
					v[N_D] += sp->d1[i * nr + k] * u[node(sp, k, j)];
					v[NN_D] += sp->d2[i * nr + k] * u[node(sp, k, j)];
					v[T_D] += sp->d1[j * nr + k] * u[node(sp, i, k)];
					v[TT_D] += sp->d2[j * nr + k] * u[node(sp, i, k)];
					double t = 0;
					for (int l = 0; l < nt; l++)
						t += sp->d1[j * nr + l] * u[node(sp, k, l)];
					v[NT_D] += sp->d1[i * nr + k] * t;
				}
			}
			for (int q = 0; q < N_DERIV; q++)
				out[q][k0] = v[q];
		}
}

/*
 * The Cartesian derivatives (u_1, u_2, u_11, u_12, u_22) from the native
 * ones at a point of polar coordinates (r, theta) (disk) or as they are
 * (square): cart = M nat. M is returned for the Jacobian.
 */
enum { C1, C2, C11, C12, C22 };

static void native_to_cartesian(enum geometry geom, double r, double theta, double M[5][5])
{
	memset(M, 0, 25 * sizeof(double));
	if (geom == GEOM_SQUARE) {
		for (int q = 0; q < 5; q++)
			M[q][q] = 1;
		return;
	}
	double c = cos(theta), s = sin(theta), ir = 1.0 / r, ir2 = ir * ir;
	double sc = s * c, cc = c * c - s * s;

	M[C1][N_D] = c;
	M[C1][T_D] = -s * ir;
	M[C2][N_D] = s;
	M[C2][T_D] = c * ir;
	M[C11][N_D] = s * s * ir;
	M[C11][T_D] = 2 * sc * ir2;
	M[C11][NN_D] = c * c;
	M[C11][NT_D] = -2 * sc * ir;
	M[C11][TT_D] = s * s * ir2;
	M[C12][N_D] = -sc * ir;
	M[C12][T_D] = -cc * ir2;
	M[C12][NN_D] = sc;
	M[C12][NT_D] = cc * ir;
	M[C12][TT_D] = -sc * ir2;
	M[C22][N_D] = c * c * ir;
	M[C22][T_D] = -2 * sc * ir2;
	M[C22][NN_D] = s * s;
	M[C22][NT_D] = 2 * sc * ir;
	M[C22][TT_D] = c * c * ir2;
}

static void node_cartesian(const struct spectral *sp, size_t k, double *const *nat,
			   double cart[5], double M[5][5])
{
	int i = (int)(k / (size_t)sp->nt), j = (int)(k % (size_t)sp->nt);

	native_to_cartesian(sp->geom, sp->geom == GEOM_DISK ? node_r(sp, i) : 1,
			    node_theta(sp, j), M);
	for (int q = 0; q < 5; q++) {
		cart[q] = 0;
		for (int p = 0; p < N_DERIV; p++)
			cart[q] += M[q][p] * nat[p][k];
	}
}

/* row += sum_q a[q] (native operator q's row at node k). */
static void spectral_add_row(const struct spectral *sp, size_t k, const double a[N_DERIV],
			     double *row)
{
	int i = (int)(k / (size_t)sp->nt), j = (int)(k % (size_t)sp->nt);
	int nr = sp->nr, nt = sp->nt;

	if (sp->geom == GEOM_DISK) {
		int jo = (j + nt / 2) % nt;
		for (int q = 0; q < nr; q++) {
			row[node(sp, q, j)] += a[N_D] * cheb_a(sp, sp->d1, i, q) +
					       a[NN_D] * cheb_a(sp, sp->d2, i, q);
			row[node(sp, q, jo)] += a[N_D] * cheb_b(sp, sp->d1, i, q) +
						a[NN_D] * cheb_b(sp, sp->d2, i, q);
		}
		for (int l = 0; l < nt; l++)
			row[node(sp, i, l)] += a[T_D] * sp->e1[j * nt + l] +
					       a[TT_D] * sp->e2[j * nt + l];
		if (a[NT_D] == 0)
			return;
		for (int q = 0; q < nr; q++) {
			double ca = a[NT_D] * cheb_a(sp, sp->d1, i, q);
			double cb = a[NT_D] * cheb_b(sp, sp->d1, i, q);
			for (int l = 0; l < nt; l++)
				row[node(sp, q, l)] += ca * sp->e1[j * nt + l] + cb * sp->e1[jo * nt + l];
		}
		return;
	}
	for (int q = 0; q < nr; q++) {
		row[node(sp, q, j)] += a[N_D] * sp->d1[i * nr + q] + a[NN_D] * sp->d2[i * nr + q];
		row[node(sp, i, q)] += a[T_D] * sp->d1[j * nr + q] + a[TT_D] * sp->d2[j * nr + q];
	}
	if (a[NT_D] == 0)
		return;
	for (int q = 0; q < nr; q++)
		for (int l = 0; l < nt; l++)
			row[node(sp, q, l)] += a[NT_D] * sp->d1[i * nr + q] * sp->d1[j * nr + l];
}

/* ---- interpolation of a field between the nodes -------------------------- */

/* Barycentric interpolation weights of the Chebyshev points x (n of them,
 * weights bw) at z: w[k], summing to 1. */
static void cheb_weights(const double *x, const double *bw, int n, double z, double *w)
{
	double sum = 0;

	for (int k = 0; k < n; k++) {
		if (z == x[k]) {
			for (int q = 0; q < n; q++)
				w[q] = q == k;
			return;
		}
		w[k] = bw[k] / (z - x[k]);
		sum += w[k];
	}
	for (int k = 0; k < n; k++)
		w[k] /= sum;
}

/* Trigonometric interpolation weights of nt (even) equally spaced angles
 * at theta. */
static void trig_weights(int nt, double theta, double *w)
{
	double h = 2.0 * M_PI / nt;

	for (int l = 0; l < nt; l++) {
		double d = theta - h * l;
		double s = sin(0.5 * d);
		if (fabs(s) < 1e-15) {
			for (int q = 0; q < nt; q++)
				w[q] = q == l;
			return;
		}
		w[l] = sin(0.5 * nt * d) * cos(0.5 * d) / (nt * s);
	}
}

/*
 * Resamples the fields f[0..nf) given at the nodes onto a tensor grid of
 * m1 x m2 points: disk radii rs[] (>= 0) times angles ts[]; square xi_1 =
 * rs[] times xi_2 = ts[]. out[q][a * m2 + b].
 */
static int spectral_resample(const struct spectral *sp, double *const *f, int nf,
			     const double *rs, int m1, const double *ts, int m2, double **out)
{
	int nr = sp->nr, nt = sp->nt, nd = sp->geom == GEOM_DISK ? 2 * nr : nr;
	_cleanup_free_ double *wt = malloc((size_t)nt * sizeof(double));
	_cleanup_free_ double *wr = malloc((size_t)nd * sizeof(double));
	/* first the angle (or xi_2): mid[q][k * m2 + b] at each radius node */
	_cleanup_free_ double *mid = malloc((size_t)nf * (size_t)nr * (size_t)m2 * sizeof(double));

	if (!wt || !wr || !mid)
		return -ENOMEM;
	for (int b = 0; b < m2; b++) {
		if (sp->geom == GEOM_DISK)
			trig_weights(nt, ts[b], wt);
		else
			cheb_weights(sp->x, sp->bw, nr, ts[b], wt);
		for (int q = 0; q < nf; q++)
			for (int k = 0; k < nr; k++) {
				double v = 0;
				for (int l = 0; l < nt; l++)
					v += wt[l] * f[q][node(sp, k, l)];
				mid[((size_t)q * nr + (size_t)k) * (size_t)m2 + (size_t)b] = v;
			}
	}
	if (sp->geom == GEOM_DISK) {
		/* the value at the opposite angle, for the other half of the
		 * diameter: the same resampling at theta + pi */
		_cleanup_free_ double *opp = malloc((size_t)nf * (size_t)nr * (size_t)m2 *
						    sizeof(double));
		if (!opp)
			return -ENOMEM;
		for (int b = 0; b < m2; b++) {
			trig_weights(nt, ts[b] + M_PI, wt);
			for (int q = 0; q < nf; q++)
				for (int k = 0; k < nr; k++) {
					double v = 0;
					for (int l = 0; l < nt; l++)
						v += wt[l] * f[q][node(sp, k, l)];
					opp[((size_t)q * nr + (size_t)k) * (size_t)m2 + (size_t)b] = v;
				}
		}
		for (int a = 0; a < m1; a++) {
			cheb_weights(sp->x, sp->bw, nd, rs[a], wr);
			for (int q = 0; q < nf; q++)
				for (int b = 0; b < m2; b++) {
					double v = 0;
					for (int k = 0; k < nr; k++)
						v += wr[k] * mid[((size_t)q * nr + (size_t)k) * (size_t)m2 + (size_t)b] +
						     wr[nd - 1 - k] * opp[((size_t)q * nr + (size_t)k) * (size_t)m2 + (size_t)b];
					out[q][(size_t)a * (size_t)m2 + (size_t)b] = v;
				}
		}
		return 0;
	}
	for (int a = 0; a < m1; a++) {
		cheb_weights(sp->x, sp->bw, nr, rs[a], wr);
		for (int q = 0; q < nf; q++)
			for (int b = 0; b < m2; b++) {
				double v = 0;
				for (int k = 0; k < nr; k++)
					v += wr[k] * mid[((size_t)q * nr + (size_t)k) * (size_t)m2 + (size_t)b];
				out[q][(size_t)a * (size_t)m2 + (size_t)b] = v;
			}
	}
	return 0;
}

/* ---- the equations ------------------------------------------------------------ */

/* w and grad w at x (the density 1 + t (w - 1) of the continuation). */
static double density(const struct asph_ot_map *m, double x, double y, double grad[2])
{
	struct asph_sag d;

	asph_surface_derivs_xy(m->s, x, y, &d);
	double w = sqrt(1.0 + d.zx * d.zx + d.zy * d.zy);
	grad[0] = m->t * (d.zx * d.zxx + d.zy * d.zxy) / w;
	grad[1] = m->t * (d.zx * d.zxy + d.zy * d.zyy) / w;
	return 1.0 + m->t * (w - 1.0);
}

static void map_point(const struct asph_ot_map *m, const double cart[5], double x[2])
{
	x[0] = m->c[0] + cart[C1] / m->hx;
	x[1] = m->c[1] + cart[C2] / m->hy;
}

/* The boundary equation at a node whose reference point is xi; its
 * derivatives by the Cartesian first derivatives in dc. */
static double boundary_eq(const struct asph_ot_map *m, const double xi[2], const double cart[5],
			  double dc[5])
{
	double hx2 = m->hx * m->hx, hy2 = m->hy * m->hy;

	memset(dc, 0, 5 * sizeof(double));
	if (m->geom == GEOM_DISK) {
		double e1 = cart[C1] / hx2, e2 = cart[C2] / hy2;
		dc[C1] = 2 * e1 / hx2;
		dc[C2] = 2 * e2 / hy2;
		return e1 * e1 + e2 * e2 - 1;
	}
	bool side1 = fabs(xi[0]) == 1, side2 = fabs(xi[1]) == 1;
	double g = 0;
	if (side1) {
		g += (cart[C1] - copysign(hx2, xi[0])) / hx2;
		dc[C1] = 1 / hx2;
	}
	if (side2) {
		g += (cart[C2] - copysign(hy2, xi[1])) / hy2;
		dc[C2] = 1 / hy2;
	}
	return g;
}

/* Residuals at every node into m->fval (n of them) and, if J is not NULL,
 * the Jacobian (n + 1 square, row major; the last unknown is g, the last
 * equation fixes u at node 0). Returns the largest |residual|, or NaN
 * where u is not convex or the map leaves the surface's domain. */
static double equations(struct asph_ot_map *m, const double *u, double g, double *J)
{
	const struct spectral *sp = &m->sp;
	size_t n = sp->n, ld = n + 1;
	double worst = 0;

	spectral_derivs(sp, u, m->deriv);
	for (size_t k = 0; k < n; k++) {
		double cart[5], M[5][5], dc[5] = { 0 }, xi[2], f, gw = 0;
		node_cartesian(sp, k, m->deriv, cart, M);
		node_xi(sp, k, xi);
		if (node_on_boundary(sp, k)) {
			f = boundary_eq(m, xi, cart, dc);
		} else {
			double x[2], grad[2], w;
			map_point(m, cart, x);
			w = density(m, x[0], x[1], grad);
			double det = cart[C11] * cart[C22] - cart[C12] * cart[C12];
			if (!(cart[C11] > 0 && det > 0) || !isfinite(w))
				return NAN;
			f = det / m->K - g / w;
			dc[C11] = cart[C22] / m->K;
			dc[C22] = cart[C11] / m->K;
			dc[C12] = -2 * cart[C12] / m->K;
			dc[C1] = g / (w * w) * grad[0] / m->hx;
			dc[C2] = g / (w * w) * grad[1] / m->hy;
			gw = -1 / w;
		}
		m->fval[k] = f;
		worst = fmax(worst, fabs(f));
		if (!J)
			continue;
		double a[N_DERIV] = { 0 }, *row = J + k * ld;
		for (int p = 0; p < N_DERIV; p++)
			for (int q = 0; q < 5; q++)
				a[p] += M[q][p] * dc[q];
		memset(row, 0, ld * sizeof(double));
		spectral_add_row(sp, k, a, row);
		row[n] = gw;
	}
	if (J) {
		memset(J + n * ld, 0, ld * sizeof(double));
		J[n * ld] = 1;
	}
	return worst;
}

/* ---- the solver ------------------------------------------------------------------ */

static void identity_guess(struct asph_ot_map *m)
{
	for (size_t k = 0; k < m->sp.n; k++) {
		double xi[2];
		node_xi(&m->sp, k, xi);
		m->u[k] = 0.5 * (m->hx * m->hx * xi[0] * xi[0] + m->hy * m->hy * xi[1] * xi[1]);
	}
	/* u is fixed at node 0 */
	double u0 = m->u[0];
	for (size_t k = 0; k < m->sp.n; k++)
		m->u[k] -= u0;
	m->g = m->gamma;
}

static void free_fields(struct asph_ot_map *m)
{
	free(m->u);
	free(m->fval);
	free(m->u_done);
	for (int q = 0; q < N_DERIV; q++)
		free(m->deriv[q]);
	m->u = m->fval = m->u_done = NULL;
	for (int q = 0; q < N_DERIV; q++)
		m->deriv[q] = NULL;
	spectral_clear(&m->sp);
}

static int alloc_fields(struct asph_ot_map *m, int nodes)
{
	free_fields(m);
	m->nodes = nodes;
	if (spectral_init(&m->sp, m->geom, nodes) < 0)
		return -ENOMEM;
	size_t n = m->sp.n;
	m->u = malloc(n * sizeof(double));
	m->fval = malloc(n * sizeof(double));
	m->u_done = malloc(n * sizeof(double));
	for (int q = 0; q < N_DERIV; q++)
		m->deriv[q] = malloc(n * sizeof(double));
	if (!m->u || !m->fval || !m->u_done)
		return -ENOMEM;
	for (int q = 0; q < N_DERIV; q++)
		if (!m->deriv[q])
			return -ENOMEM;
	return 0;
}

/* One damped Newton step at the current resolution and t. 1 when it has
 * converged, 0 when it moved, -EAGAIN when no step length reduces the
 * residual, -ENOMEM. */
static int newton_step(struct asph_ot_map *m)
{
	size_t n = m->sp.n, ld = n + 1;
	_cleanup_free_ double *J = malloc(ld * ld * sizeof(double));
	_cleanup_free_ double *rhs = malloc(ld * sizeof(double));
	_cleanup_free_ double *trial = malloc(n * sizeof(double));
	gsl_permutation *perm = gsl_permutation_alloc(ld);
	int signum;

	if (!J || !rhs || !trial || !perm) {
		gsl_permutation_free(perm);
		return -ENOMEM;
	}
	double res = equations(m, m->u, m->g, J);
	m->residual = res;
	if (res <= NEWTON_TOL) {
		gsl_permutation_free(perm);
		return 1;
	}
	for (size_t k = 0; k < n; k++)
		rhs[k] = -m->fval[k];
	rhs[n] = -m->u[0];
	gsl_matrix_view A = gsl_matrix_view_array(J, ld, ld);
	gsl_vector_view b = gsl_vector_view_array(rhs, ld);
	if (gsl_linalg_LU_decomp(&A.matrix, perm, &signum) != 0 ||
	    gsl_linalg_LU_svx(&A.matrix, perm, &b.vector) != 0) {
		gsl_permutation_free(perm);
		return -EAGAIN;
	}
	gsl_permutation_free(perm);
	for (double lambda = 1; lambda >= pow(0.5, MAX_HALVINGS); lambda *= 0.5) {
		for (size_t k = 0; k < n; k++)
			trial[k] = m->u[k] + lambda * rhs[k];
		double g = m->g + lambda * rhs[n];
		double r = equations(m, trial, g, NULL);
		if (r < (1 - 1e-4 * lambda) * res || (r <= NEWTON_TOL && r <= res)) {
			memcpy(m->u, trial, n * sizeof(double));
			m->g = g;
			m->residual = r;
			m->steps++;
			return r <= NEWTON_TOL ? 1 : 0;
		}
	}
	return res <= ROUNDING_FLOOR ? 1 : -EAGAIN;
}

/* The Jacobian equation between the nodes: |det DT w(T) / g - 1| at the
 * midpoints of the node grid (and the boundary condition at the
 * midpoints of the rim or sides), on the interpolated solution. */
static int check_between_nodes(struct asph_ot_map *m, double *worst)
{
	const struct spectral *sp = &m->sp;
	int m1 = sp->geom == GEOM_DISK ? sp->nr : sp->nr - 1, m2 = sp->geom == GEOM_DISK ? sp->nt : sp->nt - 1;
	_cleanup_free_ double *rs = malloc((size_t)m1 * sizeof(double));
	_cleanup_free_ double *ts = malloc((size_t)m2 * sizeof(double));
	double *out[5] = { 0 }, *cart_nodes[5] = { 0 };
	int r = -ENOMEM;

	*worst = 0;
	if (!rs || !ts)
		return -ENOMEM;
	for (int q = 0; q < 5; q++)
		if (!(out[q] = malloc((size_t)m1 * (size_t)m2 * sizeof(double))) ||
		    !(cart_nodes[q] = malloc(sp->n * sizeof(double))))
			goto out;
	if (sp->geom == GEOM_DISK) {
		/* the rim, then the midpoints between radii; angles halfway */
		rs[0] = 1;
		for (int a = 1; a < m1; a++)
			rs[a] = 0.5 * (sp->x[a - 1] + sp->x[a]);
		for (int b = 0; b < m2; b++)
			ts[b] = (b + 0.5) * 2.0 * M_PI / sp->nt;
	} else {
		for (int a = 0; a < m1; a++)
			rs[a] = 0.5 * (sp->x[a] + sp->x[a + 1]);
		for (int b = 0; b < m2; b++)
			ts[b] = 0.5 * (sp->x[b] + sp->x[b + 1]);
	}
	/* The Cartesian derivatives are single-valued functions of the point,
	 * which the native ones are not across the centre (u_r at -r is minus
	 * that of the opposite angle): they are what is interpolated. */
	spectral_derivs(sp, m->u, m->deriv);
	for (size_t k = 0; k < sp->n; k++) {
		double M[5][5], cart[5];
		node_cartesian(sp, k, m->deriv, cart, M);
		for (int q = 0; q < 5; q++)
			cart_nodes[q][k] = cart[q];
	}
	r = spectral_resample(sp, cart_nodes, 5, rs, m1, ts, m2, out);
	if (r < 0)
		goto out;
	for (int a = 0; a < m1; a++)
		for (int b = 0; b < m2; b++) {
			size_t k = (size_t)a * (size_t)m2 + (size_t)b;
			double cart[5], x[2], grad[2];
			for (int q = 0; q < 5; q++)
				cart[q] = out[q][k];
			if (sp->geom == GEOM_DISK && a == 0) {
				double e1 = cart[C1] / (m->hx * m->hx), e2 = cart[C2] / (m->hy * m->hy);
				*worst = fmax(*worst, fabs(hypot(e1, e2) - 1));
				continue;
			}
			map_point(m, cart, x);
			double w = density(m, x[0], x[1], grad);
			double det = cart[C11] * cart[C22] - cart[C12] * cart[C12];
			double e = det / m->K * w / m->g - 1;
			*worst = isfinite(e) ? fmax(*worst, fabs(e)) : INFINITY;
		}
	r = 0;
out:
	for (int q = 0; q < 5; q++) {
		free(out[q]);
		free(cart_nodes[q]);
	}
	return r;
}

/* The boundary condition between the nodes of a square's sides. */
static int check_square_sides(struct asph_ot_map *m, double *worst)
{
	const struct spectral *sp = &m->sp;
	int mm = sp->nr - 1;
	_cleanup_free_ double *mids = malloc((size_t)mm * sizeof(double));
	_cleanup_free_ double *a = malloc(2 * (size_t)mm * sizeof(double));
	_cleanup_free_ double *b = malloc(2 * (size_t)mm * sizeof(double));
	double ends[2] = { -1, 1 };
	double *fa[1] = { a }, *fb[1] = { b };

	if (!mids || !a || !b)
		return -ENOMEM;
	for (int k = 0; k < mm; k++)
		mids[k] = 0.5 * (sp->x[k] + sp->x[k + 1]);
	/* u_1 on xi_1 = -1, 1; u_2 on xi_2 = -1, 1 */
	if (spectral_resample(sp, &m->deriv[N_D], 1, ends, 2, mids, mm, fa) < 0 ||
	    spectral_resample(sp, &m->deriv[T_D], 1, mids, mm, ends, 2, fb) < 0)
		return -ENOMEM;
	for (int k = 0; k < mm; k++) {
		for (int e = 0; e < 2; e++) {
			*worst = fmax(*worst, fabs(a[e * mm + k] / (m->hx * m->hx) - ends[e]));
			*worst = fmax(*worst, fabs(b[k * 2 + e] / (m->hy * m->hy) - ends[e]));
		}
	}
	return 0;
}

/* u on the finer grid of `nodes`, interpolated from the current one. */
static int refine(struct asph_ot_map *m, int nodes)
{
	struct spectral old = m->sp;
	double *old_u = m->u;
	struct spectral fresh;
	int r;

	if (spectral_init(&fresh, m->geom, nodes) < 0) {
		spectral_clear(&fresh);
		return -ENOMEM;
	}
	int m1 = fresh.nr, m2 = fresh.nt;
	_cleanup_free_ double *rs = malloc((size_t)m1 * sizeof(double));
	_cleanup_free_ double *ts = malloc((size_t)m2 * sizeof(double));
	_cleanup_free_ double *nu = malloc(fresh.n * sizeof(double));
	if (!rs || !ts || !nu) {
		spectral_clear(&fresh);
		return -ENOMEM;
	}
	for (int a = 0; a < m1; a++)
		rs[a] = fresh.x[a];
	for (int b = 0; b < m2; b++)
		ts[b] = m->geom == GEOM_DISK ? node_theta(&fresh, b) : fresh.x[b];
	double *out[1] = { nu };
	r = spectral_resample(&old, &old_u, 1, rs, m1, ts, m2, out);
	spectral_clear(&fresh);
	if (r < 0)
		return r;
	double g = m->g;
	m->u = NULL;
	m->sp = (struct spectral){ 0 };
	spectral_clear(&old);
	free(old_u);
	r = alloc_fields(m, nodes);
	if (r < 0)
		return r;
	for (size_t k = 0; k < m->sp.n; k++)
		m->u[k] = nu[k] - nu[0];
	m->g = g;
	memcpy(m->u_done, m->u, m->sp.n * sizeof(double));
	m->g_done = g;
	return 0;
}

/* ---- the map's tables ---------------------------------------------------- */

static int build_tables(struct asph_ot_map *m)
{
	const struct spectral *sp = &m->sp;
	size_t n = sp->n;
	_cleanup_free_ double *f1 = malloc(n * sizeof(double));
	_cleanup_free_ double *f2 = malloc(n * sizeof(double));
	_cleanup_free_ double *rs = NULL, *ts = NULL;

	if (!f1 || !f2)
		return -ENOMEM;
	spectral_derivs(sp, m->u, m->deriv);
	for (size_t k = 0; k < n; k++) {
		double cart[5], M[5][5];
		node_cartesian(sp, k, m->deriv, cart, M);
		f1[k] = cart[C1];
		f2[k] = cart[C2];
	}
	if (m->geom == GEOM_DISK) {
		m->tr = TABLE_R + TABLE_PAD + 2;
		m->tt = TABLE_T;
		m->dr = 1.0 / TABLE_R;
		m->dt = 2.0 * M_PI / TABLE_T;
		m->t0 = 0;
	} else {
		m->tr = m->tt = TABLE_XI + 2 * TABLE_PAD + 1;
		m->dr = m->dt = 2.0 / TABLE_XI;
		m->t0 = -1.0 - TABLE_PAD * m->dr;
	}
	rs = malloc((size_t)m->tr * sizeof(double));
	ts = malloc((size_t)m->tt * sizeof(double));
	free(m->T1);
	free(m->T2);
	m->T1 = malloc((size_t)m->tr * (size_t)m->tt * sizeof(double));
	m->T2 = malloc((size_t)m->tr * (size_t)m->tt * sizeof(double));
	if (!rs || !ts || !m->T1 || !m->T2)
		return -ENOMEM;
	for (int a = 0; a < m->tr; a++)
		rs[a] = m->geom == GEOM_DISK ? a * m->dr : m->t0 + a * m->dr;
	for (int b = 0; b < m->tt; b++)
		ts[b] = m->geom == GEOM_DISK ? b * m->dt : m->t0 + b * m->dt;
	double *f[2] = { f1, f2 }, *out[2] = { m->T1, m->T2 };
	int r = spectral_resample(sp, f, 2, rs, m->tr, ts, m->tt, out);
	if (r < 0)
		return r;
	for (size_t k = 0; k < (size_t)m->tr * (size_t)m->tt; k++) {
		m->T1[k] = m->c[0] + m->T1[k] / m->hx;
		m->T2[k] = m->c[1] + m->T2[k] / m->hy;
	}
	return 0;
}

/* Cubic Lagrange weights at fraction f of the cell [1, 2] of the nodes
 * 0, 1, 2, 3, and their derivatives. */
static void cubic_weights(double f, double w[4], double dw[4])
{
	double a = f + 1, b = f, c = f - 1, d = f - 2;

	w[0] = -b * c * d / 6;
	w[1] = a * c * d / 2;
	w[2] = -a * b * d / 2;
	w[3] = a * b * c / 6;
	dw[0] = -(c * d + b * d + b * c) / 6;
	dw[1] = (c * d + a * d + a * c) / 2;
	dw[2] = -(b * d + a * d + a * b) / 2;
	dw[3] = (b * c + a * c + a * b) / 6;
}

/* The tables at (fractional) indices (pa, pb): T and its derivatives by
 * the two table coordinates. */
static void table_eval(const struct asph_ot_map *m, double pa, double pb, double T[2],
		       double dTa[2], double dTb[2])
{
	int a0 = (int)floor(pa) - 1, b0 = (int)floor(pb) - 1;
	double wa[4], dwa[4], wb[4], dwb[4];

	cubic_weights(pa - floor(pa), wa, dwa);
	cubic_weights(pb - floor(pb), wb, dwb);
	for (int c = 0; c < 2; c++)
		T[c] = dTa[c] = dTb[c] = 0;
	for (int i = 0; i < 4; i++) {
		int a = a0 + i, shift = 0;
		if (m->geom == GEOM_DISK && a < 0) {
			a = -a;
			shift = m->tt / 2;      /* r < 0: the opposite angle */
		}
		if (a > m->tr - 1)
			a = m->tr - 1;
		if (m->geom == GEOM_SQUARE && a < 0)
			a = 0;
		for (int j = 0; j < 4; j++) {
			int b = b0 + j;
			if (m->geom == GEOM_DISK)
				b = ((b + shift) % m->tt + m->tt) % m->tt;
			else
				b = b < 0 ? 0 : b > m->tt - 1 ? m->tt - 1 : b;
			size_t k = (size_t)a * (size_t)m->tt + (size_t)b;
			double v[2] = { m->T1[k], m->T2[k] };
			for (int c = 0; c < 2; c++) {
				T[c] += wa[i] * wb[j] * v[c];
				dTa[c] += dwa[i] * wb[j] * v[c];
				dTb[c] += wa[i] * dwb[j] * v[c];
			}
		}
	}
}

void asph_ot_map_apply(const struct asph_ot_map *m, double x, double y, double T[2],
		       double jac[4])
{
	double xi[2] = { (x - m->c[0]) / m->hx, (y - m->c[1]) / m->hy };
	double dTa[2], dTb[2];

	if (m->geom == GEOM_SQUARE) {
		table_eval(m, (xi[0] - m->t0) / m->dr, (xi[1] - m->t0) / m->dt, T, dTa, dTb);
		if (jac) {
			jac[0] = dTa[0] / (m->dr * m->hx);
			jac[1] = dTb[0] / (m->dt * m->hy);
			jac[2] = dTa[1] / (m->dr * m->hx);
			jac[3] = dTb[1] / (m->dt * m->hy);
		}
		return;
	}
	double r = hypot(xi[0], xi[1]), th = atan2(xi[1], xi[0]);

	if (th < 0)
		th += 2.0 * M_PI;
	table_eval(m, r / m->dr, th / m->dt, T, dTa, dTb);
	if (!jac)
		return;
	if (r > 2 * m->dr) {
		/* chain rule from (r, theta) to xi, then to x */
		double c = cos(th), s = sin(th);
		for (int k = 0; k < 2; k++) {
			double dr = dTa[k] / m->dr, dt = dTb[k] / m->dt;
			jac[2 * k] = (c * dr - s * dt / r) / m->hx;
			jac[2 * k + 1] = (s * dr + c * dt / r) / m->hy;
		}
		return;
	}
	/* near the centre, where the polar chain rule divides by r: central
	 * differences of the interpolant over a cell */
	double h = 2 * m->dr, Tp[2], Tm[2];
	for (int k = 0; k < 2; k++) {
		double e[2] = { k == 0 ? h * m->hx : 0, k == 1 ? h * m->hy : 0 };
		asph_ot_map_apply(m, x + e[0], y + e[1], Tp, NULL);
		asph_ot_map_apply(m, x - e[0], y - e[1], Tm, NULL);
		jac[k] = (Tp[0] - Tm[0]) / (2 * (e[0] + e[1]));
		jac[2 + k] = (Tp[1] - Tm[1]) / (2 * (e[0] + e[1]));
	}
}

/* ---- the stepping interface ---------------------------------------------------- */

int asph_ot_map_alloc(const struct asph_surface *s, const struct asph_ot_options *opts,
		      struct asph_ot_map **out, struct asph_error *err)
{
	struct asph_ot_options o = { 0 };
	struct asph_aperture ap;
	struct asph_ot_map *m;

	if (opts)
		o = *opts;
	if (!(o.tolerance >= 0) || o.tolerance >= 0.1)
		return asph_error_set(err, -EINVAL, "OT map: tolerance %g is not in [0, 0.1)",
				      o.tolerance);
	if (o.max_nodes < 0 || o.max_nodes > 64)
		return asph_error_set(err, -EINVAL, "OT map: max_nodes %d is not in [0, 64]",
				      o.max_nodes);
	m = calloc(1, sizeof(*m));
	if (!m)
		return asph_error_set(err, -ENOMEM, "OT map: out of memory");
	asph_surface_aperture(s, &ap);
	m->s = s;
	m->geom = ap.shape == ASPH_APERTURE_RECTANGULAR ? GEOM_SQUARE : GEOM_DISK;
	m->c[0] = ap.offset[0];
	m->c[1] = ap.offset[1];
	m->hx = 0.5 * ap.width;
	m->hy = 0.5 * ap.height;
	m->K = m->hx * m->hx * m->hy * m->hy;
	m->gamma = asph_surface_gamma(s);
	m->tol = o.tolerance > 0 ? o.tolerance : DEFAULT_TOLERANCE;
	m->max_nodes = o.max_nodes > 0 ? o.max_nodes
				       : m->geom == GEOM_DISK ? DEFAULT_MAX_DISK : DEFAULT_MAX_SQUARE;
	int first = m->geom == GEOM_DISK ? FIRST_DISK : FIRST_SQUARE;
	if (first > m->max_nodes)
		first = m->max_nodes;
	if (alloc_fields(m, first) < 0) {
		asph_ot_map_free(m);
		return asph_error_set(err, -ENOMEM, "OT map: out of memory");
	}
	/* t = 0 is solved by the identity */
	m->t = 0;
	identity_guess(m);
	m->g = 1;
	memcpy(m->u_done, m->u, m->sp.n * sizeof(double));
	m->g_done = 1;
	m->t_done = 0;
	m->t_step = 1;
	m->t = 1;
	m->g = m->gamma;
	*out = m;
	return 0;
}

void asph_ot_map_free(struct asph_ot_map *m)
{
	if (!m)
		return;
	free_fields(m);
	free(m->T1);
	free(m->T2);
	free(m);
}

int asph_ot_map_test(const struct asph_ot_map *m)
{
	return m->done;
}

static int next_resolution(const struct asph_ot_map *m)
{
	int next = m->nodes + (m->nodes + 1) / 2;

	if (m->geom == GEOM_DISK && next % 2)
		next++;
	return next > m->max_nodes ? m->max_nodes : next;
}

/* A step that converged at t: on to the next t, or check the accuracy. */
static int converged(struct asph_ot_map *m, struct asph_error *err)
{
	double worst = 0;
	int r;

	memcpy(m->u_done, m->u, m->sp.n * sizeof(double));
	m->g_done = m->g;
	m->t_done = m->t;
	m->stage_steps = 0;
	if (m->t < 1) {
		m->t_step *= 1.5;
		m->t = fmin(1, m->t + m->t_step);
		return 0;
	}
	r = check_between_nodes(m, &worst);
	if (r == 0 && m->geom == GEOM_SQUARE)
		r = check_square_sides(m, &worst);
	if (r < 0)
		return asph_error_set(err, r, "OT map: out of memory");
	m->jac_err = worst;
	if (worst <= m->tol) {
		if (build_tables(m) < 0)
			return asph_error_set(err, -ENOMEM, "OT map: out of memory");
		m->done = true;
		return 0;
	}
	if (m->nodes >= m->max_nodes)
		return asph_error_set(err, -ERANGE,
				      "OT map: the Jacobian is met to %.2g only (tolerance %.2g) at "
				      "the largest resolution (%d nodes per %s)",
				      worst, m->tol, m->nodes,
				      m->geom == GEOM_DISK ? "radius" : "side");
	return refine(m, next_resolution(m)) < 0
		       ? asph_error_set(err, -ENOMEM, "OT map: out of memory") : 0;
}

/* Newton's method stalled at t: back to the last t it converged at, and a
 * smaller step of the continuation. */
static int stalled(struct asph_ot_map *m, struct asph_error *err)
{
	m->t_step *= 0.5;
	if (m->t_step < 1e-3)
		return asph_error_set(err, -ERANGE,
				      "OT map: Newton's method fails at %.3g of the way from a "
				      "flat surface to this one (residual %.2g, %d nodes per %s)",
				      m->t_done, m->residual, m->nodes,
				      m->geom == GEOM_DISK ? "radius" : "side");
	m->t = m->t_done + m->t_step;
	memcpy(m->u, m->u_done, m->sp.n * sizeof(double));
	m->g = m->g_done;
	m->stage_steps = 0;
	return 0;
}

int asph_ot_map_iterate(struct asph_ot_map *m, struct asph_error *err)
{
	int r;

	if (m->done)
		return 0;
	r = m->stage_steps++ >= MAX_NEWTON ? -EAGAIN : newton_step(m);
	if (r == -ENOMEM)
		return asph_error_set(err, r, "OT map: out of memory");
	if (r == -EAGAIN)
		return stalled(m, err);
	if (r == 1)
		return converged(m, err);
	return 0;
}

int asph_ot_map_solve(const struct asph_surface *s, const struct asph_ot_options *opts,
		      struct asph_ot_map **out, struct asph_error *err)
{
	struct asph_ot_map *m = NULL;
	int r = asph_ot_map_alloc(s, opts, &m, err);

	while (r == 0 && !asph_ot_map_test(m))
		r = asph_ot_map_iterate(m, err);
	if (r < 0) {
		asph_ot_map_free(m);
		return r;
	}
	*out = m;
	return 0;
}

void asph_ot_map_info(const struct asph_ot_map *m, struct asph_ot_map_info *out)
{
	*out = (struct asph_ot_map_info){
		.nodes = { m->sp.nr, m->sp.nt },
		.newton_steps = m->steps,
		.residual = m->residual,
		.jacobian_error = m->jac_err,
		.gamma = m->g,
	};
}
