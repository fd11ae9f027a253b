/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Interpolation and masks, slope deviation, the Gaussian filter's
 * transmission and PSDs of surfaces with known spectra. */
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
#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>

#include "asph/areal.h"
#include "asph/delaunay.h"

/* Points on a hexagonal lattice of spacing h in the disc of radius a,
 * less those in the hole (centre hx, hy, radius hr; hr = 0: no hole). */
static size_t hex_points(double a, double h, double hx, double hy, double hr, double **xy)
{
	size_t cap = (size_t)(4 * a * a / (h * h)) + 16, n = 0;
	double *p = malloc(2 * cap * sizeof(double));

	for (int j = -(int)(a / h) - 1; j <= (int)(a / h) + 1; j++)
		for (int i = -(int)(a / h) - 2; i <= (int)(a / h) + 2; i++) {
			double x = (i + 0.5 * (j & 1)) * h + 1e-3 * h, y = j * h * sqrt(3) / 2;
			if (hypot(x, y) > a || (hr > 0 && hypot(x - hx, y - hy) < hr) || n >= cap)
				continue;
			p[2 * n] = x;
			p[2 * n + 1] = y;
			n++;
		}
	*xy = p;
	return n;
}

static struct asph_scatter *scatter_of(const double *xy, size_t n, double (*f)(double, double))
{
	double *v = malloc(n * sizeof(double));
	struct asph_scatter *s = NULL;

	for (size_t i = 0; i < n; i++)
		v[i] = f(xy[2 * i], xy[2 * i + 1]);
	assert_int_equal(asph_scatter_alloc(xy, v, n, NULL, &s, NULL), 0);
	free(v);
	return s;
}

static double plane(double x, double y)
{
	return 3.7 * x - 1.9 * y + 11.0;
}

static double bowl(double x, double y)
{
	return 0.8 * (x * x + y * y);
}

/* Linear functions come back exactly; a quadratic within the bound of
 * linear interpolation, (1/2) M r^2 with r the circumradius of a lattice
 * triangle (h / sqrt 3) and M = 1.6 the second derivative. */
static void test_interpolation(void **state)
{
	double *xy, h = 0.5, a = 10;
	size_t n = hex_points(a, h, 0, 0, 0, &xy);
	struct asph_scatter *s = scatter_of(xy, n, plane), *q = scatter_of(xy, n, bowl);
	uint32_t hint = 0, hq = 0;
	double worst = 0, v;
	int inside = 0;

	for (int k = 0; k < 2000; k++) {
		double r = 9 * sqrt((k + 0.5) / 2000.0), t = 2.399963 * k;
		double x = r * cos(t), y = r * sin(t);
		if (asph_scatter_eval(s, x, y, &hint, &v, NULL, NULL) < 0)
			continue;
		inside++;
		assert_true(fabs(v - plane(x, y)) < 1e-10);
		assert_int_equal(asph_scatter_eval(q, x, y, &hq, &v, NULL, NULL), 0);
		worst = fmax(worst, v - bowl(x, y));
		assert_true(v >= bowl(x, y) - 1e-12);     /* a convex function is overestimated */
	}
	assert_int_equal(inside, 2000);
	assert_true(worst <= 0.5 * 1.6 * h * h / 3 + 1e-12);
	assert_true(worst > 0.3 * 0.5 * 1.6 * h * h / 3);
	/* Outside the disc of points there is nothing. */
	assert_int_equal(asph_scatter_eval(s, 0, 10.6, &hint, &v, NULL, NULL), -EDOM);
	assert_true(isnan(v));
	asph_scatter_free(s);
	asph_scatter_free(q);
	free(xy);
}

/* A hole in the measured points stays a hole on the grid; nodes outside
 * the aperture are masked; nodes elsewhere carry the function. */
static void test_grid_masks(void **state)
{
	double *xy;
	size_t n = hex_points(10, 0.4, 4, 2, 2.0, &xy);
	struct asph_scatter *s = scatter_of(xy, n, plane);
	struct asph_grid *g = NULL;
	size_t masked_hole = 0, valid = 0;

	assert_int_equal(asph_grid_resample(s, 10, 0.25, &g, NULL), 0);
	assert_int_equal(g->nx, 81);
	for (size_t j = 0; j < g->ny; j++)
		for (size_t i = 0; i < g->nx; i++) {
			double x = g->x0 + i * g->dx, y = g->y0 + j * g->dx, z = g->z[j * g->nx + i];
			if (hypot(x, y) > 10)
				assert_true(isnan(z));
			if (hypot(x - 4, y - 2) < 2.0 - 0.8) {   /* well inside the hole */
				assert_true(isnan(z));
				masked_hole++;
			}
			if (!isnan(z)) {
				assert_true(fabs(z - plane(x, y)) < 1e-10);
				valid++;
			}
		}
	assert_true(masked_hole > 20);
	assert_true(valid > 4000);
	asph_grid_free(g);
	asph_scatter_free(s);
	free(xy);
}

