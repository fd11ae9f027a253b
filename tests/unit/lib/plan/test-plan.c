/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <gsl/gsl_integration.h>

#include "asph/lb.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "plan-patterns.h"

/*
 * Plans of every method on the three presets at h = 0.05 are computed once
 * (the group setup) and shared by the tests that only look at them. CVT's
 * Lloyd iterations cost seconds at that density on turning-point (minutes
 * under valgrind), so its plans are at h = 0.2; test-plan-freeform checks
 * CVT at finer densities.
 */
#define N_PRESETS 3
static const char *const presets[N_PRESETS] = { "weak", "strong", "turning-point" };
#define PLAN_H 0.05
#define PLAN_H_CVT 0.2
/* a profile's points at h = 0.05 are 43: as many as the others at 0.005 */
#define PLAN_H_PROFILES 0.005

static double plan_h(enum asph_plan_method m)
{
	return m == ASPH_PLAN_CVT ? PLAN_H_CVT : m == ASPH_PLAN_PROFILES ? PLAN_H_PROFILES : PLAN_H;
}

/* Set by the test setups valgrind and valgrindpy (tests/meson.build). */
static bool under_valgrind(void)
{
	const char *v = getenv("ASPH_UNDER_VALGRIND");
	return v && *v && strcmp(v, "0") != 0;
}

struct fixture {
	struct asph_surface *s[N_PRESETS];
	struct asph_plan *plan[N_PRESETS][ASPH_PLAN_N_METHODS];
};

static struct asph_surface *make_surface(const char *preset, double R,
					 double k, double diameter)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_EVEN_ASPHERE };
	struct asph_surface *s = NULL;

	if (preset) {
		assert_int_equal(asph_prescription_preset(preset, &p), 0);
	} else {
		p.R = R;
		p.k = k;
		p.aperture_diameter = diameter;
	}
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

static struct asph_plan *make_plan(const struct asph_surface *s,
				   enum asph_plan_method m,
				   enum asph_plan_density_kind kind, double v)
{
	struct asph_plan *p = NULL;
	struct asph_error err;
	int r = asph_plan_compute(s, m, (struct asph_plan_density){ kind, v },
				  0, &p, &err);

	if (r < 0)
		fail_msg("%s: %s", asph_plan_method_name(m), err.message);
	return p;
}

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));

	for (int i = 0; i < N_PRESETS; i++) {
		f->s[i] = make_surface(presets[i], 0, 0, 0);
		for (int m = 0; m < ASPH_PLAN_N_METHODS; m++)
			f->plan[i][m] = make_plan(f->s[i], (enum asph_plan_method)m,
						  ASPH_DENSITY_H, plan_h((enum asph_plan_method)m));
	}
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		for (int m = 0; m < ASPH_PLAN_N_METHODS; m++)
			asph_plan_free(f->plan[i][m]);
		asph_surface_free(f->s[i]);
	}
	free(f);
	return 0;
}

/* A deterministic, high-entropy sequence in (0, 1). */
static double frac(unsigned i)
{
	double x = 0.6180339887498949 * (i + 1) + 0.2718281828;
	return x - floor(x);
}

static double dist3(const double *p, const double *q)
{
	return sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
		    (p[2] - q[2]) * (p[2] - q[2]));
}

static double dist2(const double *p, const double *q)
{
	return hypot(p[0] - q[0], p[1] - q[1]);
}

/* The lattice pitch of a vertex-plane or disk pattern. */
static double pitch_of(const struct asph_surface *s, const struct asph_plan *p)
{
	return p->spacing_mm / (plan_lattice_of(p->method)->edge_per_pitch *
				sqrt(asph_surface_gamma(s)));
}

/* ---- disk grid ------------------------------------------------------------- */

/* Eq. (5) written out here; t from the arc length sigma = t^2 / (2 s0). */
static void eq5(double s0, double sigma, double out[2])
{
	double t = sqrt(2.0 * s0 * sigma);

	out[0] = s0 * cos(t / s0) + t * sin(t / s0);
	out[1] = s0 * sin(t / s0) - t * cos(t / s0);
}

/* Arc length of Eq. (5) between two parameters, by a fine polyline. */
static double polyline_length(double s0, double sig0, double sig1)
{
	double prev[2], cur[2], len = 0;
	const int steps = 4000;

	eq5(s0, sig0, prev);
	for (int j = 1; j <= steps; j++) {
		double t0 = sqrt(2.0 * s0 * sig0), t1 = sqrt(2.0 * s0 * sig1);
		double t = t0 + (t1 - t0) * j / steps;
		eq5(s0, t * t / (2.0 * s0), cur);
		len += hypot(cur[0] - prev[0], cur[1] - prev[1]);
		prev[0] = cur[0];
		prev[1] = cur[1];
	}
	return len;
}

