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
#include <gsl/gsl_errno.h>
#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>

#include "asph/fit.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "asph/zernike.h"
#include "custom-surface.h"

static const char *const lenses[] = { "weak", "strong", "turning-point" };

static int under_valgrind(void)
{
	const char *v = getenv("ASPH_UNDER_VALGRIND");
	return v && *v && strcmp(v, "0") != 0;
}

static size_t n_points(void)
{
	return under_valgrind() ? 1500 : 3000;
}

static struct asph_surface *lens(const char *name)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;

	assert_int_equal(asph_prescription_preset(name, &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/*
 * Nominal points on the surface out to radius frac * a: concentric rings of
 * equal area, each evenly spaced in angle (as the concentric plan) with an
 * irregular start angle per ring, about n points in all, rim included.
 * Even spacing on a ring keeps the sample orthogonality of the harmonics
 * that docs/characterization.md relies on.
 */
static double *ring_points(const struct asph_surface *s, size_t n, double frac,
			   size_t *n_out)
{
	double a = frac * asph_surface_aperture_radius(s);
	size_t rings = (size_t)sqrt((double)n / M_PI), total = 1, k = 1;
	double *xyz;

	for (size_t j = 1; j <= rings; j++)
		total += (size_t)(2 * M_PI * j) + 3;
	xyz = calloc(3 * total, sizeof(double));
	for (size_t j = 1; j <= rings; j++) {
		double r = a * sqrt((j - 0.5 * (j < rings)) / (double)rings);
		size_t m = (size_t)(2 * M_PI * j) + 3;
		double t0 = 2.399963229728653 * (double)j;
		for (size_t i = 0; i < m; i++, k++) {
			double t = t0 + 2 * M_PI * (double)i / (double)m;
			xyz[3 * k] = r * cos(t);
			xyz[3 * k + 1] = r * sin(t);
			xyz[3 * k + 2] = asph_surface_sag(s, r);
		}
	}
	*n_out = total;
	return xyz;
}

static struct asph_pose random_pose(gsl_rng *rng)
{
	struct asph_pose p = { 0 };     /* rz stays 0: the lenses are round */

	for (int k = 0; k < 3; k++)
		p.t[k] = 0.1 * (2 * gsl_rng_uniform(rng) - 1);
	p.rx = 1e-3 * (2 * gsl_rng_uniform(rng) - 1);
	p.ry = 1e-3 * (2 * gsl_rng_uniform(rng) - 1);
	return p;
}

/* --- Closest point ------------------------------------------------------ */

/* A sphere of radius R with centre (0, 0, R): the distance is R - |p - c|
 * (positive on the +z side, towards the centre), the foot on the ray from
 * the centre. */
static void test_closest_sphere(void **state)
{
	const double R = 37.31, a = 14.3;
	struct asph_surface *s = custom(R, 0, 2 * a);
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);

	gsl_rng_set(rng, 7);
	for (int i = 0; i < 2000; i++) {
		double r = 0.97 * a * sqrt(gsl_rng_uniform(rng)), t = 6.283 * gsl_rng_uniform(rng);
		double p[3] = { r * cos(t), r * sin(t), asph_surface_sag(s, r) + 4 * (gsl_rng_uniform(rng) - 0.5) };
		double v[3] = { p[0], p[1], p[2] - R }, len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
		struct asph_closest c;

		assert_int_equal(asph_fit_closest_point(s, p, &c), 0);
		assert_true(fabs(c.distance - (R - len)) < 1e-12);
		for (int k = 0; k < 3; k++)
			assert_true(fabs(c.foot[k] - (k == 2 ? R : 0) - R * v[k] / len) < 1e-11);
	}
	gsl_rng_free(rng);
	asph_surface_free(s);
}

/* p = foot + d n on the turning-point lens, across the steep flank (slope
 * up to ~14 at the rim) and at the vertex. */
static void test_closest_turning_point(void **state)
{
	struct asph_surface *s = lens("turning-point");
	double a = asph_surface_aperture_radius(s), rat;
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);

	assert_true(asph_surface_max_slope(s, &rat) > 10);
	gsl_rng_set(rng, 11);
	for (int i = 0; i < 3000; i++) {
		double r = i < 1000 ? a * (1 - 0.2 * gsl_rng_uniform(rng)) :
			   i < 1100 ? 1e-4 * gsl_rng_uniform(rng) : a * gsl_rng_uniform(rng);
		double t = 6.283 * gsl_rng_uniform(rng), d = 0.06 * (gsl_rng_uniform(rng) - 0.5);
		double f[3] = { r * cos(t), r * sin(t), asph_surface_sag(s, r) }, n[3], p[3];
		struct asph_closest c;

		asph_surface_normal(s, f[0], f[1], n);
		for (int k = 0; k < 3; k++)
			p[k] = f[k] + d * n[k];
		assert_int_equal(asph_fit_closest_point(s, p, &c), 0);
		assert_true(fabs(c.distance - d) < 1e-12);
		for (int k = 0; k < 3; k++) {
			assert_true(fabs(c.foot[k] - f[k]) < 1e-10);
			assert_true(fabs(c.normal[k] - n[k]) < 1e-10);
		}
		assert_true(c.inside);
	}
	/* On the axis, above and below the vertex. */
	for (int i = -2; i <= 2; i++) {
		double p[3] = { 0, 0, 0.0173 * i };
		struct asph_closest c;
		assert_int_equal(asph_fit_closest_point(s, p, &c), 0);
		assert_true(fabs(c.distance - p[2]) < 1e-15 && c.foot_radius < 1e-12);
	}
	gsl_rng_free(rng);
	asph_surface_free(s);
}

