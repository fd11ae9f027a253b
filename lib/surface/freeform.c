/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Freeform surfaces. Each is a base (a conic of revolution, a biconic, a
 * toroid, a sphere) plus departures, and each piece is differentiated
 * twice in closed form; the pieces combine by the sum and product rules.
 * docs/prescriptions.md has the formulas and conventions.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "asph/zernike.h"
#include "aperture.h"
#include "freeform.h"

static double binomial(int n, int k)
{
	double b = 1;

	for (int i = 1; i <= k; i++)
		b = b * (n - k + i) / i;
	return b;
}

/*
 * Z_j = norm R_n^|m|(rho) {cos, sin}(|m| theta) with
 * R_n^|m| = sum_s c_s rho^(n - 2s): as rho^|m| e^(i |m| theta) = (u + i v)^|m|,
 * Z_j = norm Re or Im (u + i v)^|m| sum_s c_s X^((n - |m|)/2 - s), X = rho^2.
 * Kept as a polynomial in X for each harmonic: the monomials of x and y
 * would cancel far worse at high orders.
 */
void zseries_add(struct zseries *z, int j, double w)
{
	int n, m;

	asph_zernike_noll_to_nm(j, &n, &m);
	int am = m < 0 ? -m : m, hp = (n + am) / 2, hm = (n - am) / 2;
	double norm = m == 0 ? sqrt(n + 1.0) : sqrt(2.0 * (n + 1.0));
	double cs = binomial(n, hm);

	for (int s = 0; s <= hm; s++) {
		z->c[am][m < 0][hm - s] += w * norm * cs;
		cs = -cs * (double)(hp - s) * (double)(hm - s) / ((s + 1.0) * (double)(n - s));
	}
	if (hm > z->deg[am])
		z->deg[am] = hm;
	if (am > z->m_max)
		z->m_max = am;
}

/* ---- evaluation to an order ---------------------------------------------- */

/*
 * Every piece is evaluated to a chosen order: SAG (the value), GRADIENT
 * (with its first derivatives) or HESSIAN (with its second ones too), and
 * computes no more than that order asks. The three entry points at the end
 * call one core with a constant order, which is inlined into each so that
 * the compiler drops the work the order does not need.
 */
enum order { SAG = 0, GRADIENT = 1, HESSIAN = 2 };

#define ALWAYS_INLINE static inline __attribute__((always_inline))

/* One piece and its derivatives: value, x, y, xx, xy, yy (those past the
 * order are 0). */
struct j6 {
	double v, x, y, xx, xy, yy;
};

static void j6_add(struct j6 *a, const struct j6 *b)
{
	a->v += b->v;
	a->x += b->x;
	a->y += b->y;
	a->xx += b->xx;
	a->xy += b->xy;
	a->yy += b->yy;
}

static struct j6 j6_mul(const struct j6 *a, const struct j6 *b)
{
	return (struct j6){
		a->v * b->v,
		a->x * b->v + a->v * b->x,
		a->y * b->v + a->v * b->y,
		a->xx * b->v + 2.0 * a->x * b->x + a->v * b->xx,
		a->xy * b->v + a->x * b->y + a->y * b->x + a->v * b->xy,
		a->yy * b->v + 2.0 * a->y * b->y + a->v * b->yy,
	};
}

/* g(X), X = x^2 + y^2, from g, g', g'' in X. */
ALWAYS_INLINE struct j6 j6_of_r2(double x, double y, const double g[3], enum order o)
{
	struct j6 r = { g[0], 0, 0, 0, 0, 0 };

	if (o >= GRADIENT)
		r.x = 2.0 * x * g[1], r.y = 2.0 * y * g[1];
	if (o >= HESSIAN) {
		r.xx = 2.0 * g[1] + 4.0 * x * x * g[2];
		r.xy = 4.0 * x * y * g[2];
		r.yy = 2.0 * g[1] + 4.0 * y * y * g[2];
	}
	return r;
}

/* A function of normalized coordinates (u, v) = (x, y) s as one of (x, y). */
static struct j6 j6_scaled(struct j6 d, double s)
{
	return (struct j6){ d.v, d.x * s, d.y * s, d.xx * s * s, d.xy * s * s, d.yy * s * s };
}

/* Horner for sum c[p] t^p, p <= deg, and its derivatives in t to the order. */
ALWAYS_INLINE void horner(const double *c, int deg, double t, enum order o, double g[3])
{
	g[0] = g[1] = g[2] = 0;
	for (int p = deg; p >= 0; p--) {
		if (o >= HESSIAN)
			g[2] = g[2] * t + 2.0 * g[1];
		if (o >= GRADIENT)
			g[1] = g[1] * t + g[0];
		g[0] = g[0] * t + c[p];
	}
}