static void test_disk_grid_closed_form(void **state)
{
	const double a = 17.31, p = 0.7193, s0 = p / (2.0 * M_PI);
	size_t ns = plan_disk_grid_spiral_count(a, p), n = plan_disk_grid_count(a, p);
	double *g = malloc(3 * n * sizeof(*g)), want[2];

	plan_disk_grid_fill(a, p, g);
	for (size_t k = 0; k < ns; k++) {
		eq5(s0, 2.0 * M_PI * s0 * (double)k, want);
		assert_true(fabs(g[3 * k] - want[0]) <= 1e-12 * a);
		assert_true(fabs(g[3 * k + 1] - want[1]) <= 1e-12 * a);
		assert_true(fabs(g[3 * k + 2] - hypot(want[0], want[1])) <= 1e-12 * a);
		assert_true(g[3 * k + 2] <= a - 0.5 * p);
	}
	/* The involute stops at the first sample beyond a - p/2. */
	eq5(s0, 2.0 * M_PI * s0 * (double)ns, want);
	assert_true(hypot(want[0], want[1]) > a - 0.5 * p);
	/* Equal arc length 2 pi s0 = p along the involute. */
	for (size_t k = 1; k < ns; k += ns / 7) {
		double sig = 2.0 * M_PI * s0 * (double)k;
		assert_true(fabs(polyline_length(s0, sig, sig + p) - p) <= 1e-6 * p);
	}
	/* The rim ring: ceil(2 pi a / p) points at equal angles on r = a. */
	size_t m = n - ns;
	assert_int_equal(m, (size_t)ceil(2.0 * M_PI * a / p));
	for (size_t j = 0; j < m; j++) {
		const double *q = g + 3 * (ns + j), *q1 = g + 3 * (ns + (j + 1) % m);
		assert_true(fabs(hypot(q[0], q[1]) - a) <= 1e-14 * a);
		assert_true(hypot(q[0], q[1]) <= a);
		assert_true(fabs(dist2(q, q1) - 2.0 * a * sin(M_PI / (double)m)) <= 1e-12 * a);
	}
	free(g);
}

static void test_disk_mesh(void **state)
{
	struct fixture *f = *state;
	const struct asph_plan *op = f->plan[1][ASPH_PLAN_OP];
	const struct asph_plan *ot = f->plan[1][ASPH_PLAN_OT];

	assert_true(op->n_triangles > op->n);
	/* The same mesh for every grid method (the map keeps the topology). */
	assert_int_equal(op->n_triangles, ot->n_triangles);
	assert_memory_equal(op->triangles, ot->triangles,
			    3 * op->n_triangles * sizeof(uint32_t));
	for (size_t t = 0; t < op->n_triangles; t++) {
		const uint32_t *v = op->triangles + 3 * t;
		const double *p0 = op->xyz + 3 * v[0], *p1 = op->xyz + 3 * v[1],
			     *p2 = op->xyz + 3 * v[2];
		assert_true(v[0] < op->n && v[1] < op->n && v[2] < op->n);
		/* OP keeps the disk's x, y: the q filter of 5.1 is visible. */
		assert_true(plan_triangle_q_2d(p0, p1, p2) >= 0.75);
		assert_true((p1[0] - p0[0]) * (p2[1] - p0[1]) -
			    (p1[1] - p0[1]) * (p2[0] - p0[0]) > 0);
	}
}

/* ---- the lifts and maps ---------------------------------------------------- */

static void test_op_on_surface(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		const struct asph_plan *p = f->plan[i][ASPH_PLAN_OP];
		double a = asph_surface_aperture_radius(f->s[i]);
		double pitch = pitch_of(f->s[i], p);
		size_t n = plan_disk_grid_count(a, pitch);
		assert_int_equal(n, p->n);
		double *g = malloc(3 * n * sizeof(*g));
		plan_disk_grid_fill(a, pitch, g);
		for (size_t k = 0; k < n; k++) {
			const double *q = p->xyz + 3 * k;
			assert_true(fabs(q[0] - g[3 * k]) <= 1e-12 * a);
			assert_true(fabs(q[1] - g[3 * k + 1]) <= 1e-12 * a);
			double z = asph_surface_sag(f->s[i], hypot(q[0], q[1]));
			assert_true(fabs(q[2] - z) <= 1e-12 * (1.0 + fabs(z)));
		}
		free(g);
	}
}

/* A(r) by composite 20-point Gauss-Legendre on 300 panels, independent
 * of the surface's own tables. The map is checked to 1e-12 against it:
 * its worst residual on the three presets is rounding, 4e-14 on
 * turning-point, the same with 100 or 3000 panels (3000, once used, made
 * this test most of the program's time under valgrind). */
static double area_quad(const struct asph_surface *s, double r)
{
	gsl_integration_glfixed_table *gl = gsl_integration_glfixed_table_alloc(20);
	const int panels = 300;
	double sum = 0;

	for (int i = 0; i < panels; i++) {
		double lo = r * i / panels, hi = r * (i + 1) / panels;
		for (size_t j = 0; j < 20; j++) {
			double t, w, d[3];
			gsl_integration_glfixed_point(lo, hi, j, &t, &w, gl);
			asph_surface_sag_derivs(s, t, d);
			sum += w * 2.0 * M_PI * t * sqrt(1.0 + d[1] * d[1]);
		}
	}
	gsl_integration_glfixed_table_free(gl);
	return sum;
}

