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

/* ---- bivariate polynomials ---------------------------------------------- */

void bipoly_eval(const struct bipoly *p, double u, double v, double d[6])
{
	/* p = sum_i u^i q_i(v): Horner in v for each q_i (value, q', q''),
	 * then in u over the three series. */
	double s0 = 0, s1 = 0, s2 = 0, t0 = 0, t1 = 0, w0 = 0;

	for (int i = p->deg; i >= 0; i--) {
		double q0 = 0, q1 = 0, q2 = 0;
		for (int j = p->deg - i; j >= 0; j--) {
			q2 = q2 * v + 2.0 * q1;
			q1 = q1 * v + q0;
			q0 = q0 * v + p->c[i][j];
		}
		s2 = s2 * u + 2.0 * s1;
		s1 = s1 * u + s0;
		s0 = s0 * u + q0;
		t1 = t1 * u + t0;
		t0 = t0 * u + q1;
		w0 = w0 * u + q2;
	}
	d[0] = s0;
	d[1] = s1;
	d[2] = t0;
	d[3] = s2;
	d[4] = t1;
	d[5] = w0;
}

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

/* ---- one piece and its two derivatives: value, x, y, xx, xy, yy -------- */

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
static struct j6 j6_of_r2(double x, double y, const double g[3])
{
	return (struct j6){
		g[0], 2.0 * x * g[1], 2.0 * y * g[1],
		2.0 * g[1] + 4.0 * x * x * g[2], 4.0 * x * y * g[2], 2.0 * g[1] + 4.0 * y * y * g[2],
	};
}

/* A function of normalized coordinates (u, v) = (x, y) s as one of (x, y). */
static struct j6 j6_scaled(const double d[6], double s)
{
	return (struct j6){ d[0], d[1] * s, d[2] * s, d[3] * s * s, d[4] * s * s, d[5] * s * s };
}

/* The conic of revolution c r^2 / (1 + sqrt(1 - K c^2 r^2)): gradient
 * c (x, y) / w, Hessian (c/w) I + (K c^3 / w^3) (x, y)(x, y)^T, w the root,
 * with no division by r. */
static struct j6 conic_xy(double c, double K, double x, double y)
{
	double r2 = x * x + y * y, W = 1.0 - K * c * c * r2, w = sqrt(W);
	double t = c / w, q = K * c * c * c / (W * w);

	return (struct j6){ c * r2 / (1.0 + w), t * x, t * y, t + q * x * x, q * x * y, t + q * y * y };
}

/* sum A_2k (x^2 + y^2)^k. */
static struct j6 even_radial(const struct freeform *f, double x, double y)
{
	double g[3] = { 0, 0, 0 }, X = x * x + y * y;

	for (int i = f->max_power & ~1; i >= 2; i -= 2) {
		g[2] = g[2] * X + 2.0 * g[1];
		g[1] = g[1] * X + g[0];
		g[0] = g[0] * X + f->A[i];
	}
	/* g holds sum A_2k X^(k-1): one more step multiplies by X */
	g[2] = g[2] * X + 2.0 * g[1];
	g[1] = g[1] * X + g[0];
	g[0] = g[0] * X;
	return j6_of_r2(x, y, g);
}

/* ---- the types ----------------------------------------------------------- */

/* (cx x^2 + cy y^2) / D, D = 1 + sqrt(W), W = 1 - Kx cx^2 x^2 - Ky cy^2 y^2:
 * from N = z D, z' = (N' - z D') / D and z'' = (N'' - 2 z' D' - z D'') / D. */
static struct j6 biconic(const struct freeform *f, double x, double y)
{
	double ax = f->Kx * f->cx * f->cx, ay = f->Ky * f->cy * f->cy;
	double W = 1.0 - ax * x * x - ay * y * y, w = sqrt(W), D = 1.0 + w;
	double Wx = -2.0 * ax * x, Wy = -2.0 * ay * y;
	double Dx = Wx / (2.0 * w), Dy = Wy / (2.0 * w);
	double Dxx = -ax / w - Wx * Wx / (4.0 * W * w);
	double Dyy = -ay / w - Wy * Wy / (4.0 * W * w);
	double Dxy = -Wx * Wy / (4.0 * W * w);
	struct j6 o;

	o.v = (f->cx * x * x + f->cy * y * y) / D;
	o.x = (2.0 * f->cx * x - o.v * Dx) / D;
	o.y = (2.0 * f->cy * y - o.v * Dy) / D;
	o.xx = (2.0 * f->cx - 2.0 * o.x * Dx - o.v * Dxx) / D;
	o.yy = (2.0 * f->cy - 2.0 * o.y * Dy - o.v * Dyy) / D;
	o.xy = (-o.x * Dy - o.y * Dx - o.v * Dxy) / D;
	return o;
}

