/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The freeform surfaces against closed forms (a biconic with equal radii,
 * an xy polynomial holding an even asphere's monomials, Q2D with only m = 0
 * terms, a toroid that is a sphere, hand-expanded Zernike terms), their
 * gradients and Hessians against an independent computation (hyper-dual
 * numbers carried through each type's formula, written here afresh: exact
 * first and second derivatives, no step size), the Q_n^m polynomials by
 * their orthonormality, and the checks, the apertures and the JSON reader.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph/prescription.h"
#include "asph/surface.h"
#include "asph/zernike.h"
#include "qpoly.h"

static struct asph_surface *build(const struct asph_prescription *p)
{
	struct asph_surface *s = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_surface_alloc(p, &s, &err) < 0) {
		print_error("alloc: %s: %s\n", err.field, err.message);
		fail();
	}
	return s;
}

static void assert_close(double got, double want, double tol, const char *what)
{
	if (!(fabs(got - want) <= tol)) {
		print_error("%s: got %.17g want %.17g (diff %.3g > %.3g)\n", what, got, want,
			    fabs(got - want), tol);
		fail();
	}
}

/* z, gradient and Hessian of two evaluations agree: the sag to rel
 * relative (and 1e-14 mm), the gradient to rel relative to its size, the
 * Hessian entries relative to the Hessian's largest entry. */
static void assert_same_sag(const struct asph_sag *a, const struct asph_sag *b, double rel)
{
	double gs = fmax(fabs(b->zx), fabs(b->zy));
	double hs = fmax(fabs(b->zxx), fmax(fabs(b->zxy), fabs(b->zyy)));

	/* sags near the vertex are small differences of large terms */
	assert_close(a->z, b->z, rel * fabs(b->z) + 1e-14, "z");
	assert_close(a->zx, b->zx, rel * gs, "zx");
	assert_close(a->zy, b->zy, rel * gs, "zy");
	assert_close(a->zxx, b->zxx, rel * hs, "zxx");
	assert_close(a->zxy, b->zxy, rel * hs, "zxy");
	assert_close(a->zyy, b->zyy, rel * hs, "zyy");
}

/* Points over a disk of radius a, with no symmetry to hide a term. */
static void point(int i, double a, double *x, double *y)
{
	static const double f[][2] = { { 0, 0 }, { 0.0137, -0.0071 }, { 0.3183, 0.2718 },
				       { -0.5772, 0.4142 }, { 0.6931, -0.6180 }, { -0.1414, -0.9299 },
				       { 0.9549, 0.1732 }, { -0.7071, -0.6931 } };
	*x = a * f[i][0];
	*y = a * f[i][1];
}
#define N_POINTS 8

/* ---- hyper-dual numbers: a + b e1 + c e2 + d e1 e2, e1^2 = e2^2 = 0 ----- */

typedef struct {
	double a, b, c, d;
} hd;

static hd hc(double v) { return (hd){ v, 0, 0, 0 }; }
static hd hadd(hd x, hd y) { return (hd){ x.a + y.a, x.b + y.b, x.c + y.c, x.d + y.d }; }
static hd hsub(hd x, hd y) { return (hd){ x.a - y.a, x.b - y.b, x.c - y.c, x.d - y.d }; }
static hd hscale(hd x, double s) { return (hd){ x.a * s, x.b * s, x.c * s, x.d * s }; }
static hd hmul(hd x, hd y)
{
	return (hd){ x.a * y.a, x.a * y.b + x.b * y.a, x.a * y.c + x.c * y.a,
		     x.a * y.d + x.b * y.c + x.c * y.b + x.d * y.a };
}
/* f(x) from f, f', f'' at x.a */
static hd happly(hd x, double f0, double f1, double f2)
{
	return (hd){ f0, f1 * x.b, f1 * x.c, f1 * x.d + f2 * x.b * x.c };
}
static hd hdiv(hd x, hd y) { return hmul(x, happly(y, 1 / y.a, -1 / (y.a * y.a), 2 / (y.a * y.a * y.a))); }
static hd hsqrt(hd x)
{
	double s = sqrt(x.a);
	return happly(x, s, 0.5 / s, -0.25 / (s * x.a));
}
static hd hpow(hd x, int n)
{
	hd r = hc(1);
	for (int i = 0; i < n; i++)
		r = hmul(r, x);
	return r;
}

typedef hd (*sag_fn)(const struct asph_prescription *, hd, hd);

/* The sag's derivatives by three hyper-dual evaluations. */
static void hd_derivs(sag_fn f, const struct asph_prescription *p, double x, double y,
		      struct asph_sag *o)
{
	hd xx = f(p, (hd){ x, 1, 1, 0 }, hc(y));
	hd yy = f(p, hc(x), (hd){ y, 1, 1, 0 });
	hd xy = f(p, (hd){ x, 1, 0, 0 }, (hd){ y, 0, 1, 0 });
	*o = (struct asph_sag){ xy.a, xy.b, xy.c, xx.d, xy.d, yy.d };
}

/* conic c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2)) of r^2 */
static hd h_conic(double R, double k, hd r2)
{
	double c = isinf(R) ? 0 : 1 / R;
	hd root = hsqrt(hsub(hc(1), hscale(r2, (1 + k) * c * c)));
	return hdiv(hscale(r2, c), hadd(hc(1), root));
}