static void test_closest_outside(void **state)
{
	struct asph_surface *s = lens("strong");
	double a = asph_surface_aperture_radius(s);
	double p[3] = { 1.07 * a * cos(0.3), 1.07 * a * sin(0.3), asph_surface_sag(s, 1.07 * a) + 0.01 };
	struct asph_closest c;

	assert_int_equal(asph_fit_closest_point(s, p, &c), 0);
	assert_false(c.inside);
	assert_true(c.foot_radius > a);
	asph_surface_free(s);
}

/* --- Pose --------------------------------------------------------------- */

static void test_pose_convention(void **state)
{
	/* Rx(a) takes +y towards +z; Ry(b) takes +z towards +x; shift last. */
	struct asph_pose px = { { 0, 0, 0 }, 0.3, 0 }, py = { { 0, 0, 0 }, 0, 0.2 };
	struct asph_pose pose = { { 0.07, -0.03, 0.011 }, 7e-4, -4e-4 };
	double ey[3] = { 0, 1, 0 }, ez[3] = { 0, 0, 1 }, o[3], q[3] = { 3.1, -2.7, 0.44 }, p[3], back[3];

	asph_pose_apply(&px, ey, o);
	assert_true(fabs(o[0]) < 1e-16 && fabs(o[1] - cos(0.3)) < 1e-16 && fabs(o[2] - sin(0.3)) < 1e-16);
	asph_pose_apply(&py, ez, o);
	assert_true(fabs(o[0] - sin(0.2)) < 1e-16 && fabs(o[1]) < 1e-16 && fabs(o[2] - cos(0.2)) < 1e-16);
	/* Order: Ry(ry) Rx(rx) q + t, written out. */
	double cx = cos(pose.rx), sx = sin(pose.rx), cy = cos(pose.ry), sy = sin(pose.ry);
	double v[3] = { q[0], cx * q[1] - sx * q[2], sx * q[1] + cx * q[2] };
	asph_pose_apply(&pose, q, p);
	assert_true(fabs(p[0] - (cy * v[0] + sy * v[2] + 0.07)) < 1e-15);
	assert_true(fabs(p[1] - (v[1] - 0.03)) < 1e-15);
	assert_true(fabs(p[2] - (-sy * v[0] + cy * v[2] + 0.011)) < 1e-15);
	asph_pose_apply_inverse(&pose, p, back);
	for (int k = 0; k < 3; k++)
		assert_true(fabs(back[k] - q[k]) < 1e-15);
}

/* --- Best fit ----------------------------------------------------------- */

static void expect_pose(const struct asph_fit_result *r, const struct asph_pose *p,
			double tol_mm, double tol_rad)
{
	assert_true(fabs(r->value[ASPH_FIT_TX] - p->t[0]) < tol_mm);
	assert_true(fabs(r->value[ASPH_FIT_TY] - p->t[1]) < tol_mm);
	assert_true(fabs(r->value[ASPH_FIT_TZ] - p->t[2]) < tol_mm);
	assert_true(fabs(r->value[ASPH_FIT_RX] - p->rx) < tol_rad);
	assert_true(fabs(r->value[ASPH_FIT_RY] - p->ry) < tol_rad);
}