/* The toroid's y-z curve Z(y) = conic + sum A_i y^i, d = Z, Z', Z''. */
static void toroid_curve(const struct freeform *f, double y, double d[3])
{
	double W = 1.0 - f->K * f->c * f->c * y * y, w = sqrt(W);
	double p0 = 0, p1 = 0, p2 = 0;

	for (int i = f->max_power; i >= 1; i--) {
		p2 = p2 * y + 2.0 * p1;
		p1 = p1 * y + p0;
		p0 = p0 * y + f->A[i];
	}
	d[0] = f->c * y * y / (1.0 + w) + p0 * y;
	d[1] = f->c * y / w + p1 * y + p0;
	d[2] = f->c / (W * w) + p2 * y + 2.0 * p1;
}

/*
 * The curve rotated about the axis parallel to y at z = R_rotation:
 * with e = 1 - cr Z(y) and t = sqrt(e^2 - cr^2 x^2),
 *   S = Z + cr x^2 / (e + t),  S_x = cr x / t,  S_y = Z' e / t,
 *   S_xx = cr e^2 / t^3,  S_xy = cr^2 x e Z' / t^3,
 *   S_yy = Z'' e / t + cr^3 x^2 Z'^2 / t^3.
 */
static struct j6 toroidal(const struct freeform *f, double x, double y)
{
	double d[3], cr = f->cr;

	toroid_curve(f, y, d);
	double e = 1.0 - cr * d[0], T = e * e - cr * cr * x * x, t = sqrt(T), t3 = T * t;
	return (struct j6){
		d[0] + cr * x * x / (e + t),
		cr * x / t,
		d[1] * e / t,
		cr * e * e / t3,
		cr * cr * x * e * d[1] / t3,
		d[2] * e / t + cr * cr * cr * x * x * d[1] * d[1] / t3,
	};
}

/* sum_m Re(w^m) gc[m](X) + Im(w^m) gs[m](X), w = u + i v, X = u^2 + v^2,
 * from g, g', g'' in X of each (gs[0] unused). The harmonics Re, Im w^m
 * have derivatives m w^(m-1) and m (m-1) w^(m-2) (times i for v). */
static struct j6 harmonic_series(double u, double v, int m_max, double (*gc)[3],
				 double (*gs)[3])
{
	double re[ASPH_SURFACE_XY_MAX_DEGREE + 1], im[ASPH_SURFACE_XY_MAX_DEGREE + 1];
	struct j6 out = j6_of_r2(u, v, gc[0]);

	re[0] = 1, im[0] = 0;
	for (int k = 1; k <= m_max; k++) {
		re[k] = re[k - 1] * u - im[k - 1] * v;
		im[k] = re[k - 1] * v + im[k - 1] * u;
	}
	for (int m = 1; m <= m_max; m++) {
		if (gc[m][0] == 0 && gc[m][1] == 0 && gc[m][2] == 0 && gs[m][0] == 0 &&
		    gs[m][1] == 0 && gs[m][2] == 0)
			continue;       /* an order with no terms */
		double mm = m, m2 = m * (m - 1.0);
		double c2 = m >= 2 ? re[m - 2] : 0, s2 = m >= 2 ? im[m - 2] : 0;
		struct j6 C = { re[m], mm * re[m - 1], -mm * im[m - 1], m2 * c2, -m2 * s2, -m2 * c2 };
		struct j6 S = { im[m], mm * im[m - 1], mm * re[m - 1], m2 * s2, m2 * c2, -m2 * s2 };
		struct j6 A = j6_of_r2(u, v, gc[m]), B = j6_of_r2(u, v, gs[m]);
		struct j6 ca = j6_mul(&C, &A), sb = j6_mul(&S, &B);
		j6_add(&out, &ca);
		j6_add(&out, &sb);
	}
	return out;
}

/* Horner for sum c[p] X^p, p <= deg, with two derivatives. */
static void series_x(const double *c, int deg, double X, double g[3])
{
	g[0] = g[1] = g[2] = 0;
	for (int p = deg; p >= 0; p--) {
		g[2] = g[2] * X + 2.0 * g[1];
		g[1] = g[1] * X + g[0];
		g[0] = g[0] * X + c[p];
	}
}

static struct j6 zernike(const struct freeform *f, double u, double v)
{
	const struct zseries *z = &f->zern;
	double gc[ASPH_SURFACE_XY_MAX_DEGREE + 1][3], gs[ASPH_SURFACE_XY_MAX_DEGREE + 1][3];
	double X = u * u + v * v;