/* The slope of a plane is its gradient everywhere: magnitude g, radial
 * g cos, tangential g sin; of rho^2 exactly 2 c r radially, 0 along the
 * tangent (a difference quotient is exact for a quadratic). */
static void test_slope(void **state)
{
	double *xy;
	size_t n = hex_points(10, 0.3, 0, 0, 0, &xy);
	struct asph_scatter *s = scatter_of(xy, n, plane);
	struct asph_slope sl;
	double g = hypot(3.7, 1.9);

	assert_int_equal(asph_slope_compute(s, 10, 1.0, 0.5, 0.0, &sl, NULL), 0);
	assert_true(fabs(sl.rms.v - g) < 1e-9 * g);
	assert_true(fabs(sl.max.v - g) < 1e-9 * g);
	assert_true(fabs(sl.rms_radial.v - g / sqrt(2)) < 0.02 * g);
	assert_true(fabs(sl.rms_azimuthal.v - g / sqrt(2)) < 0.02 * g);
	assert_true(sl.u_rms.v == 0 && sl.u_max.v == 0);
	asph_scatter_free(s);

	s = scatter_of(xy, n, bowl);
	assert_int_equal(asph_slope_compute(s, 10, 1.0, 0.5, 2.0, &sl, NULL), 0);
	/* Max radial slope at the outermost radius r with r + 0.5 <= 10. */
	assert_true(sl.max_radial.v <= 2 * 0.8 * 9.5 + 1e-9);
	assert_true(sl.max_radial.v > 2 * 0.8 * 9.0);
	assert_true(sl.max_azimuthal.v < 0.3 * 0.8);   /* the chord's end effect only */
	assert_true(sl.u_max.v > 0 && sl.u_rms.v > 0 && sl.u_rms.v < sl.u_max.v);
	struct asph_error err;
	asph_error_clear(&err);
	assert_int_equal(asph_slope_compute(s, 10, 25.0, 0.5, 0, &sl, &err), -EINVAL);
	assert_non_null(strstr(err.message, "evaluation length 25"));
	asph_scatter_free(s);
	free(xy);
}

/* A sinusoid's amplitude in the mean line, away from the ends. */
/* Points uniform in the disc of radius a, from a seeded generator. */
static double *random_disc(size_t n, double a, unsigned long seed)
{
	gsl_rng *g = gsl_rng_alloc(gsl_rng_mt19937);
	double *xy = malloc(2 * n * sizeof(double));

	gsl_rng_set(g, seed);
	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt(gsl_rng_uniform(g)), t = 2 * M_PI * gsl_rng_uniform(g);
		xy[2 * i] = r * cos(t);
		xy[2 * i + 1] = r * sin(t);
	}
	gsl_rng_free(g);
	return xy;
}

static int cmp_double(const void *a, const void *b)
{
	double x = *(const double *)a, y = *(const double *)b;

	return (x > y) - (x < y);
}

/* The median edge is the element a full sort puts in the middle of the
 * triangulation's 3 ntri edge lengths, exactly; on random points and on a
 * lattice, where most lengths are equal. */
static void check_median_edge(const double *xy, size_t n)
{
	struct asph_delaunay *d = asph_delaunay_alloc(n);
	uint32_t *tri = NULL;
	size_t ntri = 0;
	double *v = calloc(n, sizeof(double)), *len;
	struct asph_scatter *s = NULL;

	assert_int_equal(asph_delaunay_triangulate(d, xy, n, &tri, &ntri, NULL), 0);
	len = malloc(3 * ntri * sizeof(double));
	for (size_t t = 0; t < ntri; t++)
		for (int k = 0; k < 3; k++) {
			uint32_t a = tri[3 * t + k], b = tri[3 * t + (k + 1) % 3];
			len[3 * t + k] = hypot(xy[2 * a] - xy[2 * b], xy[2 * a + 1] - xy[2 * b + 1]);
		}
	qsort(len, 3 * ntri, sizeof(double), cmp_double);
	assert_int_equal(asph_scatter_alloc(xy, v, n, NULL, &s, NULL), 0);
	assert_true(asph_scatter_median_edge(s) == len[3 * ntri / 2]);
	asph_scatter_free(s);
	free(len);
	free(tri);
	free(v);
	asph_delaunay_free(d);
}

