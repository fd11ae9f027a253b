/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <gsl/gsl_errno.h>
#include <gsl/gsl_integration.h>

#include "asph/involute.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "involute-profile.h"

static const char *const presets[] = { "weak", "strong", "turning-point" };

static struct asph_surface *make_surface(const char *preset, double R,
					 double diameter)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE };
	struct asph_surface *s = NULL;

	if (preset)
		assert_int_equal(asph_prescription_preset(preset, &p), 0);
	else {
		p.R = R;
		p.aperture_diameter = diameter;
	}
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

static void flat_derivs(const void *ctx, double r, double d[3])
{
	d[0] = d[1] = d[2] = 0;
}

/* Eq. (5) at arc length l along the plane involute of the circle r0:
 * beta(t), t = sqrt(2 r0 l) (the arc length of beta up to t is t^2/(2 r0)). */
static void plane_involute(double r0, double l, double out[2])
{
	double t = sqrt(2 * r0 * l), phi = t / r0;

	out[0] = r0 * cos(phi) + t * sin(phi);
	out[1] = r0 * sin(phi) - t * cos(phi);
}

static void check_plane(const double *xyz, size_t n, double spacing,
			double a, double tol)
{
	double r0 = spacing / (2 * M_PI);

	/* Arc length up to radius r is (r^2 - r0^2) / (2 r0). */
	assert_int_equal(n, (size_t)floor((a * a - r0 * r0) / (2 * r0 * spacing)) + 1);
	for (size_t k = 0; k < n; k++) {
		double b[2];
		plane_involute(r0, spacing * (double)k, b);
		assert_true(hypot(xyz[3 * k] - b[0], xyz[3 * k + 1] - b[1]) <= tol);
		assert_true(fabs(xyz[3 * k + 2]) <= 1e-12);
	}
}

static void test_plane_exact(void **state)
{
	const double a = 12.53, spacing = 0.371;
	struct involute_profile prof = { .derivs = flat_derivs, .a = a };
	double *xyz = NULL;
	size_t n = 0;

	assert_int_equal(involute_points_profile(&prof, spacing, 0, &xyz, &n,
						 NULL), 0);
	/* The angle t / r0 reaches ~210 rad: rounding alone moves a point
	 * by ~1e-12 mm at the rim. */
	check_plane(xyz, n, spacing, a, 3e-12);
	free(xyz);
}

/* Through the public entry point, a sphere of radius 4.1e14 mm: its sag
 * stays below 2e-13 mm and its slope below 1e-13 over the aperture. */
static void test_plane_limit_of_surface(void **state)
{
	const double a = 9.87, spacing = 0.293;
	struct asph_surface *s = make_surface(NULL, 4.1e14, 2 * a);
	double *xyz = NULL;
	size_t n = 0;

	assert_int_equal(asph_involute_points(s, spacing, 0, &xyz, &n, NULL), 0);
	check_plane(xyz, n, spacing, a, 3e-12);
	free(xyz);
	asph_surface_free(s);
}

/* Geodesic integrals from the start r0 to r, computed independently with
 * GSL's QAWS (the 1/sqrt(rho - r0) singularity as an exact weight):
 *   t(r)     = int w rho / sqrt(rho^2 - r0^2) d rho,
 *   Theta(r) = int r0 w / (rho sqrt(rho^2 - r0^2)) d rho. */
struct geo_ctx {
	const struct asph_surface *s;
	double r0;
	int theta;
};

static double geo_integrand(double rho, void *vctx)
{
	const struct geo_ctx *c = vctx;
	double d[3];

	asph_surface_sag_derivs(c->s, rho, d);
	double w = sqrt(1 + d[1] * d[1]);
	double base = w / sqrt(rho + c->r0);
	return c->theta ? c->r0 * base / rho : rho * base;
}