static void test_ot_map(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		const struct asph_surface *s = f->s[i];
		double a = asph_surface_aperture_radius(s), area_a = area_quad(s, a);
		assert_true(asph_plan_ot_radius(s, 0) == 0);
		assert_true(fabs(asph_plan_ot_radius(s, a) - a) <= 1e-15 * a);
		double prev = 0;
		for (unsigned j = 1; j <= 400; j++) {
			double rho = a * j / 400.0 * (1.0 - 0.3 * frac(j) / 400.0);
			double r = asph_plan_ot_radius(s, rho);
			assert_true(r > prev);
			prev = r;
		}
		for (unsigned j = 0; j < 40; j++) {
			double rho = a * frac(7 * j + 3), r = asph_plan_ot_radius(s, rho);
			double lhs = area_quad(s, r) / area_a, rhs = (rho / a) * (rho / a);
			assert_true(fabs(lhs - rhs) <= 1e-12);
		}
	}
}

/* The OT plan, stepped point by point, against the exact map of its disk
 * grid (the OP plan's x, y), for every preset and a dense grid. */
static void check_ot_against_map(const struct asph_surface *s,
				 const struct asph_plan *op,
				 const struct asph_plan *ot)
{
	double a = asph_surface_aperture_radius(s);

	assert_int_equal(op->n, ot->n);
	for (size_t k = 0; k < op->n; k++) {
		const double *d = op->xyz + 3 * k, *q = ot->xyz + 3 * k;
		double rho = hypot(d[0], d[1]), r = asph_plan_ot_radius(s, rho);
		double fct = rho > 0 ? r / rho : 0;
		assert_true(fabs(q[0] - d[0] * fct) <= 1e-12 * a);
		assert_true(fabs(q[1] - d[1] * fct) <= 1e-12 * a);
		assert_true(fabs(q[2] - asph_surface_sag(s, r)) <= 1e-12 * a);
	}
}

static void test_ot_plan(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++)
		check_ot_against_map(f->s[i], f->plan[i][ASPH_PLAN_OP],
				     f->plan[i][ASPH_PLAN_OT]);
	struct asph_plan *op = make_plan(f->s[2], ASPH_PLAN_OP, ASPH_DENSITY_H, 0.02);
	struct asph_plan *ot = make_plan(f->s[2], ASPH_PLAN_OT, ASPH_DENSITY_H, 0.02);
	check_ot_against_map(f->s[2], op, ot);
	asph_plan_free(op);
	asph_plan_free(ot);
}

/* LB: the disk grid moved by T = S^-1 of asph/lb.h, point for point. */
static void test_lb_plan(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		const struct asph_surface *s = f->s[i];
		const struct asph_plan *op = f->plan[i][ASPH_PLAN_OP];
		const struct asph_plan *lb = f->plan[i][ASPH_PLAN_LB];
		double a = asph_surface_aperture_radius(s);
		struct asph_lb_map *m = NULL;
		assert_int_equal(asph_lb_map_alloc(s, &m, NULL), 0);
		assert_int_equal(op->n, lb->n);
		for (size_t k = 0; k < op->n; k++) {
			const double *d = op->xyz + 3 * k, *q = lb->xyz + 3 * k;
			double rho = hypot(d[0], d[1]);
			double r = rho >= a ? a : asph_lb_map_radius(m, rho);
			assert_true(fabs(q[0] - d[0] * r / rho) <= 1e-12 * a);
			assert_true(fabs(q[1] - d[1] * r / rho) <= 1e-12 * a);
		}
		asph_lb_map_free(m);
	}
}

/* The radial maps are monotone: along the involute (rho increasing) the
 * mapped radius increases too, and the rim stays the rim. */
static void test_radial_monotone(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		const struct asph_plan *op = f->plan[i][ASPH_PLAN_OP];
		double a = asph_surface_aperture_radius(f->s[i]);
		for (int m = ASPH_PLAN_OT; m <= ASPH_PLAN_LB; m++) {
			const struct asph_plan *p = f->plan[i][m];
			double prev = 0;
			for (size_t k = 0; k < p->n; k++) {
				const double *q = p->xyz + 3 * k, *d = op->xyz + 3 * k;
				double r = hypot(q[0], q[1]);
				if (hypot(d[0], d[1]) >= a * (1 - 1e-15)) {
					assert_true(fabs(r - a) <= 1e-14 * a);
					continue;
				}
				assert_true(r > prev && r < a);
				prev = r;
			}
		}
	}
}

static void test_flat_limit(void **state)
{
	struct asph_surface *s = make_surface(NULL, 3.1e7, -0.37, 23.7);
	struct asph_plan *op = make_plan(s, ASPH_PLAN_OP, ASPH_DENSITY_H, 0.043);
	struct asph_plan *ot = make_plan(s, ASPH_PLAN_OT, ASPH_DENSITY_H, 0.043);
	double a = asph_surface_aperture_radius(s);

	assert_int_equal(op->n, ot->n);
	for (size_t k = 0; k < 3 * op->n; k++)
		assert_true(fabs(op->xyz[k] - ot->xyz[k]) <= 1e-10 * a);
	asph_plan_free(op);
	asph_plan_free(ot);
	asph_surface_free(s);
}