/* ---- bivariate polynomials: Horner in v for each power of u, then in u --- */

ALWAYS_INLINE struct j6 bipoly(const struct bipoly *p, double u, double v, enum order o)
{
	/* p = sum_i u^i q_i(v): s = sum u^i q_i and its u derivatives, t and w
	 * the same sums of q_i' and q_i'' */
	double s0 = 0, s1 = 0, s2 = 0, t0 = 0, t1 = 0, w0 = 0;

	for (int i = p->deg; i >= 0; i--) {
		double q[3];
		horner(p->c[i], p->deg - i, v, o, q);
		if (o >= HESSIAN) {
			s2 = s2 * u + 2.0 * s1;
			t1 = t1 * u + t0;
			w0 = w0 * u + q[2];
		}
		if (o >= GRADIENT) {
			s1 = s1 * u + s0;
			t0 = t0 * u + q[1];
		}
		s0 = s0 * u + q[0];
	}
	return (struct j6){ s0, s1, t0, s2, t1, w0 };
}

/* ---- sums of harmonics ---------------------------------------------------- */

/*
 * F = sum_m Re(w^m) A_m(X) + Im(w^m) B_m(X), w = u + i v, X = |w|^2. With
 * C_m = A_m - i B_m, F = Re G, G = sum_m C_m(X) w^m: Horner in w gives
 * P = sum C_m w^m with P' and P'' in w, Q = sum C_m' w^m with Q', and
 * R = sum C_m'' w^m (' in X for C, in w for P, Q), and
 *   G_u = 2u Q + P',  G_v = 2v Q + i P',
 *   G_uu = 2Q + 4u^2 R + 4u Q' + P'',  G_vv = 2Q + 4v^2 R + 4i v Q' - P'',
 *   G_uv = 4uv R + 2(v + i u) Q' + i P''.
 * No power of w is formed and no term is expanded into monomials. The sum
 * is taken one harmonic at a time, from the highest m down.
 */
struct harmonics {
	double pr, pi, p1r, p1i, p2r, p2i;      /* P, P', P'' */
	double qr, qi, q1r, q1i, rr, ri;        /* Q, Q', R */
};

/* The harmonic m, A_m and B_m with their X-derivatives in a and b: one
 * Horner step in w. */
ALWAYS_INLINE void harmonic_step(struct harmonics *h, double u, double v, const double a[3],
				 const double b[3], enum order o)
{
	double t;

	if (o >= HESSIAN) {
		t = h->p2r * u - h->p2i * v + 2.0 * h->p1r;
		h->p2i = h->p2r * v + h->p2i * u + 2.0 * h->p1i;
		h->p2r = t;
		t = h->q1r * u - h->q1i * v + h->qr;
		h->q1i = h->q1r * v + h->q1i * u + h->qi;
		h->q1r = t;
		t = h->rr * u - h->ri * v + a[2];
		h->ri = h->rr * v + h->ri * u - b[2];
		h->rr = t;
	}
	if (o >= GRADIENT) {
		t = h->p1r * u - h->p1i * v + h->pr;
		h->p1i = h->p1r * v + h->p1i * u + h->pi;
		h->p1r = t;
		t = h->qr * u - h->qi * v + a[1];
		h->qi = h->qr * v + h->qi * u - b[1];
		h->qr = t;
	}
	t = h->pr * u - h->pi * v + a[0];
	h->pi = h->pr * v + h->pi * u - b[0];
	h->pr = t;
}

/* F and its derivatives in (u, v) once every harmonic is in. */
ALWAYS_INLINE struct j6 harmonic_sum(const struct harmonics *h, double u, double v,
				     enum order o)
{
	struct j6 out = { h->pr, 0, 0, 0, 0, 0 };

	if (o >= GRADIENT) {
		out.x = 2.0 * u * h->qr + h->p1r;
		out.y = 2.0 * v * h->qr - h->p1i;
	}
	if (o >= HESSIAN) {
		out.xx = 2.0 * h->qr + 4.0 * u * u * h->rr + 4.0 * u * h->q1r + h->p2r;
		out.yy = 2.0 * h->qr + 4.0 * v * v * h->rr - 4.0 * v * h->q1i - h->p2r;
		out.xy = 4.0 * u * v * h->rr + 2.0 * v * h->q1r - 2.0 * u * h->q1i - h->p2i;
	}
	return out;
}