static double geodesic_integral(const struct asph_surface *s, double r0,
				double r, int theta)
{
	struct geo_ctx c = { s, r0, theta };
	gsl_function f = { geo_integrand, &c };
	gsl_integration_qaws_table *tab = gsl_integration_qaws_table_alloc(-0.5, 0, 0, 0);
	gsl_integration_workspace *ws = gsl_integration_workspace_alloc(200);
	double result, abserr;

	assert_int_equal(gsl_integration_qaws(&f, r0, r, tab, 0, 1e-12, 200, ws,
					      &result, &abserr), GSL_SUCCESS);
	gsl_integration_workspace_free(ws);
	gsl_integration_qaws_table_free(tab);
	return result;
}

/* The point's angle against the geodesic integrals at its radius. */
static void check_angles(const struct asph_surface *s, const double *xyz,
			 size_t n, double spacing)
{
	double r0 = spacing / (2 * M_PI);

	for (size_t k = 1; k < n; k += n / 23 + 1) {
		double x = xyz[3 * k], y = xyz[3 * k + 1], r = hypot(x, y);
		double phi = geodesic_integral(s, r0, r, 0) / r0;
		double theta = phi - geodesic_integral(s, r0, r, 1);
		double diff = remainder(atan2(y, x) - theta, 2 * M_PI);
		assert_true(fabs(diff) * r <= 1e-10 * (1 + phi));
	}
}

static double dist3(const double *p, const double *q)
{
	return sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
		    (p[2] - q[2]) * (p[2] - q[2]));
}

static double dist_to_segment(const double *p, const double *a, const double *b)
{
	double ab[3], ap[3], t = 0, len2 = 0;

	for (int i = 0; i < 3; i++) {
		ab[i] = b[i] - a[i];
		ap[i] = p[i] - a[i];
		t += ab[i] * ap[i];
		len2 += ab[i] * ab[i];
	}
	t = len2 > 0 ? fmin(1, fmax(0, t / len2)) : 0;
	double q[3] = { a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2] };
	return dist3(p, q);
}

/*
 * Distance from point k to the next turn: the closest segment among the
 * points whose unwrapped angle lies within a quarter turn of angle(k) + 2 pi.
 */
static double next_turn_distance(const double *xyz, const double *angle,
				 size_t n, size_t k)
{
	double best = INFINITY;

	for (size_t j = k + 1; j + 1 < n && angle[j] < angle[k] + 2.5 * M_PI; j++)
		if (angle[j + 1] > angle[k] + 1.5 * M_PI)
			best = fmin(best, dist_to_segment(xyz + 3 * k, xyz + 3 * j,
							  xyz + 3 * j + 3));
	return best;
}

static void check_turns(const double *xyz, size_t n, double spacing)
{
	double *angle = malloc(n * sizeof(double));

	assert_non_null(angle);
	angle[0] = atan2(xyz[1], xyz[0]);
	for (size_t k = 1; k < n; k++) {
		double step = remainder(atan2(xyz[3 * k + 1], xyz[3 * k]) -
					atan2(xyz[3 * k - 2], xyz[3 * k - 3]), 2 * M_PI);
		assert_true(step > 0);      /* counter-clockwise, less than a turn */
		angle[k] = angle[k - 1] + step;
	}
	for (size_t k = 0; k < n; k += 7) {
		double r = hypot(xyz[3 * k], xyz[3 * k + 1]);
		if (r < 5 * spacing || angle[n - 1] < angle[k] + 2.5 * M_PI)
			continue;
		double d = next_turn_distance(xyz, angle, n, k);
		/* The geodesic gap is exactly spacing; the chord across it and
		 * the polygon of the next turn can only be shorter. */
		assert_true(d <= spacing * (1 + 1e-9));
		assert_true(d >= spacing * 0.97);
	}
	free(angle);
}