/* ---- every method ---------------------------------------------------------- */

static void test_inside_aperture(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		double a = asph_surface_aperture_radius(f->s[i]);
		for (int m = 0; m < ASPH_PLAN_N_METHODS; m++) {
			const struct asph_plan *p = f->plan[i][m];
			assert_true(p->n > 100);
			for (size_t k = 0; k < p->n; k++) {
				const double *q = p->xyz + 3 * k;
				double r = sqrt(q[0] * q[0] + q[1] * q[1]);
				if (!(r <= a))
					fail_msg("%s %s: point %zu at r - a = %g",
						 presets[i], asph_plan_method_name(m),
						 k, r - a);
				assert_true(fabs(q[2] - asph_surface_sag(f->s[i], r)) <=
					    1e-11 * a);
			}
		}
	}
}

static double signed_area_xy(const double *p0, const double *p1, const double *p2)
{
	return (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p1[1] - p0[1]) * (p2[0] - p0[0]);
}

static void test_no_folding(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		for (int m = ASPH_PLAN_OP; m <= ASPH_PLAN_LB; m++) {
			const struct asph_plan *p = f->plan[i][m];
			assert_true(p->n_triangles > 0);
			for (size_t t = 0; t < p->n_triangles; t++) {
				const uint32_t *v = p->triangles + 3 * t;
				assert_true(signed_area_xy(p->xyz + 3 * v[0], p->xyz + 3 * v[1],
							   p->xyz + 3 * v[2]) > 0);
			}
		}
	}
}

/* ---- density --------------------------------------------------------------- */

/* 3137 points, a count no pattern meets by chance. CVT's Lloyd iterations
 * at that count take most of this program's time under valgrind (two
 * minutes), where CVT is asked for 800 points: the same resolution and
 * plan code, which meets either count exactly. */
static void test_density_points(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		for (int m = 0; m < ASPH_PLAN_N_METHODS; m++) {
			const double want = m == ASPH_PLAN_CVT && under_valgrind() ? 800 : 3137;
			size_t n;
			double e;
			assert_int_equal(asph_plan_resolve(f->s[i], (enum asph_plan_method)m,
							   (struct asph_plan_density){ ASPH_DENSITY_POINTS, want },
							   &e, &n, NULL), 0);
			/* Stated tolerance: 3 % at a few thousand points. */
			if (fabs((double)n - want) > 0.03 * want)
				fail_msg("%s %s: %zu points for %g", presets[i],
					 asph_plan_method_name(m), n, want);
			if (m == ASPH_PLAN_LB)
				continue;   /* the same grid as OP; its map is slow to build */
			struct asph_plan *p = make_plan(f->s[i], (enum asph_plan_method)m,
							ASPH_DENSITY_POINTS, want);
			assert_int_equal(p->n, n);
			assert_true(p->spacing_mm == e);
			asph_plan_free(p);
		}
	}
}

/* --h H and --spacing H a are the same request, and the count follows
 * N ~ A c^2 / e^2 (docs/sampling-plans.md): the pattern's rim (ring, row
 * ends, outer ring) adds a relative excess below 2 h + 0.3 %. */
static void check_count(const struct asph_surface *s, enum asph_plan_method m,
			double h, size_t n_plan)
{
	double a = asph_surface_aperture_radius(s), area = asph_surface_area(s, a);
	double e_h, e_s;
	size_t n_h, n_s;

	assert_int_equal(asph_plan_resolve(s, m, (struct asph_plan_density){ ASPH_DENSITY_H, h },
					   &e_h, &n_h, NULL), 0);
	assert_int_equal(asph_plan_resolve(s, m, (struct asph_plan_density){ ASPH_DENSITY_SPACING, h * a },
					   &e_s, &n_s, NULL), 0);
	assert_true(fabs(e_h - h * a) <= 1e-15 * a && e_s == h * a);
	assert_int_equal(n_h, n_s);
	if (n_plan)
		assert_int_equal(n_plan, n_h);
	double c = plan_lattice_of(m)->edge_per_pitch;
	double expect = area * c * c / (e_h * e_h);
	if (fabs((double)n_h / expect - 1.0) > 2.0 * h + 0.003)
		fail_msg("%s h=%g: %zu points, expected ~%g", asph_plan_method_name(m),
			 h, n_h, expect);
}

static void test_density_h_spacing(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		/* the profiles plan covers lines, not the area: test_profiles */
		for (int m = 0; m < ASPH_PLAN_PROFILES; m++) {
			const struct asph_plan *p = f->plan[i][m];
			double a = asph_surface_aperture_radius(f->s[i]);
			double h = plan_h((enum asph_plan_method)m);
			assert_true(fabs(p->spacing_mm - h * a) <= 1e-15 * a);
			check_count(f->s[i], (enum asph_plan_method)m, h, p->n);
			check_count(f->s[i], (enum asph_plan_method)m, 0.0093, 0);
		}
	}
}

/* The mean 3-D edge length of the OT mesh is the requested spacing within
 * 3 % on the weak and strong lenses (gamma ~ 1.06 and 1.09). */
