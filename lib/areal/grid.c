/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Resampling onto a grid, profile traces, and the ISO 16610-21 Gaussian
 * filter. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "asph/areal.h"
#include "areal-internal.h"
#include "util-mem.h"

#define MAX_GRID_NODES ((size_t)1 << 26)

struct asph_grid *asph_grid_alloc(size_t nx, size_t ny)
{
	struct asph_grid *g;

	if (nx == 0 || ny == 0 || nx > MAX_GRID_NODES / ny)
		return NULL;
	g = calloc(1, sizeof(*g));
	if (!g)
		return NULL;
	g->nx = nx;
	g->ny = ny;
	g->dx = 1;
	g->z = malloc(nx * ny * sizeof(double));
	if (!g->z) {
		free(g);
		return NULL;
	}
	mem_advise_huge(g->z, nx * ny * sizeof(double));
	for (size_t i = 0; i < nx * ny; i++)
		g->z[i] = NAN;
	return g;
}

void asph_grid_free(struct asph_grid *g)
{
	if (!g)
		return;
	free(g->z);
	free(g);
}

static int check_spacing(double radius, double d, const char *what,
			 struct asph_error *err)
{
	if (!(radius > 0) || !isfinite(radius))
		return asph_error_set(err, -EINVAL, "radius %g mm is not a positive number", radius);
	if (!(d > 0) || !isfinite(d) || 2 * floor(radius / d) + 1 > ASPH_GRID_MAX_NODES)
		return asph_error_set(err, -EINVAL,
				      "%s %g mm is not positive or gives more than %d nodes across %g mm",
				      what, d, ASPH_GRID_MAX_NODES, 2 * radius);
	return 0;
}

int asph_grid_resample(const struct asph_scatter *s, double radius, double dx,
		       struct asph_grid **out, struct asph_error *err)
{
	struct asph_grid *g;
	size_t half, n;
	uint32_t hint = 0, row_hint = 0;
	int r = check_spacing(radius, dx, "grid spacing", err);

	if (r < 0)
		return r;
	half = (size_t)floor(radius / dx);
	n = 2 * half + 1;
	g = asph_grid_alloc(n, n);
	if (!g)
		return asph_error_set(err, -ENOMEM, "out of memory for a %zu x %zu grid", n, n);
	g->dx = dx;
	g->x0 = g->y0 = -(double)half * dx;
	for (size_t j = 0; j < n; j++) {
		double y = g->y0 + (double)j * dx;
		/* A row's search starts where the previous row's first node
		 * found its triangle, one spacing away, rather than at the far
		 * end of the previous row, a diameter away. */
		bool row_started = false;
		hint = row_hint;
		for (size_t i = 0; i < n; i++) {
			double x = g->x0 + (double)i * dx;
			if (hypot(x, y) > radius)
				continue;
			asph_scatter_eval(s, x, y, &hint, &g->z[j * n + i], NULL, NULL);
			if (!row_started) {
				row_hint = hint;
				row_started = true;
			}
		}
	}
	*out = g;
	return 0;
}

size_t asph_profile_length(double radius, double ds)
{
	if (!(radius > 0) || !(ds > 0) || !isfinite(radius / ds) ||
	    radius / ds > ASPH_GRID_MAX_NODES)
		return 0;
	return 2 * (size_t)floor(radius / ds) + 1;
}

int asph_profile_sample(const struct asph_scatter *s, double angle,
			double radius, double ds, double *z,
			struct asph_error *err)
{
	size_t n = asph_profile_length(radius, ds), half = n / 2;
	double c = cos(angle), sn = sin(angle);
	uint32_t hint = 0;
	int r = check_spacing(radius, ds, "profile spacing", err);

	if (r < 0)
		return r;
	for (size_t k = 0; k < n; k++) {
		double t = ((double)k - (double)half) * ds;
		asph_scatter_eval(s, t * c, t * sn, &hint, &z[k], NULL, NULL);
	}
	return 0;
}

int asph_profile_azimuthal_mean(const struct asph_scatter *s, double dr,
				size_t n, int n_angles, double *z,
				struct asph_error *err)
{
	if (!(dr > 0) || !isfinite(dr) || n_angles < 1 || n_angles > 100000)
		return asph_error_set(err, -EINVAL,
				      "radial step %g mm or %d azimuths out of range", dr, n_angles);
	for (size_t k = 0; k < n; k++) {
		double sum = 0, v, r = (double)k * dr;
		int m = 0;
		uint32_t hint = 0;
		for (int a = 0; a < n_angles; a++) {
			double th = 2 * M_PI * a / n_angles;
			if (asph_scatter_eval(s, r * cos(th), r * sin(th), &hint, &v, NULL, NULL) == 0) {
				sum += v;
				m++;
			}
		}
		z[k] = m ? sum / m : NAN;
	}
	return 0;
}

