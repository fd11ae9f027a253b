/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A fit's summary (the JSON of asph_fit_result_to_json(), as `asph fit
 * --json` prints it and asphd stores it) as text for people: what `asph
 * fit`, `asph replay` and `asphctl result` print, each quantity formatted
 * by the table of lib/util/quantity.h, so that it reads the same in all
 * three.
 */
#ifndef ASPH_TOOLS_FIT_SUMMARY_H
#define ASPH_TOOLS_FIT_SUMMARY_H

#include <stdio.h>

#include <jansson.h>

/* The fit (points, convergence), the pose with its standard uncertainty,
 * the residual, the ISO 14999-4 quantities, the slope, the radius and the
 * verdict, each line led by indent. */
void fit_summary_print(FILE *f, const json_t *summary, const char *indent);

/* The Zernike terms of the residual, four to a line. */
void fit_summary_print_zernike(FILE *f, const json_t *summary, const char *indent);

/* The acquisition's account (asphd's results, asph replay): where the
 * positions came from, the drift correction, the warnings. */
void fit_summary_print_acquisition(FILE *f, const json_t *acquisition, const char *indent);

#endif
