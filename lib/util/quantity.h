/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The quantities of a characterization as people read them: one row per
 * quantity with where it stands in the summary (asph_fit_result_to_json()),
 * its key among the expanded uncertainties (uncertainty_k2, the Monte
 * Carlo) and in the verdict, its label, the unit it is printed in and its
 * decimals. Every text that shows a quantity (asph fit, asphctl result, the
 * report) formats it here, so that a quantity reads the same everywhere:
 * one value, one sign, one precision. The JSON keeps full precision in the
 * summary's units. Shared by libasph, asph and asphctl. Internal header.
 */
#ifndef ASPH_UTIL_QUANTITY_H
#define ASPH_UTIL_QUANTITY_H

#include <stdbool.h>
#include <stddef.h>

struct quantity {
	const char *path;       /* in the summary: "rms_nm", "form.A_nm", "dof.tx" */
	const char *u_key;      /* in uncertainty_k2 and the Monte Carlo, or NULL */
	const char *verdict;    /* the verdict item's "quantity", or NULL */
	const char *label;      /* "A", "slope RMS", ... */
	const char *unit;       /* as printed: "nm", "urad", "um", "mm", "fr", "" */
	double scale;           /* printed value = summary value * scale */
	int decimals;           /* after the point; < 0: the shortest exact (%g) */
	bool sign;              /* signed: positive values print with '+' */
	bool two_sided;         /* limited in magnitude: the tolerance zone is
				   [-limit, limit], the value keeps its sign */
};

/* The rows, and the row of a summary path, a verdict item or an
 * uncertainty key; NULL when there is none. */
const struct quantity *quantity_table(size_t *n);
const struct quantity *quantity_by_path(const char *path);
const struct quantity *quantity_by_verdict(const char *name);
const struct quantity *quantity_by_u_key(const char *key);

/* The unit as typeset where the text need not be ASCII (the report, the
 * web page): "µm" for "um", "µrad" for "urad"; else the unit as printed. */
const char *quantity_symbol(const struct quantity *q);

enum quantity_format_flags {
	QUANTITY_UNIT = 1u << 0,        /* followed by the unit: "-0.74 nm" */
	QUANTITY_NO_SIGN = 1u << 1,     /* an uncertainty or a limit: no '+' */
};

/*
 * v (in the summary's unit) as printed: "-0.74", "+12.0076" (a signed
 * quantity shows '+'), "0.00" (what rounds to zero has no sign); "-" when
 * v is not a number; "%g" when q is NULL; "%.6g" from QUANTITY_MAX_FIXED
 * in magnitude (as printed) on. flags: enum quantity_format_flags. Returns
 * buf. daemon/web/names.js (print-names) carries the rule to the web page.
 */
#define QUANTITY_MAX_FIXED 1e12
const char *quantity_format(const struct quantity *q, double v, unsigned flags, char *buf,
			    size_t size);

#endif
