/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph fit --uncertainty: the Monte Carlo on the instrument's model. */
#ifndef ASPH_TOOL_FIT_UNCERTAINTY_H
#define ASPH_TOOL_FIT_UNCERTAINTY_H

#include "asph/characterize.h"
#include "asph/uncertainty.h"

struct fit_mc_cli {
	int enabled;
	const char *instrument;   /* FILE or FILE#NAME, else the scan's */
	int seed_set;
	int threads;              /* --threads; 0 = the online processors */
	int quiet;                /* no progress line */
	struct asph_mc_options opts;
};

enum {
	OPT_MC_UNCERTAINTY = 0x200,
	OPT_MC_INSTRUMENT,
	OPT_MC_TRIALS,
	OPT_MC_FIXED,
	OPT_MC_THREADS,
	OPT_MC_SEED,
};

#define FIT_MC_LONGOPTS \
	{ "uncertainty", no_argument, NULL, OPT_MC_UNCERTAINTY }, \
	{ "instrument", required_argument, NULL, OPT_MC_INSTRUMENT }, \
	{ "trials", required_argument, NULL, OPT_MC_TRIALS }, \
	{ "fixed-trials", no_argument, NULL, OPT_MC_FIXED }, \
	{ "threads", required_argument, NULL, OPT_MC_THREADS }, \
	{ "seed", required_argument, NULL, OPT_MC_SEED }

/* Takes one of the options above: 0, or -1 after saying what is wrong. */
int fit_mc_take_option(struct fit_mc_cli *c, int opt, const char *arg);

/* After all options: the options that need --uncertainty have it.
 * EXIT_OK or EXIT_USAGE. */
int fit_mc_check(const struct fit_mc_cli *c);
#define FIT_MC_HELP \
	"  --uncertainty       the measurement uncertainty by Monte Carlo (GUM S1) on the\n" \
	"                      instrument's declared contributions: U (k = 2) of every\n" \
	"                      quantity into uncertainty_k2 and the verdict, with:\n" \
	"    --instrument CONFIG   the configuration (FILE or FILE#NAME) that declares them\n" \
	"                          (default: the instrument recorded in --scan)\n" \
	"    --trials N            trials (default 200); more in blocks of 50 until the\n" \
	"                          adaptive stop (GUM S1 7.9) finds them stable, at most 2000\n" \
	"    --fixed-trials        exactly N trials, no adaptive stop\n" \
	"    --threads N           worker threads (default: the online processors)\n" \
	"    --seed S              of the trials' draws (default 1)\n"

/* The Monte Carlo of a characterization: the model and the threads. */
struct progress;
struct fit_mc_run {
	struct asph_uncertainty_model model;
	int threads;
	int quiet;                /* no progress line */
	struct progress *before;  /* a progress line to clear first (the fit's) */
};

/*
 * With --uncertainty: the model (from --instrument, else the instrument
 * recorded in the scan named scan, instrument_json; scan NULL: none), the
 * Monte Carlo's options and its runner on run into o. EXIT_OK or the exit
 * code after saying why.
 */
int fit_mc_prepare(const struct fit_mc_cli *c, const char *scan, const char *instrument_json,
		   struct fit_mc_run *run, struct asph_characterize_options *o);

/* The trials on run->threads workers, their progress on a terminal unless
 * run->quiet: an asph_characterize_mc_fn whose data is a struct
 * fit_mc_run. */
int fit_mc_run_threads(void *run, struct asph_mc *mc, struct asph_mc_result *out,
		       struct asph_error *err);

/* A whole number in lo..hi for option --name: 0, or -1 after saying what
 * is wrong, after "who: " ("asph fit"). */
int fit_mc_parse_count(const char *who, const char *arg, const char *name, unsigned long lo,
		       unsigned long hi, unsigned long *out);

/* The text summary of the Monte Carlo. */
void fit_mc_show(const struct asph_mc_result *mc);

#endif