	for (int m = 0; m <= z->m_max; m++) {
		series_x(z->c[m][0], z->deg[m], X, gc[m]);
		series_x(z->c[m][1], z->deg[m], X, gs[m]);
	}
	return harmonic_series(u, v, z->m_max, gc, gs);
}

/* u^2 (1 - u^2) S0(u^2) + sum_m [Re w^m Sa_m(u^2) + Im w^m Sb_m(u^2)],
 * w = u + i v, in normalized coordinates. */
static struct j6 q2d_departure(const struct freeform *f, double u, double v)
{
	double X = u * u + v * v, s[3] = { 0, 0, 0 };
	double gc[ASPH_SURFACE_Q2D_MAX_M + 1][3] = { { 0 } }, gs[ASPH_SURFACE_Q2D_MAX_M + 1][3] = { { 0 } };

	if (f->n0 > 0)
		qbfs_sum(&f->qbfs, f->q0, f->n0, X, s);
	gc[0][0] = X * (1.0 - X) * s[0];
	gc[0][1] = (1.0 - 2.0 * X) * s[0] + X * (1.0 - X) * s[1];
	gc[0][2] = -2.0 * s[0] + 2.0 * (1.0 - 2.0 * X) * s[1] + X * (1.0 - X) * s[2];
	for (int m = 1; m <= f->m_max; m++) {
		int n = f->count[m - 1];
		if (n == 0)
			continue;
		q2d_sum(&f->q2d[m - 1], f->qa[m - 1], n, X, gc[m]);
		q2d_sum(&f->q2d[m - 1], f->qb[m - 1], n, X, gs[m]);
	}
	return harmonic_series(u, v, f->m_max, gc, gs);
}

/* Sphere plus the departure over sqrt(1 - c^2 r^2): g = (1 - c^2 r^2)^-1/2,
 * g_x = c^2 x g^3, g_xx = c^2 g^3 + 3 c^4 x^2 g^5, g_xy = 3 c^4 x y g^5. */
static struct j6 q2d(const struct freeform *f, double x, double y)
{
	double s = f->inv_norm, c2 = f->c * f->c;
	struct j6 dn = q2d_departure(f, x * s, y * s);
	double d6[6] = { dn.v, dn.x, dn.y, dn.xx, dn.xy, dn.yy };
	struct j6 dep = j6_scaled(d6, s);
	double g = 1.0 / sqrt(1.0 - c2 * (x * x + y * y)), g3 = g * g * g, g5 = g3 * g * g;
	struct j6 gj = { g, c2 * x * g3, c2 * y * g3, c2 * g3 + 3.0 * c2 * c2 * x * x * g5,
			 3.0 * c2 * c2 * x * y * g5, c2 * g3 + 3.0 * c2 * c2 * y * y * g5 };
	struct j6 out = conic_xy(f->c, 1.0, x, y), prod = j6_mul(&gj, &dep);
	j6_add(&out, &prod);
	return out;
}

static struct j6 polynomial(const struct freeform *f, double x, double y)
{
	double u = (x - f->decenter[0]) * f->inv_norm, v = (y - f->decenter[1]) * f->inv_norm, d[6];

	if (f->type != ASPH_SURFACE_XY_POLYNOMIAL) {
		struct j6 z = zernike(f, u, v);
		double zd[6] = { z.v, z.x, z.y, z.xx, z.xy, z.yy };
		return j6_scaled(zd, f->inv_norm);
	}
	bipoly_eval(&f->poly, u, v, d);
	return j6_scaled(d, f->inv_norm);
}

void freeform_eval(const struct freeform *f, double x, double y, struct asph_sag *o)
{
	struct j6 v = { 0 }, part;

	switch (f->type) {
	case ASPH_SURFACE_BICONIC:
		v = biconic(f, x, y);
		part = even_radial(f, x, y);
		j6_add(&v, &part);
		break;
	case ASPH_SURFACE_TOROIDAL:
		v = toroidal(f, x, y);
		if (f->has_zernike) {
			part = polynomial(f, x, y);
			j6_add(&v, &part);
		}
		break;
	case ASPH_SURFACE_XY_POLYNOMIAL:
	case ASPH_SURFACE_ZERNIKE_SAG:
		v = conic_xy(f->c, f->K, x, y);
		if (f->max_power > 0) {
			part = even_radial(f, x, y);
			j6_add(&v, &part);
		}
		part = polynomial(f, x, y);
		j6_add(&v, &part);
		break;
	case ASPH_SURFACE_Q2D:
		v = q2d(f, x, y);
		break;
	default:
		v = (struct j6){ NAN, NAN, NAN, NAN, NAN, NAN };
		break;
	}
	*o = (struct asph_sag){ v.v, v.x, v.y, v.xx, v.xy, v.yy };
}

