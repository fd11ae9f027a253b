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
#include <gsl/gsl_odeiv2.h>

#include "asph/delaunay.h"
#include "asph/lb.h"
#include "asph/prescription.h"
#include "asph/surface.h"

/* The three presets and a steep sphere (slope 1.45 at the rim). */
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

static struct asph_surface *sphere(void)
{
	return make_surface(NULL, 13.71, 22.63);
}

/* A deterministic, high-entropy sequence in (0, 1). */
static double frac(unsigned i)
{
	double x = 0.6180339887498949 * (i + 1) + 0.1234567;
	return x - floor(x);
}

static double slope_w(const struct asph_surface *s, double r)
{
	double d[3];

	asph_surface_sag_derivs(s, r, d);
	return sqrt(1.0 + d[1] * d[1]);
}

static void test_flat(void **state)
{
	struct asph_surface *s = make_surface(NULL, 3.7e15, 47.3);
	struct asph_lb_map *m = NULL;

	assert_int_equal(asph_lb_map_alloc(s, &m, NULL), 0);
	assert_true(asph_lb_map_aperture_radius(m) == 23.65);
	for (unsigned i = 0; i < 500; i++) {
		double r = 23.65 * frac(i);
		assert_true(asph_lb_map_rho(m, r) == r);
		assert_true(asph_lb_map_radius(m, r) == r);
		assert_true(asph_lb_map_rho_deriv(m, r) == 1);
	}
	asph_lb_map_free(m);
	asph_surface_free(s);
}

static void check_boundary_and_monotone(const struct asph_lb_map *m, double a)
{
	assert_true(asph_lb_map_rho(m, 0) == 0);
	assert_true(asph_lb_map_radius(m, 0) == 0);
	assert_true(fabs(asph_lb_map_rho(m, a) - a) <= 1e-15 * a);
	assert_true(fabs(asph_lb_map_radius(m, a) - a) <= 1e-15 * a);
	assert_true(isnan(asph_lb_map_rho(m, a * 1.001)));
	assert_true(isnan(asph_lb_map_radius(m, a * 1.001)));
	/* Symmetric in the sign of the argument. */
	assert_true(asph_lb_map_rho(m, -0.3 * a) == asph_lb_map_rho(m, 0.3 * a));

	double prev = 0;
	for (int i = 1; i <= 4000; i++) {
		double r = a * i / 4000.0, rho = asph_lb_map_rho(m, r);
		assert_true(rho > prev);
		assert_true(asph_lb_map_rho_deriv(m, r) > 0);
		prev = rho;
	}
	assert_true(asph_lb_map_rho_deriv(m, 0) > 0);
}

/*
 * Independent solution of the two-point problem: the second-order equation
 * (r rho'/w)' = w rho / r, integrated as an initial-value problem in
 * u = ln r for y = (rho, p = r rho'/w): rho_u = w p, p_u = w rho. From
 * r_start = 1e-7 a with rho = p = r_start (the regular solution ~ r; the
 * error of that start is O((r_start/R)^2) and sits in the decaying mode),
 * then scaled so rho(a) = a.
 */
static int ode_rhs(double u, const double y[], double dy[], void *ctx)
{
	double w = slope_w(ctx, exp(u));
	dy[0] = w * y[1];
	dy[1] = w * y[0];
	return GSL_SUCCESS;
}

static int cmp_double(const void *a, const void *b)
{
	double x = *(const double *)a, y = *(const double *)b;
	return (x > y) - (x < y);
}

static void check_against_ode(const struct asph_surface *s,
			      const struct asph_lb_map *m, double a)
{
	enum { N = 60 };
	double r[N + 1], rho[N + 1];
	gsl_odeiv2_system sys = { ode_rhs, NULL, 2, (void *)s };
	gsl_odeiv2_driver *d = gsl_odeiv2_driver_alloc_y_new(
		&sys, gsl_odeiv2_step_rk8pd, 1e-6, 1e-15, 1e-15);
	double y[2] = { 1e-7 * a, 1e-7 * a }, u = log(1e-7 * a);

	for (int i = 0; i < N; i++)
		r[i] = a * (0.001 + 0.998 * frac(3 * i + 1));
	qsort(r, N, sizeof(double), cmp_double);
	r[N] = a;
	for (int i = 0; i <= N; i++) {
		assert_int_equal(gsl_odeiv2_driver_apply(d, &u, log(r[i]), y),
				 GSL_SUCCESS);
		rho[i] = y[0];
	}
	gsl_odeiv2_driver_free(d);
	for (int i = 0; i < N; i++) {
		double expect = rho[i] * a / rho[N];
		assert_true(fabs(asph_lb_map_rho(m, r[i]) - expect) <= 1e-12 * expect);
	}
}