/* The Gaussian weights at 0 .. half samples, truncated at |x| <= lc. */
static double *gaussian_kernel(double dx, double cutoff, size_t *half)
{
	double al = ASPH_GAUSSIAN_ALPHA * cutoff;
	size_t h = (size_t)floor(cutoff / dx);
	double *k = malloc((h + 1) * sizeof(double));

	if (!k)
		return NULL;
	for (size_t i = 0; i <= h; i++) {
		double x = (double)i * dx / al;
		k[i] = exp(-M_PI * x * x);
	}
	*half = h;
	return k;
}

/* out[i] = sum_j k(|i - j|) z[j] / sum_j k(|i - j|) over valid j, with
 * stride; NaN where z[i] is NaN. */
static void convolve_normalised(const double *z, size_t n, size_t stride,
				const double *k, size_t half, double *out)
{
	for (size_t i = 0; i < n; i++) {
		double num = 0, den = 0;
		size_t lo = i > half ? i - half : 0, hi = i + half < n - 1 ? i + half : n - 1;
		if (isnan(z[i * stride])) {
			out[i] = NAN;
			continue;
		}
		for (size_t j = lo; j <= hi; j++) {
			double v = z[j * stride];
			if (isnan(v))
				continue;
			double wk = k[i > j ? i - j : j - i];
			num += wk * v;
			den += wk;
		}
		out[i] = num / den;
	}
}

static int check_filter(size_t n, double dx, double cutoff, struct asph_error *err)
{
	if (n == 0 || !(dx > 0) || !isfinite(dx) || !(cutoff > 0) || !isfinite(cutoff))
		return asph_error_set(err, -EINVAL,
				      "a Gaussian filter needs samples, a positive spacing and cut-off");
	if (cutoff / dx > 1e7)
		return asph_error_set(err, -EINVAL, "cut-off %g mm is over 10^7 samples of %g mm",
				      cutoff, dx);
	return 0;
}

int asph_gaussian_profile(const double *z, size_t n, double dx, double cutoff,
			  double *mean_line, struct asph_error *err)
{
	_cleanup_free_ double *k = NULL;
	size_t half;
	int r = check_filter(n, dx, cutoff, err);

	if (r < 0)
		return r;
	k = gaussian_kernel(dx, cutoff, &half);
	if (!k)
		return asph_error_set(err, -ENOMEM, "out of memory");
	convolve_normalised(z, n, 1, k, half, mean_line);
	return 0;
}

int asph_gaussian_areal(const struct asph_grid *g, double cutoff,
			struct asph_grid *out, struct asph_error *err)
{
	_cleanup_free_ double *k = NULL, *tmp = NULL, *line = NULL, *mask = NULL;
	size_t half, nx = g->nx, ny = g->ny, big = nx > ny ? nx : ny;
	int r = check_filter(nx * ny, g->dx, cutoff, err);

	if (r < 0)
		return r;
	if (out->nx != nx || out->ny != ny)
		return asph_error_set(err, -EINVAL, "the output grid is not the input's size");
	k = gaussian_kernel(g->dx, cutoff, &half);
	/* Zeroed, though every element is set below: the analyzer cannot
	 * follow nx * ny elements set by one loop and read by two. */
	tmp = calloc(nx * ny, sizeof(double));
	line = calloc(big, sizeof(double));
	mask = calloc(nx * ny, sizeof(double));
	if (!k || !tmp || !line || !mask)
		return asph_error_set(err, -ENOMEM, "out of memory");
	/*
	 * Normalised convolution is separable only as two convolutions, of
	 * z m and of m (m the mask), divided at the end: tmp holds z m, mask
	 * holds m, each filtered along x then y with the plain kernel.
	 */
	for (size_t i = 0; i < nx * ny; i++) {
		mask[i] = isnan(g->z[i]) ? 0 : 1;
		tmp[i] = isnan(g->z[i]) ? 0 : g->z[i];
	}
	for (int pass = 0; pass < 2; pass++) {
		double *a = pass ? mask : tmp;
		for (size_t j = 0; j < ny; j++) {
			for (size_t i = 0; i < nx; i++) {
				double s = 0;
				size_t lo = i > half ? i - half : 0, hi = i + half < nx - 1 ? i + half : nx - 1;
				for (size_t q = lo; q <= hi; q++)
					s += k[i > q ? i - q : q - i] * a[j * nx + q];
				line[i] = s;
			}
			memcpy(a + j * nx, line, nx * sizeof(double));
		}
		for (size_t i = 0; i < nx; i++) {
			for (size_t j = 0; j < ny; j++) {
				double s = 0;
				size_t lo = j > half ? j - half : 0, hi = j + half < ny - 1 ? j + half : ny - 1;
				for (size_t q = lo; q <= hi; q++)
					s += k[j > q ? j - q : q - j] * a[q * nx + i];
				line[j] = s;
			}
			for (size_t j = 0; j < ny; j++)
				a[j * nx + i] = line[j];
		}
	}
	for (size_t i = 0; i < nx * ny; i++) {
		int masked = isnan(g->z[i]);
		out->z[i] = masked || !(mask[i] > 0) ? NAN : tmp[i] / mask[i];
	}
	out->x0 = g->x0;
	out->y0 = g->y0;
	out->dx = g->dx;
	return 0;
}
