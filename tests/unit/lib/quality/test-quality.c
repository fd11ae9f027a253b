/* SPDX-License-Identifier: GPL-3.0-or-later */
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
#include "asph/quality.h"
#include "asph/surface.h"

static void assert_close(double got, double want, double rel)
{
	if (!(fabs(got - want) <= rel * fmax(fabs(want), 1e-300)))
		fail_msg("got %.17g, expected %.17g (rel %.3g, allowed %.3g)", got, want,
			 fabs(got - want) / fabs(want), rel);
}

static struct asph_surface *conic(double R, double k, double aperture_diameter)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = R,
				       .k = k, .aperture_diameter = aperture_diameter };
	struct asph_surface *s = NULL;
	struct asph_error err;

	strcpy(p.name, "test");
	if (asph_surface_alloc(&p, &s, &err) < 0)
		fail_msg("surface: %s", err.message);
	return s;
}

static struct asph_surface *preset(const char *name)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;

	assert_int_equal(asph_prescription_preset(name, &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/* A rotation about an oblique axis followed by a shift, so that no
 * coordinate of the test triangles is zero or shared. */
static void place(const double in[3], double out[3])
{
	const double c = cos(0.7313), s = sin(0.7313), c2 = cos(-1.1987), s2 = sin(-1.1987);
	double x = c * in[0] - s * in[1], y = s * in[0] + c * in[1], z = in[2];

	out[0] = x + 3.217;
	out[1] = c2 * y - s2 * z - 1.493;
	out[2] = s2 * y + c2 * z + 0.281;
}

static double placed_q(const double a[3], const double b[3], const double c[3])
{
	double pa[3], pb[3], pc[3];

	place(a, pa);
	place(b, pb);
	place(c, pc);
	return asph_quality_triangle_q(pa, pb, pc);
}

static void test_q_closed_forms(void **state)
{
	const double L = 1.3719;
	const double eq[3][3] = { { 0, 0, 0 }, { L, 0, 0 }, { L / 2, L * sqrt(3) / 2, 0 } };
	const double right[3][3] = { { 0, 0, 0 }, { 0.853, 0, 0 }, { 0, 0.853, 0 } };
	const double t345[3][3] = { { 0, 0, 0 }, { 3 * 0.37, 0, 0 }, { 3 * 0.37, 4 * 0.37, 0 } };
	const double line[3][3] = { { 0.25, 0, 0 }, { 1.0, 0, 0 }, { 2.125, 0, 0 } };
	/* Isosceles with apex angle alpha: q = 2 sqrt(3) sin(alpha) / (4 - 2 cos(alpha)) */
	const double alpha = 2.417;
	const double iso[3][3] = { { 0, 0, 0 }, { 1.7, 0, 0 }, { 1.7 * cos(alpha), 1.7 * sin(alpha), 0 } };

	assert_close(placed_q(eq[0], eq[1], eq[2]), 1.0, 1e-14);
	assert_close(placed_q(right[0], right[1], right[2]), sqrt(3) / 2, 1e-14);
	assert_close(placed_q(t345[0], t345[1], t345[2]), 24 * sqrt(3) / 50, 1e-14);
	assert_close(placed_q(iso[0], iso[1], iso[2]),
		     2 * sqrt(3) * sin(alpha) / (4 - 2 * cos(alpha)), 1e-13);
	assert_true(fabs(asph_quality_triangle_q(line[0], line[1], line[2])) < 1e-15);
	assert_true(asph_quality_triangle_q(eq[0], eq[0], eq[0]) == 0);
}

static void test_summarize(void **state)
{
	const double odd[] = { 4.5, 1.25, 9.0, 2.75, 6.0 };
	const double even[] = { 0.7, 0.1, 0.9, 0.3, 0.5, 0.2 };
	const double bad[] = { 1.0, NAN };
	struct asph_quality_stats st;
	struct asph_error err;

	assert_int_equal(asph_quality_summarize(odd, 5, &st, NULL), 0);
	assert_close(st.min, 1.25, 0);
	assert_close(st.p25, 2.75, 0);
	assert_close(st.median, 4.5, 0);
	assert_close(st.p75, 6.0, 0);
	assert_close(st.max, 9.0, 0);
	assert_close(st.mean, 4.7, 1e-15);
	/* squared deviations 11.9025 + 3.8025 + 0.04 + 1.69 + 18.49 over n - 1 */
	assert_close(st.std, sqrt(35.925 / 4), 1e-14);

	assert_int_equal(asph_quality_summarize(even, 6, &st, NULL), 0);
	assert_close(st.p25, 0.225, 1e-14);
	assert_close(st.median, 0.4, 1e-14);
	assert_close(st.p75, 0.65, 1e-14);

	assert_int_equal(asph_quality_summarize(odd + 2, 1, &st, NULL), 0);
	assert_close(st.median, 9.0, 0);
	assert_true(st.std == 0);
	assert_int_equal(asph_quality_summarize(bad, 2, &st, &err), -EINVAL);
	assert_non_null(strstr(err.message, "value 1"));
	assert_int_equal(asph_quality_summarize(odd, 0, &st, &err), -EINVAL);
}

static int cmp_double(const void *a, const void *b)
{
	double x = *(const double *)a, y = *(const double *)b;

	return (x > y) - (x < y);
}

/* Type 7 on a sorted copy, as the summary's quantiles were computed by
 * sorting: selecting the order statistics gives the same numbers exactly. */
static double sorted_quantile(const double *s, size_t n, double p)
{
	double pos = p * (double)(n - 1);
	size_t i = (size_t)floor(pos);

	return i + 1 >= n ? s[n - 1] : s[i] + (pos - (double)i) * (s[i + 1] - s[i]);
}

static void test_summarize_against_sort(void **state)
{
	const size_t sizes[] = { 1, 2, 3, 4, 7, 1000, 4097 };
	uint64_t x = 88172645463325252u;

	(void)state;
	for (size_t c = 0; c < sizeof(sizes) / sizeof(sizes[0]); c++) {
		size_t n = sizes[c];
		double *v = malloc(n * sizeof(double)), *s = malloc(n * sizeof(double));
		struct asph_quality_stats st;
		for (size_t i = 0; i < n; i++) {
			x ^= x << 13, x ^= x >> 7, x ^= x << 17;
			/* many ties: 64 distinct values, and a spread of magnitudes */
			v[i] = ldexp((double)(x % 64) - 20.5, (int)(x >> 60) - 8);
		}
		memcpy(s, v, n * sizeof(double));
		qsort(s, n, sizeof(double), cmp_double);
		assert_int_equal(asph_quality_summarize(v, n, &st, NULL), 0);
		assert_true(st.min == s[0] && st.max == s[n - 1]);
		assert_true(st.p25 == sorted_quantile(s, n, 0.25));
		assert_true(st.median == sorted_quantile(s, n, 0.5));
		assert_true(st.p75 == sorted_quantile(s, n, 0.75));
		free(s);
		free(v);
	}
}

/*
 * Sphere of radius R: with r = R sin(phi) the metric is
 * R^2 (dphi^2 + sin^2 phi dtheta^2), isothermal for drho / rho = dphi /
 * sin(phi), rho = C tan(phi / 2); rho ~ r at the vertex gives C = 2 R:
 * rho = 2 R tan(phi / 2) = 2 r / (1 + sqrt(1 - r^2 / R^2)).
 */
static void test_chart_sphere(void **state)
{
	/* The last is a cap just short of a hemisphere: slope 70 at the rim,
	 * a square-root singularity of the integrand 1e-4 mm outside it. */
	const double radii[] = { 13.7, -13.7, 4.131, 1.0001 };
	const double apertures[] = { 23.8, 23.8, 7.9, 2 };

	for (int i = 0; i < 4; i++) {
		struct asph_surface *s = conic(radii[i], 0, apertures[i]);
		struct asph_conformal_chart *c = NULL;
		double R = fabs(radii[i]), a = apertures[i] / 2;

		assert_int_equal(asph_conformal_chart_alloc(s, &c, NULL), 0);
		for (int j = 0; j <= 97; j++) {
			double r = j == 0 ? 1.7e-6 : a * j / 97.0;
			double want = 2 * r / (1 + sqrt(1 - r * r / (R * R)));
			assert_close(asph_conformal_chart_rho(c, r), want, 1e-10);
		}
		assert_true(asph_conformal_chart_rho(c, 0) == 0);
		assert_true(isnan(asph_conformal_chart_rho(c, -0.5)));
		asph_conformal_chart_free(c);
		asph_surface_free(s);
	}
}

/*
 * Paraboloid Z = r^2 / (2 R) (k = -1): w = sqrt(1 + r^2 / R^2); with
 * u = w the integral of (w - 1) / t dt is int u / (u + 1) du, so
 * I = (w - 1) - log((w + 1) / 2) and rho = r exp(w - 1) 2 / (1 + w).
 */
static void test_chart_paraboloid(void **state)
{
	struct asph_surface *s = conic(7.9, -1, 2 * 9.3);
	struct asph_conformal_chart *c = NULL;
	double uv[2];

	assert_int_equal(asph_conformal_chart_alloc(s, &c, NULL), 0);
	for (int j = 1; j <= 89; j++) {
		double r = 9.3 * j / 89.0, w = sqrt(1 + r * r / (7.9 * 7.9));
		assert_close(asph_conformal_chart_rho(c, r), r * exp(w - 1) * 2 / (1 + w), 1e-10);
	}
	/* The map scales (x, y) by rho / r and keeps the azimuth. */
	asph_conformal_chart_map(c, -3.1, 5.3, uv);
	{
		double r = hypot(-3.1, 5.3), f = asph_conformal_chart_rho(c, r) / r;
		assert_close(uv[0], -3.1 * f, 1e-14);
		assert_close(uv[1], 5.3 * f, 1e-14);
	}
	asph_conformal_chart_free(c);
	asph_surface_free(s);
}

/* Chart coordinates of the surface point above (x, y). */
typedef void (*chart_fn)(const struct asph_conformal_chart *c, double x, double y,
			 double uv[2]);

static void xy_chart(const struct asph_conformal_chart *c, double x, double y, double uv[2])
{
	uv[0] = x;
	uv[1] = y;
}

/*
 * Largest deviation from conformality at (x, y): two x-y directions d1, d2
 * give 3-D tangent vectors t1, t2 and chart vectors c1, c2 (central
 * differences); a conformal chart has |c1|/|t1| = |c2|/|t2| and the same
 * angle between c1, c2 as between t1, t2.
 */
static double conformal_defect(const struct asph_surface *s,
			       const struct asph_conformal_chart *c, chart_fn f,
			       double x, double y, double d1, double d2)
{
	const double eps = 1e-5;
	double t[2][3], cv[2][2], norm_t[2], norm_c[2];
	double dirs[2] = { d1, d2 };

	for (int k = 0; k < 2; k++) {
		double dx = eps * cos(dirs[k]), dy = eps * sin(dirs[k]);
		double p[2], m[2];
		f(c, x + dx, y + dy, p);
		f(c, x - dx, y - dy, m);
		t[k][0] = 2 * dx;
		t[k][1] = 2 * dy;
		t[k][2] = asph_surface_sag(s, hypot(x + dx, y + dy)) -
			  asph_surface_sag(s, hypot(x - dx, y - dy));
		cv[k][0] = p[0] - m[0];
		cv[k][1] = p[1] - m[1];
		norm_t[k] = sqrt(t[k][0] * t[k][0] + t[k][1] * t[k][1] + t[k][2] * t[k][2]);
		norm_c[k] = hypot(cv[k][0], cv[k][1]);
	}
	double cos_t = (t[0][0] * t[1][0] + t[0][1] * t[1][1] + t[0][2] * t[1][2]) /
		       (norm_t[0] * norm_t[1]);
	double cos_c = (cv[0][0] * cv[1][0] + cv[0][1] * cv[1][1]) / (norm_c[0] * norm_c[1]);
	double stretch = (norm_c[0] / norm_t[0]) / (norm_c[1] / norm_t[1]);

	return fmax(fabs(stretch - 1), fabs(acos(cos_c) - acos(cos_t)));
}

static void test_chart_conformal(void **state)
{
	struct asph_surface *s = preset("turning-point");
	struct asph_conformal_chart *c = NULL;
	double worst_conformal = 0, worst_xy = 0;

	assert_int_equal(asph_conformal_chart_alloc(s, &c, NULL), 0);
	for (int i = 0; i < 40; i++) {
		double r = 29.7 * (i + 0.37) / 40.0, th = 2.399 * i + 0.3;
		double x = r * cos(th), y = r * sin(th);
		double d1 = 0.731 * i + 0.2, d2 = d1 + 1.1 + 0.05 * i;
		worst_conformal = fmax(worst_conformal,
				       conformal_defect(s, c, asph_conformal_chart_map, x, y, d1, d2));
		worst_xy = fmax(worst_xy, conformal_defect(s, c, xy_chart, x, y, d1, d2));
	}
	print_message("conformality defect: conformal chart %.3g, x-y chart %.3g\n",
		      worst_conformal, worst_xy);
	assert_true(worst_conformal < 1e-6);
	/* The vertex plane squeezes the steep flank radially by w. */
	assert_true(worst_xy > 0.3);
	asph_conformal_chart_free(c);
	asph_surface_free(s);
}

static void test_names(void **state)
{
	enum asph_quality_chart c;

	assert_string_equal(asph_quality_chart_name(ASPH_CHART_CONFORMAL), "conformal");
	assert_string_equal(asph_quality_chart_name(ASPH_CHART_VERTEX_PLANE), "vertex-plane");
	assert_int_equal(asph_quality_chart_from_name("xy", &c), 0);
	assert_int_equal(c, ASPH_CHART_VERTEX_PLANE);
	assert_int_equal(asph_quality_chart_from_name("plan-mesh", &c), 0);
	assert_int_equal(c, ASPH_CHART_PLAN_MESH);
	assert_int_equal(asph_quality_chart_from_name("polar", &c), -EINVAL);
}

/* Two triangles given as the mesh: q and A_i / mean in closed form. */
static void test_plan_mesh(void **state)
{
	const double L = 1.3, l = 0.9;
	double xyz[6 * 3] = {
		0.11, 0.07, 0.01, 0.11 + L, 0.07, 0.01, 0.11 + L / 2, 0.07 + L * sqrt(3) / 2, 0.01,
		-2.3, 1.1, 0.04, -2.3 + l, 1.1, 0.04, -2.3, 1.1, 0.04 + l,
	};
	const uint32_t mesh[] = { 0, 1, 2, 3, 4, 5 };
	const uint32_t bad[] = { 0, 1, 6 };
	struct asph_surface *s = preset("weak");
	struct asph_quality_options o = { .chart = ASPH_CHART_PLAN_MESH };
	struct asph_quality *q = NULL;
	struct asph_error err;
	double a1 = sqrt(3) / 4 * L * L, a2 = l * l / 2, mean = (a1 + a2) / 2;

	assert_int_equal(asph_quality_compute(s, xyz, 6, mesh, 2, &o, &q, NULL), 0);
	assert_int_equal(q->chart, ASPH_CHART_PLAN_MESH);
	assert_int_equal(q->n_triangles, 2);
	assert_int_equal(q->n_dropped, 0);
	assert_close(q->q[0], 1, 1e-14);
	assert_close(q->q[1], sqrt(3) / 2, 1e-14);
	assert_close(q->area_ratio[0], a1 / mean, 1e-14);
	assert_close(q->area_ratio[1], a2 / mean, 1e-14);
	assert_close(q->mean_area, mean, 1e-14);
	assert_close(q->q_stats.min, sqrt(3) / 2, 1e-14);
	assert_close(q->q_stats.median, (1 + sqrt(3) / 2) / 2, 1e-14);
	assert_close(q->q_frac_gt_0_9, 0.5, 0);
	assert_close(q->area_frac_within_5pct, 0, 0);
	asph_quality_free(q);

	assert_int_equal(asph_quality_compute(s, xyz, 6, bad, 1, &o, &q, &err), -EINVAL);
	assert_non_null(strstr(err.message, "point 6"));
	assert_int_equal(asph_quality_compute(s, xyz, 6, NULL, 0, &o, &q, &err), -EINVAL);
	xyz[4] = NAN;
	o.chart = ASPH_CHART_CONFORMAL;
	assert_int_equal(asph_quality_compute(s, xyz, 6, NULL, 0, &o, &q, &err), -EINVAL);
	assert_non_null(strstr(err.message, "point 1"));
	assert_int_equal(asph_quality_compute(s, xyz, 2, NULL, 0, &o, &q, &err), -EINVAL);
	asph_surface_free(s);
}

/*
 * A triangular lattice inside r = 4 and a ring of 40 points at r = 4.6 with
 * every fifth point pulled in to r = 4.5, 0.043 mm inside the chord of its
 * neighbours. The convex hull skips each pulled point and spans a sliver
 * (angle about 173 degrees) over it; the peel removes exactly those 8 and
 * nothing else.
 */
static size_t ring_and_lattice(const struct asph_surface *s, double *xyz)
{
	const double p = 0.5;
	size_t n = 0;

	for (int j = -12; j <= 12; j++)
		for (int i = -12; i <= 12; i++) {
			double x = 0.013 + p * (i + 0.5 * j), y = -0.021 + p * j * sqrt(3) / 2;
			if (hypot(x, y) > 4)
				continue;
			xyz[3 * n] = x;
			xyz[3 * n + 1] = y;
			n++;
		}
	for (int k = 0; k < 40; k++) {
		double r = k % 5 == 2 ? 4.5 : 4.6, t = 2 * M_PI * k / 40 + 0.031;
		xyz[3 * n] = r * cos(t);
		xyz[3 * n + 1] = r * sin(t);
		n++;
	}
	for (size_t i = 0; i < n; i++)
		xyz[3 * i + 2] = asph_surface_sag(s, hypot(xyz[3 * i], xyz[3 * i + 1]));
	return n;
}

static void test_rim_peel(void **state)
{
	struct asph_surface *s = preset("weak");
	double *xyz = malloc(3 * 1000 * sizeof(double));
	size_t n = ring_and_lattice(s, xyz), n_ring = 40;
	struct asph_quality_options o = { .chart = ASPH_CHART_CONFORMAL };
	struct asph_quality *q = NULL;
	size_t uses[8] = { 0 };

	assert_int_equal(asph_quality_compute(s, xyz, n, NULL, 0, &o, &q, NULL), 0);
	assert_int_equal(q->n_dropped, 8);
	/* Every pulled-in point is still a vertex of the mesh. */
	for (size_t t = 0; t < 3 * q->n_triangles; t++) {
		size_t v = q->triangles[t];
		if (v >= n - n_ring && (v - (n - n_ring)) % 5 == 2)
			uses[(v - (n - n_ring)) / 5]++;
	}
	for (int k = 0; k < 8; k++)
		assert_true(uses[k] > 0);
	asph_quality_free(q);

	/* Peeling switched off (angle limit near pi): Euler's count for a
	 * triangulation of the convex hull, 2 n - 2 - n_hull, n_hull = 32. */
	o.max_rim_angle = 3.14159;
	assert_int_equal(asph_quality_compute(s, xyz, n, NULL, 0, &o, &q, NULL), 0);
	assert_int_equal(q->n_dropped, 0);
	assert_int_equal(q->n_triangles, 2 * n - 2 - 32);
	asph_quality_free(q);
	o.max_rim_angle = 4;
	assert_int_equal(asph_quality_compute(s, xyz, n, NULL, 0, &o, &q, NULL), -EINVAL);
	free(xyz);
	asph_surface_free(s);
}

/* Points uniform in surface area (a Fermat spiral in the area coordinate). */
static size_t area_uniform(const struct asph_surface *s, size_t n, double *xyz)
{
	const double golden = M_PI * (3 - sqrt(5));
	double total = asph_surface_area(s, asph_surface_aperture_radius(s));

	for (size_t i = 0; i < n; i++) {
		double r = asph_surface_radius_at_area(s, total * (i + 0.5) / (double)n);
		xyz[3 * i] = r * cos(golden * (double)i);
		xyz[3 * i + 1] = r * sin(golden * (double)i);
		xyz[3 * i + 2] = asph_surface_sag(s, r);
	}
	return n;
}

static double frac_below(const struct asph_quality *q, double limit)
{
	size_t k = 0;

	for (size_t t = 0; t < q->n_triangles; t++)
		k += q->q[t] < limit;
	return (double)k / (double)q->n_triangles;
}

/* On the turning-point lens the x-y chart makes needles of points that are
 * evenly spread on the surface; the conformal chart does not. */
static void test_needles_in_vertex_plane(void **state)
{
	struct asph_surface *s = preset("turning-point");
	const size_t n = 3000;
	double *xyz = malloc(3 * n * sizeof(double));
	struct asph_quality_options o = { .chart = ASPH_CHART_CONFORMAL };
	struct asph_quality *conf = NULL, *xy = NULL;

	area_uniform(s, n, xyz);
	assert_int_equal(asph_quality_compute(s, xyz, n, NULL, 0, &o, &conf, NULL), 0);
	o.chart = ASPH_CHART_VERTEX_PLANE;
	assert_int_equal(asph_quality_compute(s, xyz, n, NULL, 0, &o, &xy, NULL), 0);
	assert_int_equal(xy->chart, ASPH_CHART_VERTEX_PLANE);
	print_message("conformal: q min %.3f p25 %.3f below 0.3: %.4f; xy: q min %.3f p25 %.3f below 0.3: %.4f\n",
		      conf->q_stats.min, conf->q_stats.p25, frac_below(conf, 0.3),
		      xy->q_stats.min, xy->q_stats.p25, frac_below(xy, 0.3));
	assert_true(frac_below(conf, 0.3) < 0.002);
	assert_true(frac_below(xy, 0.3) > 0.05);
	assert_true(conf->q_stats.p25 > xy->q_stats.p25 + 0.1);
	asph_quality_free(conf);
	asph_quality_free(xy);
	free(xyz);
	asph_surface_free(s);
}

static double area_iqr(const struct asph_surface *s, enum asph_plan_method m, double h)
{
	struct asph_plan_density d = { .kind = ASPH_DENSITY_H, .value = h };
	struct asph_quality_options o = { .chart = ASPH_CHART_CONFORMAL };
	struct asph_plan *plan = NULL;
	struct asph_quality *q = NULL;
	struct asph_error err;
	double iqr;

	if (asph_plan_compute(s, m, d, 0, &plan, &err) < 0)
		fail_msg("plan %s: %s", asph_plan_method_name(m), err.message);
	assert_int_equal(asph_quality_compute(s, plan->xyz, plan->n, NULL, 0, &o, &q, NULL), 0);
	iqr = q->area_stats.p75 - q->area_stats.p25;
	print_message("%s: %zu points, A_i/mean IQR %.3f, median q %.3f\n",
		      asph_plan_method_name(m), plan->n, iqr, q->q_stats.median);
	asph_quality_free(q);
	asph_plan_free(plan);
	return iqr;
}

/* The paper's Fig. 6c: OT spreads A_i / mean A far less than OP. */
static void test_turning_point_ot_vs_op(void **state)
{
	struct asph_surface *s = preset("turning-point");
	double op = area_iqr(s, ASPH_PLAN_OP, 0.04);
	double ot = area_iqr(s, ASPH_PLAN_OT, 0.04);

	assert_true(ot < 0.5 * op);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_q_closed_forms),
		cmocka_unit_test(test_summarize),
		cmocka_unit_test(test_summarize_against_sort),
		cmocka_unit_test(test_chart_sphere),
		cmocka_unit_test(test_chart_paraboloid),
		cmocka_unit_test(test_chart_conformal),
		cmocka_unit_test(test_names),
		cmocka_unit_test(test_plan_mesh),
		cmocka_unit_test(test_rim_peel),
		cmocka_unit_test(test_needles_in_vertex_plane),
		cmocka_unit_test(test_turning_point_ot_vs_op),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
