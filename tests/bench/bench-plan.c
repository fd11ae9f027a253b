/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Time to produce a sampling plan of ~1e6 points (ASPH_BENCH_N) on the
 * `strong` lens, per method, as a ratio to a baseline measured in the same
 * run: evaluating the sag at 1e6 given (x, y) and storing x, y, z.
 *
 * The plans are timed without their mesh (ASPH_PLAN_NO_MESH): the Delaunay
 * triangulation of the disk grid belongs to bench-delaunay. The grid
 * methods are also shown with the mesh, for information (no target).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "asph/plan.h"
#include "asph/prescription.h"
#include "bench-common.h"

struct baseline_ctx {
	const struct asph_surface *s;
	const double *xy;
	size_t n;
	double sink;
};

static void run_baseline(void *p)
{
	struct baseline_ctx *c = p;
	double *xyz = malloc(3 * c->n * sizeof(*xyz));

	if (!xyz)
		abort();
	for (size_t i = 0; i < c->n; i++) {
		double x = c->xy[2 * i], y = c->xy[2 * i + 1];
		xyz[3 * i] = x;
		xyz[3 * i + 1] = y;
		xyz[3 * i + 2] = asph_surface_sag(c->s, sqrt(x * x + y * y));
	}
	c->sink += xyz[3 * (c->n / 2) + 2];
	free(xyz);
}

struct plan_ctx {
	const struct asph_surface *s;
	enum asph_plan_method m;
	struct asph_plan_density d;
	unsigned flags;
	size_t n;
};

static void run_plan(void *p)
{
	struct plan_ctx *c = p;
	struct asph_plan_options o = { .flags = c->flags };
	struct asph_plan *plan = NULL;
	struct asph_error err;

	if (asph_plan_compute_opts(c->s, c->m, c->d, &o, &plan, &err) < 0) {
		fprintf(stderr, "bench-plan: %s: %s\n",
			asph_plan_method_name(c->m), err.message);
		exit(1);
	}
	c->n = plan->n;
	asph_plan_free(plan);
}

/* Points spread over the aperture like a plan's (uniform in area). */
static double *baseline_points(double a, size_t n)
{
	double *xy = malloc(2 * n * sizeof(*xy));
	const double golden = M_PI * (3.0 - sqrt(5.0));

	if (!xy)
		abort();
	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt(((double)i + 0.5) / (double)n);
		xy[2 * i] = r * cos(golden * (double)i);
		xy[2 * i + 1] = r * sin(golden * (double)i);
	}
	return xy;
}

static double target_of(enum asph_plan_method m)
{
	return m == ASPH_PLAN_CI || m == ASPH_PLAN_LB ? 10.0 : 3.0;
}

int main(void)
{
	struct asph_prescription pr;
	struct asph_surface *s = NULL;
	struct asph_error err;
	size_t n = bench_size(1000000);
	int misses = 0;

	if (asph_prescription_preset("strong", &pr) < 0 ||
	    asph_surface_alloc(&pr, &s, &err) < 0) {
		fprintf(stderr, "bench-plan: cannot build the strong lens\n");
		return 1;
	}
	struct baseline_ctx b = { s, baseline_points(asph_surface_aperture_radius(s), n), n, 0 };
	double base = bench_median(run_baseline, &b, 5);
	printf("plan benchmark, strong lens, %zu points\n", n);
	bench_report("baseline: sag at n points, store x,y,z", base, base, 0);
	for (int m = 0; m < ASPH_PLAN_N_METHODS; m++) {
		/* cvt's Lloyd iterations take minutes at this size: it is
		 * timed by bench-plan-freeform at 1e5 points */
		if (m == ASPH_PLAN_CVT)
			continue;
		struct plan_ctx c = { s, (enum asph_plan_method)m,
				      { ASPH_DENSITY_POINTS, (double)n },
				      ASPH_PLAN_NO_MESH, 0 };
		char name[96];
		double t = bench_median(run_plan, &c, 3);
		/* Per point, since a method's count is only close to n. */
		t *= (double)n / (double)c.n;
		snprintf(name, sizeof(name), "%s (%zu points)",
			 asph_plan_method_name(c.m), c.n);
		misses += bench_report(name, t, base, target_of(c.m));
	}
	for (int m = ASPH_PLAN_OP; m <= ASPH_PLAN_LB; m++) {
		struct plan_ctx c = { s, (enum asph_plan_method)m,
				      { ASPH_DENSITY_POINTS, (double)n }, 0, 0 };
		char name[96];
		snprintf(name, sizeof(name), "%s with its mesh (information)",
			 asph_plan_method_name(c.m));
		bench_report(name, bench_median(run_plan, &c, 1), base, 0);
	}
	free((void *)b.xy);
	asph_surface_free(s);
	printf("%d method(s) missed the target\n", misses);
	return misses ? 1 : 0;
}