static double bipoly_value(const struct bipoly *p, double u, double v)
{
	double s0 = 0;

	for (int i = p->deg; i >= 0; i--) {
		double q0 = 0;
		for (int j = p->deg - i; j >= 0; j--)
			q0 = q0 * v + p->c[i][j];
		s0 = s0 * u + q0;
	}
	return s0;
}

static double even_radial_value(const struct freeform *f, double X)
{
	double g = 0;

	for (int i = f->max_power & ~1; i >= 2; i -= 2)
		g = g * X + f->A[i];
	return g * X;
}

static double zernike_value(const struct zseries *z, double u, double v)
{
	double X = u * u + v * v, re = 1, im = 0, sum = 0;

	for (int m = 0; m <= z->m_max; m++) {
		double gc = 0, gs = 0;
		for (int p = z->deg[m]; p >= 0; p--) {
			gc = gc * X + z->c[m][0][p];
			gs = gs * X + z->c[m][1][p];
		}
		sum += re * gc + im * gs;
		double nre = re * u - im * v;
		im = re * v + im * u;
		re = nre;
	}
	return sum;
}

double freeform_sag(const struct freeform *f, double x, double y)
{
	double X = x * x + y * y, W, z;
	struct asph_sag o;

	switch (f->type) {
	case ASPH_SURFACE_BICONIC:
		W = 1.0 - f->Kx * f->cx * f->cx * x * x - f->Ky * f->cy * f->cy * y * y;
		return (f->cx * x * x + f->cy * y * y) / (1.0 + sqrt(W)) + even_radial_value(f, X);
	case ASPH_SURFACE_XY_POLYNOMIAL:
	case ASPH_SURFACE_ZERNIKE_SAG:
		W = 1.0 - f->K * f->c * f->c * X;
		z = f->c * X / (1.0 + sqrt(W)) + even_radial_value(f, X);
		x = (x - f->decenter[0]) * f->inv_norm;
		y = (y - f->decenter[1]) * f->inv_norm;
		if (f->type == ASPH_SURFACE_ZERNIKE_SAG)
			return z + zernike_value(&f->zern, x, y);
		return z + bipoly_value(&f->poly, x, y);
	default:
		freeform_eval(f, x, y, &o);
		return o.z;
	}
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

/* A radius: finite and non-zero, or infinite (flat); never NaN. */
static int check_radius(double R, const char *field, struct asph_error *err)
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
	if ((uses & USES_R) && (r = check_radius(p->R, "R", err)) < 0)
		return r;
	if ((uses & USES_BICONIC) && ((r = check_radius(p->Rx, "Rx", err)) < 0 ||
				      (r = check_radius(p->Ry, "Ry", err)) < 0))
		return r;
	if ((uses & USES_ROTATION) && (r = check_radius(p->R_rotation, "R_rotation", err)) < 0)
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

static int check_aperture(const struct asph_prescription *p, struct asph_error *err)
{
	const struct asph_aperture *ap = &p->aperture;

	if (ap->shape == ASPH_APERTURE_FROM_DIAMETER) {
		if (!(p->aperture_diameter > 0) || !isfinite(p->aperture_diameter))
			return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture_diameter",
						 "aperture_diameter (or aperture) must give a positive size in mm");
		return 0;
	}
	if ((unsigned)ap->shape > ASPH_APERTURE_ELLIPTICAL)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture.shape",
					 "unknown aperture shape %d", (int)ap->shape);
	if (p->aperture_diameter != 0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture_diameter",
					 "give either aperture_diameter or aperture, not both");
	if (!(ap->width > 0) || !isfinite(ap->width))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0,
					 ap->shape == ASPH_APERTURE_CIRCULAR ? "aperture.diameter"
									     : "aperture.width",
					 "the aperture's size must be a positive number of mm");
	if (!(ap->height > 0) || !isfinite(ap->height))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture.height",
					 "the aperture's height must be a positive number of mm");
	if (ap->shape == ASPH_APERTURE_CIRCULAR && ap->width != ap->height)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture",
					 "a circular aperture has one diameter");
	if (!isfinite(ap->offset[0]) || !isfinite(ap->offset[1]))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "aperture.offset",
					 "the aperture's offset must be finite");
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
		toroid_curve(&f, y, d);
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

int freeform_check(const struct asph_prescription *p, struct asph_error *err)
{
	const char *type = asph_surface_type_name(p->type);
	unsigned uses = type_uses(p);
	int r;

	if ((r = check_scalars(p, uses, type, err)) < 0 ||
	    (r = check_coefficients(p, uses, type, err)) < 0 ||
	    (r = check_aperture(p, err)) < 0)
		return r;
	return check_roots(p, err);
}
