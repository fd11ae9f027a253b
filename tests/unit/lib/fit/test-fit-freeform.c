/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The fit on freeform surfaces: the closest point in (x, y) against feet
 * built along the normal, the 6-DOF pose recovered from noise-free
 * measurements, the residual of noise and a form error as injected, and
 * the refusals (rz on a surface of revolution, R and k on a freeform).
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>
#include <gsl/gsl_errno.h>

#include "asph/fit.h"
#include "asph/surface.h"
#include "asph/zernike.h"

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

/* An off-axis segment with astigmatism, coma and trefoil in x and y. */
static struct asph_prescription xy_part(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_XY_POLYNOMIAL, .R = 61.7, .k = -0.83,
				       .norm_radius = 15,
				       .aperture = { ASPH_APERTURE_RECTANGULAR, 24, 17, { 1.7, 4.1 } } };
	p.C[asph_xy_index(2, 0)] = 0.21;
	p.C[asph_xy_index(0, 2)] = -0.13;
	p.C[asph_xy_index(2, 1)] = 0.041;
	p.C[asph_xy_index(0, 3)] = -0.027;
	p.C[asph_xy_index(3, 0)] = 0.019;
	p.C[asph_xy_index(1, 2)] = 0.033;
	p.C[asph_xy_index(4, 0)] = -0.008;
	return p;
}

/* A conic with Zernike terms to radial order 7, decentred, and a toroid
 * carrying Zernike terms: the harmonic sums of the closest point. */
static struct asph_prescription zernike_part(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_ZERNIKE_SAG, .R = 48.3, .k = -0.61,
				       .norm_radius = 12.5, .zernike_decenter = { 0.7, -0.4 },
				       .aperture_diameter = 23 };
	for (int j = 4; j <= 36; j++)
		p.Zernike[j - 1] = 2.3e-3 * (j % 3 ? 1 : -1) / j;
	return p;
}

static struct asph_prescription toroid_part(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_TOROIDAL, .R = 44.1, .k = -0.35,
				       .R_rotation = -63.7, .norm_radius = 9,
				       .aperture = { ASPH_APERTURE_RECTANGULAR, 16, 12, { 0, 0 } } };
	p.A[4] = 1.9e-6;
	p.Zernike[5] = 4.1e-3;
	p.Zernike[7] = -2.6e-3;
	p.Zernike[10] = 1.7e-3;
	return p;
}

static struct asph_prescription biconic_part(void)
{
	struct asph_prescription p = { .type = ASPH_SURFACE_BICONIC, .Rx = 37.3, .Ry = 52.9,
				       .kx = -0.4, .ky = 0.7,
				       .aperture = { ASPH_APERTURE_ELLIPTICAL, 26, 19, { 0, 0 } } };
	p.A[4] = 2.3e-6;
	return p;
}

/* Nominal points on a grid over the aperture, on the surface. */
static double *grid_points(const struct asph_surface *s, int m, size_t *n)
{
	double box[4], *xyz = malloc(3 * (size_t)(m + 1) * (m + 1) * sizeof(double));
	size_t k = 0;

	asph_surface_bounds(s, box);
	for (int i = 0; i <= m; i++)
		for (int j = 0; j <= m; j++) {
			double x = box[0] + (box[1] - box[0]) * (i + 0.31) / (m + 0.62);
			double y = box[2] + (box[3] - box[2]) * (j + 0.29) / (m + 0.58);
			if (!asph_surface_contains(s, x, y, 0))
				continue;
			xyz[3 * k] = x;
			xyz[3 * k + 1] = y;
			xyz[3 * k + 2] = asph_surface_sag_xy(s, x, y);
			k++;
		}
	*n = k;
	return xyz;
}

