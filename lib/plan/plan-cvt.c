/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The CVT plan: a centroidal Voronoi tessellation restricted to the surface
 * (docs/sampling-plans.md, "cvt"), by Lloyd's iterations started from the
 * OT plan.
 *
 * The surface is represented by samples: a square lattice of pitch
 * p / CVT_SAMPLES_PER_PITCH over the aperture, each sample lifted onto the
 * surface and weighted by its area element w = sqrt(1 + S_x^2 + S_y^2), so
 * the samples carry the surface's area. A site's restricted Voronoi cell is
 * the set of samples nearer to it in 3-D than to any other site (the
 * restricted Voronoi diagram of Yan, Levy, Liu, Sun and Wang, Comput.
 * Graph. Forum 28 (2009) 1445); its centroid is pulled back onto the
 * surface along the normal. The sites on the aperture's edge stay there:
 * they take part in the cells but do not move, so the plan keeps its
 * outline. The order of the sites is the OT plan's (the disk grid's spiral
 * scan order).
 */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "plan-cvt.h"
#include "util-mem.h"

#define CVT_SAMPLES_PER_PITCH 8
#define CVT_MAX_ITER 100
/* Stop when no site moves more than this fraction of the pitch. */
#define CVT_MOVE_TOL 1e-3

/* Sites bucketed on a square grid of the x-y plane. */
struct buckets {
	double x0, y0, cell;
	int nx, ny;
	size_t *start, *index;  /* CSR: the sites of bucket b are index[start[b]..start[b+1]) */
};

static void buckets_clear(struct buckets *b)
{
	free(b->start);
	free(b->index);
	memset(b, 0, sizeof(*b));
}

static int bucket_of(const struct buckets *b, double v, double v0, int n)
{
	int k = (int)floor((v - v0) / b->cell);

	return k < 0 ? 0 : k >= n ? n - 1 : k;
}

static int buckets_fill(struct buckets *b, const double box[4], double cell, const double *xyz,
			size_t n)
{
	b->x0 = box[0];
	b->y0 = box[2];
	b->cell = cell;
	b->nx = (int)ceil((box[1] - box[0]) / cell) + 1;
	b->ny = (int)ceil((box[3] - box[2]) / cell) + 1;
	size_t nb = (size_t)b->nx * (size_t)b->ny;
	b->start = calloc(nb + 1, sizeof(size_t));
	b->index = malloc(n * sizeof(size_t));
	if (!b->start || !b->index)
		return -ENOMEM;
	for (size_t i = 0; i < n; i++) {
		size_t k = (size_t)bucket_of(b, xyz[3 * i + 1], b->y0, b->ny) * (size_t)b->nx +
			   (size_t)bucket_of(b, xyz[3 * i], b->x0, b->nx);
		b->start[k + 1]++;
	}
	for (size_t k = 0; k < nb; k++)
		b->start[k + 1] += b->start[k];
	_cleanup_free_ size_t *fill = malloc(nb * sizeof(size_t));
	if (!fill)
		return -ENOMEM;
	memcpy(fill, b->start, nb * sizeof(size_t));
	for (size_t i = 0; i < n; i++) {
		size_t k = (size_t)bucket_of(b, xyz[3 * i + 1], b->y0, b->ny) * (size_t)b->nx +
			   (size_t)bucket_of(b, xyz[3 * i], b->x0, b->nx);
		b->index[fill[k]++] = i;
	}
	return 0;
}

static double dist2(const double *a, const double *b)
{
	double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];

	return dx * dx + dy * dy + dz * dz;
}

/* The site nearest to q in 3-D. The x-y distance bounds the 3-D one from
 * below, so the rings of buckets are searched until the next ring is
 * farther in x-y than the best site in 3-D. */
static size_t nearest_site(const struct buckets *b, const double *xyz, const double q[3])
{
	int cx = bucket_of(b, q[0], b->x0, b->nx), cy = bucket_of(b, q[1], b->y0, b->ny);
	size_t best = SIZE_MAX;
	double bd = INFINITY;
	int rmax = b->nx > b->ny ? b->nx : b->ny;

	for (int ring = 0; ring <= rmax; ring++) {
		double reach = (ring - 1) * b->cell;
		if (best != SIZE_MAX && reach > 0 && reach * reach > bd)
			break;
		for (int j = cy - ring; j <= cy + ring; j++) {
			if (j < 0 || j >= b->ny)
				continue;
			bool edge_row = j == cy - ring || j == cy + ring;
			for (int i = cx - ring; i <= cx + ring; i += edge_row ? 1 : 2 * ring) {
				if (i >= 0 && i < b->nx) {
					size_t k = (size_t)j * (size_t)b->nx + (size_t)i;
					for (size_t m = b->start[k]; m < b->start[k + 1]; m++) {
						double d = dist2(xyz + 3 * b->index[m], q);
						if (d < bd) {
							bd = d;
							best = b->index[m];
						}
					}
				}
				if (ring == 0)
					break;
			}
		}
	}
	return best;
}

/* The samples: the lattice of pitch h over the aperture, on the surface,
 * with their weights w. */