static hd h_even(const struct asph_prescription *p, hd r2)
{
	hd z = hc(0);
	for (int i = 2; i <= ASPH_SURFACE_MAX_POWER; i += 2)
		z = hadd(z, hscale(hpow(r2, i / 2), p->A[i]));
	return z;
}

static hd h_biconic(const struct asph_prescription *p, hd x, hd y)
{
	double cx = 1 / p->Rx, cy = 1 / p->Ry;
	hd x2 = hmul(x, x), y2 = hmul(y, y);
	hd num = hadd(hscale(x2, cx), hscale(y2, cy));
	hd w = hsub(hsub(hc(1), hscale(x2, (1 + p->kx) * cx * cx)), hscale(y2, (1 + p->ky) * cy * cy));
	return hadd(hdiv(num, hadd(hc(1), hsqrt(w))), h_even(p, hadd(x2, y2)));
}

static hd h_zernike_terms(const struct asph_prescription *p, hd x, hd y);

/* R_rot - sqrt((R_rot - Z(y))^2 - x^2), or Z(y) for a cylinder; plus the
 * Zernike terms */
static hd h_toroidal(const struct asph_prescription *p, hd x, hd y)
{
	hd zy = h_conic(p->R, p->k, hmul(y, y)), z;
	for (int i = 2; i <= ASPH_SURFACE_MAX_POWER; i += 2)
		zy = hadd(zy, hscale(hpow(y, i), p->A[i]));
	if (isinf(p->R_rotation)) {
		z = zy;
	} else {
		hd d = hsub(hc(p->R_rotation), zy);
		z = hsub(hc(p->R_rotation),
			 hscale(hsqrt(hsub(hmul(d, d), hmul(x, x))), p->R_rotation > 0 ? 1 : -1));
	}
	return hadd(z, h_zernike_terms(p, x, y));
}

static hd h_xy(const struct asph_prescription *p, hd x, hd y)
{
	hd u = hscale(x, 1 / p->norm_radius), v = hscale(y, 1 / p->norm_radius);
	hd z = h_conic(p->R, p->k, hadd(hmul(x, x), hmul(y, y)));
	for (int i = 0; i <= ASPH_SURFACE_XY_MAX_DEGREE; i++)
		for (int j = 0; i + j <= ASPH_SURFACE_XY_MAX_DEGREE; j++) {
			double c = p->C[asph_xy_index(i, j)];
			if (c != 0)
				z = hadd(z, hscale(hmul(hpow(u, i), hpow(v, j)), c));
		}
	return z;
}

/* Z_j by the factorial formula, rho^|m| e^(i|m|theta) = (u + iv)^|m|. */
static hd h_zernike_term(int j, hd u, hd v)
{
	int n, m;
	asph_zernike_noll_to_nm(j, &n, &m);
	int am = abs(m);
	hd re = hc(1), im = hc(0), rho2 = hadd(hmul(u, u), hmul(v, v)), radial = hc(0);
	for (int k = 0; k < am; k++) {
		hd nre = hsub(hmul(re, u), hmul(im, v));
		im = hadd(hmul(re, v), hmul(im, u));
		re = nre;
	}
	for (int s = 0; s <= (n - am) / 2; s++) {
		double c = (s % 2 ? -1 : 1) * tgamma(n - s + 1) /
			   (tgamma(s + 1) * tgamma((n + am) / 2 - s + 1) * tgamma((n - am) / 2 - s + 1));
		radial = hadd(radial, hscale(hpow(rho2, (n - am) / 2 - s), c));
	}
	double norm = m == 0 ? sqrt(n + 1.0) : sqrt(2.0 * (n + 1));
	return hscale(hmul(radial, m < 0 ? im : re), norm);
}

/* sum Z_j Zernike_j((x, y) - decenter) / norm_radius) */
static hd h_zernike_terms(const struct asph_prescription *p, hd x, hd y)
{
	hd z = hc(0);
	for (int j = 1; j <= ASPH_SURFACE_MAX_ZERNIKE; j++) {
		if (p->Zernike[j - 1] == 0)
			continue;
		hd u = hscale(hsub(x, hc(p->zernike_decenter[0])), 1 / p->norm_radius);
		hd v = hscale(hsub(y, hc(p->zernike_decenter[1])), 1 / p->norm_radius);
		z = hadd(z, hscale(h_zernike_term(j, u, v), p->Zernike[j - 1]));
	}
	return z;
}

static hd h_zernike(const struct asph_prescription *p, hd x, hd y)
{
	hd r2 = hadd(hmul(x, x), hmul(y, y));
	return hadd(hadd(h_conic(p->R, p->k, r2), h_even(p, r2)), h_zernike_terms(p, x, y));
}

/* Q2D: sum_n a_n Q_n^m(X) by the recurrence, in hyper-dual arithmetic. */
static hd h_q2d_sum(const struct q2d_coef *qc, const double *a, hd X)
{
	const int m = qc->m;
	hd p[ASPH_SURFACE_Q2D_MAX_N + 1], q[ASPH_SURFACE_Q2D_MAX_N + 1], sum = hc(0);
	for (int n = 0; n <= ASPH_SURFACE_Q2D_MAX_N; n++) {
		if (n == 0)
			p[n] = hc(0.5);
		else if (n == 1)
			p[n] = m == 1 ? hsub(hc(1), hscale(X, 0.5)) : hadd(hc(m - 0.5), hscale(X, 1 - m));
		else if (n == 2 && m == 1)
			p[n] = hscale(hadd(hsub(hc(3), hscale(X, 12)), hscale(hmul(X, X), 8)), 1.0 / 6);
		else if (n == 3 && m == 1)
			p[n] = hscale(hsub(hadd(hsub(hc(5), hscale(X, 60)), hscale(hmul(X, X), 120)),
					   hscale(hpow(X, 3), 64)), 0.1);
		else
			p[n] = hsub(hmul(hadd(hc(qc->A[n]), hscale(X, qc->B[n])), p[n - 1]),
				    hscale(p[n - 2], qc->C[n]));
		q[n] = hscale(n ? hsub(p[n], hscale(q[n - 1], qc->g[n - 1])) : p[n], 1 / qc->f[n]);
		sum = hadd(sum, hscale(q[n], a[n]));
	}
	return sum;
}

