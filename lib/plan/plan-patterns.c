/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Planar point patterns of the sampling plans, generated in scan order. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "plan-patterns.h"
#include "util-mem.h"

static void put(double *xyr, size_t i, double x, double y, double r)
{
	xyr[3 * i] = x;
	xyr[3 * i + 1] = y;
	xyr[3 * i + 2] = r;
}

/* A point on the rim r = a: nudged inward by an ulp or two where rounding
 * of the cosine and sine put it outside, so every point has r <= a. */
static void put_rim(double *xyr, size_t i, double a, double x, double y)
{
	while (sqrt(x * x + y * y) > a || hypot(x, y) > a) {
		x = nextafter(x, 0.0);
		y = nextafter(y, 0.0);
	}
	put(xyr, i, x, y, a);
}

/* ---- disk grid (paper 5.1) ---------------------------------------------- */

void plan_involute_point(double s0, size_t k, double xy[2], double *rho)
{
	/* Eq. (5) at t_k; theta = t / s0 = 2 sqrt(pi k). */
	double th = 2.0 * sqrt(M_PI * (double)k), t = s0 * th;
	double c = cos(th), s = sin(th);

	xy[0] = s0 * c + t * s;
	xy[1] = s0 * s - t * c;
	*rho = s0 * sqrt(1.0 + th * th);
}

/* Radius of the k-th involute sample: |beta(t)|^2 = s0^2 + t^2. */
static double involute_rho(double s0, size_t k)
{
	return s0 * sqrt(1.0 + 4.0 * M_PI * (double)k);
}

size_t plan_disk_grid_spiral_count(double a, double p)
{
	double s0 = p / (2.0 * M_PI), rmax = a - 0.5 * p;
	size_t k = 0;

	if (rmax >= s0) {
		double kk = floor((rmax * rmax / (s0 * s0) - 1.0) / (4.0 * M_PI));
		k = (size_t)kk + 1;
		/* Settle the rounding of the closed form on the exact test. */
		while (k > 0 && involute_rho(s0, k - 1) > rmax)
			k--;
		while (involute_rho(s0, k) <= rmax)
			k++;
	}
	return k;
}

size_t plan_disk_grid_rim_count(double a, double p)
{
	double m = ceil(2.0 * M_PI * a / p - 1e-9);
	return m < 3 ? 3 : (size_t)m;
}

size_t plan_disk_grid_count(double a, double p)
{
	return plan_disk_grid_spiral_count(a, p) + plan_disk_grid_rim_count(a, p);
}

int plan_disk_grid_fill(double a, double p, double *xyr)
{
	double s0 = p / (2.0 * M_PI), xy[2] = { a, 0 }, rho;
	size_t ns = plan_disk_grid_spiral_count(a, p), m = plan_disk_grid_rim_count(a, p);

	for (size_t k = 0; k < ns; k++) {
		plan_involute_point(s0, k, xy, &rho);
		put(xyr, k, xy[0], xy[1], rho);
	}
	/* The ring starts radially outside the last involute point and runs
	 * on in the involute's (counter-clockwise) sense. */
	double phi0 = ns ? atan2(xy[1], xy[0]) : 0.0;
	for (size_t j = 0; j < m; j++) {
		double phi = phi0 + 2.0 * M_PI * (double)j / (double)m;
		put_rim(xyr, ns + j, a, a * cos(phi), a * sin(phi));
	}
	return 0;
}

/* ---- x-y raster ------------------------------------------------------------ */

static long raster_rows(double a, double p)
{
	return (long)floor(a / p + 1e-12);
}

long plan_raster_cols(double c, double p)
{
	return c >= 0.5 * p ? (long)floor((c - 0.5 * p) / p) : -1;
}

static double raster_chord(double a, double y)
{
	double c2 = (a - y) * (a + y);
	return c2 > 0 ? sqrt(c2) : 0.0;
}

size_t plan_raster_row_count(double c, double p)
{
	if (c < 0.25 * p)
		return 1;
	return (size_t)(2 * plan_raster_cols(c, p) + 1) + 2;
}

size_t plan_raster_count(double a, double p)
{
	long rows = raster_rows(a, p);
	size_t n = 0;

	for (long j = -rows; j <= rows; j++)
		n += plan_raster_row_count(raster_chord(a, (double)j * p), p);
	return n;
}

