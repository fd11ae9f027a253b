/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Points per second through the whole acquisition path: the executor
 * sweeping the mock stage, the mock optical probe streaming without delay,
 * the scan file writer recording every point, progress reported. Target:
 * at least 1,000,000 points/s sustained, on the ideal mock and on the
 * physical bench (bench=realistic: servo, latched encoders, latency, drift
 * references) at time_factor=0. The baseline, measured in the same
 * run, is the scan file writer alone appending the same points in the same
 * batches: the ratio says what the executor and the drivers add.
 * ASPH_BENCH_N sets the number of points (default 2,000,000). The files go
 * to $ASPH_BENCH_DIR, else /dev/shm when there is one (the writer's
 * fsyncs on a disk measure the disk, and vary with what else the machine
 * does), else /tmp.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph-engine/executor.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "bench-common.h"

struct ctx {
	const struct asph_surface *s;
	const struct asph_plan *plan;
	struct asph_instrument *inst;
	char path[256];
	struct asph_scanfile_point *pts;
	uint64_t reports;
	int failed;
};

static struct asph_scanfile_writer *writer(struct ctx *c)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						  "{\"name\":\"mock\"}", NULL };
	struct asph_scanfile_writer_options wo = { .flags = ASPH_SCANFILE_OVERWRITE };
	struct asph_scanfile_writer *w = NULL;
	struct asph_error err;

	if (asph_scanfile_writer_create(c->path, &info, &wo, &w, &err) < 0) {
		fprintf(stderr, "bench-scan: %s: %s\n", c->path, err.message);
		exit(1);
	}
	return w;
}

static void run_baseline(void *p)
{
	struct ctx *c = p;
	struct asph_scanfile_writer *w = writer(c);
	size_t n = c->plan->n;

	for (size_t i = 0; i < n; i += 4096) {
		size_t k = n - i < 4096 ? n - i : 4096;
		for (size_t j = 0; j < k; j++)
			c->pts[i + j].t_ns = asph_scanfile_writer_elapsed_ns(w);
		if (asph_scanfile_writer_append(w, c->pts + i, k, NULL) < 0)
			c->failed = 1;
	}
	if (asph_scanfile_writer_finish(w, ASPH_SCANFILE_COMPLETED, NULL, NULL) < 0)
		c->failed = 1;
}

static void count_report(const struct asph_scan_progress *p, void *data)
{
	struct ctx *c = data;
	c->reports++;
}

static void run_scan(void *p)
{
	struct ctx *c = p;
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM | ASPH_SCAN_NO_HOME,
					.progress = count_report, .progress_data = c };
	struct asph_scan *sc;
	struct asph_error err;

	if (asph_scan_new(c->inst, c->s, c->plan->xyz, c->plan->n, &so, &sc, &err) < 0 ||
	    asph_scan_run(sc, writer(c), &err) < 0) {
		fprintf(stderr, "bench-scan: %s\n", err.message);
		c->failed = 1;
	}
	asph_scan_free(sc);
}

int main(void)
{
	struct asph_prescription pr;
	struct asph_surface *s;
	struct asph_plan *plan;
	struct asph_registry *reg;
	struct asph_config *cfg;
	struct ctx c = { 0 };
	size_t n = bench_size(2000000);
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	struct asph_error err;

	if (asph_registry_new(&reg, NULL) == 0 && !asph_registry_find(reg, "mock")) {
		printf("bench-scan: the mock driver is not built (-Ddrivers): skipped\n");
		asph_registry_free(reg);
		return 77;
	}
	asph_registry_free(reg);
	if (asph_prescription_preset("strong", &pr) < 0 || asph_surface_alloc(&pr, &s, NULL) < 0 ||
	    asph_plan_compute_opts(s, ASPH_PLAN_FERMAT,
				   (struct asph_plan_density){ ASPH_DENSITY_POINTS, (double)n },
				   &po, &plan, &err) < 0 ||
	    asph_registry_new(&reg, NULL) < 0 ||
	    asph_instrument_spec_parse(reg, "mock:time_factor=0,probe=optical", &cfg, &err) < 0 ||
	    asph_instrument_open(&cfg->instruments[0], 1000, &c.inst, &err) < 0) {
		fprintf(stderr, "bench-scan: setup failed\n");
		return 1;
	}
	/* the stage is homed once; every run then sweeps from where it is */
	c.inst->stage_driver->stage->home(c.inst->stage, 1000, NULL);
	c.s = s;
	c.plan = plan;
	const char *dir = getenv("ASPH_BENCH_DIR");
	if (!dir)
		dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
	snprintf(c.path, sizeof(c.path), "%s/bench-scan-%d.asph", dir, (int)getpid());
	printf("bench-scan: recording to %s\n", c.path);
	c.pts = calloc(plan->n, sizeof(*c.pts));
	if (!c.pts)
		return 1;
	for (size_t i = 0; i < plan->n; i++)
		c.pts[i] = (struct asph_scanfile_point){
			.plan_index = i, .x = plan->xyz[3 * i], .y = plan->xyz[3 * i + 1],
			.z = plan->xyz[3 * i + 2], .raw = 2.0 };

	double base = bench_median(run_baseline, &c, 3);
	double t = bench_median(run_scan, &c, 3);
	double rate = (double)plan->n / t;
	printf("bench-scan: %zu points, writer alone %.0f points/s, scan %.0f points/s "
	       "(%llu progress reports per run)\n", plan->n, (double)plan->n / base, rate,
	       (unsigned long long)(c.reports / 3));
	int miss = bench_report("scan (executor + mock + recorder + progress)", t, base, 4.0);
	printf("scan rate %.0f points/s (target >= 1000000): %s\n", rate,
	       rate >= 1e6 ? "PASS" : "MISS");

	/* the same on the physical bench */
	struct asph_instrument *ideal = c.inst;
	struct asph_config *rcfg;
	if (asph_instrument_spec_parse(reg, "mock:time_factor=0,probe=optical,bench=realistic",
				       &rcfg, &err) < 0 ||
	    asph_instrument_open(&rcfg->instruments[0], 1000, &c.inst, &err) < 0) {
		fprintf(stderr, "bench-scan: realistic bench: %s\n", err.message);
		return 1;
	}
	c.inst->stage_driver->stage->home(c.inst->stage, 1000, NULL);
	c.reports = 0;
	double tr = bench_median(run_scan, &c, 3);
	double rate_r = (double)plan->n / tr;
	printf("bench-scan: bench=realistic: %.0f points/s\n", rate_r);
	miss |= bench_report("scan on bench=realistic", tr, base, 4.0);
	printf("scan rate on bench=realistic %.0f points/s (target >= 1000000): %s\n", rate_r,
	       rate_r >= 1e6 ? "PASS" : "MISS");
	asph_instrument_close(c.inst);
	asph_config_free(rcfg);
	c.inst = ideal;
	rate = fmin(rate, rate_r);
	unlink(c.path);
	free(c.pts);
	asph_instrument_close(c.inst);
	asph_config_free(cfg);
	asph_registry_free(reg);
	asph_plan_free(plan);
	asph_surface_free(s);
	return c.failed || miss || rate < 1e6;
}