static hd h_q2d(const struct asph_prescription *p, hd x, hd y)
{
	double c = 1 / p->R;
	hd r2 = hadd(hmul(x, x), hmul(y, y));
	hd u = hscale(x, 1 / p->norm_radius), v = hscale(y, 1 / p->norm_radius);
	hd X = hadd(hmul(u, u), hmul(v, v)), dep = hc(0), re = hc(1), im = hc(0);
	struct qbfs_coef qb;
	qbfs_coef_init(&qb);
	/* m = 0: X (1 - X) sum a_n Q_n^bfs(X), Q^bfs by its own recurrence */
	hd pp = hc(0), pm = hc(0), q1 = hc(0), q2 = hc(0), s0 = hc(0);
	for (int n = 0; n <= ASPH_SURFACE_MAX_Q; n++) {
		hd pn = n == 0 ? hc(2) : n == 1 ? hsub(hc(6), hscale(X, 8))
						: hsub(hmul(hsub(hc(2), hscale(X, 4)), pp), pm);
		pm = pp;
		pp = pn;
		hd qn = pn;
		if (n >= 1)
			qn = hsub(qn, hscale(q1, qb.g[n - 1]));
		if (n >= 2)
			qn = hsub(qn, hscale(q2, qb.h[n - 2]));
		qn = hscale(qn, 1 / qb.f[n]);
		q2 = q1;
		q1 = qn;
		s0 = hadd(s0, hscale(qn, p->Q[n]));
	}
	dep = hmul(hmul(X, hsub(hc(1), X)), s0);
	for (int m = 1; m <= ASPH_SURFACE_Q2D_MAX_M; m++) {
		hd nre = hsub(hmul(re, u), hmul(im, v));
		im = hadd(hmul(re, v), hmul(im, u));
		re = nre;
		struct q2d_coef qc;
		q2d_coef_init(&qc, m);
		dep = hadd(dep, hadd(hmul(re, h_q2d_sum(&qc, p->q2d_a[m - 1], X)),
				     hmul(im, h_q2d_sum(&qc, p->q2d_b[m - 1], X))));
	}
	hd phi = hsqrt(hsub(hc(1), hscale(r2, c * c)));
	return hadd(h_conic(p->R, 0, r2), hdiv(dep, phi));
}

/* ---- prescriptions with high-entropy coefficients ---------------------- */

static struct asph_prescription biconic(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_BICONIC, .Rx = 41.37, .Ry = -63.11,
				       .kx = -0.731, .ky = 2.213, .aperture_diameter = 18.3 };
	p.A[4] = 3.71e-6;
	p.A[6] = -2.29e-9;
	p.A[10] = 1.3e-14;
	return p;
}

static struct asph_prescription toroid(double R_rotation)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_TOROIDAL, .R = 52.9, .k = -0.613,
				       .R_rotation = R_rotation,
				       .aperture = { ASPH_APERTURE_RECTANGULAR, 14.2, 11.7, { 0.37, -0.81 } } };
	p.A[4] = -1.77e-6;
	p.A[8] = 4.1e-12;
	return p;
}

/* OpticStudio's toroid with its optional Zernike Standard terms */
static struct asph_prescription toroid_zernike(void)
{
	struct asph_prescription p = toroid(-71.3);
	const int js[] = { 3, 4, 6, 7, 10, 12, 17, 24, 31, 44 };

	p.norm_radius = 9.3;
	for (size_t i = 0; i < sizeof(js) / sizeof(js[0]); i++)
		p.Zernike[js[i] - 1] = 1e-3 * (0.23 + 0.11 * (double)i) * (i % 3 ? 1 : -1);
	return p;
}

static struct asph_prescription xy_poly(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_XY_POLYNOMIAL, .R = -87.3, .k = 0.37,
				       .norm_radius = 11.3,
				       .aperture = { ASPH_APERTURE_ELLIPTICAL, 21.9, 15.1, { 1.3, -2.1 } } };
	const struct { int i, j; double c; } t[] = {
		{ 1, 0, 1.3e-3 }, { 0, 2, -2.7e-2 }, { 2, 1, 4.13e-3 }, { 1, 3, -7.9e-4 },
		{ 4, 1, 2.2e-4 }, { 0, 7, -1.1e-4 }, { 6, 3, 3.3e-5 }, { 11, 9, 1.7e-6 },
	};
	for (size_t i = 0; i < sizeof(t) / sizeof(t[0]); i++)
		p.C[asph_xy_index(t[i].i, t[i].j)] = t[i].c;
	return p;
}

