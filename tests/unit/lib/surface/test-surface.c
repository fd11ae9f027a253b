/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <string.h>

#include <cmocka.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_integration.h>

#include "asph/prescription.h"
#include "asph/surface.h"

/* Radii chosen so that no symmetric value hides a missing term. */
static const double radii[] = { 0.0, 1e-7, 0.0137, 0.731, 2.918, 5.5517, 9.03, 12.21, 13.69 };

static struct asph_surface *make(double R, double k, double diameter)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = R, .k = k,
				       .aperture_diameter = diameter };
	struct asph_surface *s = NULL;
	struct asph_error err;
	assert_int_equal(asph_surface_alloc(&p, &s, &err), 0);
	return s;
}

static void assert_rel(double got, double want, double tol)
{
	double scale = fmax(fabs(want), 1e-300);
	if (!(fabs(got - want) <= tol * scale) && !(want == 0 && fabs(got) < 1e-300)) {
		print_error("got %.17g want %.17g (rel err %.3g > %.3g)\n", got, want,
			    fabs(got - want) / scale, tol);
		fail();
	}
}

/* Sphere: sag R - sqrt(R^2 - r^2), area 2 pi R h, arc R asin(r/R). */
static void test_sphere(void **state)
{
	const double Rs[] = { 37.31, -23.77 };
	for (size_t j = 0; j < 2; j++) {
		double R = Rs[j], aR = fabs(R);
		struct asph_surface *s = make(R, 0, 27.4);
		for (size_t i = 0; i < sizeof(radii) / sizeof(radii[0]); i++) {
			double r = radii[i], d[3];
			double root = sqrt(R * R - r * r);
			/* R - sqrt(R^2 - r^2) without its cancellation */
			double h = r * r / (aR + root);
			double sag = copysign(h, R);
			asph_surface_sag_derivs(s, r, d);
			assert_rel(d[0], sag, 1e-14);
			assert_rel(d[1], r / (copysign(1, R) * root), 1e-12);
			assert_rel(d[2], R * R / (copysign(1, R) * root * root * root), 1e-12);
			if (r > 1e-3) {
				assert_rel(asph_surface_area(s, r), 2 * M_PI * aR * h, 1e-13);
				assert_rel(asph_surface_arc_length(s, r), aR * asin(r / aR), 1e-13);
				assert_rel(asph_surface_radius_at_area(s, 2 * M_PI * aR * h), r, 1e-13);
				assert_rel(asph_surface_radius_at_arc_length(s, aR * asin(r / aR)), r, 1e-13);
			}
		}
		asph_surface_free(s);
	}
}

/* Paraboloid k = -1: sag r^2/2R; area (2 pi R^2/3)((1 + r^2/R^2)^1.5 - 1). */
static void test_paraboloid(void **state)
{
	double R = 17.93;
	struct asph_surface *s = make(R, -1, 61.3);
	for (size_t i = 0; i < sizeof(radii) / sizeof(radii[0]); i++) {
		double r = radii[i] * 2.1, d[3];
		asph_surface_sag_derivs(s, r, d);
		assert_rel(d[0], r * r / (2 * R), 1e-14);
		assert_rel(d[1], r / R, 1e-14);
		assert_rel(d[2], 1 / R, 1e-14);
		if (r > 1e-3) {
			double u = r / R;
			double area = 2 * M_PI * R * R / 3 * expm1(1.5 * log1p(u * u));
			double arc = 0.5 * r * sqrt(1 + u * u) + 0.5 * R * asinh(u);
			assert_rel(asph_surface_area(s, r), area, 1e-13);
			assert_rel(asph_surface_arc_length(s, r), arc, 1e-13);
			assert_rel(asph_surface_radius_at_area(s, area), r, 1e-13);
			assert_rel(asph_surface_radius_at_arc_length(s, arc), r, 1e-13);
		}
	}
	asph_surface_free(s);
}

/* Hyperboloid (k < -1) against the conic's implicit equation
 * (1+k) z^2 - 2 R z + r^2 = 0: z' = r / (R - (1+k) z),
 * z'' = (1 + (1+k) z'^2) / (R - (1+k) z). */