ALWAYS_INLINE struct j6 zernike(const struct zseries *z, double u, double v, enum order o)
{
	struct harmonics h = { 0 };
	double X = u * u + v * v, a[3], b[3];

	for (int m = z->m_max; m >= 0; m--) {
		/* the cos and sin polynomials side by side: two chains at once */
		a[0] = a[1] = a[2] = b[0] = b[1] = b[2] = 0;
		for (int p = z->deg[m]; p >= 0; p--) {
			if (o >= HESSIAN) {
				a[2] = a[2] * X + 2.0 * a[1];
				b[2] = b[2] * X + 2.0 * b[1];
			}
			if (o >= GRADIENT) {
				a[1] = a[1] * X + a[0];
				b[1] = b[1] * X + b[0];
			}
			a[0] = a[0] * X + z->c[m][0][p];
			b[0] = b[0] * X + z->c[m][1][p];
		}
		harmonic_step(&h, u, v, a, b, o);
	}
	return harmonic_sum(&h, u, v, o);
}

/* ---- the pieces of the surfaces ------------------------------------------ */

/* The conic of revolution c r^2 / (1 + sqrt(1 - K c^2 r^2)): gradient
 * c (x, y) / w, Hessian (c/w) I + (K c^3 / w^3) (x, y)(x, y)^T, w the root,
 * with no division by r. */
ALWAYS_INLINE struct j6 conic_xy(double c, double K, double x, double y, enum order o)
{
	double r2 = x * x + y * y, W = 1.0 - K * c * c * r2, w = sqrt(W);
	struct j6 r = { c * r2 / (1.0 + w), 0, 0, 0, 0, 0 };

	if (o >= GRADIENT) {
		double t = c / w;
		r.x = t * x, r.y = t * y;
		if (o >= HESSIAN) {
			double q = K * c * c * c / (W * w);
			r.xx = t + q * x * x, r.xy = q * x * y, r.yy = t + q * y * y;
		}
	}
	return r;
}

/* sum A_2k (x^2 + y^2)^k = X sum A_2k X^(k-1). */
ALWAYS_INLINE struct j6 even_radial(const struct freeform *f, double x, double y, enum order o)
{
	double g[3] = { 0, 0, 0 }, X = x * x + y * y;

	for (int i = f->max_power & ~1; i >= 2; i -= 2) {
		if (o >= HESSIAN)
			g[2] = g[2] * X + 2.0 * g[1];
		if (o >= GRADIENT)
			g[1] = g[1] * X + g[0];
		g[0] = g[0] * X + f->A[i];
	}
	g[2] = g[2] * X + 2.0 * g[1];
	g[1] = g[1] * X + g[0];
	g[0] = g[0] * X;
	return j6_of_r2(x, y, g, o);
}

/* (cx x^2 + cy y^2) / D, D = 1 + sqrt(W), W = 1 - Kx cx^2 x^2 - Ky cy^2 y^2:
 * from N = z D, z' = (N' - z D') / D and z'' = (N'' - 2 z' D' - z D'') / D. */
ALWAYS_INLINE struct j6 biconic(const struct freeform *f, double x, double y, enum order o)
{
	double ax = f->Kx * f->cx * f->cx, ay = f->Ky * f->cy * f->cy;
	double W = 1.0 - ax * x * x - ay * y * y, w = sqrt(W), D = 1.0 + w;
	struct j6 r = { (f->cx * x * x + f->cy * y * y) / D, 0, 0, 0, 0, 0 };

	if (o >= GRADIENT) {
		double Wx = -2.0 * ax * x, Wy = -2.0 * ay * y;
		double Dx = Wx / (2.0 * w), Dy = Wy / (2.0 * w);
		r.x = (2.0 * f->cx * x - r.v * Dx) / D;
		r.y = (2.0 * f->cy * y - r.v * Dy) / D;
		if (o >= HESSIAN) {
			double Dxx = -ax / w - Wx * Wx / (4.0 * W * w);
			double Dyy = -ay / w - Wy * Wy / (4.0 * W * w);
			double Dxy = -Wx * Wy / (4.0 * W * w);
			r.xx = (2.0 * f->cx - 2.0 * r.x * Dx - r.v * Dxx) / D;
			r.yy = (2.0 * f->cy - 2.0 * r.y * Dy - r.v * Dyy) / D;
			r.xy = (-r.x * Dy - r.y * Dx - r.v * Dxy) / D;
		}
	}
	return r;
}

