/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Measuring time per plan on the realistic bench (mock:bench=realistic),
 * strong at h = 0.01 (ASPH_BENCH_H sets h), the table a user chooses a
 * plan by: for CI, concentric, raster and spiral,
 *
 * - the feed-rate planner's time along the path against the kinematic
 *   lower bound for the same points and limits, computed independently
 *   of lib/motion in motion-bound.c: no motion through the points in
 *   order within each axis' speed, acceleration and jerk and the probe's
 *   rate is faster. It adds each segment's least time (the slowest axis at
 *   its speed, the probe's rate) and, where an axis turns back or the path
 *   starts and ends at rest, the least time of a jerk-limited reversal or
 *   start (docs/scanning.md states the argument). Target <= 1.10.
 * - the prediction (asph_scan_estimate(), what asph plan --estimate and
 *   job.submit's estimate_s say) against the duration the executor takes
 *   on the simulated bench at time_factor=0. Target within 5 %.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph-engine/executor.h"
#include "asph/motion.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "bench-common.h"
#include "motion-bound.h"

#define SPEC "mock:time_factor=0,bench=realistic"

/* The limits the executor's planner gets from the described instrument. */
static void limits_of(const struct asph_stage_info *si, const struct asph_probe_info *pi,
		      struct asph_motion_limits *lim)
{
	memset(lim, 0, sizeof(*lim));
	for (int k = 0; k < 3; k++) {
		lim->speed[k] = si->axes[k].max_speed > 0 ? si->axes[k].max_speed : 1e6;
		lim->accel[k] = si->max_accel[k];
		lim->jerk[k] = si->max_jerk[k];
	}
	lim->rate = pi->rate;
}

/* The executor measuring the plan on the simulated bench: its duration on
 * the instrument's clock. */
static double simulated(struct asph_registry *reg, const struct asph_surface *s,
			const struct asph_plan *plan, const char *path)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", "{\"method\":\"bench\"}",
						  "{\"name\":\"mock\"}", NULL };
	struct asph_scanfile_writer_options wo = { .flags = ASPH_SCANFILE_OVERWRITE };
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	struct asph_scanfile_writer *w;
	struct asph_config *cfg;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_error err;
	double t = -1;

	if (asph_instrument_spec_parse(reg, SPEC, &cfg, &err) < 0 ||
	    asph_instrument_open(&cfg->instruments[0], 1000, &inst, &err) < 0) {
		fprintf(stderr, "bench-motion: %s\n", err.message);
		exit(1);
	}
	if (asph_scan_new(inst, s, plan->xyz, plan->n, &so, &sc, &err) == 0 &&
	    asph_scanfile_writer_create(path, &info, &wo, &w, &err) == 0) {
		uint64_t t0 = asph_instrument_clock(inst);
		if (asph_scan_run(sc, w, &err) == 0)
			t = (double)(asph_instrument_clock(inst) - t0) * 1e-9;
		asph_scan_free(sc);
	}
	if (t < 0)
		fprintf(stderr, "bench-motion: scan: %s\n", err.message);
	asph_instrument_close(inst);
	asph_config_free(cfg);
	return t;
}