static void test_hyperboloid(void **state)
{
	const double R = 11.37, k = -2.71;
	struct asph_surface *s = make(R, k, 44.0);
	for (size_t i = 0; i < sizeof(radii) / sizeof(radii[0]); i++) {
		double r = radii[i] * 1.6, d[3];
		if (r < 0.5)
			continue;
		double z = (R - sqrt(R * R - (1 + k) * r * r)) / (1 + k);
		double dz = r / (R - (1 + k) * z);
		double d2z = (1 + (1 + k) * dz * dz) / (R - (1 + k) * z);
		asph_surface_sag_derivs(s, r, d);
		assert_rel(d[0], z, 1e-12);
		assert_rel(d[1], dz, 1e-12);
		assert_rel(d[2], d2z, 1e-12);
	}
	/* Stable at the vertex: no NaN, leading term c r^2 / 2. */
	double d[3];
	asph_surface_sag_derivs(s, 0, d);
	assert_true(d[0] == 0 && d[1] == 0);
	assert_rel(d[2], 1 / R, 1e-15);
	asph_surface_sag_derivs(s, 3e-9, d);
	assert_rel(d[0], 3e-9 * 3e-9 / (2 * R), 1e-15);
	asph_surface_free(s);
}

/* The polynomial terms add exactly sum A_i r^i and its derivatives. */
static void test_polynomial_terms(void **state)
{
	struct asph_prescription p = { .R = -53.9, .k = 0.37, .aperture_diameter = 21.3 };
	p.A[4] = 3.17e-5;
	p.A[6] = -2.3e-8;
	p.A[10] = 7.1e-13;
	struct asph_prescription q = p;
	memset(q.A, 0, sizeof(q.A));
	struct asph_surface *s, *base;
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	assert_int_equal(asph_surface_alloc(&q, &base, NULL), 0);
	for (size_t i = 0; i < sizeof(radii) / sizeof(radii[0]); i++) {
		double r = radii[i] * 0.77, d[3], b[3];
		asph_surface_sag_derivs(s, r, d);
		asph_surface_sag_derivs(base, r, b);
		double poly = p.A[4] * pow(r, 4) + p.A[6] * pow(r, 6) + p.A[10] * pow(r, 10);
		double dpoly = 4 * p.A[4] * pow(r, 3) + 6 * p.A[6] * pow(r, 5) + 10 * p.A[10] * pow(r, 9);
		double d2poly = 12 * p.A[4] * r * r + 30 * p.A[6] * pow(r, 4) + 90 * p.A[10] * pow(r, 8);
		assert_true(fabs(d[0] - b[0] - poly) <= 1e-15 * (fabs(d[0]) + fabs(b[0]) + 1e-300));
		assert_true(fabs(d[1] - b[1] - dpoly) <= 1e-15 * (fabs(d[1]) + fabs(b[1]) + 1e-300));
		assert_true(fabs(d[2] - b[2] - d2poly) <= 1e-14 * (fabs(d[2]) + fabs(b[2])));
	}
	asph_surface_free(s);
	asph_surface_free(base);
}

