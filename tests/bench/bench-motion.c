/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Measuring time per plan on the realistic bench (mock:bench=realistic),
 * strong at h = 0.01 (ASPH_BENCH_H sets h), the table a user chooses a
 * plan by: for CI, concentric, raster and spiral,
 *
 * - the feed-rate planner's time along the path against the kinematic
 *   lower bound for the same path and limits, computed here independently
 *   as the time-optimal velocity profile along the polyline through the
 *   points (a forward and a backward pass): each axis's speed, its
 *   acceleration along the path and across it at each corner (v^2 times
 *   the turn's curvature), one reading per point at the probe's rate;
 *   jerk left out, which only lowers the bound. Target <= 1.10.
 * - the prediction (asph_scan_estimate(), what asph plan --estimate and
 *   job.submit's estimate_s say) against the duration the executor takes
 *   on the simulated bench at time_factor=0. Target within 5 %.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph/executor.h"
#include "asph/motion.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "bench-common.h"

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

/* The largest s with |s u_k| <= cap_k on every axis (cap 0: none). */
static double along(const double u[3], const double cap[3])
{
	double s = INFINITY;

	for (int k = 0; k < 3; k++)
		if (cap[k] > 0 && fabs(u[k]) > 1e-15)
			s = fmin(s, cap[k] / fabs(u[k]));
	return s;
}

/* Time of a segment of length d from speed v0 to v1, at most vmax, with
 * acceleration a (INFINITY: none): up, cruise, down. */
static double segment_time(double d, double v0, double v1, double vmax, double a)
{
	if (!(d > 0))
		return 0;
	if (isinf(a))
		return d / vmax;
	double vp = fmin(vmax, sqrt((2 * a * d + v0 * v0 + v1 * v1) / 2));
	double up = (vp * vp - v0 * v0) / (2 * a), down = (vp * vp - v1 * v1) / (2 * a);
	double cruise = fmax(0, d - up - down);
	return (vp - v0) / a + (vp - v1) / a + cruise / vp;
}

/* The time-optimal profile along the polyline through the n points m. */
static double lower_bound(const double *m, size_t n, const struct asph_motion_limits *lim,
			  double *length)
{
	double *ds = calloc(n, sizeof(double)), *u = calloc(3 * n, sizeof(double));
	double *vcap = calloc(n, sizeof(double)), *v = calloc(n, sizeof(double));
	double *acc = calloc(n, sizeof(double)), *vseg = calloc(n, sizeof(double)), t = 0;

	*length = 0;
	for (size_t i = 0; i + 1 < n; i++) {
		double d[3];
		for (int k = 0; k < 3; k++)
			d[k] = m[3 * (i + 1) + k] - m[3 * i + k];
		ds[i] = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
		*length += ds[i];
		for (int k = 0; k < 3; k++)
			u[3 * i + k] = ds[i] > 0 ? d[k] / ds[i] : 0;
		vseg[i] = along(u + 3 * i, lim->speed);
		acc[i] = along(u + 3 * i, lim->accel);
	}
	for (size_t i = 0; i < n; i++) {
		vcap[i] = INFINITY;
		if (i == 0 || i + 1 == n) {
			vcap[i] = 0;
			continue;
		}
		vcap[i] = fmin(vseg[i - 1], vseg[i]);
		/* the turn: curvature |u_i - u_(i-1)| over the mean length */
		double dn[3], len = 0, h = (ds[i - 1] + ds[i]) / 2;
		for (int k = 0; k < 3; k++) {
			dn[k] = u[3 * i + k] - u[3 * (i - 1) + k];
			len += dn[k] * dn[k];
		}
		len = sqrt(len);
		if (len > 1e-12 && h > 0) {
			double kappa = len / h, nrm[3] = { dn[0] / len, dn[1] / len, dn[2] / len };
			double ac = along(nrm, lim->accel);
			if (isfinite(ac))
				vcap[i] = fmin(vcap[i], sqrt(ac / kappa));
		}
	}
	/* forward and backward: reachable with the acceleration along the path */
	v[0] = 0;
	for (size_t i = 1; i < n; i++)
		v[i] = fmin(vcap[i], isinf(acc[i - 1]) ? INFINITY
					: sqrt(v[i - 1] * v[i - 1] + 2 * acc[i - 1] * ds[i - 1]));
	for (size_t i = n - 1; i-- > 0;)
		v[i] = fmin(v[i], isinf(acc[i]) ? INFINITY : sqrt(v[i + 1] * v[i + 1] + 2 * acc[i] * ds[i]));
	for (size_t i = 0; i + 1 < n; i++) {
		double ti = segment_time(ds[i], fmin(v[i], vseg[i]), fmin(v[i + 1], vseg[i]), vseg[i],
					 acc[i]);
		/* one reading per point at the probe's rate */
		t += lim->rate > 0 ? fmax(ti, 1 / lim->rate) : ti;
	}
	free(ds);
	free(u);
	free(vcap);
	free(v);
	free(acc);
	free(vseg);
	return t;
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
	printf("| plan | points | path (mm) | lower bound (s) | planner (s) | ratio | "
	       "predicted (s) | simulated (s) | predicted / simulated |\n");
	printf("|---|---|---|---|---|---|---|---|---|\n");
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
		double bound = lower_bound(m, plan->n, &lim, &len);
		if (asph_motion_path_duration(pl, m, plan->n, &lim, &planned, &err) < 0 ||
		    asph_scan_estimate(&cfg->instruments[0], s, plan->xyz, plan->n, &so, &est,
				       &err) < 0) {
			fprintf(stderr, "bench-motion: %s\n", err.message);
			return 1;
		}
		double sim = simulated(reg, s, plan, path);
		printf("| %s | %zu | %.0f | %.1f | %.1f | %.3f | %.1f | %.1f | %.3f |\n",
		       asph_plan_method_name(methods[k]), plan->n, len, bound, planned,
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
