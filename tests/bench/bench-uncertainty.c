/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The Monte Carlo uncertainty, N = 200 trials of the whole characterization
 * of 10,000 points on every online processor, against one characterization
 * (fit, residual statistics, Zernike, form quantities, slope) of the same
 * points measured in the same run. Target: <= 1.2 N / cores. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

#include <gsl/gsl_errno.h>

#include "asph/fit.h"
#include "asph-mc/mc-runner.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "asph/uncertainty.h"
#include "bench-common.h"

#define TRIALS 200

struct ctx {
	const struct asph_surface *s;
	const double *xyz;
	size_t n;
	struct asph_fit *w;
	struct asph_fit_result res;
	struct asph_mc *mc;
	struct asph_mc_threads threads;
	struct asph_mc_result mcres;
	int failed;
};

static void characterize(void *p)
{
	struct ctx *c = p;
	struct asph_error err;

	if (asph_fit_run(c->w, c->xyz, c->n, &c->res, &err) < 0 || !c->res.converged) {
		fprintf(stderr, "characterization failed: %s\n", err.message);
		c->failed = 1;
	}
}

static void monte_carlo(void *p)
{
	struct ctx *c = p;
	struct asph_error err;

	if (asph_mc_run_threads(c->mc, &c->threads, &c->mcres, &err) < 0) {
		fprintf(stderr, "Monte Carlo failed: %s\n", err.message);
		c->failed = 1;
	}
}

/* Processor time of the whole process (every thread), seconds: on a
 * machine shared with other work the wall time of a parallel run says as
 * much about the others as about us, so both are printed. */
static double cpu_now(void)
{
	struct timespec ts;

	clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
	return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double *measured_points(const struct asph_surface *s, size_t n)
{
	struct asph_synth_term terms[] = { { 4, 31.0 }, { 5, -12.5 }, { 11, 8.25 } };
	struct asph_synth_options so = {
		.pose = { { 0.043, -0.071, 0.027 }, 6.3e-4, -3.7e-4, 0 },
		.terms = terms, .n_terms = 3, .noise_nm = 2.0, .seed = 5,
	};
	double a = 0.98 * asph_surface_aperture_radius(s), *xyz = malloc(3 * n * sizeof(double));

	if (!xyz)
		return NULL;
	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt((i + 0.5) / (double)n), t = 2.399963229728653 * (double)i;
		xyz[3 * i] = r * cos(t);
		xyz[3 * i + 1] = r * sin(t);
		xyz[3 * i + 2] = 0;
	}
	if (asph_fit_synthesize(s, xyz, n, &so, xyz, NULL) < 0) {
		free(xyz);
		return NULL;
	}
	return xyz;
}

int main(void)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;
	struct ctx c = { 0 };
	struct asph_uncertainty_model m = {
		.probe_noise_nm = 6, .position_noise_um = 0.2, .position_resolution_um = 0.05,
		.latency_us = 40, .scan_speed_mm_s = 4, .drift_residual_nm = 5,
		.tip_radius_um = 0.3,
	};
	long cpus = sysconf(_SC_NPROCESSORS_ONLN);
	int cores = cpus > 0 ? (int)cpus : 1;
	struct asph_mc_options o = { .n_trials = TRIALS, .fixed = 1, .seed = 1 };
	struct asph_error err;

	gsl_set_error_handler_off();
	c.threads.n_threads = cores;
	c.n = bench_size(10000);
	if (asph_prescription_preset("weak", &p) < 0 || asph_surface_alloc(&p, &s, NULL) < 0)
		return 1;
	c.s = s;
	c.xyz = measured_points(s, c.n);
	if (!c.xyz || asph_fit_alloc(s, c.n, NULL, &c.w, NULL) < 0)
		return 1;
	double cpu0 = cpu_now();
	double t_one = bench_median(characterize, &c, 5);
	double cpu_one = (cpu_now() - cpu0) / 5;
	if (c.failed)
		return 1;
	if (asph_mc_alloc(s, c.xyz, c.n, NULL, &c.res, &m, &o, &c.mc, &err) < 0) {
		fprintf(stderr, "%s\n", err.message);
		return 1;
	}
	cpu0 = cpu_now();
	double t_mc = bench_median(monte_carlo, &c, 1);
	double cpu_mc = cpu_now() - cpu0;
	if (c.failed)
		return 1;
	printf("%zu points, %d cores: one characterization %.4f s (%d iterations); "
	       "%zu trials, %zu failed, U(tz) %.3g mm, U(RMSt) %.3g nm\n", c.n, cores, t_one,
	       c.res.iterations, c.mcres.n_trials, c.mcres.n_failed, c.mcres.U[ASPH_FIT_TZ],
	       c.mcres.U[ASPH_MC_RMS_T]);
	double load[3] = { 0 };
	getloadavg(load, 3);
	printf("processor time: one characterization %.4f s, Monte Carlo %.3f s, ratio %.1f "
	       "(%.2f characterizations per trial); load average %.2f\n", cpu_one, cpu_mc,
	       cpu_mc / cpu_one, cpu_mc / cpu_one / TRIALS, load[0]);
	char label[96];
	snprintf(label, sizeof(label), "Monte Carlo N = %d on %d cores", TRIALS, cores);
	int miss = bench_report(label, t_mc, t_one, 1.2 * TRIALS / cores);
	asph_mc_free(c.mc);
	asph_fit_free(c.w);
	free((void *)c.xyz);
	asph_surface_free(s);
	return miss;
}