static void test_normal(void **state)
{
	struct asph_prescription p;
	struct asph_surface *s;
	assert_int_equal(asph_prescription_preset("turning-point", &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	const double pts[][2] = { { 0, 0 }, { 3.1, -7.7 }, { -21.9, 13.3 }, { 0.4, 29.1 } };
	for (size_t i = 0; i < 4; i++) {
		double x = pts[i][0], y = pts[i][1], n[3], d[3];
		double r = hypot(x, y);
		asph_surface_normal(s, x, y, n);
		asph_surface_sag_derivs(s, r, d);
		assert_rel(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1, 1e-15);
		assert_true(n[2] > 0);
		if (r > 0) {
			/* perpendicular to the radial and the tangential directions */
			double tr[3] = { x / r, y / r, d[1] };
			double tt[3] = { -y / r, x / r, 0 };
			assert_true(fabs(n[0] * tr[0] + n[1] * tr[1] + n[2] * tr[2]) < 1e-14);
			assert_true(fabs(n[0] * tt[0] + n[1] * tt[1]) < 1e-15);
		} else {
			assert_true(n[0] == 0 && n[1] == 0 && n[2] == 1);
		}
	}
	asph_surface_free(s);
}

static double area_integrand(double r, void *ctx)
{
	double d[3];
	asph_surface_sag_derivs(ctx, r, d);
	return 2 * M_PI * r * sqrt(1 + d[1] * d[1]);
}

/* gamma as the paper reports it, and the area against GSL's adaptive QAG. */
static void test_presets_gamma(void **state)
{
	const char *names[] = { "weak", "strong", "turning-point" };
	const double gamma[] = { 1.06, 1.09, 3.22 };
	gsl_integration_workspace *w = gsl_integration_workspace_alloc(1000);
	for (size_t i = 0; i < 3; i++) {
		struct asph_prescription p;
		struct asph_surface *s;
		assert_int_equal(asph_prescription_preset(names[i], &p), 0);
		assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
		double g = asph_surface_gamma(s);
		assert_true(fabs(g - gamma[i]) < 0.005);
		double a = asph_surface_aperture_radius(s);
		for (double f = 0.113; f <= 1.0; f += 0.2217) {
			gsl_function fn = { area_integrand, s };
			double ref, abserr;
			gsl_integration_qag(&fn, 0, a * f, 0, 1e-13, 1000, GSL_INTEG_GAUSS61, w, &ref, &abserr);
			assert_rel(asph_surface_area(s, a * f), ref, 1e-13);
			assert_rel(asph_surface_radius_at_area(s, ref), a * f, 1e-13);
		}
		assert_rel(asph_surface_area(s, a), g * M_PI * a * a, 1e-14);
		/* max slope: no sampled slope exceeds it */
		double r_at, m = asph_surface_max_slope(s, &r_at);
		for (int j = 0; j <= 1000; j++) {
			double d[3];
			asph_surface_sag_derivs(s, a * j / 1000.0, d);
			assert_true(fabs(d[1]) <= m * (1 + 1e-15));
		}
		asph_surface_free(s);
	}
	gsl_integration_workspace_free(w);
}

static void test_arc_length_monotone_and_outside(void **state)
{
	struct asph_surface *s = make(29.3, -0.61, 30.0);
	double prev = -1;
	for (int i = 0; i <= 200; i++) {
		double r = 15.0 * i / 200.0, v = asph_surface_arc_length(s, r);
		assert_true(v > prev);
		prev = v;
	}
	/* past the aperture the exact quadrature takes over, continuously */
	double in = asph_surface_arc_length(s, 15.0), out = asph_surface_arc_length(s, 15.2);
	assert_true(out > in && out - in < 0.25);
	assert_rel(asph_surface_radius_at_arc_length(s, out), 15.2, 1e-12);
	asph_surface_free(s);
}

static void expect_refusal(struct asph_prescription p, const char *field,
			   const char *needle)
{
	struct asph_surface *s = NULL;
	struct asph_error err;
	asph_error_clear(&err);
	assert_int_equal(asph_surface_alloc(&p, &s, &err), -EINVAL);
	assert_null(s);
	assert_string_equal(err.field, field);
	if (!strstr(err.message, needle)) {
		print_error("message '%s' lacks '%s'\n", err.message, needle);
		fail();
	}
}

static void test_refusals(void **state)
{
	struct asph_prescription ok = { .R = 10, .k = 0, .aperture_diameter = 12 }, p;

	p = ok; p.R = 0;
	expect_refusal(p, "R", "R = 0");
	p = ok; p.R = NAN;
	expect_refusal(p, "R", "not a number");
	p = ok; p.k = INFINITY;
	expect_refusal(p, "k", "finite");
	p = ok; p.A[8] = NAN;
	expect_refusal(p, "A.8", "not finite");
	p = ok; p.A[5] = 1e-6;
	expect_refusal(p, "A.5", "even powers");
	p = ok; p.aperture_diameter = 0;
	expect_refusal(p, "aperture_diameter", "positive");
	p = ok; p.aperture_diameter = -4;
	expect_refusal(p, "aperture_diameter", "positive");
	/* A sphere of radius 10 ends at r = 10: a 25 mm aperture does not fit. */
	p = ok; p.aperture_diameter = 25;
	expect_refusal(p, "k", "r = 10 mm");
	/* k = 3: the root vanishes at r = R / 2 = 5 */
	p = ok; p.k = 3;
	expect_refusal(p, "k", "r = 5 mm");
	/* Finite coefficients whose slope squared overflows (|Z'| ~ 1e302 at
	 * the edge): refused at once instead of building tables for seconds. */
	p = ok; p.A[4] = 3.7e299;
	expect_refusal(p, "", "too steep");
	p = ok; p.A[20] = -2.9e281;
	expect_refusal(p, "", "too steep");
}


/* The graph of a sphere, S = R - sqrt(R^2 - x^2 - y^2): gradient (x, y)/w
 * and Hessian (R^2 I - (y^2, -xy; -xy, x^2)) / w^3, w = sqrt(R^2 - r^2). */
static void test_sphere_xy(void **state)
{
	const double Rs[] = { 37.31, -23.77 };
	const double pts[][2] = { { 0, 0 }, { 1e-7, -3e-8 }, { 3.17, -2.09 }, { -9.41, 6.02 },
				  { 0.0, 12.7 } };
	for (size_t j = 0; j < 2; j++) {
		double R = Rs[j], sg = copysign(1, R);
		struct asph_surface *s = make(R, 0, 27.4);
		for (size_t i = 0; i < sizeof(pts) / sizeof(pts[0]); i++) {
			double x = pts[i][0], y = pts[i][1], r2 = x * x + y * y;
			double w = sqrt(R * R - r2), w3 = w * w * w;
			struct asph_sag d;
			asph_surface_derivs_xy(s, x, y, &d);
			assert_rel(d.z, sg * r2 / (fabs(R) + w), 1e-14);
			assert_rel(asph_surface_sag_xy(s, x, y), d.z, 0);
			assert_rel(d.zx, sg * x / w, 1e-13);
			assert_rel(d.zy, sg * y / w, 1e-13);
			/* Hessian entries relative to its norm: zxy is a difference
			 * of two curvatures near the vertex. */
			double hn = fabs(R) / w3 * R;
			assert_true(fabs(d.zxx - sg * (R * R - y * y) / w3) <= 1e-13 * fabs(hn));
			assert_true(fabs(d.zxy - sg * x * y / w3) <= 1e-13 * fabs(hn));
			assert_true(fabs(d.zyy - sg * (R * R - x * x) / w3) <= 1e-13 * fabs(hn));
			assert_rel(asph_surface_area_element(s, x, y), fabs(R) / w, 1e-14);
		}
		asph_surface_free(s);
	}
}

static void test_aperture_of_rotational(void **state)
{
	struct asph_surface *s = make(37.31, -0.7, 27.4);
	struct asph_aperture ap;
	double box[4];

	assert_true(asph_surface_is_rotational(s));
	asph_surface_aperture(s, &ap);
	assert_int_equal(ap.shape, ASPH_APERTURE_CIRCULAR);
	assert_rel(ap.width, 27.4, 0);
	assert_true(asph_surface_contains(s, 13.7, 0, 0));
	assert_true(asph_surface_contains(s, 0, -13.7, 0));
	assert_false(asph_surface_contains(s, 9.7, 9.7, 0));
	assert_true(asph_surface_contains(s, 9.7, 9.7, 0.02));
	asph_surface_bounds(s, box);
	assert_rel(box[0], -13.7, 0);
	assert_rel(box[3], 13.7, 0);
	assert_rel(asph_surface_projected_area(s), M_PI * 13.7 * 13.7, 1e-15);
	assert_rel(asph_surface_total_area(s), asph_surface_area(s, 13.7), 1e-14);
	asph_surface_free(s);
}

/* The turning-point lens rises and falls again: its extreme sag is inside
 * the aperture, where Z' = 0. */
static void test_extent(void **state)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;
	struct asph_surface_extent e;
	struct asph_error err;
	double d[3], r_slope;

	assert_int_equal(asph_prescription_preset("turning-point", &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, &err), 0);
	asph_surface_extent(s, &e);
	for (int i = 0; i <= 1000; i++) {
		double z = asph_surface_sag(s, 30.0 * i / 1000);
		assert_true(z <= e.sag_max && z >= e.sag_min);
	}
	assert_true(e.sag_max_at[0] > 0 && e.sag_max_at[0] < 30);
	asph_surface_sag_derivs(s, e.sag_max_at[0], d);
	assert_true(fabs(d[1]) < 1e-12);
	assert_rel(e.sag_max, d[0], 0);
	assert_rel(e.max_slope, asph_surface_max_slope(s, &r_slope), 0);
	assert_rel(e.max_slope_at[0], r_slope, 0);
	asph_surface_free(s);
}

/* The area of the sphere of radius R over [x0, x1] x [y0, y1] (inside its
 * equator): the integral of R / sqrt(R^2 - x^2 - y^2), from its
 * antiderivative F at the corners. */
static double sphere_area_over_rectangle(double R, double x0, double x1, double y0, double y1)
{
	double xs[2] = { x0, x1 }, ys[2] = { y0, y1 }, sum = 0;

	for (int i = 0; i < 2; i++)
		for (int j = 0; j < 2; j++) {
			double x = xs[i], y = ys[j];
			double F = R * (x * asin(y / sqrt(R * R - x * x)) +
					y * asin(x / sqrt(R * R - y * y)) -
					R * atan(x * y / (R * sqrt(R * R - x * x - y * y))));
			sum += (i == j ? 1 : -1) * F;
		}
	return sum;
}

/* An off-axis segment: a sphere over a rectangle whose centre is off the
 * axis. Its sag is the parent's; the radial tables of the whole part do
 * not apply, the extent and the area come from the aperture. */
static void test_segment(void **state)
{
	const double R = 37.31;
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = R,
				       .aperture = { ASPH_APERTURE_RECTANGULAR, 10, 8, { 0, 12 } } };
	struct asph_surface *s = NULL;
	struct asph_surface_extent e;
	struct asph_error err;
	struct asph_sag d;

	asph_error_clear(&err);
	assert_int_equal(asph_surface_alloc(&p, &s, &err), 0);
	assert_false(asph_surface_is_rotational(s));
	assert_true(asph_surface_is_radial(s));
	assert_true(isnan(asph_surface_arc_length(s, 5)) && isnan(asph_surface_area(s, 5)));
	assert_rel(asph_surface_aperture_radius(s), hypot(5, 16), 1e-15);
	/* the parent's sag, gradient and Hessian */
	const double pts[][2] = { { 0.31, 12.7 }, { -4.9, 8.2 }, { 3.3, 15.9 } };
	for (size_t i = 0; i < 3; i++) {
		double x = pts[i][0], y = pts[i][1], r2 = x * x + y * y, w = sqrt(R * R - r2);
		asph_surface_derivs_xy(s, x, y, &d);
		assert_rel(d.z, r2 / (R + w), 1e-14);
		assert_rel(d.zx, x / w, 1e-13);
		assert_rel(d.zy, y / w, 1e-13);
		assert_rel(d.zxx, (R * R - y * y) / (w * w * w), 1e-12);
		assert_rel(asph_surface_sag(s, sqrt(r2)), d.z, 1e-15);
	}
	assert_true(asph_surface_contains(s, 4.9, 15.9, 0) && !asph_surface_contains(s, 0, 0, 0));
	/* lowest at the edge nearest the axis, highest and steepest at the far
	 * corners */
	asph_surface_extent(s, &e);
	assert_rel(e.sag_min, 64 / (R + sqrt(R * R - 64)), 1e-12);
	assert_rel(e.sag_max, 281 / (R + sqrt(R * R - 281)), 1e-12);
	assert_rel(e.max_slope, sqrt(281) / sqrt(R * R - 281), 1e-9);
	assert_rel(asph_surface_total_area(s), sphere_area_over_rectangle(R, -5, 5, 8, 16), 1e-12);
	assert_rel(asph_surface_projected_area(s), 80, 1e-15);
	asph_surface_free(s);
}