/*
 * Residual of the second-order equation with the map's own rho and rho',
 * differentiated by a fourth-order central difference: P = r rho'/w must
 * satisfy P' = w rho / r. Also rho' against the difference of rho.
 */
static void check_residual(const struct asph_surface *s,
			   const struct asph_lb_map *m, double a)
{
	const double h = 2e-3 * a;

	for (unsigned i = 0; i < 200; i++) {
		double r = 3 * h + (a - 6 * h) * frac(7 * i + 2);
		double P[5], rho[5];
		for (int j = 0; j < 5; j++) {
			double x = r + (j - 2) * h;
			P[j] = x * asph_lb_map_rho_deriv(m, x) / slope_w(s, x);
			rho[j] = asph_lb_map_rho(m, x);
		}
		double dP = (P[0] - 8 * P[1] + 8 * P[3] - P[4]) / (12 * h);
		double drho = (rho[0] - 8 * rho[1] + 8 * rho[3] - rho[4]) / (12 * h);
		double rhs = slope_w(s, r) * rho[2] / r;
		assert_true(fabs(dP - rhs) <= 2e-6 * rhs);
		assert_true(fabs(drho - asph_lb_map_rho_deriv(m, r)) <=
			    2e-6 * asph_lb_map_rho_deriv(m, r));
	}
}

static void check_round_trip(const struct asph_lb_map *m, double a)
{
	for (unsigned i = 0; i < 2000; i++) {
		double r = a * frac(11 * i + 5);
		double back = asph_lb_map_radius(m, asph_lb_map_rho(m, r));
		assert_true(fabs(back - r) <= 1e-13 * r);
	}
}

static void check_map(struct asph_surface *s)
{
	struct asph_lb_map *m = NULL;
	double a = asph_surface_aperture_radius(s);

	assert_int_equal(asph_lb_map_alloc(s, &m, NULL), 0);
	check_boundary_and_monotone(m, a);
	check_against_ode(s, m, a);
	check_residual(s, m, a);
	check_round_trip(m, a);
	asph_lb_map_free(m);
	asph_surface_free(s);
}

static void test_sphere(void **state)
{
	check_map(sphere());
}

static void test_presets(void **state)
{
	for (size_t i = 0; i < sizeof(presets) / sizeof(presets[0]); i++)
		check_map(make_surface(presets[i], 0, 0));
}

/*
 * A structured disk mesh: the centre and rings i = 1..M of 6 i nodes at
 * radius a i / M (odd rings turned by half a step), stitched ring to ring
 * by walking both rings in angle. Boundary nodes lie on |x| = a.
 */
struct mesh {
	size_t n, ntri;
	double *xy;
	uint32_t *tri;
};

static void ring_angles(int i, double *first, double *step)
{
	*step = 2 * M_PI / (6 * i);
	*first = (i % 2) ? 0.5 * *step : 0;
}

static void stitch_rings(struct mesh *me, int i)
{
	uint32_t in0 = i == 0 ? 0 : 1 + 3 * (uint32_t)(i - 1) * (uint32_t)i;
	uint32_t out0 = 1 + 3 * (uint32_t)i * (uint32_t)(i + 1);
	uint32_t nin = i == 0 ? 1 : 6 * (uint32_t)i, nout = 6 * (uint32_t)(i + 1);
	double fin = 0, sin_ = 0, fout, sout;
	uint32_t a = 0, b = 0;

	if (i > 0)
		ring_angles(i, &fin, &sin_);
	ring_angles(i + 1, &fout, &sout);
	if (i == 0)
		a = nin;        /* the centre is a fan: only the outer ring walks */
	while (a < nin || b < nout) {
		double ta = i == 0 ? INFINITY : fin + sin_ * (a + 1);
		double tb = fout + sout * (b + 1);
		uint32_t *t = me->tri + 3 * me->ntri++;
		t[0] = in0 + a % nin;
		t[1] = out0 + b % nout;
		if (a == nin || (b < nout && tb <= ta)) {
			t[2] = out0 + (b + 1) % nout;
			b++;
		} else {
			t[2] = in0 + (a + 1) % nin;
			a++;
		}
	}
}

