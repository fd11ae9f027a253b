/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Delaunay triangulation of 1e6 points (ASPH_BENCH_N), as a ratio to Qhull
 * (libqhull_r, "d Qt Qbb Qc Qz Q12") on the same points in the same run;
 * target <= 0.1. Three layouts:
 *   plan-op:  the x, y of the OP sampling plan of the `strong` lens with
 *             about n points (asph_plan_compute, mesh left out);
 *   involute: the disk grid of a sampling plan, points of the planar circle
 *             involute (paper Eq. 5) at equal arc length 2 pi s0 inside a
 *             disk of radius 20 mm;
 *   uniform:  uniformly random points in the same disk.
 * Without Qhull only our time is printed.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"
#include "asph/delaunay.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "bench-common.h"

#if HAVE_QHULL
#include <libqhull_r/qhull_ra.h>
#endif

#define RADIUS 20.0

/* Eq. (5): beta(t) = (s0 cos(t/s0) + t sin(t/s0), s0 sin(t/s0) - t cos(t/s0)),
 * arc length t^2 / (2 s0); points every 2 pi s0 of arc length, so
 * t_k = 2 s0 sqrt(pi k) and |beta(t_k)|^2 = s0^2 (1 + 4 pi k). s0 is chosen
 * so that exactly n points fall inside the disk. */
static void involute_points(double *xy, size_t n)
{
	double s0 = RADIUS / sqrt(4 * M_PI * (double)n + 1);

	for (size_t k = 0; k < n; k++) {
		double t = 2 * s0 * sqrt(M_PI * (double)k), phi = t / s0;
		xy[2 * k] = s0 * cos(phi) + t * sin(phi);
		xy[2 * k + 1] = s0 * sin(phi) - t * cos(phi);
	}
}

static void uniform_points(double *xy, size_t n)
{
	uint64_t s = 0x2545f4914f6cdd1du;

	for (size_t k = 0; k < n;) {
		double p[2];
		for (int i = 0; i < 2; i++) {
			s ^= s << 13;
			s ^= s >> 7;
			s ^= s << 17;
			p[i] = RADIUS * (2.0 * (double)(s >> 11) * 0x1p-53 - 1.0);
		}
		if (p[0] * p[0] + p[1] * p[1] <= RADIUS * RADIUS) {
			xy[2 * k] = p[0];
			xy[2 * k + 1] = p[1];
			k++;
		}
	}
}

/* The x, y of an OP plan of the strong lens, about n points; NULL (with a
 * message) when the plan cannot be made. */
static double *plan_points(size_t n, size_t *m)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;
	struct asph_plan *plan = NULL;
	struct asph_plan_options o = { .flags = ASPH_PLAN_NO_MESH };
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, (double)n };
	struct asph_error err = { 0 };
	double *xy = NULL;

	if (asph_prescription_preset("strong", &p) < 0 ||
	    asph_surface_alloc(&p, &s, &err) < 0 ||
	    asph_plan_compute_opts(s, ASPH_PLAN_OP, d, &o, &plan, &err) < 0) {
		printf("plan-op: no plan (%s), layout skipped\n", err.message);
		asph_surface_free(s);
		return NULL;
	}
	xy = malloc(2 * plan->n * sizeof(*xy));
	if (!xy)
		abort();
	for (size_t i = 0; i < plan->n; i++) {
		xy[2 * i] = plan->xyz[3 * i];
		xy[2 * i + 1] = plan->xyz[3 * i + 1];
	}
	*m = plan->n;
	asph_plan_free(plan);
	asph_surface_free(s);
	return xy;
}

struct run {
	struct asph_delaunay *w;
	const double *xy;
	size_t n;
	size_t n_triangles;
	int status;
};