/* A plane base (R infinite, curvature 0): the sag is the polynomial alone,
 * and the radial tables hold. */
static void test_plane_base(void **state)
{
	const double A4 = 2.173e-6, A6 = -3.41e-9, a = 14.3;
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = INFINITY,
				       .aperture_diameter = 2 * a };
	struct asph_surface *s = NULL;
	struct asph_error err;
	double d[3];

	p.A[4] = A4, p.A[6] = A6;
	asph_error_clear(&err);
	assert_int_equal(asph_surface_alloc(&p, &s, &err), 0);
	assert_true(asph_surface_is_rotational(s));
	for (size_t i = 0; i < sizeof(radii) / sizeof(radii[0]); i++) {
		double r = radii[i], r3 = r * r * r;
		asph_surface_sag_derivs(s, r, d);
		assert_rel(d[0], A4 * r3 * r + A6 * r3 * r3, 1e-14);
		assert_rel(d[1], 4 * A4 * r3 + 6 * A6 * r3 * r * r, 1e-14);
		assert_rel(d[2], 12 * A4 * r * r + 30 * A6 * r3 * r, 1e-14);
	}
	/* a flat: the area is the disk's, the arc length the radius */
	p.A[4] = p.A[6] = 0;
	p.R = -INFINITY;
	asph_surface_free(s);
	assert_int_equal(asph_surface_alloc(&p, &s, &err), 0);
	assert_rel(asph_surface_area(s, a), M_PI * a * a, 1e-14);
	assert_rel(asph_surface_arc_length(s, 0.731), 0.731, 1e-14);
	assert_true(asph_surface_sag(s, a) == 0 && asph_surface_max_slope(s, NULL) == 0);
	asph_surface_free(s);
}

int main(void)
{
	gsl_set_error_handler_off();
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_sphere),
		cmocka_unit_test(test_paraboloid),
		cmocka_unit_test(test_hyperboloid),
		cmocka_unit_test(test_polynomial_terms),
		cmocka_unit_test(test_normal),
		cmocka_unit_test(test_presets_gamma),
		cmocka_unit_test(test_arc_length_monotone_and_outside),
		cmocka_unit_test(test_refusals),
		cmocka_unit_test(test_sphere_xy),
		cmocka_unit_test(test_aperture_of_rotational),
		cmocka_unit_test(test_extent),
		cmocka_unit_test(test_segment),
		cmocka_unit_test(test_plane_base),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