/* The toroid's y-z curve Z(y) = conic + sum A_i y^i, d = Z, Z', Z''. */
ALWAYS_INLINE void toroid_curve(const struct freeform *f, double y, enum order o, double d[3])
{
	double W = 1.0 - f->K * f->c * f->c * y * y, w = sqrt(W), p[3];

	horner(f->A + 1, f->max_power - 1, y, o, p);
	d[0] = f->c * y * y / (1.0 + w) + p[0] * y;
	d[1] = o >= GRADIENT ? f->c * y / w + p[1] * y + p[0] : 0;
	d[2] = o >= HESSIAN ? f->c / (W * w) + p[2] * y + 2.0 * p[1] : 0;
}

/*
 * The curve rotated about the axis parallel to y at z = R_rotation:
 * with e = 1 - cr Z(y) and t = sqrt(e^2 - cr^2 x^2),
 *   S = Z + cr x^2 / (e + t),  S_x = cr x / t,  S_y = Z' e / t,
 *   S_xx = cr e^2 / t^3,  S_xy = cr^2 x e Z' / t^3,
 *   S_yy = Z'' e / t + cr^3 x^2 Z'^2 / t^3.
 */
ALWAYS_INLINE struct j6 toroidal(const struct freeform *f, double x, double y, enum order o)
{
	double d[3], cr = f->cr;

	toroid_curve(f, y, o, d);
	double e = 1.0 - cr * d[0], T = e * e - cr * cr * x * x, t = sqrt(T), t3 = T * t;
	struct j6 r = { d[0] + cr * x * x / (e + t), 0, 0, 0, 0, 0 };
	if (o >= GRADIENT)
		r.x = cr * x / t, r.y = d[1] * e / t;
	if (o >= HESSIAN) {
		r.xx = cr * e * e / t3;
		r.xy = cr * cr * x * e * d[1] / t3;
		r.yy = d[2] * e / t + cr * cr * cr * x * x * d[1] * d[1] / t3;
	}
	return r;
}

/* u^2 (1 - u^2) S0(u^2) + sum_m [Re w^m Sa_m(u^2) + Im w^m Sb_m(u^2)],
 * w = u + i v, in normalized coordinates. */
ALWAYS_INLINE struct j6 q2d_departure(const struct freeform *f, double u, double v,
				      enum order o)
{
	double X = u * u + v * v, s[3] = { 0, 0, 0 };
	double a[ASPH_SURFACE_Q2D_MAX_M + 1][3] = { { 0 } }, b[ASPH_SURFACE_Q2D_MAX_M + 1][3] = { { 0 } };

	if (f->n0 > 0)
		qbfs_sum(&f->qbfs, f->q0, f->n0, X, s);
	a[0][0] = X * (1.0 - X) * s[0];
	a[0][1] = (1.0 - 2.0 * X) * s[0] + X * (1.0 - X) * s[1];
	a[0][2] = -2.0 * s[0] + 2.0 * (1.0 - 2.0 * X) * s[1] + X * (1.0 - X) * s[2];
	struct harmonics h = { 0 };
	for (int m = f->m_max; m >= 0; m--) {
		int n = m > 0 ? f->count[m - 1] : 0;
		if (n > 0) {
			q2d_sum(&f->q2d[m - 1], f->qa[m - 1], n, X, a[m]);
			q2d_sum(&f->q2d[m - 1], f->qb[m - 1], n, X, b[m]);
		}
		harmonic_step(&h, u, v, a[m], b[m], o);
	}
	return harmonic_sum(&h, u, v, o);
}

/* Sphere plus the departure over sqrt(1 - c^2 r^2): g = (1 - c^2 r^2)^-1/2,
 * g_x = c^2 x g^3, g_xx = c^2 g^3 + 3 c^4 x^2 g^5, g_xy = 3 c^4 x y g^5. */
ALWAYS_INLINE struct j6 q2d(const struct freeform *f, double x, double y, enum order o)
{
	double s = f->inv_norm, c2 = f->c * f->c;
	struct j6 dep = j6_scaled(q2d_departure(f, x * s, y * s, o), s);
	double g = 1.0 / sqrt(1.0 - c2 * (x * x + y * y)), g3 = g * g * g, g5 = g3 * g * g;
	struct j6 gj = { g, c2 * x * g3, c2 * y * g3, c2 * g3 + 3.0 * c2 * c2 * x * x * g5,
			 3.0 * c2 * c2 * x * y * g5, c2 * g3 + 3.0 * c2 * c2 * y * y * g5 };
	struct j6 out = conic_xy(f->c, 1.0, x, y, o), prod = j6_mul(&gj, &dep);
	j6_add(&out, &prod);
	return out;
}

/* The xy polynomial's terms, or the Zernike terms (of a Zernike sag or a
 * toroid), in coordinates normalized about their centre. */
