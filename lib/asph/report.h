/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_REPORT_H
#define ASPH_REPORT_H

#include <stddef.h>
#include <stdio.h>

#include "asph/areal.h"
#include "asph/error.h"
#include "asph/fit.h"
#include "asph/tolerance.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The measurement report: one A4 PDF page drawn with cairo's PDF surface
 * (docs/characterization.md, "The report"): the part (part, lot, serial),
 * lens, plan and instrument with the SHA-256 of each description and of the
 * measured data, the verdict table (values, expanded uncertainties,
 * limits), the residual map, the radial profile, the Zernike terms and the
 * PSD. Without cairo at build time: -ENOTSUP.
 */
struct asph_report {
	const char *part, *lot, *serial;    /* NULL: not given */
	const char *lens_name;
	const char *lens_json;              /* provenance texts, hashed and */
	const char *plan_json;              /* summarised; NULL: not known */
	const char *instrument_json;
	const char *data_name;              /* the measured data, hashed */
	const void *data;
	size_t data_len;
	const char *software;               /* e.g. "asph 0.1.0" */
	const struct asph_fit_result *fit;
	const struct asph_tolerance *tolerance;   /* NULL: none */
	/* The residual of the used points (part frame, mm; nm) and its
	 * interpolant over the aperture of radius `radius`. */
	const double *xy, *residual_nm;
	size_t n;
	const struct asph_scatter *scatter;
	double radius;
	/* asph_psd_residual() of scatter and radius when the caller has it
	 * (the daemon writes it to psd.csv too); NULL: computed here. */
	const struct asph_psd *psd;
};

int asph_report_write_pdf(const char *path, const struct asph_report *r,
			  struct asph_error *err);
/* The same written to f (name for messages); f is flushed, not closed. */
int asph_report_write_pdf_stream(FILE *f, const char *name, const struct asph_report *r,
				 struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