static struct asph_prescription zernike_sag(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_ZERNIKE_SAG, .R = 71.3, .k = -1.21,
				       .norm_radius = 10.7, .zernike_decenter = { 0.41, -0.23 },
				       .aperture_diameter = 20.1 };
	/* up to radial order 10: the higher orders' explicit radial
	 * polynomials carry rounding of their own (test_zernike_terms) */
	const int js[] = { 2, 5, 8, 9, 11, 16, 22, 37, 56, 61, 65 };
	p.A[4] = -2.2e-6;
	for (size_t i = 0; i < sizeof(js) / sizeof(js[0]); i++)
		p.Zernike[js[i] - 1] = 1e-3 * (0.31 + 0.17 * (double)i) * (i % 2 ? -1 : 1);
	return p;
}

static struct asph_prescription q2d(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_Q2D, .R = 48.1, .norm_radius = 12.6,
				       .aperture_diameter = 24.4 };
	p.Q[0] = 2.1e-3;
	p.Q[1] = -4.4e-4;
	p.Q[5] = 1.3e-5;
	p.q2d_a[0][0] = 7.3e-4;
	p.q2d_a[0][3] = -1.9e-4;
	p.q2d_b[1][0] = 3.1e-4;
	p.q2d_a[2][2] = -2.3e-5;
	p.q2d_b[2][7] = 6.1e-6;
	p.q2d_a[4][1] = 1.7e-5;
	p.q2d_b[5][12] = -2.9e-6;
	p.q2d_a[19][20] = 3.7e-7;
	return p;
}

static void check_against_hd(const struct asph_prescription *p, sag_fn f, double a)
{
	struct asph_surface *s = build(p);
	for (int i = 0; i < N_POINTS; i++) {
		double x, y;
		struct asph_sag got, want;
		point(i, a, &x, &y);
		x += p->aperture.offset[0];
		y += p->aperture.offset[1];
		asph_surface_derivs_xy(s, x, y, &got);
		hd_derivs(f, p, x, y, &want);
		assert_same_sag(&got, &want, 1e-12);
		assert_close(asph_surface_sag_xy(s, x, y), got.z, 1e-15 * fabs(got.z) + 1e-300, "sag_xy");
		/* the gradient alone is the same computation without the Hessian */
		double g[3];
		asph_surface_sag_grad_xy(s, x, y, g);
		struct asph_sag first = { g[0], g[1], g[2], want.zxx, want.zxy, want.zyy };
		assert_same_sag(&first, &want, 1e-12);
	}
	asph_surface_free(s);
}

static void test_derivatives_independent(void **state)
{
	struct asph_prescription p = biconic();
	check_against_hd(&p, h_biconic, 9.1);
	p = toroid(37.9);
	check_against_hd(&p, h_toroidal, 5.8);
	p = toroid(-44.1);
	check_against_hd(&p, h_toroidal, 5.8);
	p = toroid(INFINITY);
	check_against_hd(&p, h_toroidal, 5.8);
	p = toroid_zernike();
	check_against_hd(&p, h_toroidal, 5.8);
	p = xy_poly();
	check_against_hd(&p, h_xy, 7.5);
	p = zernike_sag();
	check_against_hd(&p, h_zernike, 9.9);
	p = q2d();
	check_against_hd(&p, h_q2d, 12.1);
}

/* ---- closed forms -------------------------------------------------------- */

static struct asph_prescription even_asphere(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = 23.71, .k = -0.93,
				       .aperture_diameter = 19.2 };
	p.A[2] = 1.3e-4;
	p.A[4] = -2.0868e-5;
	p.A[6] = -3.9031e-9;
	p.A[8] = 3.4102e-11;
	return p;
}

static void compare_surfaces(const struct asph_prescription *pa, const struct asph_prescription *pb,
			     double a, double rel)
{
	struct asph_surface *sa = build(pa), *sb = build(pb);
	for (int i = 0; i < N_POINTS; i++) {
		double x, y;
		struct asph_sag da, db;
		point(i, a, &x, &y);
		asph_surface_derivs_xy(sa, x, y, &da);
		asph_surface_derivs_xy(sb, x, y, &db);
		assert_same_sag(&da, &db, rel);
	}
	asph_surface_free(sa);
	asph_surface_free(sb);
}

static void test_biconic_equal_radii_is_even_asphere(void **state)
{
	struct asph_prescription e = even_asphere();
	struct asph_prescription b = { .type = ASPH_SURFACE_BICONIC, .Rx = e.R, .Ry = e.R,
				       .kx = e.k, .ky = e.k, .aperture_diameter = e.aperture_diameter };
	memcpy(b.A, e.A, sizeof(b.A));
	compare_surfaces(&b, &e, 9.6, 1e-13);
}

/* A4 r^4 = A4 rho^4 (u^2 + v^2)^2 and so on, expanded binomially. */
static void test_xy_polynomial_holding_even_asphere(void **state)
{
	struct asph_prescription e = even_asphere();
	double rho = 8.37;
	struct asph_prescription p = { .type = ASPH_SURFACE_XY_POLYNOMIAL, .R = e.R, .k = e.k,
				       .norm_radius = rho, .aperture_diameter = e.aperture_diameter };
	for (int i = 2; i <= 8; i += 2) {
		int h = i / 2;
		double binom = 1;
		for (int l = 0; l <= h; l++) {
			p.C[asph_xy_index(2 * l, 2 * (h - l))] = e.A[i] * pow(rho, i) * binom;
			binom = binom * (h - l) / (l + 1);
		}
	}
	compare_surfaces(&p, &e, 9.6, 1e-12);
}