ALWAYS_INLINE struct j6 polynomial(const struct freeform *f, double x, double y, enum order o)
{
	double u = (x - f->decenter[0]) * f->inv_norm, v = (y - f->decenter[1]) * f->inv_norm;

	if (f->type == ASPH_SURFACE_XY_POLYNOMIAL)
		return j6_scaled(bipoly(&f->poly, u, v, o), f->inv_norm);
	return j6_scaled(zernike(&f->zern, u, v, o), f->inv_norm);
}

ALWAYS_INLINE struct j6 eval(const struct freeform *f, double x, double y, enum order o)
{
	struct j6 v, part;

	switch (f->type) {
	case ASPH_SURFACE_BICONIC:
		v = biconic(f, x, y, o);
		if (f->max_power > 0) {
			part = even_radial(f, x, y, o);
			j6_add(&v, &part);
		}
		return v;
	case ASPH_SURFACE_TOROIDAL:
		v = toroidal(f, x, y, o);
		if (f->has_zernike) {
			part = polynomial(f, x, y, o);
			j6_add(&v, &part);
		}
		return v;
	case ASPH_SURFACE_XY_POLYNOMIAL:
	case ASPH_SURFACE_ZERNIKE_SAG:
		v = conic_xy(f->c, f->K, x, y, o);
		if (f->max_power > 0) {
			part = even_radial(f, x, y, o);
			j6_add(&v, &part);
		}
		part = polynomial(f, x, y, o);
		j6_add(&v, &part);
		return v;
	case ASPH_SURFACE_Q2D:
		return q2d(f, x, y, o);
	default:
		return (struct j6){ NAN, NAN, NAN, NAN, NAN, NAN };
	}
}

void freeform_eval(const struct freeform *f, double x, double y, struct asph_sag *o)
{
	struct j6 v = eval(f, x, y, HESSIAN);

	*o = (struct asph_sag){ v.v, v.x, v.y, v.xx, v.xy, v.yy };
}

void freeform_sag_grad(const struct freeform *f, double x, double y, double g[3])
{
	struct j6 v = eval(f, x, y, GRADIENT);

	g[0] = v.v, g[1] = v.x, g[2] = v.y;
}

double freeform_sag(const struct freeform *f, double x, double y)
{
	return eval(f, x, y, SAG).v;
}

/* curvature of a radius that may be infinite (a plane) */
static double curvature(double R)
{
	return isinf(R) ? 0.0 : 1.0 / R;
}

void freeform_init(struct freeform *f, const struct asph_prescription *p)
{
	memset(f, 0, sizeof(*f));
	f->type = p->type;
	f->c = curvature(p->R);
	f->K = 1.0 + p->k;
	f->cx = curvature(p->Rx);
	f->cy = curvature(p->Ry);
	f->Kx = 1.0 + p->kx;
	f->Ky = 1.0 + p->ky;
	f->cr = curvature(p->R_rotation);
	memcpy(f->A, p->A, sizeof(f->A));
	for (int i = 1; i <= ASPH_SURFACE_MAX_POWER; i++)
		if (p->A[i] != 0)
			f->max_power = i;
	f->inv_norm = p->norm_radius > 0 ? 1.0 / p->norm_radius : 0.0;
	f->poly.deg = -1;
	if (p->type == ASPH_SURFACE_XY_POLYNOMIAL) {
		for (int d = 1; d <= ASPH_SURFACE_XY_MAX_DEGREE; d++)
			for (int j = 0; j <= d; j++) {
				double c = p->C[asph_xy_index(d - j, j)];
				f->poly.c[d - j][j] = c;
				if (c != 0)
					f->poly.deg = d;
			}
	}
	if (p->type == ASPH_SURFACE_ZERNIKE_SAG || p->type == ASPH_SURFACE_TOROIDAL) {
		f->decenter[0] = p->zernike_decenter[0];
		f->decenter[1] = p->zernike_decenter[1];
		for (int j = 1; j <= ASPH_SURFACE_MAX_ZERNIKE; j++)
			if (p->Zernike[j - 1] != 0) {
				zseries_add(&f->zern, j, p->Zernike[j - 1]);
				f->has_zernike = 1;
			}
	}
	if (p->type == ASPH_SURFACE_Q2D) {
		qbfs_coef_init(&f->qbfs);
		memcpy(f->q0, p->Q, sizeof(f->q0));
		for (int n = 0; n <= ASPH_SURFACE_MAX_Q; n++)
			if (p->Q[n] != 0)
				f->n0 = n + 1;
		for (int m = 1; m <= ASPH_SURFACE_Q2D_MAX_M; m++) {
			for (int n = 0; n <= ASPH_SURFACE_Q2D_MAX_N; n++) {
				f->qa[m - 1][n] = p->q2d_a[m - 1][n];
				f->qb[m - 1][n] = p->q2d_b[m - 1][n];
				if (p->q2d_a[m - 1][n] != 0 || p->q2d_b[m - 1][n] != 0)
					f->count[m - 1] = n + 1;
			}
			if (f->count[m - 1] > 0) {
				q2d_coef_init(&f->q2d[m - 1], m);
				f->m_max = m;
			}
		}
	}
}