static void test_median_edge(void **state)
{
	double *xy = random_disc(20001, 10, 7);

	(void)state;
	check_median_edge(xy, 20001);
	free(xy);
	size_t n = hex_points(10, 0.3, 0, 0, 0, &xy);
	check_median_edge(xy, n);
	free(xy);
}

/* One stencil's difference quotient, each end located from scratch. */
static int quotient_ref(const struct asph_scatter *s, double a, double x, double y, double ex,
			double ey, double L, double *q)
{
	double v[2];

	for (int k = 0; k < 2; k++) {
		double sign = k ? -0.5 : 0.5, px = x + sign * L * ex, py = y + sign * L * ey;
		if (hypot(px, py) > a || asph_scatter_eval(s, px, py, NULL, &v[k], NULL, NULL) < 0)
			return -1;
	}
	*q = (v[0] - v[1]) / L;
	return 0;
}

/* The slope deviation of rough data on random points against the same
 * sums, every stencil end found by a walk from the first triangle: how
 * the search is started changes nothing beyond rounding. */
static void test_slope_reference(void **state)
{
	const double a = 10, L = 1.0, h = 0.23;
	size_t n = 30000;
	double *xy = random_disc(n, a, 11), *v = malloc(n * sizeof(double));
	double r2 = 0, t2 = 0, mmax = 0, rmax = 0, tmax = 0;
	long half = (long)floor(a / h);
	size_t m = 0;
	gsl_rng *g = gsl_rng_alloc(gsl_rng_mt19937);
	struct asph_scatter *s = NULL;
	struct asph_slope sl;

	(void)state;
	for (size_t i = 0; i < n; i++)
		v[i] = bowl(xy[2 * i], xy[2 * i + 1]) + gsl_ran_gaussian(g, 0.05);
	assert_int_equal(asph_scatter_alloc(xy, v, n, NULL, &s, NULL), 0);
	assert_int_equal(asph_slope_compute(s, a, L, h, 0, &sl, NULL), 0);
	for (long j = -half; j <= half; j++)
		for (long i = -half; i <= half; i++) {
			double x = (double)i * h, y = (double)j * h, rr = hypot(x, y), qr, qt;
			if (rr > a || rr == 0 || quotient_ref(s, a, x, y, x / rr, y / rr, L, &qr) < 0 ||
			    quotient_ref(s, a, x, y, -y / rr, x / rr, L, &qt) < 0)
				continue;
			r2 += qr * qr;
			t2 += qt * qt;
			mmax = fmax(mmax, hypot(qr, qt));
			rmax = fmax(rmax, fabs(qr));
			tmax = fmax(tmax, fabs(qt));
			m++;
		}
	assert_int_equal(sl.n, m);
	assert_true(fabs(sl.rms.v - sqrt((r2 + t2) / (double)m)) < 1e-12 * sl.rms.v);
	assert_true(fabs(sl.rms_radial.v - sqrt(r2 / (double)m)) < 1e-12 * sl.rms.v);
	assert_true(fabs(sl.rms_azimuthal.v - sqrt(t2 / (double)m)) < 1e-12 * sl.rms.v);
	assert_true(fabs(sl.max.v - mmax) < 1e-12 * mmax);
	assert_true(fabs(sl.max_radial.v - rmax) < 1e-12 * mmax);
	assert_true(fabs(sl.max_azimuthal.v - tmax) < 1e-12 * mmax);
	asph_scatter_free(s);
	gsl_rng_free(g);
	free(v);
	free(xy);
}

static double transmitted(double wavelength, double cutoff)
{
	size_t n = 4000;
	double dx = 0.01, *z = malloc(n * sizeof(double)), *m = malloc(n * sizeof(double)), amp = 0;

	for (size_t k = 0; k < n; k++)
		z[k] = 3.0 * sin(2 * M_PI * k * dx / wavelength + 0.3);
	assert_int_equal(asph_gaussian_profile(z, n, dx, cutoff, m, NULL), 0);
	for (size_t k = n / 3; k < 2 * n / 3; k++)
		amp = fmax(amp, fabs(m[k]));
	free(z);
	free(m);
	return amp / 3.0;
}

/* ISO 16610-21: 50 % +- 1 % at the cut-off, and the Gaussian on either
 * side: exp(-pi alpha^2 (lc / l)^2) = 2^-((lc/l)^2). */