/* One row: the rim end, lattice columns, the other rim end; reversed on
 * odd rows (serpentine). */
static size_t raster_row(double a, double p, double y, int reverse,
			 double *xyr, size_t at)
{
	double c = raster_chord(a, y);
	size_t cnt = plan_raster_row_count(c, p);

	if (cnt == 1) {
		put(xyr, at, 0.0, y, fabs(y));
		return 1;
	}
	long cols = plan_raster_cols(c, p);
	for (size_t q = 0; q < cnt; q++) {
		size_t i = reverse ? cnt - 1 - q : q;
		if (i == 0 || i == cnt - 1) {
			put_rim(xyr, at + q, a, i == 0 ? -c : c, y);
			continue;
		}
		double x = (double)((long)i - 1 - cols) * p;
		put(xyr, at + q, x, y, sqrt(x * x + y * y));
	}
	return cnt;
}

int plan_raster_fill(double a, double p, double *xyr)
{
	long rows = raster_rows(a, p);
	size_t at = 0;

	for (long j = -rows; j <= rows; j++)
		at += raster_row(a, p, (double)j * p, (j + rows) % 2, xyr, at);
	return 0;
}

/* ---- concentric circles ---------------------------------------------------- */

static size_t concentric_rings(double a, double p)
{
	double m = ceil(a / p - 1e-9);
	return m < 1 ? 1 : (size_t)m;
}

static size_t ring_points(double r, double p)
{
	double m = ceil(2.0 * M_PI * r / p - 1e-9);
	return m < 3 ? 3 : (size_t)m;
}

static double ring_radius(double a, size_t j, size_t rings)
{
	return j == rings ? a : a * (double)j / (double)rings;
}

size_t plan_concentric_count(double a, double p)
{
	size_t rings = concentric_rings(a, p), n = 1;

	for (size_t j = 1; j <= rings; j++)
		n += ring_points(ring_radius(a, j, rings), p);
	return n;
}

int plan_concentric_fill(double a, double p, double *xyr)
{
	size_t rings = concentric_rings(a, p), at = 1;
	double phi_end = 0;

	put(xyr, 0, 0.0, 0.0, 0.0);
	for (size_t j = 1; j <= rings; j++) {
		double r = ring_radius(a, j, rings);
		size_t m = ring_points(r, p);
		double step = 2.0 * M_PI / (double)m, phi0 = phi_end;
		for (size_t i = 0; i < m; i++) {
			double phi = phi0 + step * (double)i;
			if (j == rings)
				put_rim(xyr, at++, a, r * cos(phi), r * sin(phi));
			else
				put(xyr, at++, r * cos(phi), r * sin(phi), r);
		}
		phi_end = fmod(phi0 + step * (double)(m - 1), 2.0 * M_PI);
	}
	return 0;
}

/* ---- Archimedean spiral ---------------------------------------------------- */

/* Arc length of r = b theta from 0 to theta. */
static double spiral_arc(double b, double th)
{
	return 0.5 * b * (th * sqrt(1.0 + th * th) + asinh(th));
}

static size_t spiral_steps(double a, double p)
{
	double b = p / (2.0 * M_PI), len = spiral_arc(b, a / b);
	double m = ceil(len / p - 1e-9);
	return m < 1 ? 1 : (size_t)m;
}

size_t plan_spiral_count(double a, double p)
{
	return spiral_steps(a, p) + 1;
}

/* theta with spiral_arc(theta) = target, Newton from a second-order
 * prediction off the previous sample. */
static double spiral_solve(double b, double th, double arc_prev,
			   double target)
{
	double w = sqrt(1.0 + th * th), f = b * w, df = b * th / w;
	double d = target - arc_prev;
	double x = th + 2.0 * d / (f + sqrt(f * f + 2.0 * df * d));

	for (int it = 0; it < 60; it++) {
		double step = (spiral_arc(b, x) - target) /
			      (b * sqrt(1.0 + x * x));
		x -= step;
		if (fabs(step) <= 1e-15 * x)
			break;
	}
	return x;
}

static void spiral_state(double b, double th, double target,
			 struct inverse_step *st)
{
	double w = sqrt(1.0 + th * th);

