/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The JSON summary of a fit: one builder for `asph fit --json` and the
 * results asphd stores, so both carry the same keys. Internal.
 */
#ifndef ASPH_FIT_JSON_H
#define ASPH_FIT_JSON_H

#include <jansson.h>

#include "asph/fit.h"

/* lens: the lens name shown; robust: whether the fit was robust. A value
 * that could not be computed is null (JSON has no NaN). NULL on ENOMEM. */
json_t *fit_result_json(const struct asph_fit_result *r, const char *lens,
			int robust);

#endif
