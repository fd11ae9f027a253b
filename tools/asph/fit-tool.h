/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What asph fit and asph replay share: the fit's options, the fit and how
 * it is shown. */
#ifndef ASPH_TOOL_FIT_H
#define ASPH_TOOL_FIT_H

#include <stdint.h>
#include <stdio.h>

#include "asph/areal.h"
#include "asph/correction.h"
#include "asph/fit.h"
#include "asph/points.h"
#include "asph/tolerance.h"
#include "fit-uncertainty.h"

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
};

/* The fit's options and `operands` operands (asph fit: LENS POINTS_FILE,
 * asph replay: SCAN, in points). EXIT_OK, the exit code to leave with, or
 * -1 after --help. */
int fit_cli_parse(struct fit_cli *c, int argc, char **argv, int operands,
		  void (*usage_fn)(FILE *out));

/* Fits pts to s and shows it (JSON with acquisition, a JSON object's text,
 * as member "acquisition" when not NULL; the text followed by
 * more_text()). Writes --residuals and --map. An exit code. */
int fit_cli_run(const struct fit_cli *c, const struct asph_surface *s,
		const struct asph_points *pts, const char *acquisition,
		void (*more_text)(void *data), void *data);

#endif
