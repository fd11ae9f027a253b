/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What asph fit and asph replay share: the fit's options, the fit and how
 * it is shown. */
#ifndef ASPH_TOOL_FIT_H
#define ASPH_TOOL_FIT_H

#include <stdint.h>
#include <stdio.h>

#include "asph/areal.h"
#include "asph/characterize.h"
#include "asph/correction.h"
#include "asph/fit.h"
#include "asph/points.h"
#include "asph/scanfile.h"
#include "asph/tolerance.h"
#include "fit-uncertainty.h"
#include "points-input.h"

struct fit_cli {
	const char *lens, *points, *residuals_out, *map_out, *tolerance_arg;
	struct asph_fit_options opts;
	struct asph_tolerance tolerance;
	int json;
	const char *x3p_out, *correction_out;
	double grid_spacing;
	struct asph_correction_options correction;
	const char *report_out, *part, *lot, *serial, *scan, *operator_name;
	int64_t measured_ns;            /* --measured; 0: not given */
	struct fit_mc_cli mc;
	int quiet;              /* no progress line */
	int bands_given;
	struct asph_bands bands;
	const char *out_dir;            /* asph replay --out */
	char *tolerance_json;           /* --tolerance's text */
	struct points_input input;      /* --format, --units */
};

/* Frees what parsing kept. */
void fit_cli_release(struct fit_cli *c);

/* The fit's options and `operands` operands (asph fit: 2, LENS
 * POINTS_FILE; asph replay: 1, SCAN, or LENS MEASURED), in lens (NULL
 * for a scan) and points. EXIT_OK, the exit code to leave with, or -1
 * after --help. */
int fit_cli_parse(struct fit_cli *c, int argc, char **argv, int operands,
		  void (*usage_fn)(FILE *out));

/* What is characterized: points (asph fit) or a recorded scan (asph
 * replay), on surface, and what names the run. */
struct fit_input {
	const struct asph_surface *surface;
	const struct asph_points *points;
	const struct asph_scanfile *scan;
	const char *name;               /* the points' or the scan's file */
	struct asph_characterize_run run;
};

/* Characterizes in and shows it (JSON, or the text followed by
 * more_text(), may be NULL), then writes the files the options ask for.
 * An exit code. */
int fit_cli_run(const struct fit_cli *c, const struct fit_input *in,
		void (*more_text)(const struct asph_characterize_result *res));

#endif