static void fit_points(const struct asph_surface *s, const double *xyz, size_t n,
		       const struct asph_fit_options *o, struct asph_fit_result *res)
{
	struct asph_fit *w = NULL;
	struct asph_error err;

	assert_int_equal(asph_fit_alloc(s, n, o, &w, &err), 0);
	if (asph_fit_run(w, xyz, n, res, &err) != 0)
		fail_msg("fit: %s", err.message);
	asph_fit_free(w);
}

static void test_noise_free(void **state)
{
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	size_t n = n_points();

	gsl_rng_set(rng, 20261121);
	for (size_t l = 0; l < 3; l++) {
		struct asph_surface *s = lens(lenses[l]);
		double *xyz = ring_points(s, n_points(), 1.0, &n);
		for (int rep = 0; rep < 2; rep++) {
			struct asph_synth_options so = { .pose = random_pose(rng), .seed = 1 };
			struct asph_fit_options fo = { .residual = (enum asph_fit_residual_kind)rep };
			struct asph_fit_result res;
			double *meas = malloc(3 * n * sizeof(double));

			assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
			fit_points(s, meas, n, &fo, &res);
			expect_pose(&res, &so.pose, 1e-9, 1e-9);
			assert_true(res.converged);
			assert_true(res.rms.v < 0.01);
			assert_int_equal(res.n_used, n);
			assert_int_equal(res.n_outside_aperture, 0);
			free(meas);
		}
		free(xyz);
		asph_surface_free(s);
	}
	gsl_rng_free(rng);
}

/* Form error with |m| >= 2 (orthogonal to what shifts and tilts do, see
 * docs/characterization.md) plus 2 nm noise. */
static const struct asph_synth_term form_terms[] = {
	{ 5, 37.2 }, { 9, -61.5 }, { 12, 18.3 }, { 14, 44.1 }, { 23, -12.7 },
};

/* RMS about the mean of the injected form at the nominal points. */
static double form_rms(const struct asph_surface *s, const double *xyz, size_t n,
		       double *truth)
{
	double a = asph_surface_aperture_radius(s), sum = 0, sum2 = 0;

	memset(truth, 0, 36 * sizeof(double));
	for (size_t t = 0; t < sizeof(form_terms) / sizeof(form_terms[0]); t++)
		truth[form_terms[t].j - 1] = form_terms[t].nm;
	for (size_t i = 0; i < n; i++) {
		double x = xyz[3 * i], y = xyz[3 * i + 1];
		double e = asph_zernike_series(truth, 36, hypot(x, y) / a, atan2(y, x), NULL);
		sum += e;
		sum2 += e * e;
	}
	return sqrt(sum2 / n - (sum / n) * (sum / n));
}

static void check_form_fit(int robust, double outlier_fraction)
{
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	size_t n = n_points();

	gsl_rng_set(rng, 4242 + robust);
	for (size_t l = 0; l < 3; l++) {
		struct asph_surface *s = lens(lenses[l]);
		double *xyz = ring_points(s, n_points(), 1.0, &n), truth[36];
		double *meas = malloc(3 * n * sizeof(double));
		struct asph_synth_options so = {
			.pose = random_pose(rng), .terms = form_terms,
			.n_terms = sizeof(form_terms) / sizeof(form_terms[0]),
			.noise_nm = 2.0, .seed = 99 + l,
		};
		struct asph_fit_options fo = { .robust = robust };
		struct asph_fit_result res;
		double rms = form_rms(s, xyz, n, truth);
		size_t n_out = 0;

		assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
		for (size_t i = 0; i < n; i++)
			if (gsl_rng_uniform(rng) < outlier_fraction) {
				meas[3 * i + 2] += (i % 2 ? 5e-3 : -5e-3);
				n_out++;
			}
		fit_points(s, meas, n, &fo, &res);
		assert_true(res.converged);
		assert_true(fabs(res.rms.v - rms) < 1.0);
		for (int j = 0; j < 36; j++)
			assert_true(fabs(res.zernike[j].v - truth[j]) < 1.0);
		/* The pose within 5 standard uncertainties, which are small. */
		for (int d = 0; d < 5; d++) {
			double want = d < 3 ? so.pose.t[d] : d == 3 ? so.pose.rx : so.pose.ry;
			assert_true(fabs(res.value[d] - want) < 5 * res.uncertainty[d] + 1e-12);
			assert_true(res.uncertainty[d] < 2e-3);
		}
		if (robust)
			/* A rim point pushed off may also leave the aperture. */
			assert_true(res.n_outliers + res.n_outside_aperture >= n_out);
		free(meas);
		free(xyz);
		asph_surface_free(s);
	}
	gsl_rng_free(rng);
}