int main(void)
{
	static const enum asph_plan_method methods[] = {
		ASPH_PLAN_CI, ASPH_PLAN_CONCENTRIC, ASPH_PLAN_RASTER, ASPH_PLAN_SPIRAL,
	};
	const char *henv = getenv("ASPH_BENCH_H");
	double h = henv ? atof(henv) : 0.01;
	struct asph_prescription pr;
	struct asph_surface *s;
	struct asph_registry *reg;
	struct asph_config *cfg;
	struct asph_stage_info si;
	struct asph_probe_info pi;
	struct asph_motion_limits lim;
	struct asph_motion_planner *pl;
	struct asph_error err;
	char path[256];
	int miss = 0;

	if (asph_registry_new(&reg, NULL) < 0 || !asph_registry_find(reg, "mock")) {
		printf("bench-motion: the mock driver is not built (-Ddrivers): skipped\n");
		asph_registry_free(reg);
		return 77;
	}
	if (asph_prescription_preset("strong", &pr) < 0 || asph_surface_alloc(&pr, &s, NULL) < 0 ||
	    asph_instrument_spec_parse(reg, SPEC, &cfg, &err) < 0 ||
	    asph_instrument_describe(&cfg->instruments[0], &si, &pi, &err) < 0 ||
	    asph_motion_planner_alloc(0, &pl) < 0) {
		fprintf(stderr, "bench-motion: setup failed\n");
		return 1;
	}
	limits_of(&si, &pi, &lim);
	snprintf(path, sizeof(path), "/tmp/bench-motion-%d.asph", (int)getpid());
	printf("bench-motion: strong, h = %g, %s\n", h, SPEC);
	printf("| plan | points | path (mm) | segments (s) | lower bound (s) | planner (s) | "
	       "planner / bound | predicted (s) | simulated (s) | predicted / simulated |\n");
	printf("|---|---|---|---|---|---|---|---|---|---|\n");
	for (size_t k = 0; k < sizeof(methods) / sizeof(methods[0]); k++) {
		struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
		struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
		struct asph_plan *plan;
		double len, planned, est;

		if (asph_plan_compute_opts(s, methods[k], (struct asph_plan_density){ ASPH_DENSITY_H, h },
					   &po, &plan, &err) < 0) {
			fprintf(stderr, "bench-motion: plan: %s\n", err.message);
			return 1;
		}
		double *m = malloc(3 * plan->n * sizeof(double));
		for (size_t i = 0; i < plan->n; i++) {
			m[3 * i] = plan->xyz[3 * i];
			m[3 * i + 1] = plan->xyz[3 * i + 1];
			m[3 * i + 2] = plan->xyz[3 * i + 2] - pi.standoff;
		}
		struct mb_axis ax[3];
		struct mb_stats st;
		for (int a = 0; a < 3; a++)
			ax[a] = (struct mb_axis){ lim.speed[a], lim.accel[a], lim.jerk[a] };
		double bound = mb_path_bound(m, plan->n, ax, lim.rate, &st);
		if (bound < 0) {
			fprintf(stderr, "bench-motion: out of memory\n");
			return 1;
		}
		len = st.length;
		if (asph_motion_path_duration(pl, m, plan->n, &lim, &planned, &err) < 0 ||
		    asph_scan_estimate(&cfg->instruments[0], s, plan->xyz, plan->n, &so, &est,
				       &err) < 0) {
			fprintf(stderr, "bench-motion: %s\n", err.message);
			return 1;
		}
		double sim = simulated(reg, s, plan, path);
		printf("| %s | %zu | %.0f | %.1f | %.1f | %.1f | %.3f | %.1f | %.1f | %.3f |\n",
		       asph_plan_method_name(methods[k]), plan->n, len, st.segments, bound, planned,
		       planned / bound, est, sim, est / sim);
		char name[96];
		snprintf(name, sizeof(name), "%s: planner over the lower bound",
			 asph_plan_method_name(methods[k]));
		miss |= bench_report(name, planned, bound, 1.10);
		snprintf(name, sizeof(name), "%s: prediction over the simulated duration",
			 asph_plan_method_name(methods[k]));
		miss |= !(sim > 0) || fabs(est / sim - 1) > 0.05;
		printf("%s: %.3f (target within 5 %%): %s\n", name, est / sim,
		       fabs(est / sim - 1) <= 0.05 ? "PASS" : "MISS");
		free(m);
		asph_plan_free(plan);
	}
	remove(path);
	asph_motion_planner_free(pl);
	asph_config_free(cfg);
	asph_registry_free(reg);
	asph_surface_free(s);
	return miss;
}
