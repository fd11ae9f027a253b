/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The plans on freeform surfaces (~1e5 points, ASPH_BENCH_N), as a
 * ratio to one pass of the sag S(x, y) over the plan's own points measured
 * in the same run (issue targets: OT <= 200, CI <= 200). Two freeforms: an xy
 * polynomial over an off-centre rectangle and a Zernike sag over an
 * off-centre circle (those of the plan tests). The plans are timed without
 * their mesh; cvt (no target set) and lb are shown for information.
 * ASPH_BENCH_METHODS (e.g. "ot,ci") times only the methods it names: cvt
 * and lb take minutes.
 */
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/plan.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "bench-common.h"

struct sag_ctx {
	const struct asph_surface *s;
	const double *xyz;
	size_t n;
	double sink;
};

static void sag_pass(void *p)
{
	struct sag_ctx *c = p;
	double sum = 0;

	for (size_t i = 0; i < c->n; i++)
		sum += asph_surface_sag_xy(c->s, c->xyz[3 * i], c->xyz[3 * i + 1]);
	c->sink += sum;
}

struct plan_ctx {
	const struct asph_surface *s;
	enum asph_plan_method m;
	size_t n;
	struct asph_plan *keep;
};

static void run_plan(void *p)
{
	struct plan_ctx *c = p;
	struct asph_plan_options o = { .flags = ASPH_PLAN_NO_MESH };
	struct asph_plan *plan = NULL;
	struct asph_error err;

	if (asph_plan_compute_opts(c->s, c->m, (struct asph_plan_density){ ASPH_DENSITY_POINTS,
									   (double)c->n },
				   &o, &plan, &err) < 0) {
		fprintf(stderr, "bench-plan-freeform: %s: %s\n", asph_plan_method_name(c->m),
			err.message);
		exit(1);
	}
	asph_plan_free(c->keep);
	c->keep = plan;
}

static struct asph_surface *freeform(int which)
{
	struct asph_prescription p = { 0 };
	struct asph_surface *s = NULL;
	struct asph_error err;

	if (which == 0) {
		p = (struct asph_prescription){
			.type = ASPH_SURFACE_XY_POLYNOMIAL, .R = 61.7, .k = -0.83, .norm_radius = 15,
			.aperture = { ASPH_APERTURE_RECTANGULAR, 24, 17, { 1.7, 4.1 } },
		};
		p.C[asph_xy_index(2, 0)] = 0.21;
		p.C[asph_xy_index(0, 2)] = -0.13;
		p.C[asph_xy_index(2, 1)] = 0.041;
		p.C[asph_xy_index(0, 3)] = -0.027;
		p.C[asph_xy_index(3, 0)] = 0.019;
	} else {
		p = (struct asph_prescription){
			.type = ASPH_SURFACE_ZERNIKE_SAG, .R = 48.3, .k = -0.61, .norm_radius = 12,
			.aperture = { ASPH_APERTURE_CIRCULAR, 22, 22, { -0.9, 1.3 } },
		};
		for (int j = 4; j <= 22; j++)
			p.Zernike[j - 1] = 2e-3 * (j % 2 ? 1 : -1) / j;
	}
	if (asph_surface_alloc(&p, &s, &err) < 0) {
		fprintf(stderr, "bench-plan-freeform: %s\n", err.message);
		exit(1);
	}
	return s;
}

/* Whether ASPH_BENCH_METHODS, if set, names m. */
static bool selected(enum asph_plan_method m)
{
	const char *list = getenv("ASPH_BENCH_METHODS"), *name = asph_plan_method_name(m);
	size_t len = strlen(name);

	if (!list)
		return true;
	for (const char *p = list; (p = strstr(p, name)); p += len)
		if ((p == list || p[-1] == ',') && (p[len] == ',' || p[len] == '\0'))
			return true;
	return false;
}

int main(void)
{
	const char *names[] = { "xy polynomial, rectangle", "Zernike sag, off-centre circle" };
	const enum asph_plan_method methods[] = { ASPH_PLAN_OP, ASPH_PLAN_OT, ASPH_PLAN_CI,
						  ASPH_PLAN_CVT, ASPH_PLAN_LB };
	size_t n = bench_size(100000);
	int misses = 0;

	for (int k = 0; k < 2; k++) {
		struct asph_surface *s = freeform(k);
		printf("freeform plan benchmark, %s, %zu points\n", names[k], n);
		for (size_t m = 0; m < sizeof(methods) / sizeof(methods[0]); m++) {
			if (!selected(methods[m]))
				continue;
			struct plan_ctx c = { s, methods[m], n, NULL };
			/* cvt and lb, for information, once: they take minutes */
			bool once = methods[m] == ASPH_PLAN_LB || methods[m] == ASPH_PLAN_CVT;
			double t = bench_median(run_plan, &c, once ? 1 : 3);
			struct sag_ctx b = { s, c.keep->xyz, c.keep->n, 0 };
			double base = bench_median(sag_pass, &b, 7);
			char name[96];
			snprintf(name, sizeof(name), "%s (%zu points)", asph_plan_method_name(methods[m]),
				 c.keep->n);
			bool target = methods[m] == ASPH_PLAN_OT || methods[m] == ASPH_PLAN_CI;
			misses += bench_report(name, t, base, target ? 200 : 0);
			asph_plan_free(c.keep);
		}
		asph_surface_free(s);
	}
	printf("%d method(s) missed the target\n", misses);
	return misses ? 1 : 0;
}