static struct mesh disk_mesh(double a, int M)
{
	struct mesh me = { .n = 1 + 3 * (size_t)M * (M + 1) };

	me.xy = malloc(2 * me.n * sizeof(double));
	me.tri = malloc(3 * 6 * (size_t)M * M * sizeof(uint32_t));
	assert_non_null(me.xy);
	assert_non_null(me.tri);
	me.xy[0] = me.xy[1] = 0;
	size_t k = 1;
	for (int i = 1; i <= M; i++) {
		double first, step;
		ring_angles(i, &first, &step);
		for (int j = 0; j < 6 * i; j++, k++) {
			me.xy[2 * k] = a * i / M * cos(first + step * j);
			me.xy[2 * k + 1] = a * i / M * sin(first + step * j);
		}
	}
	for (int i = 0; i < M; i++)
		stitch_rings(&me, i);
	assert_int_equal(me.ntri, 6 * (size_t)M * M);
	return me;
}

static void mesh_free(struct mesh *me)
{
	free(me->xy);
	free(me->tri);
}

/* Largest distance |S_fe(x) - rho(r) x / r| over the nodes. */
static double fem_error(const struct asph_surface *s,
			const struct asph_lb_map *m, int M)
{
	double a = asph_surface_aperture_radius(s), worst = 0;
	struct mesh me = disk_mesh(a, M);
	double *S = malloc(2 * me.n * sizeof(double));

	assert_non_null(S);
	assert_int_equal(asph_lb_fem_solve(s, me.xy, me.n, me.tri, me.ntri, S,
					   NULL), 0);
	for (size_t i = 0; i < me.n; i++) {
		double x = me.xy[2 * i], y = me.xy[2 * i + 1], r = hypot(x, y);
		double f = r > 0 ? asph_lb_map_rho(m, r) / r : 0;
		worst = fmax(worst, hypot(S[2 * i] - f * x, S[2 * i + 1] - f * y));
	}
	free(S);
	mesh_free(&me);
	return worst;
}

static void check_fem_convergence(struct asph_surface *s, double tol_fine)
{
	struct asph_lb_map *m = NULL;

	assert_int_equal(asph_lb_map_alloc(s, &m, NULL), 0);
	double coarse = fem_error(s, m, 12), fine = fem_error(s, m, 24);
	/* P1 elements: O(h^2), so halving h divides the error by ~4. */
	assert_true(fine < coarse / 3.2);
	assert_true(fine < tol_fine);
	asph_lb_map_free(m);
	asph_surface_free(s);
}

static void test_fem_matches_radial(void **state)
{
	check_fem_convergence(sphere(), 4e-3);
	check_fem_convergence(make_surface("strong", 0, 0), 2e-3);
}

/*
 * An unstructured mesh: Delaunay triangulation of a Fermat (golden-angle)
 * spiral strictly inside the disk plus a ring of nodes on the rim.
 */
