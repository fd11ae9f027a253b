/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The report's figures: the residual map, the radial profiles, the
 * Zernike terms and the PSD, each with its title, axes, labels (7 pt or
 * larger) and legend inside the area it is given. Internal to lib/plot. */
#ifndef ASPH_REPORT_CHART_H
#define ASPH_REPORT_CHART_H

#include "config.h"
#include "asph/report.h"

/* A rectangle on the page, points, y down. */
struct report_rect {
	double x, y, w, h;
};

/* The smallest text of a figure (tick labels, legend, notes), points. */
#define REPORT_MIN_TEXT 7.0

#if HAVE_CAIRO
#include <cairo.h>

/* noise_nm > 0: the residual is numerical noise below it (drawn on the
 * fixed scale +- noise_nm, and a note says so). -ENOMEM. */
int report_map(cairo_t *cr, const struct report_rect *area, const struct asph_report *r,
	       double noise_nm);
int report_profiles(cairo_t *cr, const struct report_rect *area, const struct asph_report *r,
		    double noise_nm);
void report_zernike(cairo_t *cr, const struct report_rect *area,
		    const struct asph_fit_result *f);
int report_psd(cairo_t *cr, const struct report_rect *area, const struct asph_report *r);
#endif

#endif