	inverse_step_set(st, th, target, b * w, b * th / w);
}

/* Arc-length samples by the stepper of plan.h, anchored on the closed form
 * of the arc length. */
int plan_spiral_fill(double a, double p, double *xyr)
{
	double b = p / (2.0 * M_PI), th_end = a / b;
	size_t m = spiral_steps(a, p), since = INVERSE_STEP_ANCHOR;
	double delta = spiral_arc(b, th_end) / (double)m;
	struct inverse_step st;

	spiral_state(b, 0.0, 0.0, &st);
	put(xyr, 0, 0.0, 0.0, 0.0);
	for (size_t k = 1; k <= m; k++) {
		double target = delta * (double)k, th = -1;
		if (k == m) {
			put_rim(xyr, k, a, a * cos(th_end), a * sin(th_end));
			break;
		}
		if (since < INVERSE_STEP_ANCHOR) {
			double x0 = inverse_step_predict(&st, target);
			double w = sqrt(1.0 + x0 * x0);
			if (inverse_step_finish(&st, target, x0, b * w,
						b * x0 / w, &th) == 0)
				since++;
			else
				th = -1;
		}
		if (th < 0) {
			th = spiral_solve(b, st.x, st.F, target);
			spiral_state(b, th, target, &st);
			since = 0;
		}
		put(xyr, k, b * th * cos(th), b * th * sin(th), b * th);
	}
	return 0;
}

/* ---- Fermat (golden-angle) spiral ----------------------------------------- */

size_t plan_fermat_count(double a, double p)
{
	double n = round(M_PI * a * a / (p * p));
	return n < 2 ? 2 : (size_t)n;
}

static size_t fermat_bands(double a, double p)
{
	double b = round(a / p);
	return b < 1 ? 1 : (size_t)b;
}

/* First index of band j: ceil((n - 1) j^2 / B^2), in integers. */
static size_t band_start(size_t n, size_t j, size_t bands)
{
	if (j >= bands)
		return n;
	uint64_t num = (uint64_t)(n - 1) * j * j, den = (uint64_t)bands * bands;
	return (size_t)((num + den - 1) / den);
}

/* Fraction of a turn of point i: frac(i (2 - golden ratio)), exact to the
 * last bit for i < 2^32 (the multiplier is split so that i g_hi is exact). */
static double golden_turn(size_t i)
{
	const double g = 0.3819660112501051; /* (3 - sqrt 5) / 2 */
	const double g_hi = 400520.0 / 1048576.0; /* g to 20 fraction bits */
	const double g_lo = g - g_hi;
	double u = (double)i * g_hi;

	u -= floor(u);
	u += (double)i * g_lo;
	return u - floor(u);
}

/* Sorts the m keys' order by key: a bucket pass, then insertion sort,
 * which is linear here because the golden turns are evenly spread. */
static void sort_by_turn(const double *key, uint32_t *order, size_t *count,
			 uint32_t *tmp, size_t m)
{
	for (size_t b = 0; b <= m; b++)
		count[b] = 0;
	for (size_t q = 0; q < m; q++)
		count[(size_t)(key[q] * (double)m) + 1]++;
	for (size_t b = 0; b < m; b++)
		count[b + 1] += count[b];
	for (size_t q = 0; q < m; q++)
		tmp[count[(size_t)(key[q] * (double)m)]++] = (uint32_t)q;
	/* The bucket pass wrote each of tmp[0, m) once (count holds the
	 * prefix sums), so the insertion sort reads no unset entry. */
	for (size_t q = 1; q < m; q++) {
		uint32_t v = tmp[q]; // NOLINT(clang-analyzer-core.uninitialized.Assign)
		size_t z = q;
		while (z > 0 && key[tmp[z - 1]] > key[v]) {
			tmp[z] = tmp[z - 1];
			z--;
		}
		tmp[z] = v;
	}
	for (size_t q = 0; q < m; q++)
		order[q] = tmp[q]; // NOLINT(clang-analyzer-core.uninitialized.Assign): see above
}

struct fermat_work {
	double *key;
	uint32_t *order, *tmp;
	size_t *count;
};

static void fermat_work_free(struct fermat_work *w)
{
	free(w->key);
	free(w->order);
	free(w->tmp);
	free(w->count);
}

