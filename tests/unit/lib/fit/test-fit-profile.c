/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Line profiles and the curvature (docs/characterization.md, "Line
 * profiles", "Radius and curvature"): a profile's decentre, tilt, R and k
 * recovered, a cross and a star of four fitted together, the slope along
 * a trace against its closed form, flats and near-flats with R free, and
 * the refusals.
 *
 * The measured points are made as a profilometer measures: machine x-y on
 * straight traces, z where the posed part is there (posed_z()), noise
 * along z. Tolerances:
 * - noise-free: the fit stops when a step is below xtol (|x| + 1e-3)
 *   with xtol = 1e-9 and converges quadratically, so the error is below
 *   that step: 1e-9 mm and rad for the pose, 1e-8 relative for R and k
 *   (their steps scale with |c| + 1e-3 and |k| + 1e-3);
 * - with noise: the covariance sigma^2 (J^T J)^-1 of the least-squares
 *   problem, J by central differences of posed_z() here (independent of
 *   the fit's analytic Jacobian), or the closed form of the linear model
 *   of a near-flat; each value within 4.5 of its standard deviations
 *   (two-sided probability 7e-6 each); the fit's own uncertainty is that
 *   covariance with the fit's estimate of sigma (to 1e-3: the
 *   linearisation, the difference steps, the tilts), and that estimate
 *   within 10 % of sigma (from n - p residuals its relative standard
 *   deviation is 1 / sqrt(2 (n - p)), 2.5 % for 800 points).
 */
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
#include <gsl/gsl_linalg.h>
#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>
#include <jansson.h>

#include "asph/fit.h"
#include "asph/surface.h"
#include "custom-surface.h"

#define DOF(d) ASPH_FIT_DOF_BIT(ASPH_FIT_##d)
#define DEG (M_PI / 180)

/* z where the part of surface s, lying with pose, is at machine (x, y):
 * Newton on g(z) = q_z - S(q_x, q_y), q the point in the part frame. */
static double posed_z(const struct asph_surface *s, const struct asph_pose *pose, double x,
		      double y)
{
	const struct asph_pose turn = { { 0, 0, 0 }, pose->rx, pose->ry, pose->rz };
	double ez[3] = { 0, 0, 1 }, dq[3], z = pose->t[2] + asph_surface_sag(s, hypot(x, y));

	asph_pose_apply_inverse(&turn, ez, dq);
	for (int it = 0; it < 60; it++) {
		double p[3] = { x, y, z }, q[3], g[3];
		asph_pose_apply_inverse(pose, p, q);
		asph_surface_sag_grad_xy(s, q[0], q[1], g);
		double step = (q[2] - g[0]) / (dq[2] - g[1] * dq[0] - g[2] * dq[1]);
		z -= step;
		if (fabs(step) < 1e-15 * (1 + fabs(z)))
			break;
	}
	return z;
}

/* A trace: n points at positions s in [-half, half] along azimuth phi
 * at offset o across it (machine x-y), scanned forward or backward. */
struct trace {
	double phi, offset, half;
	size_t n;
	int backward;
};

static void trace_xy(const struct trace *t, size_t i, double xy[2])
{
	double f = (double)i / (double)(t->n - 1), s = t->half * (2 * (t->backward ? 1 - f : f) - 1);

	xy[0] = s * cos(t->phi) - t->offset * sin(t->phi);
	xy[1] = s * sin(t->phi) + t->offset * cos(t->phi);
}

/* The points of traces measured on the part s_true lying with the machine
 * pose, z noise sigma_nm (0: none). Returns 3 n values. */
static double *measure(const struct asph_surface *s_true, const struct asph_pose *pose,
		       const struct trace *tr, int n_traces, double sigma_nm, unsigned long seed,
		       size_t *n_out)
{
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	size_t n = 0, k = 0;
	double *xyz;

	gsl_rng_set(rng, seed);
	for (int t = 0; t < n_traces; t++)
		n += tr[t].n;
	xyz = malloc(3 * n * sizeof(double));
	for (int t = 0; t < n_traces; t++)
		for (size_t i = 0; i < tr[t].n; i++, k++) {
			trace_xy(&tr[t], i, xyz + 3 * k);
			xyz[3 * k + 2] = posed_z(s_true, pose, xyz[3 * k], xyz[3 * k + 1]) +
					 (sigma_nm > 0 ? gsl_ran_gaussian_ziggurat(rng, sigma_nm * 1e-6) : 0);
		}
	gsl_rng_free(rng);
	*n_out = n;
	return xyz;
}

/* A pose given in a trace's frame (x along azimuth phi) in the machine's:
 * the pose the profile fit reports, as the measurement made it. */
static struct asph_pose machine_pose(double phi, double d, double tz, double beta)
{
	/* p = Rz(phi) (Ry(beta) q' + (d, 0, tz)); the axis Rz Ry e_z */
	double ax = cos(phi) * sin(beta), ay = sin(phi) * sin(beta), az = cos(beta);

	return (struct asph_pose){ { d * cos(phi), d * sin(phi), tz }, -asin(ay), atan2(ax, az), 0 };
}

static int fit(const struct asph_surface *s, const double *xyz, size_t n,
	       const struct asph_fit_options *o, struct asph_fit_result *res,
	       struct asph_error *err)
{
	struct asph_fit *w = NULL;
	int r = asph_fit_alloc(s, n, o, &w, err);

	if (r == 0)
		r = asph_fit_run(w, xyz, n, res, err);
	asph_fit_free(w);
	return r;
}

static void expect_near(double got, double want, double tol, const char *what)
{
	if (!(fabs(got - want) <= tol))
		fail_msg("%s: %.15g, want %.15g (off by %.3g, tolerance %.3g)", what, got, want,
			 got - want, tol);
}

/* --- One profile ---------------------------------------------------- */

static const double R0 = 41.7, K0 = -0.63, D0 = 30;

/* A profile along azimuth phi at offset o of a part with R and k off the
 * nominal, decentred along the trace, shifted in z and tilted about the
 * axis across it, noise-free: tx, tz, ry (in the trace's frame), R and k
 * come back to the step test's bound. */
static void one_profile(double phi, double offset)
{
	const double Rt = R0 * (1 - 2.3e-4), kt = K0 + 0.0137, d = 0.0371, tz = -0.0123,
		     beta = 6.1e-4;
	struct asph_surface *nominal = custom(R0, K0, D0), *truth = custom(Rt, kt, D0);
	struct asph_pose pose = machine_pose(phi, d, tz, beta);
	struct trace tr = { phi, offset, 0.97 * D0 / 2 * sqrt(1 - pow(offset / (D0 / 2), 2)), 801, 0 };
	struct asph_fit_options o = { .dof = DOF(TX) | DOF(TZ) | DOF(RY) | DOF(R) | DOF(K) };
	struct asph_fit_result res;
	struct asph_error err;
	size_t n;
	double *xyz = measure(truth, &pose, &tr, 1, 0, 1, &n);

	asph_error_clear(&err);
	if (fit(nominal, xyz, n, &o, &res, &err) != 0)
		fail_msg("fit: %s", err.message);
	assert_true(res.converged);
	assert_true(res.profile);
	assert_int_equal(res.n_profiles, 1);
	assert_int_equal(res.dof, o.dof);
	expect_near(res.profiles[0].azimuth, phi, 1e-12, "azimuth");
	expect_near(res.profiles[0].offset_mm, offset, 1e-12, "offset");
	expect_near(res.value[ASPH_FIT_TX], d, 1e-9, "tx (along the trace)");
	expect_near(res.value[ASPH_FIT_TZ], tz, 1e-9, "tz");
	expect_near(res.value[ASPH_FIT_RY], beta, 1e-9, "ry (about the axis across)");
	expect_near(res.value[ASPH_FIT_R], Rt, 1e-8 * Rt, "R");
	expect_near(res.curvature, 1 / Rt, 1e-8 / Rt, "c");
	expect_near(res.value[ASPH_FIT_K], kt, 1e-8, "k");
	/* the pose in the machine frame */
	expect_near(res.pose.t[0], pose.t[0], 1e-9, "machine tx");
	expect_near(res.pose.t[1], pose.t[1], 1e-9, "machine ty");
	expect_near(res.pose.rx, pose.rx, 1e-9, "machine rx");
	expect_near(res.pose.ry, pose.ry, 1e-9, "machine ry");
	assert_true(res.rms.v < 1e-3);
	/* a single profile: A and B along it; C and RMSa need more azimuths */
	assert_true(res.form_valid);
	assert_true(isfinite(res.form.A.v) && isfinite(res.form.B.v) && isfinite(res.form.rms_i.v));
	assert_true(isnan(res.form.C.v) && isnan(res.form.rms_a.v));
	assert_int_equal(res.n_zernike, 0);
	assert_true(isnan(res.pvr.v));
	free(xyz);
	asph_surface_free(nominal);
	asph_surface_free(truth);
}

static void test_profile_recovers(void **state)
{
	(void)state;
	one_profile(0, 0);                      /* along x through the apex */
	one_profile(37 * DEG, 0.8);             /* oblique, off the apex */
	one_profile(-90 * DEG + 1e-9, 0);       /* along y: azimuth 90 deg */
}

/* The model of the noisy test: z at the points of tr for (d, tz, beta, c, k). */
static void model_z(const struct trace *tr, const double *theta, double *z)
{
	struct asph_surface *s = custom(1 / theta[3], theta[4], D0);
	struct asph_pose pose = machine_pose(tr->phi, theta[0], theta[1], theta[2]);

	for (size_t i = 0; i < tr->n; i++) {
		double xy[2];
		trace_xy(tr, i, xy);
		z[i] = posed_z(s, &pose, xy[0], xy[1]);
	}
	asph_surface_free(s);
}

/* sigma sqrt(diag (J^T J)^-1), J by central differences of model_z(). */
static void covariance_u(const struct trace *tr, const double *theta, double sigma, double *u)
{
	const double h[5] = { 1e-4, 1e-4, 1e-5, 1e-7, 1e-4 };
	double *J = malloc(5 * tr->n * sizeof(double)), *zp = malloc(tr->n * sizeof(double));
	double *zm = malloc(tr->n * sizeof(double)), A[25] = { 0 };
	gsl_matrix_view M = gsl_matrix_view_array(A, 5, 5);

	for (int j = 0; j < 5; j++) {
		double tp[5], tm[5];
		memcpy(tp, theta, sizeof(tp));
		memcpy(tm, theta, sizeof(tm));
		tp[j] += h[j];
		tm[j] -= h[j];
		model_z(tr, tp, zp);
		model_z(tr, tm, zm);
		for (size_t i = 0; i < tr->n; i++)
			J[i * 5 + (size_t)j] = (zp[i] - zm[i]) / (2 * h[j]);
	}
	for (size_t i = 0; i < tr->n; i++)
		for (int a = 0; a < 5; a++)
			for (int b = 0; b < 5; b++)
				A[a * 5 + b] += J[i * 5 + (size_t)a] * J[i * 5 + (size_t)b];
	assert_int_equal(gsl_linalg_cholesky_decomp1(&M.matrix), 0);
	assert_int_equal(gsl_linalg_cholesky_invert(&M.matrix), 0);
	for (int j = 0; j < 5; j++)
		u[j] = sigma * sqrt(A[j * 5 + j]);
	free(J);
	free(zp);
	free(zm);
}

/* With 3 nm of noise along z (sag residuals, the model's): each value
 * within 4.5 standard deviations of the least-squares covariance, which
 * the fit's uncertainties are with its estimate of sigma. */
static void test_profile_noise(void **state)
{
	const double sigma = 3, theta[5] = { 0.0371, -0.0123, 6.1e-4, 1 / (R0 * (1 - 2.3e-4)),
					     K0 + 0.0137 };
	const int dof[5] = { ASPH_FIT_TX, ASPH_FIT_TZ, ASPH_FIT_RY, ASPH_FIT_R, ASPH_FIT_K };
	const char *names[5] = { "tx", "tz", "ry", "c", "k" };
	struct asph_surface *nominal = custom(R0, K0, D0), *truth = custom(1 / theta[3], theta[4], D0);
	struct asph_pose pose = machine_pose(0.4, theta[0], theta[1], theta[2]);
	struct trace tr = { 0.4, 0, 0.97 * D0 / 2, 801, 1 };
	struct asph_fit_options o = { .dof = DOF(TX) | DOF(TZ) | DOF(RY) | DOF(R) | DOF(K),
				      .residual = ASPH_FIT_RESIDUAL_SAG };
	struct asph_fit_result res;
	struct asph_error err;
	double u[5];
	size_t n;
	double *xyz = measure(truth, &pose, &tr, 1, sigma, 11, &n);

	(void)state;
	covariance_u(&tr, theta, sigma * 1e-6, u);
	assert_int_equal(fit(nominal, xyz, n, &o, &res, &err), 0);
	assert_true(res.converged && res.profile);
	for (int j = 0; j < 5; j++) {
		double got = j == 3 ? res.curvature : res.value[dof[j]];
		double u_fit = j == 3 ? res.u_curvature : res.uncertainty[dof[j]];
		expect_near(got, theta[j], 4.5 * u[j], names[j]);
		/* the fit's covariance is this one with its estimate of sigma */
		expect_near(u_fit / (u[j] * res.sigma_mm * 1e6 / sigma), 1, 1e-3, names[j]);
	}
	expect_near(res.sigma_mm * 1e6 / sigma, 1, 0.1, "sigma");
	/* R = 1/c, u(R) = u(c) / c^2 */
	expect_near(res.value[ASPH_FIT_R], 1 / res.curvature, 1e-12, "R = 1/c");
	expect_near(res.uncertainty[ASPH_FIT_R], res.u_curvature / pow(res.curvature, 2),
		    1e-12 * res.uncertainty[ASPH_FIT_R], "u(R)");
	/* the noise, on the trace and its slope (no form error) */
	expect_near(res.profiles[0].rms.v / sigma, 1, 0.1, "RMS along the trace");
	free(xyz);
	asph_surface_free(nominal);
	asph_surface_free(truth);
}

/* --- Several profiles ------------------------------------------------ */

/* n_traces profiles through the apex at azimuths phi0 + k 180 / n, scanned
 * back and forth, of a part with R and k off the nominal lying with a full
 * five-DOF pose: fitted together in the machine frame. */
static void star(int n_traces, double phi0)
{
	const double Rt = R0 * (1 + 1.7e-4), kt = K0 - 0.0091;
	struct asph_surface *nominal = custom(R0, K0, D0), *truth = custom(Rt, kt, D0);
	struct asph_pose pose = { { 0.021, -0.034, 0.011 }, 4.1e-4, -2.7e-4, 0 };
	struct trace tr[8];
	struct asph_fit_options o = { .dof = ASPH_FIT_DOF_RIGID | DOF(R) | DOF(K) };
	struct asph_fit_result res;
	struct asph_error err;
	size_t n;

	for (int k = 0; k < n_traces; k++)
		tr[k] = (struct trace){ phi0 + k * M_PI / n_traces, 0, 0.95 * D0 / 2, 301, k % 2 };
	double *xyz = measure(truth, &pose, tr, n_traces, 0, 1, &n);
	asph_error_clear(&err);
	if (fit(nominal, xyz, n, &o, &res, &err) != 0)
		fail_msg("%d profiles: %s", n_traces, err.message);
	assert_true(res.converged);
	assert_true(res.profile);
	assert_int_equal(res.n_profiles, (size_t)n_traces);
	for (int k = 0; k < n_traces; k++) {
		double want = remainder(tr[k].phi, M_PI);
		expect_near(res.profiles[k].azimuth, want, 1e-12, "azimuth");
		assert_int_equal(res.profiles[k].n_points, 301);
		assert_int_equal(res.profiles[k].n_used, 301);
	}
	expect_near(res.value[ASPH_FIT_TX], pose.t[0], 1e-9, "tx");
	expect_near(res.value[ASPH_FIT_TY], pose.t[1], 1e-9, "ty");
	expect_near(res.value[ASPH_FIT_TZ], pose.t[2], 1e-9, "tz");
	expect_near(res.value[ASPH_FIT_RX], pose.rx, 1e-9, "rx");
	expect_near(res.value[ASPH_FIT_RY], pose.ry, 1e-9, "ry");
	expect_near(res.value[ASPH_FIT_R], Rt, 1e-8 * Rt, "R");
	expect_near(res.value[ASPH_FIT_K], kt, 1e-8, "k");
	/* several azimuths: every form quantity */
	assert_true(res.form_valid && isfinite(res.form.C.v) && isfinite(res.form.rms_a.v));
	free(xyz);
	asph_surface_free(nominal);
	asph_surface_free(truth);
}

static void test_cross_and_star(void **state)
{
	(void)state;
	star(2, 0);             /* a cross along x and y */
	star(2, 15 * DEG);      /* a turned cross */
	star(4, 10 * DEG);      /* a star of four */
}

/* Points on parallel lines are a raster, not profiles; so are rings. */
static void test_not_profiles(void **state)
{
	struct asph_surface *s = custom(R0, K0, D0);
	struct asph_pose pose = { { 0.003, 0, 0 }, 0, 0, 0 };
	struct trace tr[5];
	struct asph_fit_result res;
	struct asph_error err;
	size_t n;

	(void)state;
	for (int k = 0; k < 5; k++)
		tr[k] = (struct trace){ 0, -10 + 5.0 * k, 10, 41, k % 2 };
	double *xyz = measure(s, &pose, tr, 5, 0, 1, &n);
	assert_int_equal(fit(s, xyz, n, NULL, &res, &err), 0);
	assert_false(res.profile);
	assert_int_equal(res.n_profiles, 0);
	free(xyz);
	asph_surface_free(s);
}

/* --- The slope along a trace ----------------------------------------- */

/*
 * A ripple F(s) = A sin(2 pi s / P) along one profile: its slope over L is
 * (F(p + L/2) - F(p - L/2)) / L = (2 A / L) sin(pi L / P) cos(2 pi p / P),
 * whose RMS over whole periods is sqrt(2) (A / L) sin(pi L / P) and whose
 * maximum sqrt(2) times that. Within 1 %: the positions span 30.1
 * periods, not whole ones (the mean of cos^2 over them is off 1/2 by at
 * most 1 / (4 pi 30) = 0.3 %); the rigid DOF and the trace's straight
 * line take up the ripple's projection on smooth functions, whose slope
 * is smaller still; the linear interpolation between points, 48 of them
 * a period, takes 1 - sinc(1/48)^2 = 0.05 % off the amplitude.
 */
static void test_slope_along_trace(void **state)
{
	const double A = 25, P = 0.93, L = 0.4;
	struct asph_surface *s = custom(R0, K0, D0);
	struct asph_pose pose = { { 0 }, 0, 0, 0 };
	struct trace tr = { 0, 0, 14, 1201, 0 };
	struct asph_fit_options o = { .residual = ASPH_FIT_RESIDUAL_SAG, .slope_length_mm = L };
	struct asph_fit_result res;
	struct asph_error err;
	size_t n;
	double *xyz = measure(s, &pose, &tr, 1, 0, 1, &n);
	double want = sqrt(2) * A / L * sin(M_PI * L / P);

	(void)state;
	for (size_t i = 0; i < n; i++)
		xyz[3 * i + 2] += A * 1e-6 * sin(2 * M_PI * xyz[3 * i] / P);
	assert_int_equal(fit(s, xyz, n, &o, &res, &err), 0);
	assert_true(res.slope_valid);
	expect_near(res.slope.rms.v / want, 1, 0.01, "slope RMS along the trace");
	expect_near(res.slope.max.v / (want * sqrt(2)), 1, 0.01, "slope max");
	expect_near(res.profiles[0].slope_rms.v, res.slope.rms.v, 1e-12, "the trace's");
	assert_true(isnan(res.slope.rms_radial.v) && isnan(res.slope.rms_azimuthal.v));
	free(xyz);
	asph_surface_free(s);
}

/* --- Flats and near-flats ------------------------------------------- */

/* Points over a disk of radius a: rings of equal area, evenly spaced. */
static double *disk_points(const struct asph_surface *s, const struct asph_pose *pose, double a,
			   size_t rings, double sigma_nm, unsigned long seed, size_t *n_out)
{
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	size_t total = 1, k = 1;
	double *xyz;

	gsl_rng_set(rng, seed);
	for (size_t j = 1; j <= rings; j++)
		total += 6 * j;
	xyz = malloc(3 * total * sizeof(double));
	xyz[0] = xyz[1] = 0;
	for (size_t j = 1; j <= rings; j++)
		for (size_t i = 0; i < 6 * j; i++, k++) {
			double r = a * (double)j / (double)rings, t = 0.31 * j + 2 * M_PI * i / (6.0 * j);
			xyz[3 * k] = r * cos(t);
			xyz[3 * k + 1] = r * sin(t);
		}
	for (size_t i = 0; i < total; i++)
		xyz[3 * i + 2] = posed_z(s, pose, xyz[3 * i], xyz[3 * i + 1]) +
				 gsl_ran_gaussian_ziggurat(rng, sigma_nm * 1e-6);
	gsl_rng_free(rng);
	*n_out = total;
	return xyz;
}

/* u(c) of the linear model of a sag residual on a near-flat: columns 1,
 * y, x and d conic / dc = r^2 / (S (1 + S)) at the nominal c, over the
 * points, times sigma: sigma sqrt((M^T M)^-1_cc). */
static double closed_form_uc(const double *xyz, size_t n, double c, double sigma)
{
	double A[16] = { 0 };
	gsl_matrix_view M = gsl_matrix_view_array(A, 4, 4);

	for (size_t i = 0; i < n; i++) {
		double x = xyz[3 * i], y = xyz[3 * i + 1], r2 = x * x + y * y;
		double S = sqrt(1 - c * c * r2), row[4] = { 1, y, x, r2 / (S * (1 + S)) };
		for (int a = 0; a < 4; a++)
			for (int b = 0; b < 4; b++)
				A[a * 4 + b] += row[a] * row[b];
	}
	assert_int_equal(gsl_linalg_cholesky_decomp1(&M.matrix), 0);
	assert_int_equal(gsl_linalg_cholesky_invert(&M.matrix), 0);
	return sigma * sqrt(A[15]);
}

/* A 50 mm flat, 2 nm of noise, R free: the fit converges in a few
 * steps, c is within its noise of 0, and R is null, from a nominal plane
 * and from a nominal flat given as R = 1e8 mm (where a fit of R itself
 * ran into its iteration limit). */
static void test_flat(void **state)
{
	const double nominal[2] = { INFINITY, 1e8 };
	struct asph_pose pose = { { 0, 0, 0.0021 }, 1.3e-4, -0.7e-4, 0 };
	struct asph_fit_options o = { .dof = DOF(TZ) | DOF(RX) | DOF(RY) | DOF(R),
				      .residual = ASPH_FIT_RESIDUAL_SAG };
	struct asph_surface *flat = custom(INFINITY, 0, 50);
	struct asph_fit_result res;
	struct asph_error err;
	char *text = NULL;
	size_t n;
	double *xyz = disk_points(flat, &pose, 25, 30, 2, 5, &n);

	(void)state;
	for (int i = 0; i < 2; i++) {
		struct asph_surface *s = custom(nominal[i], 0, 50);
		double c0 = isinf(nominal[i]) ? 0 : 1 / nominal[i];
		asph_error_clear(&err);
		if (fit(s, xyz, n, &o, &res, &err) != 0)
			fail_msg("flat %g: %s", nominal[i], err.message);
		assert_true(res.converged);
		assert_true(res.iterations < 20);
		assert_false(res.profile);
		expect_near(res.u_curvature / closed_form_uc(xyz, n, c0, res.sigma_mm), 1, 1e-3,
			    "u(c) against the closed form");
		/* c = 0 within U(c) (here 0.4 u: this seed's draw) */
		assert_true(fabs(res.curvature) <= 2 * res.u_curvature);
		assert_true(isnan(res.value[ASPH_FIT_R]) && isnan(res.uncertainty[ASPH_FIT_R]));
		assert_true(isnan(res.R_deviation_mm));
		assert_int_equal(asph_fit_result_to_json(&res, "flat", 0, &text), 0);
		json_t *root = json_loads(text, 0, NULL);
		assert_true(json_is_null(json_object_get(json_object_get(root, "dof"), "R")));
		assert_true(json_is_real(json_object_get(json_object_get(root, "dof"), "c")));
		assert_true(json_is_real(json_object_get(json_object_get(root, "uncertainty"), "c")));
		assert_true(json_is_null(json_object_get(json_object_get(root, "radius"), "R_mm")));
		assert_true(json_is_real(json_object_get(json_object_get(root, "uncertainty_k2"),
							 "c_per_mm")));
		assert_true(json_is_false(json_object_get(root, "profile")));
		json_decref(root);
		free(text);
		asph_surface_free(s);
	}
	free(xyz);
	asph_surface_free(flat);
}

/* A near-flat, R = 50 m, measured as 49.8 m: c and R both reported, R
 * within 4.5 u(R) with u(R) = u(c) / c^2, u(c) the closed form's. */
static void test_near_flat(void **state)
{
	const double Rn = 50000, Rt = 49800;
	struct asph_surface *s = custom(Rn, 0, 50), *truth = custom(Rt, 0, 50);
	struct asph_pose pose = { { 0, 0, -0.0007 }, -0.4e-4, 0.9e-4, 0 };
	struct asph_fit_options o = { .dof = DOF(TZ) | DOF(RX) | DOF(RY) | DOF(R),
				      .residual = ASPH_FIT_RESIDUAL_SAG };
	struct asph_fit_result res;
	struct asph_error err;
	size_t n;
	double *xyz = disk_points(truth, &pose, 25, 30, 2, 9, &n);

	(void)state;
	assert_int_equal(fit(s, xyz, n, &o, &res, &err), 0);
	assert_true(res.converged);
	expect_near(res.u_curvature / closed_form_uc(xyz, n, 1 / Rn, res.sigma_mm), 1, 1e-3,
		    "u(c) against the closed form");
	assert_true(fabs(res.curvature) > 2 * res.u_curvature);
	expect_near(res.value[ASPH_FIT_R], Rt, 4.5 * res.uncertainty[ASPH_FIT_R], "R");
	expect_near(res.curvature, 1 / Rt, 4.5 * res.u_curvature, "c");
	expect_near(res.uncertainty[ASPH_FIT_R], res.u_curvature * res.value[ASPH_FIT_R] *
		    res.value[ASPH_FIT_R], 1e-9 * res.uncertainty[ASPH_FIT_R], "u(R) = u(c) R^2");
	expect_near(res.R_deviation_mm, res.value[ASPH_FIT_R] - Rn, 1e-9, "R - R nominal");
	expect_near(res.uncertainty_k2.R_mm, 2 * res.uncertainty[ASPH_FIT_R], 1e-12, "U(R)");
	expect_near(res.uncertainty_k2.c_per_mm, 2 * res.u_curvature, 1e-20, "U(c)");
	free(xyz);
	asph_surface_free(s);
	asph_surface_free(truth);
}

/* --- Refusals --------------------------------------------------------- */

static void test_bad_profiles(void **state)
{
	struct asph_surface *s = custom(R0, K0, D0), *plane = custom(INFINITY, 0, 20);
	struct asph_pose pose = { { 0 }, 0, 0, 0 };
	struct trace tr = { 0.2, 0, 10, 3, 0 };
	struct asph_fit_options o = { .dof = DOF(TX) | DOF(TZ) | DOF(RY) | DOF(R) };
	struct asph_fit *w = NULL;
	struct asph_fit_result res;
	struct asph_error err;
	unsigned mask;
	size_t n;
	double *few = measure(s, &pose, &tr, 1, 0, 1, &n);

	(void)state;
	/* three points for four DOF */
	assert_int_equal(fit(s, few, n, &o, &res, &err), -EINVAL);
	assert_non_null(strstr(err.message, "line profile of 3 points"));
	assert_non_null(strstr(err.message, "tx, tz, ry, R"));
	/* DOF a profile cannot tell apart */
	tr.n = 101;
	double *xyz = measure(s, &pose, &tr, 1, 0, 1, &n);
	static const char *const asked[] = { "tx,ty,tz", "tz,rx", "tx,tz,ry,R,k,ty" };
	for (size_t i = 0; i < 3; i++) {
		struct asph_fit_options bad = { 0 };
		assert_int_equal(asph_fit_dof_parse(asked[i], &bad.dof, &err), 0);
		assert_int_equal(fit(s, xyz, n, &bad, &res, &err), -EINVAL);
		assert_non_null(strstr(err.message, "one line profile"));
		assert_non_null(strstr(err.message, "--dof tx,tz,ry"));
	}
	/* the default is the profile's */
	assert_int_equal(fit(s, xyz, n, NULL, &res, &err), 0);
	assert_int_equal(res.dof, DOF(TX) | DOF(TZ) | DOF(RY));
	/* k on a plane base does nothing */
	struct asph_fit_options k = { .dof = DOF(TZ) | DOF(R) | DOF(K) };
	assert_int_equal(asph_fit_alloc(plane, 10, &k, &w, &err), -EINVAL);
	assert_non_null(strstr(err.message, "plane"));
	/* c names R */
	assert_int_equal(asph_fit_dof_parse("tz,c", &mask, &err), 0);
	assert_int_equal(mask, DOF(TZ) | DOF(R));
	assert_int_equal(asph_fit_dof_parse("R,c", &mask, &err), -EINVAL);
	assert_non_null(strstr(err.message, "twice"));
	free(few);
	free(xyz);
	asph_surface_free(s);
	asph_surface_free(plane);
}

/* The summary of a cross: "profile": true, the traces, the DOF fitted. */
static void test_profile_json(void **state)
{
	struct asph_surface *s = custom(R0, K0, D0);
	struct asph_pose pose = { { 0.01, 0.002, 0 }, 0, 1e-4, 0 };
	struct trace tr[2] = { { 0, 0, 14, 101, 0 }, { M_PI / 2, 0, 14, 101, 1 } };
	struct asph_fit_result res;
	struct asph_error err;
	char *text = NULL;
	size_t n;
	double *xyz = measure(s, &pose, tr, 2, 1, 3, &n);

	(void)state;
	assert_int_equal(fit(s, xyz, n, NULL, &res, &err), 0);
	assert_int_equal(asph_fit_result_to_json(&res, "x", 0, &text), 0);
	json_t *root = json_loads(text, 0, NULL), *p = json_object_get(root, "profiles");
	assert_true(json_is_true(json_object_get(root, "profile")));
	assert_int_equal(json_object_size(json_object_get(root, "dof")), 5);
	assert_int_equal(json_array_size(p), 2);
	expect_near(json_real_value(json_object_get(json_array_get(p, 1), "azimuth_deg")), 90, 1e-9,
		    "azimuth_deg");
	assert_int_equal(json_integer_value(json_object_get(json_array_get(p, 0), "n_points")), 101);
	assert_true(json_is_real(json_object_get(json_array_get(p, 0), "slope_rms_urad")));
	assert_true(json_is_null(json_object_get(root, "pvr_nm")));
	json_decref(root);
	free(text);
	free(xyz);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_profile_recovers),
		cmocka_unit_test(test_profile_noise),
		cmocka_unit_test(test_cross_and_star),
		cmocka_unit_test(test_not_profiles),
		cmocka_unit_test(test_slope_along_trace),
		cmocka_unit_test(test_flat),
		cmocka_unit_test(test_near_flat),
		cmocka_unit_test(test_bad_profiles),
		cmocka_unit_test(test_profile_json),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