static void test_density_mean_edge(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < 2; i++) {
		const struct asph_plan *p = f->plan[i][ASPH_PLAN_OT];
		double sum = 0;
		for (size_t t = 0; t < p->n_triangles; t++)
			for (int j = 0; j < 3; j++)
				sum += dist3(p->xyz + 3 * p->triangles[3 * t + j],
					     p->xyz + 3 * p->triangles[3 * t + (j + 1) % 3]);
		double mean = sum / (3.0 * (double)p->n_triangles);
		assert_true(fabs(mean / p->spacing_mm - 1.0) <= 0.03);
	}
}

static void expect_refused(const struct asph_surface *s, enum asph_plan_method m,
			   enum asph_plan_density_kind kind, double v,
			   size_t max_points, const char *needle)
{
	struct asph_plan *p = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_plan_compute(s, m, (struct asph_plan_density){ kind, v },
					   max_points, &p, &err), -EINVAL);
	assert_null(p);
	if (!strstr(err.message, needle))
		fail_msg("message '%s' lacks '%s'", err.message, needle);
}

static void test_bad_density(void **state)
{
	struct fixture *f = *state;
	const struct asph_surface *s = f->s[1];
	const double bad[] = { 0, -0.02, NAN, INFINITY, -INFINITY };
	struct asph_error err;

	for (int kind = ASPH_DENSITY_H; kind <= ASPH_DENSITY_POINTS; kind++)
		for (size_t j = 0; j < sizeof(bad) / sizeof(bad[0]); j++)
			expect_refused(s, ASPH_PLAN_OT, kind, bad[j], 0,
				       "must be positive and finite");
	expect_refused(s, ASPH_PLAN_OP, ASPH_DENSITY_H, 1.7, 0, "too coarse");
	expect_refused(s, ASPH_PLAN_CI, ASPH_DENSITY_POINTS, 2, 0, "too coarse");
	expect_refused(s, ASPH_PLAN_RASTER, ASPH_DENSITY_SPACING, 1e-7, 0,
		       "the most a plan can hold");
	/* Over the limit: the message gives the count it would produce. */
	size_t n;
	assert_int_equal(asph_plan_resolve(s, ASPH_PLAN_FERMAT,
					   (struct asph_plan_density){ ASPH_DENSITY_H, 0.01 },
					   NULL, &n, NULL), 0);
	char needle[64];
	snprintf(needle, sizeof(needle), "gives %zu points, more than the limit of 999", n);
	expect_refused(s, ASPH_PLAN_FERMAT, ASPH_DENSITY_H, 0.01, 999, needle);
	asph_error_clear(&err);
	assert_int_equal(asph_plan_resolve(s, ASPH_PLAN_N_METHODS,
					   (struct asph_plan_density){ ASPH_DENSITY_H, 0.1 },
					   NULL, NULL, &err), -EINVAL);
	enum asph_plan_method m;
	assert_int_equal(asph_plan_method_from_name("spirale", &m), -EINVAL);
	for (int k = 0; k < ASPH_PLAN_N_METHODS; k++) {
		assert_int_equal(asph_plan_method_from_name(asph_plan_method_name(k), &m), 0);
		assert_int_equal(m, k);
	}
}

/* ---- scan order ------------------------------------------------------------ */

/*
 * CI, OT, LB: consecutive points at most 2.5 e apart on the surface (the
 * step onto the rim ring of OT and LB included); CVT, which moves OT's
 * points by up to about half a pitch, 3 e. The vertex-plane patterns
 * and OP: at most 2 p apart in the x-y plane, except the documented line
 * changes of the raster (the next row starts on the rim).
 */
static void test_scan_order(void **state)
{
	struct fixture *f = *state;

	for (int i = 0; i < N_PRESETS; i++) {
		double a = asph_surface_aperture_radius(f->s[i]);
		for (int m = 0; m < ASPH_PLAN_N_METHODS; m++) {
			const struct asph_plan *p = f->plan[i][m];
			int on_surface = m == ASPH_PLAN_CI || m == ASPH_PLAN_OT || m == ASPH_PLAN_LB ||
					 m == ASPH_PLAN_CVT;
			double bound = on_surface ? (m == ASPH_PLAN_CVT ? 3.0 : 2.5) * p->spacing_mm
						  : 2.0 * pitch_of(f->s[i], p);
			for (size_t k = 0; k + 1 < p->n; k++) {
				const double *q = p->xyz + 3 * k, *q1 = q + 3;
				double d = on_surface ? dist3(q, q1) : dist2(q, q1);
				if (d <= bound)
					continue;
				if (m == ASPH_PLAN_RASTER && q[1] != q1[1] &&
				    fabs(hypot(q1[0], q1[1]) - a) <= 1e-12 * a)
					continue;
				fail_msg("%s %s: step %zu is %g mm (bound %g)", presets[i],
					 asph_plan_method_name(m), k, d, bound);
			}
		}
	}
}

/* ---- the classic patterns -------------------------------------------------- */