/* ---- checks ------------------------------------------------------------- */

enum uses {
	USES_R = 1 << 0, USES_K = 1 << 1, USES_BICONIC = 1 << 2, USES_ROTATION = 1 << 3,
	USES_A = 1 << 4, USES_NORM = 1 << 5, USES_C = 1 << 6, USES_ZERNIKE = 1 << 7,
	USES_Q = 1 << 8, USES_DECENTER = 1 << 9,
};

static int has_zernike(const struct asph_prescription *p)
{
	for (int j = 0; j < ASPH_SURFACE_MAX_ZERNIKE; j++)
		if (p->Zernike[j] != 0)
			return 1;
	return 0;
}

static unsigned type_uses(const struct asph_prescription *p)
{
	switch (p->type) {
	case ASPH_SURFACE_BICONIC:
		return USES_BICONIC | USES_A;
	case ASPH_SURFACE_TOROIDAL:
		/* the Zernike terms are optional, and their radius with them */
		return USES_R | USES_K | USES_A | USES_ROTATION | USES_ZERNIKE |
		       (has_zernike(p) || p->norm_radius != 0 ? USES_NORM : 0);
	case ASPH_SURFACE_XY_POLYNOMIAL:
		return USES_R | USES_K | USES_NORM | USES_C;
	case ASPH_SURFACE_ZERNIKE_SAG:
		return USES_R | USES_K | USES_A | USES_NORM | USES_ZERNIKE | USES_DECENTER;
	case ASPH_SURFACE_Q2D:
		return USES_R | USES_NORM | USES_Q;
	default:
		return 0;
	}
}

int radius_check(double R, const char *field, struct asph_error *err)
{
	if (isnan(R))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "%s is not a number", field);
	if (R == 0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "%s = 0 is not a radius of curvature "
					 "(a flat base is \"infinity\")", field);
	if (isfinite(R) && !isfinite(1.0 / R))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "%s = %g mm is too small: its curvature overflows", field, R);
	return 0;
}

/* A field the type does not use must be 0. */
static int check_unused(double v, unsigned uses, unsigned bit, const char *field,
			const char *type, struct asph_error *err)
{
	if (!(uses & bit) && v != 0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "a %s surface has no %s", type, field);
	return 0;
}

static int check_scalars(const struct asph_prescription *p, unsigned uses, const char *type,
			 struct asph_error *err)
{
	const struct { double v; unsigned bit; const char *name; } f[] = {
		{ p->R, USES_R, "R" }, { p->k, USES_K, "k" }, { p->Rx, USES_BICONIC, "Rx" },
		{ p->Ry, USES_BICONIC, "Ry" }, { p->kx, USES_BICONIC, "kx" },
		{ p->ky, USES_BICONIC, "ky" }, { p->R_rotation, USES_ROTATION, "R_rotation" },
		{ p->norm_radius, USES_NORM, "norm_radius" },
		{ p->zernike_decenter[0], USES_DECENTER, "zernike_decenter" },
		{ p->zernike_decenter[1], USES_DECENTER, "zernike_decenter" },
	};
	int r;

	for (size_t i = 0; i < sizeof(f) / sizeof(f[0]); i++)
		if ((r = check_unused(f[i].v, uses, f[i].bit, f[i].name, type, err)) < 0)
			return r;
	if ((uses & USES_R) && (r = radius_check(p->R, "R", err)) < 0)
		return r;
	if ((uses & USES_BICONIC) && ((r = radius_check(p->Rx, "Rx", err)) < 0 ||
				      (r = radius_check(p->Ry, "Ry", err)) < 0))
		return r;
	if ((uses & USES_ROTATION) && (r = radius_check(p->R_rotation, "R_rotation", err)) < 0)
		return r;
	const struct { double v; const char *name; } fin[] = {
		{ p->k, "k" }, { p->kx, "kx" }, { p->ky, "ky" },
		{ p->zernike_decenter[0], "zernike_decenter" },
		{ p->zernike_decenter[1], "zernike_decenter" },
	};
	for (size_t i = 0; i < sizeof(fin) / sizeof(fin[0]); i++)
		if (!isfinite(fin[i].v))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, fin[i].name,
						 "%s must be a finite number", fin[i].name);
	if ((uses & USES_NORM) && (!(p->norm_radius > 0) || !isfinite(p->norm_radius)))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "norm_radius",
					 "norm_radius must be a positive number of mm%s",
					 p->type == ASPH_SURFACE_TOROIDAL
						 ? " (the radius of the Zernike terms)" : "");
	return 0;
}