static void test_gaussian_profile(void **state)
{
	assert_true(fabs(transmitted(2.5, 2.5) - 0.5) < 0.01);
	assert_true(fabs(transmitted(0.8, 0.8) - 0.5) < 0.01);
	assert_true(fabs(transmitted(5.0, 2.5) - pow(2, -0.25)) < 0.005);
	assert_true(fabs(transmitted(1.25, 2.5) - pow(2, -4)) < 0.005);
	/* Masked samples stay masked; a constant stays itself next to them. */
	double z[50], m[50];
	for (int k = 0; k < 50; k++)
		z[k] = k >= 20 && k < 25 ? NAN : 7.5;
	assert_int_equal(asph_gaussian_profile(z, 50, 0.1, 1.0, m, NULL), 0);
	for (int k = 0; k < 50; k++)
		assert_true(k >= 20 && k < 25 ? isnan(m[k]) : fabs(m[k] - 7.5) < 1e-12);
	struct asph_error err;
	asph_error_clear(&err);
	assert_int_equal(asph_gaussian_profile(z, 50, 0.1, -1.0, m, &err), -EINVAL);
}

static void test_gaussian_areal(void **state)
{
	struct asph_grid *g = asph_grid_alloc(301, 101);
	double amp = 0;

	g->dx = 0.02;
	for (size_t j = 0; j < g->ny; j++)
		for (size_t i = 0; i < g->nx; i++)
			g->z[j * g->nx + i] = 2.0 * cos(2 * M_PI * (i * 0.02) / 0.8);
	assert_int_equal(asph_gaussian_areal(g, 0.8, g, NULL), 0);
	for (size_t i = 100; i < 200; i++)
		amp = fmax(amp, fabs(g->z[50 * g->nx + i]));
	assert_true(fabs(amp / 2.0 - 0.5) < 0.01);
	asph_grid_free(g);
}

/* Two sinusoids and white noise: the PSD integrates to each sinusoid's
 * a^2 / 2 around its frequency and to 2 sigma^2 dx per unit frequency in
 * the white floor. */
static void test_psd_profile(void **state)
{
	size_t n = 3000;
	double dx = 0.01, *z = malloc(n * sizeof(double));
	struct asph_psd *p = NULL;
	gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	double f1 = 2.0, f2 = 11.0, floor_sum = 0;
	int floor_n = 0;

	for (size_t k = 0; k < n; k++)
		z[k] = 5 * sin(2 * M_PI * f1 * k * dx) + 2 * cos(2 * M_PI * f2 * k * dx + 1) +
		       gsl_ran_gaussian_ziggurat(rng, 0.1);
	assert_int_equal(asph_psd_profile(z, n, dx, &p, NULL), 0);
	for (int s = 0; s < 2; s++) {
		double f = s ? f2 : f1, sum = 0, a = s ? 2 : 5;
		size_t k0 = (size_t)(f / p->df + 0.5);
		for (size_t k = k0 - 4; k <= k0 + 4; k++)
			sum += p->psd[k] * p->df;
		assert_true(fabs(sum - a * a / 2) < 0.01 * a * a / 2);
	}
	for (size_t k = 0; k < p->n; k++) {
		double f = k * p->df;
		if (f > 20 && f < 45) {
			floor_sum += p->psd[k];
			floor_n++;
		}
	}
	assert_true(fabs(floor_sum / floor_n / (2 * 0.01 * dx) - 1) < 0.1);
	asph_psd_free(p);
	gsl_rng_free(rng);
	free(z);
}

/* An areal surface of one long and one short wavelength: the bands hold
 * each one's RMS, the areal PSD its power at its frequency. */
static void test_psd_areal_bands(void **state)
{
	struct asph_grid *g = asph_grid_alloc(200, 200);
	struct asph_psd2 *p = NULL;
	struct asph_psd *r = NULL;
	struct asph_band_rms b;
	struct asph_bands bands = { .form_mm = 1.0, .high_mm = 0.1 };
	struct asph_error err;

	g->dx = 0.01;
	for (size_t j = 0; j < g->ny; j++)
		for (size_t i = 0; i < g->nx; i++)
			g->z[j * g->nx + i] = 4 * sin(2 * M_PI * i * 0.01 / 0.4) +
					      1 * cos(2 * M_PI * j * 0.01 / 0.05);
	assert_int_equal(asph_psd_areal(g, &p, NULL), 0);
	assert_int_equal(asph_band_rms(p, &bands, &b, NULL), 0);
	assert_true(fabs(b.mid - 4 / sqrt(2)) < 0.02 * 4 / sqrt(2));
	assert_true(fabs(b.high - 1 / sqrt(2)) < 0.02 / sqrt(2));
	assert_true(b.form < 0.05);
	assert_true(fabs(b.total - sqrt(8.5)) < 0.02 * sqrt(8.5));
	assert_int_equal(asph_psd2_radial(p, &r, NULL), 0);
	double sum = 0;
	for (size_t k = 0; k < r->n; k++)
		sum += r->psd[k] * r->df;
	assert_true(fabs(sum - b.total * b.total) < 1e-9 * sum + p->psd[0] * p->dfx * p->dfy);
	asph_error_clear(&err);
	bands.high_mm = 2;
	assert_int_equal(asph_band_rms(p, &bands, &b, &err), -EINVAL);
	assert_non_null(strstr(err.message, "bands"));
	asph_psd_free(r);
	asph_psd2_free(p);
	asph_grid_free(g);
}