static void test_raster(void **state)
{
	const double a = 11.83, p = 0.6571;
	size_t n = plan_raster_count(a, p);
	double *g = malloc(3 * n * sizeof(*g));

	plan_raster_fill(a, p, g);
	for (size_t k = 0; k < n; k++) {
		double x = g[3 * k], y = g[3 * k + 1];
		double c = sqrt(a * a - y * y);
		assert_true(fabs(y / p - round(y / p)) <= 1e-9);
		assert_true(fabs(x / p - round(x / p)) <= 1e-9 || fabs(fabs(x) - c) <= 1e-12 * a);
		assert_true(fabs(g[3 * k + 2] - hypot(x, y)) <= 1e-14 * a);
		if (k + 1 < n && g[3 * k + 4] == y) {
			/* Serpentine: rows alternate in x direction. */
			long row = lround(y / p) + lround(floor(a / p));
			assert_true(row % 2 == 0 ? g[3 * k + 3] > x : g[3 * k + 3] < x);
		}
	}
	free(g);
}

static void test_concentric(void **state)
{
	const double a = 9.77, p = 0.4123;
	size_t n = plan_concentric_count(a, p), rings = (size_t)ceil(a / p), at = 1;
	double *g = malloc(3 * n * sizeof(*g));

	plan_concentric_fill(a, p, g);
	assert_true(g[0] == 0 && g[1] == 0);
	for (size_t j = 1; j <= rings; j++) {
		double r = a * (double)j / (double)rings;
		size_t m = (size_t)ceil(2.0 * M_PI * r / p - 1e-9);
		for (size_t i = 0; i < m; i++, at++) {
			const double *q = g + 3 * at, *q1 = g + 3 * (at + (i + 1 < m ? 1 : 1 - m));
			assert_true(fabs(hypot(q[0], q[1]) - r) <= 1e-13 * a);
			assert_true(fabs(dist2(q, q1) - 2 * r * sin(M_PI / (double)m)) <= 1e-12 * a);
			/* counter-clockwise */
			assert_true(q[0] * q1[1] - q[1] * q1[0] > 0);
		}
	}
	assert_int_equal(at, n);
	free(g);
}

static double spiral_arc(double b, double th)
{
	return 0.5 * b * (th * sqrt(1.0 + th * th) + asinh(th));
}

static void test_archimedean(void **state)
{
	const double a = 13.9, p = 0.0917, b = p / (2.0 * M_PI);
	size_t n = plan_spiral_count(a, p);
	double *g = malloc(3 * n * sizeof(*g)), th_prev = 0;
	double step = spiral_arc(b, a / b) / (double)(n - 1);

	plan_spiral_fill(a, p, g);
	assert_true(step <= p && step > 0.99 * p);
	for (size_t k = 1; k < n; k++) {
		const double *q = g + 3 * k;
		double r = hypot(q[0], q[1]);
		/* theta unwrapped from the previous sample (steps < pi). */
		double th = atan2(q[1], q[0]);
		th += 2.0 * M_PI * round((th_prev - th) / (2.0 * M_PI));
		while (th < th_prev)
			th += 2.0 * M_PI;
		assert_true(fabs(r - b * th) <= 1e-11 * a);
		assert_true(fabs(spiral_arc(b, r / b) - step * (double)k) <= 1e-10 * a);
		th_prev = th;
	}
	assert_true(fabs(hypot(g[3 * (n - 1)], g[3 * (n - 1) + 1]) - a) <= 1e-14 * a);
	free(g);
}

static void test_fermat(void **state)
{
	const double a = 8.61, p = 0.2213, golden = M_PI * (3.0 - sqrt(5.0));
	size_t n = plan_fermat_count(a, p);
	double *g = malloc(3 * n * sizeof(*g));
	char *seen = calloc(n, 1);

	assert_int_equal(plan_fermat_fill(a, p, g), 0);
	assert_int_equal(n, (size_t)round(M_PI * a * a / (p * p)));
	for (size_t k = 0; k < n; k++) {
		const double *q = g + 3 * k;
		double r = hypot(q[0], q[1]);
		size_t i = (size_t)llround(r * r / (a * a) * (double)(n - 1));
		assert_true(i < n && !seen[i]);
		seen[i] = 1;
		assert_true(fabs(r - a * sqrt((double)i / (double)(n - 1))) <= 1e-13 * a);
		if (i == 0)
			continue;
		double want = fmod((double)i * golden, 2.0 * M_PI);
		double d = remainder(atan2(q[1], q[0]) - want, 2.0 * M_PI);
		assert_true(fabs(d) <= 1e-9);
	}
	free(seen);
	free(g);
}

/* The plan's JSON: one writer, and a reader of both shapes scan headers
 * have held. */
/*
 * The profiles plan: N diameters at azimuths k 180 / N deg, each with its
 * ends on the rim, the apex on every one, at most the pitch apart in x-y,
 * back and forth, on the surface; the mean spacing along a trace on the
 * surface is the one asked for, less by at most one step in the
 * diameter's (the count is rounded up); --points N gives N / profiles a
 * profile.
 */