static int make_samples(const struct asph_surface *s, double h, double **out, double **wout,
			size_t *nout)
{
	double box[4];
	size_t cap = 0, n = 0;
	double *xyz = NULL, *w = NULL;

	asph_surface_bounds(s, box);
	double cx = 0.5 * (box[0] + box[1]), cy = 0.5 * (box[2] + box[3]);
	int kx = (int)ceil(0.5 * (box[1] - box[0]) / h), ky = (int)ceil(0.5 * (box[3] - box[2]) / h);
	cap = (size_t)(2 * kx + 1) * (size_t)(2 * ky + 1);
	xyz = malloc(3 * cap * sizeof(double));
	w = malloc(cap * sizeof(double));
	if (!xyz || !w) {
		free(xyz);
		free(w);
		return -ENOMEM;
	}
	/* cell centres, so that the lattice is symmetric about the centre */
	for (int j = -ky; j < ky; j++)
		for (int i = -kx; i < kx; i++) {
			double x = cx + (i + 0.5) * h, y = cy + (j + 0.5) * h;
			if (!asph_surface_contains(s, x, y, 0))
				continue;
			double g[3];
			asph_surface_sag_grad_xy(s, x, y, g);
			xyz[3 * n] = x;
			xyz[3 * n + 1] = y;
			xyz[3 * n + 2] = g[0];
			w[n++] = sqrt(1 + g[1] * g[1] + g[2] * g[2]);
		}
	*out = xyz;
	*wout = w;
	*nout = n;
	return 0;
}

/* The point of the surface nearest to c, by Gauss-Newton steps in (x, y)
 * from (c_x, c_y): c is within a cell's sagitta of the surface. */
static void pull_back(const struct asph_surface *s, const double c[3], double out[3])
{
	double x = c[0], y = c[1];

	for (int it = 0; it < 3; it++) {
		double g[3];
		asph_surface_sag_grad_xy(s, x, y, g);
		/* tangents (1, 0, S_x), (0, 1, S_y); J^T J d = J^T r */
		double r[3] = { c[0] - x, c[1] - y, c[2] - g[0] };
		double a = 1 + g[1] * g[1], b = g[1] * g[2], d = 1 + g[2] * g[2];
		double u = r[0] + g[1] * r[2], v = r[1] + g[2] * r[2];
		double det = a * d - b * b;
		double dx = (d * u - b * v) / det, dy = (a * v - b * u) / det;
		double nx = x + dx, ny = y + dy;
		if (!asph_surface_contains(s, nx, ny, 0))
			break;
		x = nx;
		y = ny;
	}
	out[0] = x;
	out[1] = y;
	out[2] = asph_surface_sag_xy(s, x, y);
}

int plan_cvt_relax(const struct asph_surface *s, double p, double *xyz, size_t n,
		   struct plan_cvt_info *info, struct asph_error *err)
{
	_cleanup_free_ double *samples = NULL, *w = NULL, *sum = NULL;
	_cleanup_free_ bool *fixed = NULL;
	_cleanup_(buckets_clear) struct buckets b = { 0 };
	double box[4], centre[2], R;
	size_t ns = 0;
	int it;

	if (!(p > 0) || n == 0)
		return asph_error_set(err, -EINVAL, "cvt: pitch %g, %zu points", p, n);
	if (make_samples(s, p / CVT_SAMPLES_PER_PITCH, &samples, &w, &ns) < 0 ||
	    !(sum = malloc(4 * n * sizeof(double))) || !(fixed = malloc(n * sizeof(bool))))
		return asph_error_set(err, -ENOMEM, "cvt: out of memory (%zu points)", n);
	asph_surface_bounds(s, box);
	asph_surface_aperture_disk(s, centre, &R);
	for (size_t i = 0; i < n; i++)
		fixed[i] = !asph_surface_contains(s, xyz[3 * i], xyz[3 * i + 1], -1e-9 * R);
	double moved = INFINITY;
	for (it = 0; it < CVT_MAX_ITER && moved > CVT_MOVE_TOL * p; it++) {
		buckets_clear(&b);
		if (buckets_fill(&b, box, p, xyz, n) < 0)
			return asph_error_set(err, -ENOMEM, "cvt: out of memory");
		memset(sum, 0, 4 * n * sizeof(double));
		for (size_t k = 0; k < ns; k++) {
			size_t i = nearest_site(&b, xyz, samples + 3 * k);
			for (int e = 0; e < 3; e++)
				sum[4 * i + e] += w[k] * samples[3 * k + e];
			sum[4 * i + 3] += w[k];
		}
		moved = 0;
		for (size_t i = 0; i < n; i++) {
			if (fixed[i] || !(sum[4 * i + 3] > 0))
				continue;
			double c[3] = { sum[4 * i] / sum[4 * i + 3], sum[4 * i + 1] / sum[4 * i + 3],
					sum[4 * i + 2] / sum[4 * i + 3] }, q[3];
			pull_back(s, c, q);
			moved = fmax(moved, sqrt(dist2(q, xyz + 3 * i)));
			memcpy(xyz + 3 * i, q, sizeof(q));
		}
	}
	if (info)
		*info = (struct plan_cvt_info){ .iterations = it, .last_move = moved / p,
						.samples = ns };
	return 0;
}