/* The radial PSD from scattered points of a radial-free sinusoid along x:
 * every diameter sees it, at its own projected frequency, and the mean
 * square comes back. */
static void test_psd_radial_and_profiles(void **state)
{
	double *xy;
	size_t n = hex_points(10, 0.2, 0, 0, 0, &xy), len = asph_profile_length(10, 0.1);
	struct asph_scatter *s = scatter_of(xy, n, plane);
	struct asph_psd *p = NULL;
	double *z = malloc(len * sizeof(double)), *mean = malloc(101 * sizeof(double));

	assert_int_equal(len, 201);
	assert_int_equal(asph_profile_sample(s, M_PI / 2, 10, 0.1, z, NULL), 0);
	assert_true(fabs(z[100] - 11.0) < 1e-9);
	assert_true(fabs(z[150] - plane(0, 5)) < 1e-9);
	assert_int_equal(asph_profile_azimuthal_mean(s, 0.1, 101, 36, mean, NULL), 0);
	assert_true(fabs(mean[50] - 11.0) < 1e-9);     /* the plane averages out */
	assert_int_equal(asph_psd_radial(s, 10, 0.1, 12, &p, NULL), 0);
	assert_int_equal(p->n_profiles, 12);
	asph_psd_free(p);
	free(z);
	free(mean);
	asph_scatter_free(s);
	free(xy);
}

static double ripple_x(double x, double y)
{
	return 5.0 * cos(2 * M_PI * x / 2.0);     /* 5 nm, wavelength 2 mm */
}

/* The residual's PSD (the report's, the daemon's psd.csv) is the radial
 * PSD of ASPH_PSD_DIAMETERS diameters at half the median spacing; a
 * ripple along x of wavelength L puts no power above 1 / L (each diameter
 * sees it at cos(angle) / L), and the spectrum holds the ripple's mean
 * square A^2 / 2 on the 17 diameters not across it. */
static void test_psd_residual(void **state)
{
	double *xy;
	size_t n = hex_points(10, 0.2, 0, 0, 0, &xy);
	struct asph_scatter *s = scatter_of(xy, n, ripple_x);
	struct asph_psd *p = NULL, *q = NULL;
	double ds = asph_scatter_median_edge(s) / 2, total = 0, above = 0;

	assert_true(fabs(ds - 0.1) < 1e-6);
	assert_int_equal(asph_psd_residual(s, 10, &p, NULL), 0);
	assert_int_equal(asph_psd_radial(s, 10, ds, ASPH_PSD_DIAMETERS, &q, NULL), 0);
	assert_int_equal(p->n, q->n);
	assert_int_equal(p->n_profiles, ASPH_PSD_DIAMETERS);
	assert_memory_equal(p->psd, q->psd, p->n * sizeof(double));
	/* 201 samples padded to 216 = 2^3 3^3 */
	assert_true(fabs(p->df - 1 / (216 * 0.1)) < 1e-12);
	for (size_t k = 0; k < p->n; k++) {
		total += p->psd[k] * p->df;
		if (k * p->df > 0.5 + 3 * p->df)
			above += p->psd[k] * p->df;
	}
	assert_true(above < 1e-3 * total);
	/* linear interpolation at 10 points a wavelength loses a few percent */
	assert_true(fabs(total - 17.0 / 18 * 12.5) < 0.1 * 12.5);
	asph_psd_free(p);
	asph_psd_free(q);
	asph_scatter_free(s);
	free(xy);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_interpolation),
		cmocka_unit_test(test_grid_masks),
		cmocka_unit_test(test_slope),
		cmocka_unit_test(test_median_edge),
		cmocka_unit_test(test_slope_reference),
		cmocka_unit_test(test_gaussian_profile),
		cmocka_unit_test(test_gaussian_areal),
		cmocka_unit_test(test_psd_profile),
		cmocka_unit_test(test_psd_areal_bands),
		cmocka_unit_test(test_psd_radial_and_profiles),
		cmocka_unit_test(test_psd_residual),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