/* A point a distance d along the normal from a foot has that foot. */
static void test_closest_point(void **state)
{
	struct asph_prescription p = xy_part();
	struct asph_surface *s = build(&p);
	const double feet[][2] = { { 1.7, 4.1 }, { -8.3, 10.2 }, { 12.9, -3.7 }, { 5.5, 11.9 } };
	const double ds[] = { 0.3, -0.47, 1e-7, 2.1 };

	for (size_t i = 0; i < 4; i++) {
		double n[3], q[3], x = feet[i][0], y = feet[i][1];
		struct asph_closest c;
		asph_surface_normal(s, x, y, n);
		for (int k = 0; k < 3; k++)
			q[k] = (k == 0 ? x : k == 1 ? y : asph_surface_sag_xy(s, x, y)) + ds[i] * n[k];
		assert_int_equal(asph_fit_closest_point(s, q, &c), 0);
		assert_true(fabs(c.foot[0] - x) < 1e-11 && fabs(c.foot[1] - y) < 1e-11);
		assert_true(fabs(c.distance - ds[i]) < 1e-12);
		assert_true(fabs(c.normal[2] - n[2]) < 1e-12);
		assert_int_equal(c.inside, asph_surface_contains(s, x, y, 0));
	}
	asph_surface_free(s);
}

static void fit_points(const struct asph_surface *s, const double *xyz, size_t n,
		       enum asph_fit_residual_kind kind, struct asph_fit_result *res)
{
	struct asph_fit_options o = { .dof = ASPH_FIT_DOF_RIGID6, .residual = kind };
	struct asph_fit *w = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_fit_alloc(s, n, &o, &w, &err), 0);
	if (asph_fit_run(w, xyz, n, res, &err) < 0) {
		print_error("fit: %s\n", err.message);
		fail();
	}
	asph_fit_free(w);
}

static void check_pose(const struct asph_fit_result *r, const struct asph_pose *pose, double tol_mm,
		       double tol_rad)
{
	const double want[] = { pose->t[0], pose->t[1], pose->t[2], pose->rx, pose->ry };
	for (int k = 0; k < 5; k++)
		if (!(fabs(r->value[k] - want[k]) <= (k < 3 ? tol_mm : tol_rad))) {
			print_error("%s: got %.17g want %.17g\n", asph_fit_dof_name(k), r->value[k], want[k]);
			fail();
		}
	if (!(fabs(r->value[ASPH_FIT_RZ] - pose->rz) <= tol_rad)) {
		print_error("rz: got %.17g want %.17g\n", r->value[ASPH_FIT_RZ], pose->rz);
		fail();
	}
}

static void test_six_dof_noise_free(void **state)
{
	const struct asph_prescription parts[] = { xy_part(), biconic_part(), zernike_part(),
						   toroid_part() };
	const struct asph_pose pose = { { 0.137, -0.083, 0.029 }, 1.3e-3, -0.9e-3, 2.7e-3 };

	for (size_t k = 0; k < sizeof(parts) / sizeof(parts[0]); k++) {
		struct asph_surface *s = build(&parts[k]);
		struct asph_synth_options so = { .pose = pose };
		struct asph_fit_result res;
		struct asph_error err;
		size_t n;
		double *xyz = grid_points(s, 36, &n);
		assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, xyz, &err), 0);
		fit_points(s, xyz, n, ASPH_FIT_RESIDUAL_NORMAL, &res);
		assert_true(res.converged);
		assert_int_equal(res.n_used, n);
		check_pose(&res, &pose, 1e-9, 1e-9);
		assert_true(res.rms.v < 1e-6);
		fit_points(s, xyz, n, ASPH_FIT_RESIDUAL_SAG, &res);
		check_pose(&res, &pose, 1e-9, 1e-9);
		free(xyz);
		asph_surface_free(s);
	}
}

/* Noise and a pentafoil and a hexafoil on the biconic: the rigid motions
 * move the surface by functions of angular order 3 or less (the biconic's
 * anamorphism adds little above), so they cannot absorb these; the
 * residual keeps the form error and the noise, and its RMS is theirs. */
