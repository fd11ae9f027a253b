/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_TOLERANCE_H
#define ASPH_TOLERANCE_H

#include <stddef.h>

#include "asph/areal.h"
#include "asph/error.h"
#include "asph/form.h"
#include "asph/units.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Tolerances of a part and the decision whether it conforms (ISO 14253-1),
 * docs/characterization.md, "Tolerances and the verdict".
 *
 * The tolerance object (JSON):
 *   {"iso10110_5": "3/2(0.5/0.3)", "wavelength_nm": 546.07,
 *    "rms_nm": {"t": 60, "i": 40, "a": 25},
 *    "slope_urad": {"rms": 20, "max": 80, "length_mm": 1.0},
 *    "R_mm": 0.005}
 * Every member is optional, at least one limit is required. A JSON string
 * alone is a call-out alone.
 */

struct asph_tolerance {
	double wavelength_nm;        /* of the fringes */
	char callout[160];           /* as written, "" when none */
	/* Upper limits; NaN where not toleranced. A limits |A|. */
	asph_nm A, B, C;
	asph_nm rms_t, rms_i, rms_a;
	asph_urad slope_rms, slope_max;
	double slope_length_mm;      /* NaN without a slope limit */
	double R_mm;                 /* limit of |R - R_nominal| */
};

/* No limits, the default wavelength. */
void asph_tolerance_init(struct asph_tolerance *t);

/*
 * An ISO 10110-5 surface form call-out, e.g. "3/2(0.5/0.3)",
 * "3/-(1); RMSa < 0.1", "3/2(1/0.5; RMSi < 0.05)", "3/- RMSt < 100 nm",
 * with an optional "lambda = 632.8 nm" (or "λ = ..."). Numbers without a
 * unit are fringes of wavelength_nm (or of the call-out's lambda), "nm"
 * makes them nanometres; "-" leaves a quantity untoleranced. Fills t's
 * limits (and its wavelength when the call-out names one). On error
 * *column (may be NULL) is the 1-based byte column in callout where the
 * problem is, and err says why. -EINVAL.
 */
int asph_tolerance_parse_callout(const char *callout, double wavelength_nm,
				 struct asph_tolerance *t, int *column,
				 struct asph_error *err);

/* A tolerance object from JSON text; errors name source, line, column
 * (for a call-out: the column of the offending character in the text) and
 * the member. -EINVAL. */
int asph_tolerance_parse_json(const char *text, size_t len,
			      const char *source, struct asph_tolerance *t,
			      struct asph_error *err);

/*
 * What a tolerance given on a command line or in a form is, by the one
 * rule of asph, asphctl and the web page: JSON text when it starts (after
 * blanks) with '{' or '"', an ISO 10110-5 call-out when it starts with "3"
 * and "/" (blanks allowed: "3/2(0.5/0.3)"), else the name of a file holding
 * the JSON ("-": standard input; a file whose name starts with "3/" is
 * named "./3/...").
 */
enum asph_tolerance_arg_kind {
	ASPH_TOLERANCE_ARG_JSON = 0,
	ASPH_TOLERANCE_ARG_CALLOUT,
	ASPH_TOLERANCE_ARG_FILE,
};

static inline enum asph_tolerance_arg_kind asph_tolerance_arg_kind(const char *arg)
{
	while (*arg == ' ' || *arg == '\t' || *arg == '\n' || *arg == '\r')
		arg++;
	if (*arg == '{' || *arg == '"')
		return ASPH_TOLERANCE_ARG_JSON;
	if (*arg++ == '3') {
		while (*arg == ' ' || *arg == '\t')
			arg++;
		if (*arg == '/')
			return ASPH_TOLERANCE_ARG_CALLOUT;
	}
	return ASPH_TOLERANCE_ARG_FILE;
}

/* A tolerance as asph_tolerance_arg_kind() tells: the JSON text, the
 * call-out alone (errors give its column), or the file holding the JSON. */
int asph_tolerance_load(const char *arg, struct asph_tolerance *t,
			struct asph_error *err);
/* The same, keeping the JSON text read in *text (malloc'd), which a
 * result's provenance records. */
int asph_tolerance_load_text(const char *arg, struct asph_tolerance *t, char **text,
			     struct asph_error *err);

/* ---------------------------------------------------------------- verdict */

enum asph_verdict {
	ASPH_VERDICT_PASS = 0,
	ASPH_VERDICT_FAIL,
	ASPH_VERDICT_UNDECIDED,
};

/* "pass", "fail", "undecided" */
const char *asph_verdict_name(enum asph_verdict v);

/*
 * ISO 14253-1 for an upper limit L with the expanded uncertainty U:
 * pass when value + U <= L (conformance proven; on the limit passes),
 * fail when value - U > L (non-conformance proven; value - U = L is not),
 * undecided otherwise, and whenever value or U is not a number.
 */
enum asph_verdict asph_verdict_decide(double value, double U, double limit);

#define ASPH_VERDICT_MAX_ITEMS 9

struct asph_verdict_item {
	const char *quantity;       /* "A_nm", "B_nm", ..., "R_deviation_mm" */
	double value, U, limit;     /* NaN: not available. A and R_deviation
				       keep their sign and are decided on
				       their magnitude (zone [-limit, limit]) */
	enum asph_verdict verdict;
};

struct asph_verdict_report {
	int present;                /* a tolerance was given */
	enum asph_verdict overall;  /* fail if any fails, else undecided if
				       any is, else pass */
	size_t n_items;
	struct asph_verdict_item items[ASPH_VERDICT_MAX_ITEMS];
};

/*
 * One item per toleranced quantity, in the order A, B, C, RMSt, RMSi, RMSa,
 * slope RMS, slope max, R. slope may be NULL (no slope evaluated); R_dev is
 * R - R_nominal (NaN when R was not fitted), U its expanded uncertainty.
 */
void asph_verdict_evaluate(const struct asph_tolerance *t,
			   const struct asph_form *form,
			   const struct asph_slope *slope, double R_dev,
			   const struct asph_uncertainty_k2 *U,
			   struct asph_verdict_report *out);

#ifdef __cplusplus
}
#endif

#endif
