/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph fit --uncertainty: the Monte Carlo on the instrument's model, its
 * options, its summary and its keys in the JSON. */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <jansson.h>

#include "acquire-tool.h"
#include "asph-mc/mc-runner.h"
#include "asph-tool.h"
#include "fit-uncertainty.h"
#include "progress.h"
#include "quantity.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_registry *, asph_registry_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)

int fit_mc_parse_count(const char *who, const char *arg, const char *name, unsigned long lo,
		       unsigned long hi, unsigned long *out)
{
	char *end;
	unsigned long v;

	errno = 0;
	v = strtoul(arg, &end, 10);
	if (errno || end == arg || *end || arg[0] == '-' || v < lo || v > hi) {
		fprintf(stderr, "%s: --%s: '%s' is not a whole number in %lu..%lu\n", who, name,
			arg, lo, hi);
		return -1;
	}
	*out = v;
	return 0;
}

int fit_mc_take_option(struct fit_mc_cli *c, int opt, const char *arg)
{
	unsigned long v;

	switch (opt) {
	case OPT_MC_UNCERTAINTY:
		c->enabled = 1;
		return 0;
	case OPT_MC_INSTRUMENT:
		c->instrument = arg;
		return 0;
	case OPT_MC_FIXED:
		c->opts.fixed = 1;
		return 0;
	case OPT_MC_TRIALS:
		if (fit_mc_parse_count("asph fit", arg, "trials", 2, ASPH_MC_DEFAULT_MAX_TRIALS, &v) < 0)
			return -1;
		c->opts.n_trials = v;
		return 0;
	case OPT_MC_THREADS:
		if (fit_mc_parse_count("asph fit", arg, "threads", 1, 256, &v) < 0)
			return -1;
		c->threads = (int)v;
		return 0;
	case OPT_MC_SEED:
		if (fit_mc_parse_count("asph fit", arg, "seed", 0, 4294967295ul, &v) < 0)
			return -1;
		c->opts.seed = v;
		c->seed_set = 1;
		return 0;
	default:
		return -1;
	}
}

int fit_mc_check(const struct fit_mc_cli *c)
{
	const struct asph_mc_options *o = &c->opts;

	if (!c->enabled && (c->instrument || o->n_trials || o->fixed || c->threads || c->seed_set)) {
		fprintf(stderr, "asph fit: --instrument, --trials, --fixed-trials, --threads and "
			"--seed go with --uncertainty\n");
		return EXIT_USAGE;
	}
	if (c->enabled && !o->fixed && o->n_trials && o->n_trials % ASPH_MC_DEFAULT_BLOCK) {
		fprintf(stderr, "asph fit: --trials %zu: the adaptive stop runs blocks of %d, so a "
			"multiple of %d (or --fixed-trials)\n", o->n_trials, ASPH_MC_DEFAULT_BLOCK,
			ASPH_MC_DEFAULT_BLOCK);
		return EXIT_USAGE;
	}
	return EXIT_OK;
}

/* The "uncertainty" member of an instrument's JSON (a scan header's); scan
 * names it in messages. */
static int model_from_scan(const char *scan, const char *instrument_json,
			   struct asph_uncertainty_model *m)
{
	_cleanup_(json_decrefp) json_t *root = instrument_json ?
		json_loads(instrument_json, 0, NULL) : NULL;
	json_t *u = json_object_get(root, "uncertainty");
	struct asph_error err;
	const char *key;
	json_t *v;

	if (!json_is_object(u)) {
		fprintf(stderr, "asph fit: --uncertainty: the instrument recorded in %s declares no "
			"uncertainty contributions (give --instrument CONFIG)\n", scan);
		return -1;
	}
	asph_error_clear(&err);
	asph_uncertainty_model_init(m);
	json_object_foreach(u, key, v) {
		if (!json_is_number(v) ||
		    asph_uncertainty_model_set(m, key, json_number_value(v), &err) < 0) {
			fprintf(stderr, "asph fit: %s: instrument.uncertainty.%s: %s\n", scan, key,
				err.message[0] ? err.message : "not a number");
			return -1;
		}
	}
	if (asph_uncertainty_model_check(m, &err) < 0) {
		fprintf(stderr, "asph fit: %s: instrument.uncertainty.%s: %s\n", scan, err.field,
			err.message);
		return -1;
	}
	return 0;
}