/* Emits band [i0, i1) sorted by angle, starting at the first angle at or
 * after *turn (the previous band's last) so the band change is short. */
static size_t fermat_band(double a, size_t n, size_t i0, size_t i1,
			  struct fermat_work *w, double *turn, double *xyr,
			  size_t at)
{
	size_t m = i1 - i0, start = 0;

	for (size_t q = 0; q < m; q++)
		w->key[q] = golden_turn(i0 + q);
	sort_by_turn(w->key, w->order, w->count, w->tmp, m);
	while (start < m && w->key[w->order[start]] < *turn)
		start++;
	for (size_t q = 0; q < m; q++) {
		size_t i = i0 + w->order[(start + q) % m];
		double u = w->key[i - i0], th = 2.0 * M_PI * u;
		double r = a * sqrt((double)i / (double)(n - 1));
		if (i == n - 1)
			put_rim(xyr, at + q, a, a * cos(th), a * sin(th));
		else
			put(xyr, at + q, r * cos(th), r * sin(th), r);
		*turn = u;
	}
	return m;
}

int plan_fermat_fill(double a, double p, double *xyr)
{
	size_t n = plan_fermat_count(a, p), bands = fermat_bands(a, p);
	size_t max_m = 0, at = 0;
	double turn = 0;
	_cleanup_(fermat_work_free) struct fermat_work w = { 0 };

	for (size_t j = 0; j < bands; j++) {
		size_t m = band_start(n, j + 1, bands) - band_start(n, j, bands);
		if (m > max_m)
			max_m = m;
	}
	/* max_m >= 1: the bands split n >= 1 points. */
	w.key = malloc(max_m * sizeof(*w.key)); // NOLINT(clang-analyzer-optin.portability.UnixAPI)
	w.order = malloc(max_m * sizeof(*w.order));
	w.tmp = malloc(max_m * sizeof(*w.tmp));
	w.count = malloc((max_m + 1) * sizeof(*w.count));
	if (!w.key || !w.order || !w.tmp || !w.count)
		return -ENOMEM;
	for (size_t j = 0; j < bands; j++)
		at += fermat_band(a, n, band_start(n, j, bands),
				  band_start(n, j + 1, bands), &w, &turn, xyr,
				  at);
	return 0;
}

/* ---- the patterns ------------------------------------------------------------ */

/*
 * Lattices measured on flat patterns of 1.26e5 points on the unit disk
 * (Delaunay triangulation, mean edge length; points per area),
 * docs/sampling-plans.md, "Density". Each lattice has one point per p^2 of
 * area to within 0.5 %.
 */
const struct plan_pattern plan_disk_grid = {
	.lattice = { 1.0, 1.099 }, .count = plan_disk_grid_count, .fill = plan_disk_grid_fill,
	.rim_count = plan_disk_grid_rim_count,
};
const struct plan_pattern plan_raster = {
	.lattice = { 1.0, 1.138 } /* (2 + sqrt 2) / 3 */, .count = plan_raster_count,
	.fill = plan_raster_fill, .rows = true,
};
const struct plan_pattern plan_concentric = {
	.lattice = { 1.0, 1.098 }, .count = plan_concentric_count, .fill = plan_concentric_fill,
};
const struct plan_pattern plan_spiral = {
	.lattice = { 1.0, 1.099 }, .count = plan_spiral_count, .fill = plan_spiral_fill,
};
const struct plan_pattern plan_fermat = {
	.lattice = { 1.0, 1.114 }, .count = plan_fermat_count, .fill = plan_fermat_fill,
};

/* ---- triangles -------------------------------------------------------------- */

double plan_triangle_q_2d(const double *p0, const double *p1, const double *p2)
{
	double ux = p1[0] - p0[0], uy = p1[1] - p0[1];
	double vx = p2[0] - p0[0], vy = p2[1] - p0[1];
	double wx = p2[0] - p1[0], wy = p2[1] - p1[1];
	double area = 0.5 * fabs(ux * vy - uy * vx);
	double l2 = ux * ux + uy * uy + vx * vx + vy * vy + wx * wx + wy * wy;

	return l2 > 0 ? 4.0 * sqrt(3.0) * area / l2 : 0.0;
}