static void test_fem_delaunay_mesh(void **state)
{
	struct asph_surface *s = make_surface("strong", 0, 0);
	const double a = asph_surface_aperture_radius(s), h = 0.9;
	const size_t n_ring = (size_t)ceil(2 * M_PI * a / h);
	const size_t n_in = (size_t)(M_PI * (a - 0.6 * h) * (a - 0.6 * h) / (h * h));
	const size_t n = n_in + n_ring;
	double *xy = malloc(2 * n * sizeof(double)), *S = malloc(2 * n * sizeof(double));
	struct asph_lb_map *m = NULL;
	struct asph_delaunay *w = asph_delaunay_alloc(n);
	uint32_t *tri = NULL;
	size_t ntri = 0;
	double worst = 0;

	assert_non_null(xy);
	assert_non_null(S);
	assert_non_null(w);
	for (size_t i = 0; i < n_in; i++) {
		double r = (a - 0.6 * h) * sqrt((i + 0.5) / n_in);
		double t = M_PI * (3 - sqrt(5)) * i;
		xy[2 * i] = r * cos(t);
		xy[2 * i + 1] = r * sin(t);
	}
	for (size_t i = 0; i < n_ring; i++) {
		xy[2 * (n_in + i)] = a * cos(2 * M_PI * i / n_ring + 0.1);
		xy[2 * (n_in + i) + 1] = a * sin(2 * M_PI * i / n_ring + 0.1);
	}
	assert_int_equal(asph_delaunay_triangulate(w, xy, n, &tri, &ntri, NULL), 0);
	assert_int_equal(asph_lb_fem_solve(s, xy, n, tri, ntri, S, NULL), 0);
	assert_int_equal(asph_lb_map_alloc(s, &m, NULL), 0);
	for (size_t i = 0; i < n; i++) {
		double x = xy[2 * i], y = xy[2 * i + 1], r = hypot(x, y);
		double f = asph_lb_map_rho(m, r) / r;
		worst = fmax(worst, hypot(S[2 * i] - f * x, S[2 * i + 1] - f * y));
	}
	/* r - rho reaches 0.68 mm on this lens; P1 elements at h = 0.9 mm
	 * come within ~1.4e-3 mm of it. */
	assert_true(worst < 3e-3);
	asph_lb_map_free(m);
	asph_delaunay_free(w);
	free(tri);
	free(xy);
	free(S);
	asph_surface_free(s);
}

/* A tilted plane z = 0.83 x - 1.37 y: constant metric, so S(x) = x is the
 * exact solution and P1 elements reproduce it to rounding. */
static void tilted_plane(void *ctx, double x, double y, double g[2])
{
	g[0] = 0.83;
	g[1] = -1.37;
}

static void test_fem_tilted_plane(void **state)
{
	struct mesh me = disk_mesh(7.3, 9);
	double *S = malloc(2 * me.n * sizeof(double));

	assert_non_null(S);
	assert_int_equal(asph_lb_fem_solve_graph(tilted_plane, NULL, me.xy, me.n,
						 me.tri, me.ntri, S, NULL), 0);
	for (size_t i = 0; i < 2 * me.n; i++)
		assert_true(fabs(S[i] - me.xy[i]) <= 1e-12 * 7.3);
	free(S);
	mesh_free(&me);
}

/*
 * Known harmonic maps with other boundary values: a developable surface's
 * development onto the plane is an isometry, so its coordinates are
 * harmonic for the surface's metric. Given them on the boundary, the
 * solver must find them inside.
 */

/* The tilted plane: its development is linear in (x, y) (an orthonormal
 * frame of the plane), which P1 elements reproduce to rounding. */
struct plane_frame {
	double e1[3], e2[3];
};

static void plane_development(void *ctx, double x, double y, double S[2])
{
	const struct plane_frame *f = ctx;
	double X[3] = { x, y, 0.83 * x - 1.37 * y };

	S[0] = f->e1[0] * X[0] + f->e1[1] * X[1] + f->e1[2] * X[2];
	S[1] = f->e2[0] * X[0] + f->e2[1] * X[1] + f->e2[2] * X[2];
}

static void test_fem_plane_development(void **state)
{
	struct mesh me = disk_mesh(7.3, 9);
	double *S = malloc(2 * me.n * sizeof(double)), want[2];
	/* tangents (1, 0, 0.83) and (0, 1, -1.37), Gram-Schmidt */
	double t1[3] = { 1, 0, 0.83 }, t2[3] = { 0, 1, -1.37 }, n1 = sqrt(1 + 0.83 * 0.83);
	struct plane_frame f;

	for (int k = 0; k < 3; k++)
		f.e1[k] = t1[k] / n1;
	double d = t2[0] * f.e1[0] + t2[1] * f.e1[1] + t2[2] * f.e1[2];
	for (int k = 0; k < 3; k++)
		t2[k] -= d * f.e1[k];
	double n2 = sqrt(t2[0] * t2[0] + t2[1] * t2[1] + t2[2] * t2[2]);
	for (int k = 0; k < 3; k++)
		f.e2[k] = t2[k] / n2;
	assert_non_null(S);
	assert_int_equal(asph_lb_fem_solve_graph_dirichlet(tilted_plane, NULL, plane_development,
							   &f, me.xy, me.n, me.tri, me.ntri,
							   S, NULL), 0);
	for (size_t i = 0; i < me.n; i++) {
		plane_development(&f, me.xy[2 * i], me.xy[2 * i + 1], want);
		assert_true(fabs(S[2 * i] - want[0]) <= 1e-12 * 7.3);
		assert_true(fabs(S[2 * i + 1] - want[1]) <= 1e-12 * 7.3);
	}
	free(S);
	mesh_free(&me);
}