static void test_q2d_m0_is_qbfs(void **state)
{
	struct asph_prescription qb = { .type = ASPH_SURFACE_QBFS, .R = 48.1, .norm_radius = 12.6,
					.aperture_diameter = 24.4 };
	qb.Q[0] = 2.1e-3;
	qb.Q[1] = -4.4e-4;
	qb.Q[4] = 7.7e-5;
	qb.Q[9] = -3.1e-6;
	struct asph_prescription p = { .type = ASPH_SURFACE_Q2D, .R = qb.R, .norm_radius = qb.norm_radius,
				       .aperture_diameter = qb.aperture_diameter };
	memcpy(p.Q, qb.Q, sizeof(p.Q));
	compare_surfaces(&p, &qb, 12.1, 1e-12);
}

/* A circle of radius R rotated about an axis at distance R is a sphere. */
static void test_toroid_sphere_and_cylinder(void **state)
{
	struct asph_prescription t = { .type = ASPH_SURFACE_TOROIDAL, .R = 31.7, .R_rotation = 31.7,
				       .aperture_diameter = 20 };
	struct asph_prescription sph = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = 31.7,
					 .aperture_diameter = 20 };
	compare_surfaces(&t, &sph, 9.8, 1e-13);
	/* a cylinder: the y-z curve only */
	t.R_rotation = INFINITY;
	struct asph_surface *s = build(&t), *e = build(&sph);
	for (int i = 0; i < N_POINTS; i++) {
		double x, y;
		struct asph_sag d;
		point(i, 9.8, &x, &y);
		asph_surface_derivs_xy(s, x, y, &d);
		assert_close(d.z, asph_surface_sag(e, fabs(y)), 1e-14, "cylinder z");
		assert_close(d.zx, 0, 0, "cylinder zx");
		assert_close(d.zxx, 0, 0, "cylinder zxx");
	}
	asph_surface_free(s);
	asph_surface_free(e);
}

/* Z4 .. Z11 expanded by hand in u, v. */
static double hand_zernike(int j, double u, double v)
{
	double r2 = u * u + v * v;
	switch (j) {
	case 1: return 1;
	case 2: return 2 * u;
	case 3: return 2 * v;
	case 4: return sqrt(3) * (2 * r2 - 1);
	case 5: return sqrt(6) * 2 * u * v;
	case 6: return sqrt(6) * (u * u - v * v);
	case 7: return sqrt(8) * (3 * r2 - 2) * v;
	case 8: return sqrt(8) * (3 * r2 - 2) * u;
	case 9: return sqrt(8) * (3 * u * u * v - v * v * v);
	case 10: return sqrt(8) * (u * u * u - 3 * u * v * v);
	case 11: return sqrt(5) * (6 * r2 * r2 - 6 * r2 + 1);
	default: return NAN;
	}
}

/* Z_j in long double by the factorial formula, and the rounding bound of
 * its evaluation in double: eps times the sum of the magnitudes of the
 * radial coefficients (the terms cancel at rho near 1). */
static long double zernike_ld(int j, long double u, long double v, double *bound)
{
	int n, m;
	asph_zernike_noll_to_nm(j, &n, &m);
	int am = abs(m);
	long double re = 1, im = 0, r2 = u * u + v * v, radial = 0, mag = 0;
	for (int k = 0; k < am; k++) {
		long double nre = re * u - im * v;
		im = re * v + im * u;
		re = nre;
	}
	for (int s = 0; s <= (n - am) / 2; s++) {
		long double c = (s % 2 ? -1 : 1) * tgammal(n - s + 1) /
				(tgammal(s + 1) * tgammal((n + am) / 2 - s + 1) * tgammal((n - am) / 2 - s + 1));
		radial += c * powl(r2, (n - am) / 2 - s);
		mag += fabsl(c);
	}
	long double norm = m == 0 ? sqrtl(n + 1.0L) : sqrtl(2.0L * (n + 1));
	*bound = (double)(norm * mag) * 0x1p-52 * (1 + am);
	return norm * radial * (m < 0 ? im : re);
}

/* The terms of each radial order n together, each with its own
 * coefficient, against the sum of the long double references; Z1 .. Z11
 * also against the hand expansions. */
static void test_zernike_terms(void **state)
{
	const double rho = 9.3;
	struct asph_prescription p = { .type = ASPH_SURFACE_ZERNIKE_SAG, .R = INFINITY,
				       .norm_radius = rho, .aperture_diameter = 18.6 };
	for (int n = 0; n <= 20; n++) {
		int j0 = n * (n + 1) / 2 + 1, j1 = (n + 1) * (n + 2) / 2;
		memset(p.Zernike, 0, sizeof(p.Zernike));
		for (int j = j0; j <= j1; j++)
			p.Zernike[j - 1] = 1.3e-6 * (1.0 + 0.173 * (j - j0)) * (j % 3 ? 1 : -1);
		struct asph_surface *s = build(&p);
		for (int i = 0; i < N_POINTS; i++) {
			double x, y, want = 0, bound = 0;
			point(i, rho, &x, &y);
			double u = x / rho, v = y / rho, z = asph_surface_sag_xy(s, x, y);
			for (int j = j0; j <= j1; j++) {
				double b, w = fabs(p.Zernike[j - 1]);
				double zj = (double)zernike_ld(j, u, v, &b);
				if (j <= 11)
					assert_close(zj, hand_zernike(j, u, v), 1e-14, "hand-expanded");
				want += p.Zernike[j - 1] * zj;
				bound += w * b;
			}
			assert_close(z, want, bound + 1e-300, "Z_j");
		}
		asph_surface_free(s);
	}
}