static void check_surface(const struct asph_surface *s, double spacing)
{
	double a = asph_surface_aperture_radius(s), r0 = spacing / (2 * M_PI);
	double *xyz = NULL, prev_r = 0, prev_area = 0;
	size_t n = 0;

	assert_int_equal(asph_involute_points(s, spacing, 0, &xyz, &n, NULL), 0);
	double expect = (asph_surface_area(s, a) - asph_surface_area(s, r0)) /
			(spacing * spacing);
	assert_true(fabs((double)n - 1 - floor(expect)) <= 1);
	assert_true(xyz[0] == r0 && xyz[1] == 0);
	for (size_t k = 0; k < n; k++) {
		const double *p = xyz + 3 * k;
		double r = hypot(p[0], p[1]), area = asph_surface_area(s, r);
		assert_true(r <= a);
		assert_true(fabs(p[2] - asph_surface_sag(s, r)) <= 1e-12);
		if (k == 0) {
			prev_r = r;
			prev_area = area;
			continue;
		}
		assert_true(r > prev_r);
		/* Each step of arc length spacing sweeps the area spacing^2 (the
		 * unwound string is 2 pi r0 = spacing long per turn). */
		assert_true(fabs(area - prev_area - spacing * spacing) <=
			    1e-9 * spacing * spacing);
		double chord = dist3(p, p - 3);
		assert_true(chord <= spacing * (1 + 1e-12));
		/* Arc minus chord ~ spacing^3 kappa^2 / 24: the plane involute's
		 * curvature is 1/sqrt(2 r0 l), so the first step (from the cusp)
		 * is 0.697 spacing, the second 0.913, then ~1 - pi/(24 k). */
		double least = k == 1 ? 0.69 : (r > 3 * spacing ? 0.985 : 0.88);
		assert_true(chord >= spacing * least);
		prev_r = r;
		prev_area = area;
	}
	check_angles(s, xyz, n, spacing);
	check_turns(xyz, n, spacing);
	free(xyz);
}

static void test_presets(void **state)
{
	const double spacing[] = { 0.613, 0.587, 0.911 };

	for (size_t i = 0; i < sizeof(presets) / sizeof(presets[0]); i++) {
		struct asph_surface *s = make_surface(presets[i], 0, 0);
		check_surface(s, spacing[i]);
		asph_surface_free(s);
	}
}

static void test_sphere(void **state)
{
	struct asph_surface *s = make_surface(NULL, 13.71, 22.63);

	check_surface(s, 0.419);
	asph_surface_free(s);
}

static void test_errors(void **state)
{
	struct asph_surface *s = make_surface("strong", 0, 0);
	double *xyz = NULL;
	size_t n = 0;
	struct asph_error e;

	assert_int_equal(asph_involute_points(s, 0, 0, &xyz, &n, &e), -EINVAL);
	assert_int_equal(asph_involute_points(s, -0.3, 0, &xyz, &n, &e), -EINVAL);
	assert_int_equal(asph_involute_points(s, NAN, 0, &xyz, &n, &e), -EINVAL);
	assert_int_equal(asph_involute_points(s, INFINITY, 0, &xyz, &n, &e), -EINVAL);
	/* r0 = spacing / 2 pi must lie inside the aperture radius 20. */
	assert_int_equal(asph_involute_points(s, 2 * M_PI * 20.01, 0, &xyz, &n, &e),
			 -EINVAL);
	assert_non_null(strstr(e.message, "too coarse"));
	assert_int_equal(asph_involute_points(s, 0.5, 1000, &xyz, &n, &e), -E2BIG);
	assert_null(xyz);
	/* Just inside: one point, the start of the unwinding. */
	assert_int_equal(asph_involute_points(s, 2 * M_PI * 19.99, 0, &xyz, &n, &e), 0);
	assert_int_equal(n, 1);
	free(xyz);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_plane_exact),
		cmocka_unit_test(test_plane_limit_of_surface),
		cmocka_unit_test(test_presets),
		cmocka_unit_test(test_sphere),
		cmocka_unit_test(test_errors),
	};
	/* Report GSL failures through return codes, which the tests assert. */
	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