static int check_coefficients(const struct asph_prescription *p, unsigned uses,
			      const char *type, struct asph_error *err)
{
	char field[48];

	for (int i = 0; i <= ASPH_SURFACE_MAX_POWER; i++) {
		snprintf(field, sizeof(field), "A.%d", i);
		if (!isfinite(p->A[i]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "coefficient A%d is not finite", i);
		if (p->A[i] != 0 && !(uses & USES_A))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "a %s surface has no power coefficients A", type);
		if (p->A[i] != 0 && (i < 2 || i % 2))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "a %s surface has even powers A2, A4, ..., A20 only "
						 "(A%d given)", type, i);
	}
	for (int i = 0; i <= ASPH_SURFACE_XY_MAX_DEGREE; i++)
		for (int j = 0; i + j <= ASPH_SURFACE_XY_MAX_DEGREE; j++) {
			double c = p->C[asph_xy_index(i, j)];
			snprintf(field, sizeof(field), "c.x%dy%d", i, j);
			if (!isfinite(c))
				return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
							 "coefficient x%dy%d is not finite", i, j);
			if (c != 0 && !(uses & USES_C))
				return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
							 "a %s surface has no x-y coefficients c", type);
			if (c != 0 && i + j == 0)
				return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
							 "the constant term x0y0 would move the vertex "
							 "off the origin");
		}
	for (int j = 1; j <= ASPH_SURFACE_MAX_ZERNIKE; j++) {
		snprintf(field, sizeof(field), "zernike.[%d]", j - 1);
		if (!isfinite(p->Zernike[j - 1]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "Zernike coefficient Z%d is not finite", j);
		if (p->Zernike[j - 1] != 0 && !(uses & USES_ZERNIKE))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "a %s surface has no Zernike terms", type);
	}
	for (int n = 0; n <= ASPH_SURFACE_MAX_Q; n++) {
		snprintf(field, sizeof(field), "a.[%d]", n);
		if (!isfinite(p->Q[n]))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "coefficient a%d is not finite", n);
		if (p->Q[n] != 0 && !(uses & USES_Q))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
						 "a %s surface has no Q coefficients", type);
	}
	for (int m = 1; m <= ASPH_SURFACE_Q2D_MAX_M; m++)
		for (int n = 0; n <= ASPH_SURFACE_Q2D_MAX_N; n++)
			for (int b = 0; b < 2; b++) {
				double v = b ? p->q2d_b[m - 1][n] : p->q2d_a[m - 1][n];
				snprintf(field, sizeof(field), "%s.%d.[%d]", b ? "b_m" : "a_m", m, n);
				if (!isfinite(v))
					return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
								 "coefficient %c_%d^%d is not finite",
								 b ? 'b' : 'a', n, m);
				if (v != 0 && !(uses & USES_Q))
					return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
								 "a %s surface has no Q coefficients", type);
			}
	return 0;
}

/* The largest value of fn over the aperture boundary (sampled, then refined
 * by golden section around the best sample), and where. */
static double boundary_max(const struct asph_aperture *ap,
			   double (*fn)(const void *, double, double), const void *ctx,
			   double at[2])
{
	const int n = 4096;
	double best = -INFINITY, tb = 0, pt[2], dp[2];

	for (int i = 0; i < n; i++) {
		aperture_boundary(ap, (double)i / n, pt, dp);
		double v = fn(ctx, pt[0], pt[1]);
		if (!(v <= best)) {
			best = v;
			tb = (double)i / n;
		}
	}
	double lo = tb - 1.0 / n, hi = tb + 1.0 / n;
	const double g = 0.5 * (sqrt(5.0) - 1.0);
	for (int it = 0; it < 60; it++) {
		double a = hi - g * (hi - lo), b = lo + g * (hi - lo), pa[2], pb[2];
		aperture_boundary(ap, a, pa, dp);
		aperture_boundary(ap, b, pb, dp);
		if (fn(ctx, pa[0], pa[1]) > fn(ctx, pb[0], pb[1]))
			hi = b;
		else
			lo = a;
	}
	aperture_boundary(ap, 0.5 * (lo + hi), pt, dp);
	double v = fn(ctx, pt[0], pt[1]);
	if (!(v <= best)) {
		best = v;
		at[0] = pt[0], at[1] = pt[1];
	} else {
		aperture_boundary(ap, tb, at, dp);
	}
	return best;
}