static void test_form_error(void **state)
{
	check_form_fit(0, 0.0);
}

static void test_robust_outliers(void **state)
{
	check_form_fit(1, 0.01);
}

/* A part made with another R (and k): fitting them finds them. */
static void test_fit_radius_conic(void **state)
{
	struct asph_surface *nominal = custom(-51.37, -0.61, 30);
	struct asph_surface *part = custom(-51.37 * (1 + 3e-4), -0.61 + 2e-3, 30);
	size_t n = n_points() / 2;
	double *xyz = ring_points(part, n, 1.0, &n), *meas = malloc(3 * n * sizeof(double));
	struct asph_synth_options so = { .pose = { { 0.031, -0.047, 0.012 }, 3.3e-4, -6.1e-4 } };
	struct asph_fit_options fo = { .dof = ASPH_FIT_DOF_RIGID | ASPH_FIT_DOF_BIT(ASPH_FIT_R) |
					      ASPH_FIT_DOF_BIT(ASPH_FIT_K) };
	struct asph_fit_result res;

	assert_int_equal(asph_fit_synthesize(part, xyz, n, &so, meas, NULL), 0);
	fit_points(nominal, meas, n, &fo, &res);
	assert_true(res.converged);
	expect_pose(&res, &so.pose, 1e-9, 1e-9);
	assert_true(fabs(res.value[ASPH_FIT_R] - -51.37 * (1 + 3e-4)) < 1e-8);
	assert_true(fabs(res.value[ASPH_FIT_K] - (-0.61 + 2e-3)) < 1e-8);
	assert_true(res.rms.v < 0.01);
	free(xyz);
	free(meas);
	asph_surface_free(nominal);
	asph_surface_free(part);
}

/* Points past the rim are excluded and counted; the fit is unaffected. */
static void test_outside_aperture(void **state)
{
	struct asph_surface *s = lens("weak");
	size_t n = n_points();
	double *xyz = ring_points(s, n, 1.08, &n), *meas = malloc(3 * n * sizeof(double));
	double a = asph_surface_aperture_radius(s);
	struct asph_pose pose = { { -0.021, 0.013, 0.0071 }, -2.2e-4, 5.1e-4 };
	struct asph_fit_result res;
	size_t expect = 0;

	for (size_t i = 0; i < n; i++) {
		double q[3] = { xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2] };
		expect += hypot(q[0], q[1]) > a + 1e-3;
		asph_pose_apply(&pose, q, meas + 3 * i);
	}
	assert_true(expect > 50);
	fit_points(s, meas, n, NULL, &res);
	assert_int_equal(res.n_outside_aperture, expect);
	assert_int_equal(res.n_used, n - expect);
	expect_pose(&res, &pose, 1e-9, 1e-9);
	free(xyz);
	free(meas);
	asph_surface_free(s);
}

static void test_too_many_outside(void **state)
{
	struct asph_surface *s = lens("strong");
	size_t n = 400;
	double *xyz = ring_points(s, n, 1.0, &n);
	struct asph_fit *w = NULL;
	struct asph_error err;
	struct asph_fit_result res;

	/* A part three times the size of the lens: no pose brings most of its
	 * points inside the aperture. */
	for (size_t i = 0; i < n; i++) {
		xyz[3 * i] *= 3;
		xyz[3 * i + 1] *= 3;
		xyz[3 * i + 2] = asph_surface_sag(s, hypot(xyz[3 * i], xyz[3 * i + 1]));
	}
	assert_int_equal(asph_fit_alloc(s, n, NULL, &w, &err), 0);
	assert_int_equal(asph_fit_run(w, xyz, n, &res, &err), -EDOM);
	assert_non_null(strstr(err.message, "aperture"));
	asph_fit_free(w);
	free(xyz);
	asph_surface_free(s);
}

