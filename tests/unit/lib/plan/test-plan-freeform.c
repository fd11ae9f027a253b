/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans on freeform surfaces and non-circular apertures. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph/plan.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "plan-aperture.h"
#include "plan-patterns.h"

static struct asph_surface *alloc_surface(const struct asph_prescription *p)
{
	struct asph_surface *s = NULL;
	struct asph_error err;

	if (asph_surface_alloc(p, &s, &err) < 0)
		fail_msg("surface: %s", err.message);
	return s;
}

/* An off-axis segment: an xy polynomial over an off-centre rectangle. */
static struct asph_surface *segment(void)
{
	struct asph_prescription p = {
		.type = ASPH_SURFACE_XY_POLYNOMIAL, .R = 61.7, .k = -0.83, .norm_radius = 15,
		.aperture = { ASPH_APERTURE_RECTANGULAR, 24, 17, { 1.7, 4.1 } },
	};

	p.C[asph_xy_index(2, 0)] = 0.21;
	p.C[asph_xy_index(0, 2)] = -0.13;
	p.C[asph_xy_index(2, 1)] = 0.041;
	p.C[asph_xy_index(0, 3)] = -0.027;
	p.C[asph_xy_index(3, 0)] = 0.019;
	return alloc_surface(&p);
}

/* A biconic over an off-centre ellipse. */
static struct asph_surface *biconic_ellipse(void)
{
	struct asph_prescription p = {
		.type = ASPH_SURFACE_BICONIC, .Rx = 45.3, .Ry = 61.2, .kx = -0.4, .ky = 0.2,
		.aperture = { ASPH_APERTURE_ELLIPTICAL, 30, 20, { 0.6, -1.1 } },
	};

	return alloc_surface(&p);
}

/* A Zernike freeform over an off-centre circle. */
static struct asph_surface *zernike_offset(void)
{
	struct asph_prescription p = {
		.type = ASPH_SURFACE_ZERNIKE_SAG, .R = 48.3, .k = -0.61, .norm_radius = 12,
		.aperture = { ASPH_APERTURE_CIRCULAR, 22, 22, { -0.9, 1.3 } },
	};

	for (int j = 4; j <= 22; j++)
		p.Zernike[j - 1] = 2e-3 * (j % 2 ? 1 : -1) / j;
	return alloc_surface(&p);
}

/* The even asphere of a preset written as an xy polynomial: the same conic
 * and the monomials of each A_2m r^2m, normalized by rho. */
static struct asph_surface *preset_as_xy(const char *name)
{
	struct asph_prescription e, p = { .type = ASPH_SURFACE_XY_POLYNOMIAL };
	double rho;

	assert_int_equal(asph_prescription_preset(name, &e), 0);
	rho = 0.5 * e.aperture_diameter;
	p.R = e.R;
	p.k = e.k;
	p.norm_radius = rho;
	p.aperture_diameter = e.aperture_diameter;
	for (int m = 2; 2 * m <= ASPH_SURFACE_MAX_POWER; m++) {
		double binom = 1;
		for (int k = 0; k <= m; k++) {
			p.C[asph_xy_index(2 * k, 2 * (m - k))] += e.A[2 * m] * pow(rho, 2 * m) * binom;
			binom = binom * (m - k) / (k + 1);
		}
	}
	return alloc_surface(&p);
}

static struct asph_surface *preset(const char *name)
{
	struct asph_prescription p;

	assert_int_equal(asph_prescription_preset(name, &p), 0);
	return alloc_surface(&p);
}

static struct asph_plan *plan_of(const struct asph_surface *s, enum asph_plan_method m,
				 double h)
{
	struct asph_plan *p = NULL;
	struct asph_error err;

	if (asph_plan_compute(s, m, (struct asph_plan_density){ ASPH_DENSITY_H, h }, 0, &p, &err) < 0)
		fail_msg("%s: %s", asph_plan_method_name(m), err.message);
	return p;
}

/* ---- the patterns over an aperture ------------------------------------------ */

static const enum asph_plan_method vertex_plane[] = {
	ASPH_PLAN_OP, ASPH_PLAN_RASTER, ASPH_PLAN_CONCENTRIC, ASPH_PLAN_SPIRAL, ASPH_PLAN_FERMAT,
};

/* Distance of (x, y) from the edge of a rectangle or an ellipse (for the
 * ellipse, along the ray from its centre: an upper bound within the
 * ratio of its axes). */
static double edge_gap(const struct asph_aperture *ap, double x, double y)
{
	double u = x - ap->offset[0], v = y - ap->offset[1];
	double hx = 0.5 * ap->width, hy = 0.5 * ap->height;

	if (ap->shape == ASPH_APERTURE_RECTANGULAR)
		return fmin(hx - fabs(u), hy - fabs(v));
	double f = sqrt(u * u / (hx * hx) + v * v / (hy * hy));
	return f > 0 ? (1 - f) * hypot(u, v) / f : fmin(hx, hy);
}