/* (1 + kx) cx^2 x^2 + (1 + ky) cy^2 y^2: its only critical point is the
 * origin (value 0), so its maximum over the aperture is 0 or on the edge. */
static double biconic_root_term(const void *ctx, double x, double y)
{
	const struct asph_prescription *p = ctx;
	double cx = curvature(p->Rx), cy = curvature(p->Ry);

	return (1.0 + p->kx) * cx * cx * x * x + (1.0 + p->ky) * cy * cy * y * y;
}

/* The largest |x| of the aperture at height y (-1 when y is outside). */
static double aperture_x_extent(const struct asph_aperture *ap, double y)
{
	double hx = 0.5 * ap->width, hy = 0.5 * ap->height, v = (y - ap->offset[1]) / hy;

	if (fabs(v) > 1)
		return -1;
	if (ap->shape != ASPH_APERTURE_RECTANGULAR)
		hx *= sqrt(fmax(0.0, 1.0 - v * v));
	return fabs(ap->offset[0]) + hx;
}

static int check_toroid_roots(const struct asph_prescription *p, const struct asph_aperture *ap,
			      struct asph_error *err)
{
	struct freeform f;
	double box[4], c = curvature(p->R), ymax;
	const int n = 4096;

	aperture_bounds(ap, box);
	ymax = fmax(fabs(box[2]), fabs(box[3]));
	if ((1.0 + p->k) * c * c * ymax * ymax >= 1.0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "k",
					 "the y-z curve's square root 1 - (1+k) y^2/R^2 reaches zero "
					 "inside the aperture (|y| up to %.6g mm; R = %g, k = %g)", ymax, p->R, p->k);
	freeform_init(&f, p);
	for (int i = 0; i <= n; i++) {
		double y = box[2] + (box[3] - box[2]) * i / n, d[3];
		double x = aperture_x_extent(ap, y);
		toroid_curve(&f, y, SAG, d);
		double e = 1.0 - f.cr * d[0];
		if (!(e > 0) || !(e * e - f.cr * f.cr * x * x > 0))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "R_rotation",
						 "the circle of rotation (R_rotation = %g mm) does not reach the "
						 "aperture's edge at x = %.6g mm, y = %.6g mm", p->R_rotation, x, y);
	}
	return 0;
}

static int check_roots(const struct asph_prescription *p, struct asph_error *err)
{
	struct asph_aperture ap;
	double at[2] = { 0, 0 };

	aperture_resolve(p, &ap);
	double rmax = aperture_max_radius(&ap), c = curvature(p->R);
	switch (p->type) {
	case ASPH_SURFACE_BICONIC:
		if (boundary_max(&ap, biconic_root_term, p, at) >= 1.0)
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0,
						 fabs(at[0] * curvature(p->Rx)) >=
								 fabs(at[1] * curvature(p->Ry))
							 ? "kx" : "ky",
						 "the biconic square root 1 - (1+kx) x^2/Rx^2 - (1+ky) y^2/Ry^2 "
						 "reaches zero inside the aperture, at x = %.6g mm, y = %.6g mm",
						 at[0], at[1]);
		return 0;
	case ASPH_SURFACE_TOROIDAL:
		return check_toroid_roots(p, &ap, err);
	case ASPH_SURFACE_Q2D:
		if (c * c * rmax * rmax >= 1.0)
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "R",
						 "the aperture reaches r = %.6g mm, past the best-fit "
						 "sphere's radius |R| = %g mm", rmax, fabs(p->R));
		return 0;
	default:
		if ((1.0 + p->k) * c * c * rmax * rmax >= 1.0)
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "k",
						 "the conic square root 1 - (1+k) r^2/R^2 reaches zero "
						 "inside the aperture, which reaches r = %.6g mm (R = %g, k = %g)",
						 rmax, p->R, p->k);
		return 0;
	}
}

int freeform_check(const struct asph_prescription *p, const char *type, struct asph_error *err)
{
	unsigned uses = type_uses(p);
	int r;

	if ((r = check_scalars(p, uses, type, err)) < 0 ||
	    (r = check_coefficients(p, uses, type, err)) < 0 ||
	    (r = aperture_check(p, err)) < 0)
		return r;
	return check_roots(p, err);
}