static void test_bad_input(void **state)
{
	struct asph_surface *s = lens("weak");
	size_t n = 50;
	double *xyz = ring_points(s, n, 1.0, &n);
	struct asph_fit *w = NULL;
	struct asph_error err;
	unsigned mask;

	assert_int_equal(asph_fit_alloc(s, n, NULL, &w, &err), 0);
	assert_int_equal(asph_fit_init(w, xyz, 0, &err), -EINVAL);
	assert_int_equal(asph_fit_init(w, xyz, 5, &err), -EINVAL);   /* 5 points, 5 DOF */
	assert_non_null(strstr(err.message, "degrees of freedom"));
	assert_int_equal(asph_fit_init(w, xyz, n + 1, &err), -EINVAL);
	xyz[3 * 17 + 1] = NAN;
	assert_int_equal(asph_fit_init(w, xyz, n, &err), -EINVAL);
	assert_non_null(strstr(err.message, "point 18"));
	for (size_t i = 0; i < n; i++) {      /* all at one place */
		xyz[3 * i] = 0.3;
		xyz[3 * i + 1] = -0.2;
		xyz[3 * i + 2] = 0.01 * i;
	}
	assert_int_equal(asph_fit_init(w, xyz, n, &err), -EINVAL);
	assert_non_null(strstr(err.message, "one place"));
	assert_int_equal(asph_fit_iterate(w, &err), -EINVAL);
	for (size_t i = 0; i < n; i++) {      /* all on one line: a line profile */
		xyz[3 * i] = 0.3 * i - 7;
		xyz[3 * i + 1] = 0.5 * xyz[3 * i] + 0.2;
		xyz[3 * i + 2] = asph_surface_sag(s, hypot(xyz[3 * i], xyz[3 * i + 1]));
	}
	assert_int_equal(asph_fit_init(w, xyz, n, &err), 0);
	/* which cannot tell ty and rx apart when they are asked for */
	struct asph_fit *rigid = NULL;
	struct asph_fit_options ro = { .dof = ASPH_FIT_DOF_RIGID };
	assert_int_equal(asph_fit_alloc(s, n, &ro, &rigid, &err), 0);
	assert_int_equal(asph_fit_init(rigid, xyz, n, &err), -EINVAL);
	assert_non_null(strstr(err.message, "line profile"));
	assert_non_null(strstr(err.message, "not ty, rx"));
	asph_fit_free(rigid);
	/* All at one radius: a decentre and a tilt do the same there. */
	for (size_t i = 0; i < n; i++) {
		double t = 0.37 + 2 * M_PI * i / n, r = 11.3;
		xyz[3 * i] = r * cos(t);
		xyz[3 * i + 1] = r * sin(t);
		xyz[3 * i + 2] = asph_surface_sag(s, r);
	}
	assert_int_equal(asph_fit_init(w, xyz, n, &err), -EDOM);
	assert_non_null(strstr(err.message, "tell the degrees of freedom apart"));
	asph_fit_free(w);

	struct asph_fit_options bad = { .n_zernike = 500 };
	assert_int_equal(asph_fit_alloc(s, n, &bad, &w, &err), -EINVAL);
	assert_int_equal(asph_fit_dof_parse("tx,ty,tz,rx,ry,R,k", &mask, &err), 0);
	assert_int_equal(mask, 0x7f);
	assert_int_equal(asph_fit_dof_parse("tx,tx", &mask, &err), -EINVAL);
	assert_int_equal(asph_fit_dof_parse("tx,rw", &mask, &err), -EINVAL);
	assert_int_equal(asph_fit_dof_parse("tx,ty,tz,rx,ry,rz", &mask, &err), 0);
	assert_int_equal(mask, ASPH_FIT_DOF_RIGID6);
	assert_int_equal(asph_fit_dof_parse("", &mask, &err), -EINVAL);
	free(xyz);
	asph_surface_free(s);
}

/* Too few points for 36 Zernike terms: the fit stands without them. */
static void test_few_points(void **state)
{
	struct asph_surface *s = lens("strong");
	size_t n = 0;
	double *xyz = ring_points(s, 25, 1.0, &n), *meas = malloc(3 * n * sizeof(double));
	struct asph_synth_options so = { .pose = { { -0.013, 0.029, 0.0061 }, -1.7e-4, 4.4e-4 } };
	struct asph_fit_result res;

	assert_true(n > 6 && n < 36);
	assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
	fit_points(s, meas, n, NULL, &res);
	expect_pose(&res, &so.pose, 1e-9, 1e-9);
	assert_int_equal(res.n_zernike, 0);
	assert_true(isnan(res.pvr.v) && isnan(res.slope_rms.v));
	assert_true(res.rms.v < 0.01);
	free(xyz);
	free(meas);
	asph_surface_free(s);
}