/* Orthonormality of the gradients of u^m Q_n^m(u^2) cos(m theta):
 * (1/pi) int_0^1 (R_a' R_b' + m^2 R_a R_b / u^2) / sqrt(1 - u^2) du
 * = delta_ab, R = u^m Q(u^2). With u = sin t the integrand is even and a
 * trigonometric polynomial: the trapezoid rule over a period is exact. */
static void test_q2d_orthonormal(void **state)
{
	const int K = 256, N = ASPH_SURFACE_Q2D_MAX_N + 1;
	for (int m = 1; m <= ASPH_SURFACE_Q2D_MAX_M; m++) {
		struct q2d_coef c;
		double G[ASPH_SURFACE_Q2D_MAX_N + 1][ASPH_SURFACE_Q2D_MAX_N + 1] = { { 0 } };
		q2d_coef_init(&c, m);
		for (int k = 0; k < K; k++) {
			double u = sin(2 * M_PI * (k + 0.5) / K), q[ASPH_SURFACE_Q2D_MAX_N + 1][3];
			double um1 = 1, R[ASPH_SURFACE_Q2D_MAX_N + 1], Rp[ASPH_SURFACE_Q2D_MAX_N + 1];
			for (int i = 0; i < m - 1; i++)
				um1 *= u;
			q2d_eval(&c, N, u * u, q);
			for (int n = 0; n < N; n++) {
				R[n] = um1 * q[n][0];   /* R / u */
				Rp[n] = m * um1 * q[n][0] + um1 * u * q[n][1] * 2 * u;
			}
			for (int a = 0; a < N; a++)
				for (int b = 0; b < N; b++)
					G[a][b] += (Rp[a] * Rp[b] + m * m * R[a] * R[b]) / (2.0 * K);
		}
		for (int a = 0; a < N; a++)
			for (int b = 0; b < N; b++)
				assert_close(G[a][b], a == b, 1e-12, "Gram");
	}
}

/* ---- apertures, area, extent ----------------------------------------------- */

/* z = t x / rho is a tilted plane: the area element is sqrt(1 + (t/rho)^2)
 * everywhere, the slope t/rho, the sag extremes at the aperture's x ends. */
static void test_plane_area_extent(void **state)
{
	const double rho = 7.1, t = 2.3;
	const struct asph_aperture aps[] = {
		{ ASPH_APERTURE_RECTANGULAR, 12.4, 7.9, { 1.1, -3.2 } },
		{ ASPH_APERTURE_ELLIPTICAL, 9.7, 15.3, { -2.2, 0.6 } },
		{ ASPH_APERTURE_CIRCULAR, 11.1, 11.1, { 0.4, 0.9 } },
	};
	for (size_t i = 0; i < sizeof(aps) / sizeof(aps[0]); i++) {
		struct asph_prescription p = { .type = ASPH_SURFACE_XY_POLYNOMIAL, .R = INFINITY,
					       .norm_radius = rho, .aperture = aps[i] };
		struct asph_surface_extent e;
		p.C[asph_xy_index(1, 0)] = t;
		struct asph_surface *s = build(&p);
		double proj = aps[i].shape == ASPH_APERTURE_RECTANGULAR
				      ? aps[i].width * aps[i].height
				      : M_PI / 4 * aps[i].width * aps[i].height;
		double el = sqrt(1 + t * t / (rho * rho));
		assert_close(asph_surface_projected_area(s), proj, 1e-13 * proj, "projected");
		assert_close(asph_surface_total_area(s), proj * el, 1e-12 * proj, "area");
		assert_close(asph_surface_gamma(s), el, 1e-12, "gamma");
		asph_surface_extent(s, &e);
		double xmax = aps[i].offset[0] + aps[i].width / 2;
		double xmin = aps[i].offset[0] - aps[i].width / 2;
		assert_close(e.sag_max, t * xmax / rho, 1e-9 * aps[i].width, "sag_max");
		assert_close(e.sag_min, t * xmin / rho, 1e-9 * aps[i].width, "sag_min");
		assert_close(e.max_slope, t / rho, 1e-14, "slope");
		assert_true(asph_surface_contains(s, e.sag_max_at[0], e.sag_max_at[1], 0));
		assert_true(isnan(asph_surface_sag(s, 1.0)));
		assert_true(isnan(asph_surface_area(s, 1.0)));
		assert_false(asph_surface_is_rotational(s));
		asph_surface_free(s);
	}
}

/* A sphere as a zernike_sag with no terms: area 2 pi R h over a disk. */
static void test_sphere_area(void **state)
{
	const double R = 21.7, a = 9.4;
	struct asph_prescription p = { .type = ASPH_SURFACE_ZERNIKE_SAG, .R = R, .norm_radius = a,
				       .aperture_diameter = 2 * a };
	struct asph_surface *s = build(&p);
	double h = a * a / (R + sqrt(R * R - a * a));
	assert_close(asph_surface_total_area(s), 2 * M_PI * R * h, 1e-12 * R * h, "sphere area");
	assert_close(asph_surface_aperture_radius(s), a, 0, "aperture radius");
	asph_surface_free(s);
}