static void check_profiles(const struct asph_surface *s, unsigned profiles, double h)
{
	struct asph_plan_options o = { .profiles = profiles };
	struct asph_plan *p = NULL;
	double a = asph_surface_aperture_radius(s), e;
	size_t n;

	assert_int_equal(asph_plan_compute_opts(s, ASPH_PLAN_PROFILES,
						(struct asph_plan_density){ ASPH_DENSITY_H, h }, &o,
						&p, NULL), 0);
	assert_int_equal(asph_plan_resolve_opts(s, ASPH_PLAN_PROFILES,
						(struct asph_plan_density){ ASPH_DENSITY_H, h }, &o,
						&e, &n, NULL), 0);
	assert_int_equal(p->n, n);
	assert_int_equal(p->profiles, profiles);
	assert_int_equal(p->n % profiles, 0);
	assert_true(e == p->spacing_mm && fabs(e - h * a) <= 1e-15 * a);
	size_t m = n / profiles;
	for (unsigned j = 0; j < profiles; j++) {
		const double *q = p->xyz + 3 * m * j;
		double phi = M_PI * j / profiles, len = 0, apex = INFINITY;
		/* from -a to a along phi for even profiles, back for odd ones */
		double sign = j % 2 ? 1 : -1;
		assert_true(fabs(q[0] - sign * a * cos(phi)) < 1e-12 &&
			    fabs(q[1] - sign * a * sin(phi)) < 1e-12);
		for (size_t k = 0; k < m; k++) {
			const double *v = q + 3 * k;
			double r = hypot(v[0], v[1]);
			assert_true(fabs(v[0] * sin(phi) - v[1] * cos(phi)) < 1e-12);
			/* (cos, sin) of the azimuth put the rim within rounding of a) */
			assert_true(r <= a * (1 + 1e-15) &&
				    fabs(v[2] - asph_surface_sag(s, fmin(r, a))) <= 1e-12 * a);
			apex = fmin(apex, r);
			if (k > 0) {
				assert_true(dist2(v, v - 3) <= h * a * a /
						asph_surface_arc_length(s, a) * (1 + 1e-12));
				len += dist3(v, v - 3);
			}
		}
		assert_true(fabs(hypot(q[3 * (m - 1)], q[3 * (m - 1) + 1]) - a) < 1e-12);
		assert_true(apex < 1e-12 || m % 2 == 0);
		double mean = len / (double)(m - 1);
		if (!(mean <= e * (1 + 1e-9) && mean >= e * (1 - 1.0 / (double)(m - 1)) * (1 - 1e-3)))
			fail_msg("%u profiles h=%g: mean spacing %g, asked %g", profiles, h, mean, e);
	}
	asph_plan_free(p);
	assert_int_equal(asph_plan_resolve_opts(s, ASPH_PLAN_PROFILES,
						(struct asph_plan_density){ ASPH_DENSITY_POINTS, 1000 },
						&o, &e, &n, NULL), 0);
	assert_int_equal(n, profiles * (size_t)round(1000.0 / profiles));
}

static void test_profiles(void **state)
{
	struct fixture *f = *state;
	struct asph_plan_options o = { .profiles = ASPH_PLAN_MAX_PROFILES + 1 };
	struct asph_plan *p = NULL;
	struct asph_error err;
	size_t n;

	for (int i = 0; i < N_PRESETS; i++) {
		check_profiles(f->s[i], 1, 0.0137);
		check_profiles(f->s[i], 2, 0.011);
		check_profiles(f->s[i], 4, 0.02);
		check_profiles(f->s[i], ASPH_PLAN_MAX_PROFILES, 0.05);
	}
	/* the default is one profile */
	assert_int_equal(f->plan[0][ASPH_PLAN_PROFILES]->profiles, 1);
	/* refused: too many profiles, a count for another method */
	asph_error_clear(&err);
	assert_int_equal(asph_plan_compute_opts(f->s[0], ASPH_PLAN_PROFILES,
						(struct asph_plan_density){ ASPH_DENSITY_H, 0.05 },
						&o, &p, &err), -EINVAL);
	assert_non_null(strstr(err.message, "1 to 36"));
	o.profiles = 2;
	assert_int_equal(asph_plan_resolve_opts(f->s[0], ASPH_PLAN_OT,
						(struct asph_plan_density){ ASPH_DENSITY_H, 0.05 },
						&o, NULL, &n, &err), -EINVAL);
	assert_non_null(strstr(err.message, "profiles method"));
	assert_null(p);
}