static int model_from_config(const char *arg, struct asph_uncertainty_model *m)
{
	_cleanup_(asph_registry_freep) struct asph_registry *reg = NULL;
	_cleanup_(asph_config_freep) struct asph_config *cfg = NULL;
	struct asph_error err;
	size_t idx;

	asph_error_clear(&err);
	if (tool_registry_new(NULL, &reg) < 0)
		return -1;
	if (asph_config_resolve(reg, arg, &cfg, &idx, &err) < 0) {
		tool_print_error("fit: --instrument", &err);
		return -1;
	}
	if (!cfg->instruments[idx].has_uncertainty) {
		fprintf(stderr, "asph fit: --instrument %s: the instrument '%s' declares no "
			"uncertainty contributions (an \"uncertainty\" section, docs/drivers.md)\n",
			arg, cfg->instruments[idx].name);
		return -1;
	}
	*m = cfg->instruments[idx].uncertainty;
	return 0;
}

/* The trials on --threads workers (drivers/mc/mc-runner.c), their progress
 * on a terminal (tools/progress.c). */
int fit_mc_run_threads(void *data, struct asph_mc *mc, struct asph_mc_result *out,
		       struct asph_error *err)
{
	const struct fit_mc_run *run = data;
	struct progress p;
	struct asph_mc_threads th = { .n_threads = run->threads, .progress = progress_show,
				      .progress_data = &p };
	int r;

	if (run->before)
		progress_stop(run->before);
	progress_start(&p, "Monte Carlo", "trials", run->quiet);
	r = asph_mc_run_threads(mc, &th, out, err);
	progress_stop(&p);
	return r;
}

int fit_mc_prepare(const struct fit_mc_cli *c, const char *scan, const char *instrument_json,
		   struct fit_mc_run *run, struct asph_characterize_options *o)
{
	if (!c->enabled)
		return EXIT_OK;
	if (c->instrument ? model_from_config(c->instrument, &run->model) < 0
			  : !scan ? (fprintf(stderr, "asph fit: --uncertainty needs --instrument "
						     "CONFIG or --scan SCAN (whose instrument "
						     "declares the contributions)\n"), -1)
				  : model_from_scan(scan, instrument_json, &run->model) < 0)
		return EXIT_FAILURE_RUN;
	run->threads = c->threads;
	run->quiet = c->quiet;
	o->uncertainty = &run->model;
	o->mc = c->opts;
	if (!c->seed_set)
		o->mc.seed = 1;
	o->run_mc = fit_mc_run_threads;
	o->run_mc_data = run;
	return EXIT_OK;
}

void fit_mc_show(const struct asph_mc_result *mc)
{
	const struct asph_uncertainty_model *m = &mc->model;

	printf("Monte Carlo (GUM S1): %zu trials%s%s, %zu failed, seed %lu\n", mc->n_trials,
	       mc->fixed ? "" : ", adaptive stop ", mc->fixed ? "" : mc->stable ? "stable" : "NOT stable",
	       mc->n_failed, mc->seed);
	printf("  model: probe %g nm, position %g um (step %g um), latency %g us at %g mm/s,\n"
	       "         drift %g nm, tip radius %g um\n", m->probe_noise_nm, m->position_noise_um,
	       m->position_resolution_um, m->latency_us, m->scan_speed_mm_s, m->drift_residual_nm,
	       m->tip_radius_um);
	for (int q = 0; q < ASPH_MC_N_QUANTITIES; q++) {
		const char *key = asph_mc_quantity_key((enum asph_mc_quantity)q);
		const struct quantity *row = quantity_by_u_key(key);
		char v[48], u[32], U[32];

		if (!mc->covered[q])
			continue;
		printf("  %-9s %16s  u %-10s U(k=2) %s\n", key,
		       quantity_format(row, mc->value[q], QUANTITY_UNIT, v, sizeof(v)),
		       quantity_format(row, mc->u[q], QUANTITY_NO_SIGN, u, sizeof(u)),
		       quantity_format(row, mc->U[q], QUANTITY_NO_SIGN, U, sizeof(U)));
	}
}