static void test_aperture_geometry(void **state)
{
	struct asph_prescription p = xy_poly();
	struct asph_surface *s = build(&p);
	double box[4], far = 0;
	/* the ellipse 21.9 x 15.1 centred at (1.3, -2.1) */
	asph_surface_bounds(s, box);
	assert_close(box[0], 1.3 - 10.95, 1e-15, "x_min");
	assert_close(box[3], -2.1 + 7.55, 1e-15, "y_max");
	assert_true(asph_surface_contains(s, 1.3 + 10.95, -2.1, 0));
	assert_false(asph_surface_contains(s, 1.3 + 10.96, -2.1, 0));
	assert_true(asph_surface_contains(s, 1.3 + 10.96, -2.1, 0.02));
	assert_false(asph_surface_contains(s, 1.3 + 7.8, -2.1 + 5.4, 0));
	for (int i = 0; i < 100000; i++) {
		double t = 2 * M_PI * i / 100000.0;
		far = fmax(far, hypot(1.3 + 10.95 * cos(t), -2.1 + 7.55 * sin(t)));
	}
	assert_close(asph_surface_aperture_radius(s), far, 1e-8, "farthest point");
	asph_surface_free(s);
}

/* ---- checks and the reader ------------------------------------------------- */

static void expect_refusal(const struct asph_prescription *p, const char *field)
{
	struct asph_error err;
	asph_error_clear(&err);
	assert_int_equal(asph_prescription_check(p, &err), -EINVAL);
	if (strcmp(err.field, field)) {
		print_error("field '%s' (%s), expected '%s'\n", err.field, err.message, field);
		fail();
	}
}

static void test_checks(void **state)
{
	struct asph_prescription p = biconic();
	p.kx = 30;     /* (1 + kx) x^2 / Rx^2 > 1 at the edge */
	expect_refusal(&p, "kx");
	p = biconic();
	p.Ry = 0;
	expect_refusal(&p, "Ry");
	p = biconic();
	p.k = 1;
	expect_refusal(&p, "k");
	p = biconic();
	p.A[3] = 1e-5;
	expect_refusal(&p, "A.3");
	p = toroid(5.0);  /* the circle of rotation is smaller than the aperture */
	expect_refusal(&p, "R_rotation");
	p = toroid_zernike();
	p.norm_radius = 0;
	expect_refusal(&p, "norm_radius");
	p = toroid_zernike();
	p.zernike_decenter[1] = 0.5;  /* OpticStudio's toroid centres its terms */
	expect_refusal(&p, "zernike_decenter");
	p = xy_poly();
	p.C[0] = 1;
	expect_refusal(&p, "c.x0y0");
	p = xy_poly();
	p.A[4] = 1e-6;
	expect_refusal(&p, "A.4");
	p = xy_poly();
	p.norm_radius = 0;
	expect_refusal(&p, "norm_radius");
	p = xy_poly();
	p.aperture_diameter = 10;
	expect_refusal(&p, "aperture_diameter");
	p = xy_poly();
	p.aperture.height = -1;
	expect_refusal(&p, "aperture.height");
	p = zernike_sag();
	p.Zernike[7] = NAN;
	expect_refusal(&p, "zernike.[7]");
	p = q2d();
	p.R = 10;       /* the aperture reaches past the sphere */
	expect_refusal(&p, "R");
	p = q2d();
	p.q2d_b[2][4] = INFINITY;
	expect_refusal(&p, "b_m.3.[4]");
	p = q2d();
	p.k = -1;
	expect_refusal(&p, "k");
}

static void parse_ok(const char *json, struct asph_prescription *p)
{
	struct asph_error err;
	asph_error_clear(&err);
	if (asph_prescription_parse(json, strlen(json), "t.json", p, &err) < 0) {
		print_error("%s: %s\n", err.field, err.message);
		fail();
	}
}

static void parse_fails(const char *json, const char *field, int line, int column)
{
	struct asph_prescription p;
	struct asph_error err;
	asph_error_clear(&err);
	assert_int_equal(asph_prescription_parse(json, strlen(json), "t.json", &p, &err), -EINVAL);
	if (strcmp(err.field, field) || err.line != line || err.column != column) {
		print_error("got %s at %d:%d (%s), expected %s at %d:%d\n", err.field, err.line,
			    err.column, err.message, field, line, column);
		fail();
	}
	assert_string_equal(err.source, "t.json");
}

