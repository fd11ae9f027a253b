/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_REPORT_H
#define ASPH_REPORT_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "asph/areal.h"
#include "asph/error.h"
#include "asph/fit.h"
#include "asph/tolerance.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The measurement report: an A4 PDF drawn with cairo's PDF surface
 * (docs/characterization.md, "The report"). Page 1: what was measured
 * (part, lot, serial), when (the measurement and the report, ISO 8601 in
 * the local time zone with its offset), by whom and on which instrument;
 * the lens, plan and data summarised with their SHA-256; the verdict, the
 * table of values, expanded uncertainties and limits, the residual map
 * and the radial profiles. Page 2: the fit, the Zernike terms and the PSD.
 * Then the lens, plan and instrument descriptions in full, wrapped. Every
 * text is wrapped inside the margins. Without cairo at build time:
 * -ENOTSUP.
 */
struct asph_report {
	const char *part, *lot, *serial;    /* NULL: not given */
	const char *operator_name;          /* who measured (the job's
					       submitter); NULL: not given */
	/* Realtime ns since the Unix epoch; 0: not known. */
	int64_t measured_ns;                /* the measurement's start */
	int64_t measured_end_ns;            /* its end */
	int64_t reported_ns;                /* the report's; 0: now */
	int64_t job;                        /* asphd's job number; 0: none */
	const char *label;                  /* the job's label; NULL: none */
	const char *lens_name;
	const char *lens_json;              /* provenance texts, hashed, */
	const char *plan_json;              /* summarised on page 1 and given */
	const char *instrument_json;        /* in full; NULL: not known */
	const char *instrument_name;        /* NULL: instrument_json's "name" */
	const char *data_name;              /* the measured data, hashed */
	const void *data;
	size_t data_len;
	const char *data_sha256;            /* NULL: hashed from data */
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

/*
 * The smallest residual PV (nm) the report tells apart from the numerical
 * noise of a fit in double precision over an aperture of radius_mm: 1000
 * rounding steps of the radius (DBL_EPSILON radius_mm). Exact points of
 * the three built-in lenses, aligned or misaligned, leave a PV of 0.7 to
 * 3.2 such steps. A map whose PV is below it is drawn on the fixed scale of
 * +- this value and said to be numerical noise, never stretched.
 */
double asph_report_noise_floor_nm(double radius_mm);

#ifdef __cplusplus
}
#endif

#endif