static void test_plan_json(void **state)
{
	struct fixture *f = *state;
	const struct asph_plan *p = f->plan[1][ASPH_PLAN_OT];
	struct asph_plan_info info;
	struct asph_error err;
	char *text = NULL;

	assert_int_equal(asph_plan_to_json(p, &text), 0);
	assert_int_equal(asph_plan_info_from_json(text, strlen(text), "t", &info, &err), 0);
	assert_int_equal(info.method, ASPH_PLAN_OT);
	assert_int_equal(info.density.kind, p->density.kind);
	assert_true(info.density.value == p->density.value);
	assert_true(info.spacing_mm == p->spacing_mm);
	assert_int_equal(info.points, p->n);
	assert_int_equal(info.profiles, 0);
	assert_non_null(strstr(text, "\"density\":\"h\""));
	assert_null(strstr(text, "profiles"));
	free(text);

	/* the profiles plan says how many */
	struct asph_plan *pp = NULL;
	struct asph_plan_options po = { .profiles = 3 };
	assert_int_equal(asph_plan_compute_opts(f->s[0], ASPH_PLAN_PROFILES,
						(struct asph_plan_density){ ASPH_DENSITY_H, 0.1 },
						&po, &pp, NULL), 0);
	assert_int_equal(asph_plan_to_json(pp, &text), 0);
	assert_int_equal(asph_plan_info_from_json(text, strlen(text), "t", &info, &err), 0);
	assert_true(info.method == ASPH_PLAN_PROFILES && info.profiles == 3 && info.points == pp->n);
	free(text);
	asph_plan_free(pp);
	const char *one = "{\"method\":\"profiles\",\"density\":\"h\",\"value\":0.1}";
	assert_int_equal(asph_plan_info_from_json(one, strlen(one), "t", &info, &err), 0);
	assert_int_equal(info.profiles, 1);

	/* as asph scan wrote it before: the density an object */
	const char *old = "{\"method\":\"fermat\",\"density\":{\"kind\":\"points\","
			  "\"value\":50},\"spacing_mm\":4.71,\"points\":50}";
	assert_int_equal(asph_plan_info_from_json(old, strlen(old), "t", &info, &err), 0);
	assert_true(info.method == ASPH_PLAN_FERMAT && info.density.kind == ASPH_DENSITY_POINTS);
	assert_true(info.density.value == 50 && info.spacing_mm == 4.71 && info.points == 50);
	/* spacing and count are optional */
	const char *bare = "{\"method\":\"ci\",\"density\":\"spacing\",\"value\":0.25}";
	assert_int_equal(asph_plan_info_from_json(bare, strlen(bare), "t", &info, &err), 0);
	assert_true(info.method == ASPH_PLAN_CI && info.density.kind == ASPH_DENSITY_SPACING);
	assert_true(info.density.value == 0.25 && isnan(info.spacing_mm) && info.points == 0);

	static const struct { const char *text, *field; } bad[] = {
		{ "[1]", "plan" },
		{ "{\"method\":\"zigzag\",\"density\":\"h\",\"value\":0.1}", "plan.method" },
		{ "{\"method\":\"ot\",\"density\":\"n\",\"value\":0.1}", "plan.density" },
		{ "{\"method\":\"ot\",\"density\":\"h\",\"value\":0}", "plan.value" },
		{ "{\"method\":\"ot\",\"density\":{\"kind\":\"h\"}}", "plan.density.value" },
		{ "{\"method\":\"ot\",\"density\":{\"kind\":1,\"value\":1}}", "plan.density.kind" },
		{ "{\"method\":\"ot\",\"density\":\"h\",\"value\":0.1,\"points\":-3}", "plan.points" },
		{ "{\"method\":\"ot\",\"density\":\"h\",\"value\":0.1,\"profiles\":2}", "plan.profiles" },
		{ "{\"method\":\"profiles\",\"density\":\"h\",\"value\":0.1,\"profiles\":37}",
		  "plan.profiles" },
		{ "{\"method\":\"profiles\",\"density\":\"h\",\"value\":0.1,\"profiles\":1.5}",
		  "plan.profiles" },
	};
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
		asph_error_clear(&err);
		assert_int_equal(asph_plan_info_from_json(bad[i].text, strlen(bad[i].text), "hdr",
							  &info, &err), -EINVAL);
		assert_string_equal(err.field, bad[i].field);
		assert_string_equal(err.source, "hdr");
	}

	enum asph_plan_density_kind k;
	for (int i = 0; i < 3; i++) {
		assert_int_equal(asph_plan_density_from_name(
			asph_plan_density_name((enum asph_plan_density_kind)i), &k), 0);
		assert_int_equal(k, i);
	}
	assert_int_equal(asph_plan_density_from_name("H", &k), -EINVAL);
	assert_int_equal(asph_plan_density_from_name(NULL, &k), -EINVAL);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_disk_grid_closed_form),
		cmocka_unit_test(test_disk_mesh),
		cmocka_unit_test(test_op_on_surface),
		cmocka_unit_test(test_ot_map),
		cmocka_unit_test(test_ot_plan),
		cmocka_unit_test(test_lb_plan),
		cmocka_unit_test(test_radial_monotone),
		cmocka_unit_test(test_flat_limit),
		cmocka_unit_test(test_inside_aperture),
		cmocka_unit_test(test_no_folding),
		cmocka_unit_test(test_density_points),
		cmocka_unit_test(test_density_h_spacing),
		cmocka_unit_test(test_density_mean_edge),
		cmocka_unit_test(test_bad_density),
		cmocka_unit_test(test_scan_order),
		cmocka_unit_test(test_raster),
		cmocka_unit_test(test_concentric),
		cmocka_unit_test(test_archimedean),
		cmocka_unit_test(test_fermat),
		cmocka_unit_test(test_profiles),
		cmocka_unit_test(test_plan_json),
	};

	return cmocka_run_group_tests(tests, setup, teardown);
}