static void run_ours(void *p)
{
	struct run *r = p;
	uint32_t *tri = NULL;
	struct asph_error err = { 0 };

	r->status = asph_delaunay_triangulate(r->w, r->xy, r->n, &tri,
					      &r->n_triangles, &err);
	if (r->status)
		fprintf(stderr, "triangulation failed: %s\n", err.message);
	free(tri);
}

#if HAVE_QHULL
static void run_qhull(void *p)
{
	struct run *r = p;
	qhT qh_qh;
	qhT *qh = &qh_qh;
	char flags[] = "qhull d Qt Qbb Qc Qz Q12";
	double *pts = malloc(2 * r->n * sizeof(*pts));
	uint32_t *tri;
	size_t m = 0;

	if (!pts)
		abort();
	memcpy(pts, r->xy, 2 * r->n * sizeof(*pts));
	qh_zero(qh, stderr);
	r->status = qh_new_qhull(qh, 2, (int)r->n, pts, False, flags, NULL, stderr);
	if (!r->status) {
		facetT *facet;
		vertexT *vertex, **vertexp;
		FORALLfacets {
			if (!facet->upperdelaunay)
				m++;
		}
		/* Collect the triangles as a caller would. */
		tri = malloc(3 * m * sizeof(*tri));
		if (!tri)
			abort();
		m = 0;
		FORALLfacets {
			if (facet->upperdelaunay)
				continue;
			int k = 0;
			FOREACHvertex_(facet->vertices)
				tri[3 * m + k++] = (uint32_t)qh_pointid(qh, vertex->point);
			m++;
		}
		free(tri);
	}
	qh_freeqhull(qh, !qh_ALL);
	int curlong, totlong;
	qh_memfreeshort(qh, &curlong, &totlong);
	free(pts);
	r->n_triangles = m;
}
#endif

static int bench_layout(const char *name, const double *xy, size_t n,
			struct asph_delaunay *w)
{
	struct run ours = { .w = w, .xy = xy, .n = n };
	char label[96];
	double t_ours = bench_median(run_ours, &ours, 3);

	if (ours.status)
		return 1;
#if HAVE_QHULL
	struct run qh = { .xy = xy, .n = n };
	double t_qhull = bench_median(run_qhull, &qh, 1);

	if (qh.status || qh.n_triangles != ours.n_triangles) {
		printf("%s: Qhull gave %zu triangles (status %d), ours %zu\n",
		       name, qh.n_triangles, qh.status, ours.n_triangles);
	}
	snprintf(label, sizeof(label), "qhull %s (baseline)", name);
	bench_report(label, t_qhull, t_qhull, 0);
	snprintf(label, sizeof(label), "delaunay %s", name);
	return bench_report(label, t_ours, t_qhull, 0.1);
#else
	snprintf(label, sizeof(label), "delaunay %s", name);
	printf("%-40s %10.4f s  (%zu triangles)\n", label, t_ours, ours.n_triangles);
	return 0;
#endif
}

int main(void)
{
	size_t n = bench_size(1000000);
	double *xy = malloc(2 * n * sizeof(*xy));
	struct asph_delaunay *w = asph_delaunay_alloc(n);
	int misses = 0;

	if (!xy || !w) {
		fprintf(stderr, "out of memory for %zu points\n", n);
		return 1;
	}
	printf("Delaunay triangulation of %zu points\n", n);
#if !HAVE_QHULL
	printf("Qhull not available: no baseline, our times only\n");
#endif
	size_t m = 0;
	double *plan = plan_points(n, &m);
	if (plan) {
		struct asph_delaunay *wp = asph_delaunay_alloc(m);
		if (!wp)
			abort();
		misses += bench_layout("plan-op (strong)", plan, m, wp);
		asph_delaunay_free(wp);
		free(plan);
	}
	involute_points(xy, n);
	misses += bench_layout("involute", xy, n, w);
	uniform_points(xy, n);
	misses += bench_layout("uniform", xy, n, w);
	asph_delaunay_free(w);
	free(xy);
	return misses ? 1 : 0;
}