/* Every point inside; the trailing outline on the edge, counter-clockwise,
 * its steps at most p and, for a rectangle, its four corners in it; on a
 * rectangle or an ellipse the points before it at least p/2 inside (a
 * circle has the circle's own patterns). */
static void check_pattern(const struct asph_surface *s, enum asph_plan_method m, double p)
{
	struct plan_points pp = { 0 };
	struct asph_aperture ap;
	size_t n_edge = 0, corners = 0;

	asph_surface_aperture(s, &ap);
	assert_int_equal(plan_aperture_pattern(s, m, p, &pp, &n_edge), 0);
	assert_true(pp.n > 10);
	for (size_t i = 0; i < pp.n; i++)
		assert_true(asph_surface_contains(s, pp.xyz[3 * i], pp.xyz[3 * i + 1], 0));
	if (m == ASPH_PLAN_RASTER)
		assert_int_equal(n_edge, 0);
	if (m == ASPH_PLAN_OP || (m != ASPH_PLAN_RASTER && ap.shape != ASPH_APERTURE_CIRCULAR))
		assert_int_equal(n_edge, plan_outline_count(s, p));
	for (size_t i = 0; i + n_edge < pp.n; i++)
		if (m != ASPH_PLAN_RASTER && ap.shape != ASPH_APERTURE_CIRCULAR)
			assert_true(edge_gap(&ap, pp.xyz[3 * i], pp.xyz[3 * i + 1]) >=
				    (ap.shape == ASPH_APERTURE_ELLIPTICAL ? 0.49 : 0.5 - 1e-12) * p);
	for (size_t k = 0; k < n_edge; k++) {
		const double *q = pp.xyz + 3 * (pp.n - n_edge + k);
		const double *q1 = pp.xyz + 3 * (pp.n - n_edge + (k + 1) % n_edge);
		assert_true(fabs(edge_gap(&ap, q[0], q[1])) <= 1e-12 * ap.width);
		assert_true(hypot(q1[0] - q[0], q1[1] - q[1]) <= p * (1 + 1e-12));
		/* counter-clockwise about the centre */
		double cr = (q[0] - ap.offset[0]) * (q1[1] - ap.offset[1]) -
			    (q[1] - ap.offset[1]) * (q1[0] - ap.offset[0]);
		assert_true(cr > 0);
		corners += fabs(fabs(q[0] - ap.offset[0]) - 0.5 * ap.width) < 1e-12 &&
			   fabs(fabs(q[1] - ap.offset[1]) - 0.5 * ap.height) < 1e-12;
	}
	if (ap.shape == ASPH_APERTURE_RECTANGULAR && n_edge)
		assert_int_equal(corners, 4);
	plan_points_clear(&pp);
}

static void test_aperture_patterns(void **state)
{
	struct asph_surface *s[3] = { segment(), biconic_ellipse(), zernike_offset() };

	for (int i = 0; i < 3; i++)
		for (size_t m = 0; m < sizeof(vertex_plane) / sizeof(vertex_plane[0]); m++)
			check_pattern(s[i], vertex_plane[m], 1.137);
	for (int i = 0; i < 3; i++)
		asph_surface_free(s[i]);
}

/* A rectangle's raster: rows from the bottom side to the top side, each
 * with both ends on the sides. */
static void test_rectangle_raster(void **state)
{
	struct asph_surface *s = segment();
	struct plan_points pp = { 0 };
	const double p = 0.913;
	size_t rows = 0, ends = 0;

	assert_int_equal(plan_aperture_pattern(s, ASPH_PLAN_RASTER, p, &pp, NULL), 0);
	for (size_t i = 0; i < pp.n; i++) {
		double u = pp.xyz[3 * i] - 1.7;
		ends += fabs(fabs(u) - 12) < 1e-12;
		if (i == 0 || pp.xyz[3 * i + 1] != pp.xyz[3 * i - 2]) {
			rows++;
			if (i)
				assert_true(pp.xyz[3 * i + 1] - pp.xyz[3 * i - 2] <= p);
		}
	}
	assert_int_equal(rows, (size_t)ceil(17 / p) + 1);
	assert_int_equal(ends, 2 * rows);
	assert_true(pp.xyz[1] == 4.1 - 8.5);
	assert_true(pp.xyz[3 * pp.n - 2] == 4.1 + 8.5);
	plan_points_clear(&pp);
	asph_surface_free(s);
}

/* On a centred circle the freeform plans are the rotational ones: the
 * preset as an xy polynomial gives the preset's points. */