/* init / iterate / test, with progress, reaches the one-call result. */
static void test_stepwise(void **state)
{
	struct asph_surface *s = lens("strong");
	size_t n = 800;
	double *xyz = ring_points(s, n, 1.0, &n), *meas = malloc(3 * n * sizeof(double));
	struct asph_synth_options so = { .pose = { { 0.051, 0.022, -0.034 }, 8.1e-4, 2.9e-4 } };
	struct asph_fit *w = NULL;
	struct asph_fit_progress pr;
	struct asph_fit_result res;
	int steps = 0;

	assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
	assert_int_equal(asph_fit_alloc(s, n, NULL, &w, NULL), 0);
	assert_int_equal(asph_fit_init(w, meas, n, NULL), 0);
	while (!asph_fit_test(w)) {
		assert_int_equal(asph_fit_iterate(w, NULL), 0);
		asph_fit_get_progress(w, &pr);
		assert_int_equal(pr.total_iterations, ++steps);
	}
	assert_true(pr.rms_mm < 1e-11);
	assert_int_equal(asph_fit_get_result(w, &res, NULL), 0);
	assert_int_equal(res.iterations, steps);
	expect_pose(&res, &so.pose, 1e-9, 1e-9);
	assert_true(asph_fit_residuals(w) && asph_fit_weights(w)[5] == 1.0);
	/* the solver released, the residuals stay; a run makes it again */
	double r5 = asph_fit_residuals(w)[5];
	struct asph_fit_result again;
	asph_fit_release_solver(w);
	asph_fit_release_solver(w);
	assert_true(asph_fit_residuals(w)[5] == r5);
	asph_fit_get_progress(w, &pr);
	assert_true(pr.rms_mm == 0);
	assert_int_equal(asph_fit_run(w, meas, n, &again, NULL), 0);
	expect_pose(&again, &so.pose, 1e-9, 1e-9);
	asph_fit_free(w);
	free(xyz);
	free(meas);
	asph_surface_free(s);
}

/* release_solver: the solver goes inside the result, which is the same
 * bit for bit; a second result is refused, a run makes the solver again. */
static void test_release_solver_option(void **state)
{
	struct asph_surface *s = lens("strong");
	size_t n = 800;
	double *xyz = ring_points(s, n, 1.0, &n), *meas = malloc(3 * n * sizeof(double));
	struct asph_synth_options so = { .pose = { { 0.051, 0.022, -0.034 }, 8.1e-4, 2.9e-4 } };
	struct asph_fit_options once = { .release_solver = 1 };
	struct asph_fit *kept = NULL, *w = NULL;
	struct asph_fit_result ref, res, again;
	struct asph_fit_progress pr;
	struct asph_error err = { 0 };

	assert_int_equal(asph_fit_synthesize(s, xyz, n, &so, meas, NULL), 0);
	assert_int_equal(asph_fit_alloc(s, n, NULL, &kept, NULL), 0);
	assert_int_equal(asph_fit_alloc(s, n, &once, &w, NULL), 0);
	assert_int_equal(asph_fit_run(kept, meas, n, &ref, NULL), 0);
	assert_int_equal(asph_fit_run(w, meas, n, &res, NULL), 0);
	assert_memory_equal(&res, &ref, sizeof(res));
	assert_memory_equal(asph_fit_residuals(w), asph_fit_residuals(kept), n * sizeof(double));
	asph_fit_get_progress(w, &pr);
	assert_true(pr.rms_mm == 0);
	assert_int_equal(asph_fit_get_result(w, &again, &err), -EINVAL);
	assert_non_null(strstr(err.message, "released"));
	assert_int_equal(asph_fit_run(w, meas, n, &again, NULL), 0);
	assert_memory_equal(&again, &ref, sizeof(again));
	asph_fit_free(kept);
	asph_fit_free(w);
	free(xyz);
	free(meas);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_closest_sphere),
		cmocka_unit_test(test_closest_turning_point),
		cmocka_unit_test(test_closest_outside),
		cmocka_unit_test(test_pose_convention),
		cmocka_unit_test(test_noise_free),
		cmocka_unit_test(test_form_error),
		cmocka_unit_test(test_robust_outliers),
		cmocka_unit_test(test_fit_radius_conic),
		cmocka_unit_test(test_outside_aperture),
		cmocka_unit_test(test_too_many_outside),
		cmocka_unit_test(test_bad_input),
		cmocka_unit_test(test_stepwise),
		cmocka_unit_test(test_release_solver_option),
		cmocka_unit_test(test_few_points),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