/* The cylinder z = R - sqrt(R^2 - y^2) (a toroidal surface with its axis
 * of rotation at infinity): its development is (x, R asin(y / R)). */
#define CYL_R 11.3

static void cylinder_development(void *ctx, double x, double y, double S[2])
{
	S[0] = x;
	S[1] = CYL_R * asin(y / CYL_R);
}

static void surface_gradient(void *ctx, double x, double y, double g[2])
{
	double v[3];

	asph_surface_sag_grad_xy(ctx, x, y, v);
	g[0] = v[1];
	g[1] = v[2];
}

/* RMS over the nodes of |S_fe - development|, on the ring mesh with M
 * rings (its refinements are not nested, so the largest error jumps about;
 * the RMS converges smoothly). */
static double cylinder_error(const struct asph_surface *s, int M)
{
	struct mesh me = disk_mesh(9.1, M);
	double *S = malloc(2 * me.n * sizeof(double)), want[2], sum = 0;

	assert_non_null(S);
	assert_int_equal(asph_lb_fem_solve_graph_dirichlet(surface_gradient, (void *)s,
							   cylinder_development, NULL, me.xy,
							   me.n, me.tri, me.ntri, S, NULL), 0);
	for (size_t i = 0; i < me.n; i++) {
		cylinder_development(NULL, me.xy[2 * i], me.xy[2 * i + 1], want);
		sum += pow(S[2 * i] - want[0], 2) + pow(S[2 * i + 1] - want[1], 2);
	}
	free(S);
	mesh_free(&me);
	return sqrt(sum / (double)me.n);
}

static void test_fem_cylinder_development(void **state)
{
	struct asph_prescription p = {
		.type = ASPH_SURFACE_TOROIDAL, .R = CYL_R, .R_rotation = INFINITY,
		.aperture_diameter = 18.2,
	};
	struct asph_surface *s = NULL;
	double e[3];

	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	for (int k = 0; k < 3; k++)
		e[k] = cylinder_error(s, 6 << k);
	/* P1 elements: O(h^2), the nodal RMS error divides by ~4 per halving
	 * of h (seen 4.38, 4.27, and 4.07 for the next halving); the slope
	 * reaches 1.35 on the rim. */
	assert_true(e[0] / e[1] > 3.5 && e[0] / e[1] < 4.6);
	assert_true(e[1] / e[2] > 3.5 && e[1] / e[2] < 4.6);
	assert_true(e[2] < 3e-4);
	asph_surface_free(s);
}

static void test_fem_errors(void **state)
{
	struct asph_surface *s = sphere();
	double xy[] = { 0, 0, 1, 0, 0, 1, 2, 2 };
	uint32_t bad_index[] = { 0, 1, 4 };
	uint32_t degenerate[] = { 0, 1, 2, 0, 3, 3 };
	double S[8];
	struct asph_error e;

	assert_int_equal(asph_lb_fem_solve(s, xy, 4, bad_index, 1, S, &e), -EINVAL);
	assert_non_null(strstr(e.message, "node 4"));
	assert_int_equal(asph_lb_fem_solve(s, xy, 4, degenerate, 2, S, &e), -EINVAL);
	assert_non_null(strstr(e.message, "triangle 1"));
	assert_int_equal(asph_lb_fem_solve(s, xy, 0, degenerate, 0, S, &e), -EINVAL);
	/* Every node on the boundary: S = x. */
	assert_int_equal(asph_lb_fem_solve(s, xy, 4, degenerate, 1, S, &e), 0);
	assert_memory_equal(S, xy, sizeof(xy));
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_flat),
		cmocka_unit_test(test_sphere),
		cmocka_unit_test(test_presets),
		cmocka_unit_test(test_fem_matches_radial),
		cmocka_unit_test(test_fem_delaunay_mesh),
		cmocka_unit_test(test_fem_tilted_plane),
		cmocka_unit_test(test_fem_plane_development),
		cmocka_unit_test(test_fem_cylinder_development),
		cmocka_unit_test(test_fem_errors),
	};
	return cmocka_run_group_tests(tests, NULL, NULL);
}