static void test_centred_circle_is_rotational(void **state)
{
	struct asph_surface *rot = preset("strong"), *xy = preset_as_xy("strong");
	double a = asph_surface_aperture_radius(rot);

	for (size_t m = 0; m < sizeof(vertex_plane) / sizeof(vertex_plane[0]); m++) {
		struct asph_plan *p = plan_of(rot, vertex_plane[m], 0.05);
		struct asph_plan *q = plan_of(xy, vertex_plane[m], 0.05);
		size_t n = 0;
		/* gamma of the two agree to the freeform area's quadrature, so
		 * the pitch may differ in the last bits */
		assert_int_equal(p->n, q->n);
		assert_true(fabs(p->spacing_mm - q->spacing_mm) <= 1e-12 * p->spacing_mm);
		assert_int_equal(asph_plan_resolve(xy, vertex_plane[m],
						   (struct asph_plan_density){ ASPH_DENSITY_H, 0.05 },
						   NULL, &n, NULL), 0);
		assert_int_equal(n, q->n);
		for (size_t i = 0; i < p->n; i++) {
			assert_true(fabs(p->xyz[3 * i] - q->xyz[3 * i]) <= 1e-9 * a);
			assert_true(fabs(p->xyz[3 * i + 1] - q->xyz[3 * i + 1]) <= 1e-9 * a);
			assert_true(fabs(p->xyz[3 * i + 2] - q->xyz[3 * i + 2]) <= 1e-9 * a);
		}
		assert_int_equal(p->n_triangles, q->n_triangles);
		asph_plan_free(p);
		asph_plan_free(q);
	}
	asph_surface_free(rot);
	asph_surface_free(xy);
}

/* The count asph_plan_resolve() promises is the plan's, and every point is
 * on the surface. */
static void test_freeform_counts(void **state)
{
	struct asph_surface *s[3] = { segment(), biconic_ellipse(), zernike_offset() };

	for (int i = 0; i < 3; i++) {
		for (size_t m = 0; m < sizeof(vertex_plane) / sizeof(vertex_plane[0]); m++) {
			struct asph_plan_density d = { ASPH_DENSITY_POINTS, 700 };
			struct asph_plan *p = NULL;
			size_t n = 0;
			assert_int_equal(asph_plan_resolve(s[i], vertex_plane[m], d, NULL, &n, NULL), 0);
			assert_int_equal(asph_plan_compute(s[i], vertex_plane[m], d, 0, &p, NULL), 0);
			assert_int_equal(p->n, n);
			assert_true(fabs((double)n - 700) <= 0.05 * 700);
			for (size_t k = 0; k < p->n; k++)
				assert_true(p->xyz[3 * k + 2] ==
					    asph_surface_sag_xy(s[i], p->xyz[3 * k], p->xyz[3 * k + 1]));
			asph_plan_free(p);
		}
		asph_surface_free(s[i]);
	}
}

/* Largest distance between the points of two plans with the same grid. */
static double plan_distance(const struct asph_plan *p, const struct asph_plan *q)
{
	double worst = 0;

	assert_int_equal(p->n, q->n);
	for (size_t i = 0; i < p->n; i++) {
		const double *a = p->xyz + 3 * i, *b = q->xyz + 3 * i;
		worst = fmax(worst, sqrt(pow(a[0] - b[0], 2) + pow(a[1] - b[1], 2) +
					 pow(a[2] - b[2], 2)));
	}
	return worst;
}

/* LB on a freeform is the P1 solution of Eq. (6), inverted piecewise
 * linearly: on a surface of revolution written as a freeform it approaches
 * the rotational plan (the exact radial map) as O(h^2), i.e. O(h) of the
 * spacing (seen 9.7e-4 and 5.2e-4 of it on strong at h = 0.08, 0.04; 0.47
 * and 0.27 on turning-point at h = 0.1, 0.05, whose map stretches the
 * centre 3.7 times). */
static void test_lb_freeform_converges(void **state)
{
	const char *names[] = { "strong", "turning-point" };
	const double h[] = { 0.08, 0.1 }, tol[] = { 1e-3, 0.35 };

	for (int k = 0; k < 2; k++) {
		struct asph_surface *rot = preset(names[k]), *xy = preset_as_xy(names[k]);
		double d[2];
		for (int j = 0; j < 2; j++) {
			struct asph_plan *p = plan_of(rot, ASPH_PLAN_LB, h[k] / (1 << j));
			struct asph_plan *q = plan_of(xy, ASPH_PLAN_LB, h[k] / (1 << j));
			d[j] = plan_distance(p, q) / p->spacing_mm;
			asph_plan_free(p);
			asph_plan_free(q);
		}
		assert_true(d[0] / d[1] > 1.6);
		assert_true(d[1] < tol[k]);
		asph_surface_free(rot);
		asph_surface_free(xy);
	}
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_aperture_patterns),
		cmocka_unit_test(test_rectangle_raster),
		cmocka_unit_test(test_centred_circle_is_rotational),
		cmocka_unit_test(test_freeform_counts),
		cmocka_unit_test(test_lb_freeform_converges),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