static void test_json(void **state)
{
	struct asph_prescription p, back;
	char *text = NULL;

	parse_ok("{\"type\": \"biconic\", \"Rx\": \"infinity\", \"Ry\": 40, \"ky\": -1,\n"
		 " \"A\": {\"4\": 1e-6}, \"aperture\": {\"shape\": \"rectangular\", \"width\": 20,"
		 " \"height\": 10, \"offset\": [0, 5]}}", &p);
	assert_true(isinf(p.Rx));
	assert_int_equal(p.aperture.shape, ASPH_APERTURE_RECTANGULAR);
	assert_close(p.aperture.offset[1], 5, 0, "offset");
	assert_int_equal(asph_prescription_to_json(&p, &text), 0);
	parse_ok(text, &back);
	assert_memory_equal(&p, &back, sizeof(p));
	free(text);

	parse_ok("{\"type\": \"q2d\", \"R\": 50, \"norm_radius\": 10, \"a\": [1e-3],"
		 " \"a_m\": {\"2\": [1e-4, 2e-5]}, \"b_m\": {\"1\": [0, 3e-6]}, \"aperture_diameter\": 20}", &p);
	assert_close(p.q2d_a[1][1], 2e-5, 0, "a_1^2");
	assert_close(p.q2d_b[0][1], 3e-6, 0, "b_1^1");
	assert_int_equal(asph_prescription_to_json(&p, &text), 0);
	parse_ok(text, &back);
	assert_memory_equal(&p, &back, sizeof(p));
	free(text);

	parse_ok("{\"type\": \"xy_polynomial\", \"R\": -80, \"k\": 0.5, \"norm_radius\": 10,"
		 " \"c\": {\"x2y0\": 1e-3, \"x0y2\": -2e-3, \"x3y17\": 1e-7},"
		 " \"aperture\": {\"shape\": \"elliptical\", \"width\": 20, \"height\": 12}}", &p);
	assert_close(p.C[asph_xy_index(3, 17)], 1e-7, 0, "x3y17");
	assert_int_equal(asph_prescription_to_json(&p, &text), 0);
	parse_ok(text, &back);
	assert_memory_equal(&p, &back, sizeof(p));
	free(text);

	parse_ok("{\"type\": \"zernike_sag\", \"R\": 60, \"norm_radius\": 10, \"zernike\": [0, 1e-4, 0, 2e-4],"
		 " \"zernike_decenter\": [0.5, 0], \"A\": {\"4\": 1e-6}, \"aperture_diameter\": 20}", &p);
	assert_int_equal(asph_prescription_to_json(&p, &text), 0);
	parse_ok(text, &back);
	assert_memory_equal(&p, &back, sizeof(p));
	free(text);

	parse_ok("{\"type\": \"toroidal\", \"R\": 60, \"R_rotation\": -40, \"A\": {\"4\": 1e-6},"
		 " \"aperture_diameter\": 20}", &p);
	assert_int_equal(asph_prescription_to_json(&p, &text), 0);
	parse_ok(text, &back);
	assert_memory_equal(&p, &back, sizeof(p));
	free(text);

	parse_ok("{\"type\": \"toroidal\", \"R\": 60, \"R_rotation\": -40, \"norm_radius\": 9,"
		 " \"zernike\": [0, 0, 2e-4, 0, 0, -1e-4], \"aperture_diameter\": 16}", &p);
	assert_close(p.Zernike[5], -1e-4, 0, "Z6");
	assert_int_equal(asph_prescription_to_json(&p, &text), 0);
	assert_non_null(strstr(text, "\"zernike\""));
	parse_ok(text, &back);
	assert_memory_equal(&p, &back, sizeof(p));
	free(text);
	parse_fails("{\"type\": \"toroidal\", \"R\": 60, \"R_rotation\": -40,\n"
		    " \"zernike\": [0, 1e-4], \"aperture_diameter\": 16}", "", 0, 0);
	parse_fails("{\"type\": \"toroidal\", \"R\": 60, \"R_rotation\": -40, \"norm_radius\": 9,\n"
		    " \"zernike_decenter\": [1, 0], \"aperture_diameter\": 16}", "zernike_decenter", 2, 2);
	parse_fails("{\"type\": \"xy_polynomial\", \"R\": 50, \"norm_radius\": 10,\n"
		    "  \"c\": {\"x2\": 1e-3}, \"aperture_diameter\": 20}", "c.x2", 2, 9);
	parse_fails("{\"type\": \"xy_polynomial\", \"R\": 50, \"norm_radius\": 10,\n"
		    "  \"c\": {\"x12y9\": 1e-3}, \"aperture_diameter\": 20}", "c.x12y9", 2, 9);
	parse_fails("{\"type\": \"biconic\", \"Rx\": 40,\n \"Ry\": \"flat\", \"aperture_diameter\": 20}",
		    "Ry", 2, 2);
	parse_fails("{\"type\": \"q2d\", \"R\": 50, \"norm_radius\": 10,\n"
		    " \"a_m\": {\"0\": [1]}, \"aperture_diameter\": 20}", "a_m.0", 2, 10);
	parse_fails("{\"type\": \"xy_polynomial\", \"R\": 50, \"norm_radius\": 10,\n"
		    " \"aperture\": {\"shape\": \"hexagonal\", \"width\": 3}}", "aperture.shape", 2, 15);
	parse_fails("{\"type\": \"biconic\", \"Rx\": 40, \"Ry\": 50,\n \"kx\": 60, \"aperture_diameter\": 20}",
		    "kx", 2, 2);
	parse_fails("{\"type\": \"even_asphere\", \"R\": 40,\n \"aperture\": {\"shape\": \"circular\", "
		    "\"diameter\": 3, \"offset\": [45, 1]}}", "k", 0, 0);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_derivatives_independent),
		cmocka_unit_test(test_biconic_equal_radii_is_even_asphere),
		cmocka_unit_test(test_xy_polynomial_holding_even_asphere),
		cmocka_unit_test(test_q2d_m0_is_qbfs),
		cmocka_unit_test(test_toroid_sphere_and_cylinder),
		cmocka_unit_test(test_zernike_terms),
		cmocka_unit_test(test_q2d_orthonormal),
		cmocka_unit_test(test_plane_area_extent),
		cmocka_unit_test(test_sphere_area),
		cmocka_unit_test(test_aperture_geometry),
		cmocka_unit_test(test_checks),
		cmocka_unit_test(test_json),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