static void test_noise_and_form_error(void **state)
{
	struct asph_prescription p = biconic_part();
	struct asph_surface *s = build(&p);
	const struct asph_synth_term terms[] = { { 20, 23.0 }, { 27, -11.0 } };
	struct asph_synth_options so = { .pose = { { -0.05, 0.11, 0.02 }, -2e-3, 1.1e-3, -4e-3 },
					 .terms = terms, .n_terms = 2, .noise_nm = 4.0, .seed = 7 };
	struct asph_synth_options form_only = so;
	struct asph_fit_result res;
	struct asph_error err;
	size_t n;
	double *nominal = grid_points(s, 40, &n), *xyz = malloc(3 * n * sizeof(double));
	double *plain = malloc(3 * n * sizeof(double)), sum = 0, sum2 = 0;

	assert_int_equal(asph_fit_synthesize(s, nominal, n, &so, xyz, &err), 0);
	/* the injected error at each point: the same part with no pose, less
	 * the nominal surface along z, projected onto the normal */
	form_only.pose = (struct asph_pose){ 0 };
	assert_int_equal(asph_fit_synthesize(s, nominal, n, &form_only, plain, &err), 0);
	for (size_t i = 0; i < n; i++) {
		double nrm[3], e = 0;
		asph_surface_normal(s, nominal[3 * i], nominal[3 * i + 1], nrm);
		for (int k = 0; k < 3; k++)
			e += (plain[3 * i + k] - nominal[3 * i + k]) * nrm[k];
		sum += e;
		sum2 += e * e;
	}
	double injected_nm = 1e6 * sqrt(sum2 / n - (sum / n) * (sum / n));
	fit_points(s, xyz, n, ASPH_FIT_RESIDUAL_NORMAL, &res);
	assert_true(res.converged);
	if (!(fabs(res.rms.v - injected_nm) < 0.5)) {
		print_error("rms %.4f nm, injected %.4f nm\n", res.rms.v, injected_nm);
		fail();
	}
	/* The pose comes back within its uncertainty (a decentre and a tilt
	 * are strongly correlated on a part this close to a sphere). */
	const double want[ASPH_FIT_N_DOF] = { so.pose.t[0], so.pose.t[1], so.pose.t[2], so.pose.rx,
					      so.pose.ry, 0, 0, so.pose.rz };
	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (ASPH_FIT_DOF_RIGID6 & ASPH_FIT_DOF_BIT(d) &&
		    !(fabs(res.value[d] - want[d]) <= 4 * res.uncertainty[d])) {
			print_error("%s: %.9g, want %.9g +- %.3g\n", asph_fit_dof_name(d), res.value[d],
				    want[d], res.uncertainty[d]);
			fail();
		}
	free(nominal);
	free(xyz);
	free(plain);
	asph_surface_free(s);
}

static void test_refusals(void **state)
{
	struct asph_prescription even = { .type = ASPH_SURFACE_EVEN_ASPHERE, .R = 30,
					  .aperture_diameter = 20 };
	struct asph_prescription ff = xy_part();
	struct asph_surface *s = build(&even), *f = build(&ff);
	struct asph_fit_options o = { .dof = ASPH_FIT_DOF_RIGID6 };
	struct asph_fit *w = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_fit_alloc(s, 100, &o, &w, &err), -EINVAL);
	assert_non_null(strstr(err.message, "rz"));
	o.dof = ASPH_FIT_DOF_RIGID | ASPH_FIT_DOF_BIT(ASPH_FIT_R);
	assert_int_equal(asph_fit_alloc(f, 100, &o, &w, &err), -EINVAL);
	assert_non_null(strstr(err.message, "R and k"));
	asph_surface_free(s);
	asph_surface_free(f);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_closest_point),
		cmocka_unit_test(test_six_dof_noise_free),
		cmocka_unit_test(test_noise_and_form_error),
		cmocka_unit_test(test_refusals),
	};
	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
