/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The tolerance object and its ISO 10110-5 call-out. A refusal names a
 * column inside the text (or none); an accepted tolerance has positive
 * finite limits only and at least one of them; the call-out alone parses
 * to the same limits as inside an object.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "asph/tolerance.h"
#include "fuzz.h"

static int limits_ok(const struct asph_tolerance *t)
{
	const double v[] = { t->A.v, t->B.v, t->C.v, t->rms_t.v, t->rms_i.v, t->rms_a.v,
			     t->slope_rms.v, t->slope_max.v, t->R_mm };
	int any = 0;

	for (size_t i = 0; i < sizeof(v) / sizeof(v[0]); i++) {
		if (isnan(v[i]))
			continue;
		if (!(v[i] > 0) || !isfinite(v[i]))
			return 0;
		any = 1;
	}
	return any && t->wavelength_nm > 0 && isfinite(t->wavelength_nm);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_tolerance t;
	struct asph_error err;
	char *text = malloc(size + 1);
	int column = 0;

	if (!text)
		return 0;
	memcpy(text, data, size);
	text[size] = '\0';
	asph_error_clear(&err);
	if (asph_tolerance_parse_json(text, size, "fuzz.json", &t, &err) < 0) {
		fuzz_check_error(&err);
		if (err.column < 0 || (size_t)err.column > size + 1)
			fuzz_die("column %d outside the %zu bytes", err.column, size);
	} else if (!limits_ok(&t)) {
		fuzz_die("an accepted tolerance has a limit that is not positive, or none");
	}
	/* The same bytes as a bare call-out. */
	asph_error_clear(&err);
	asph_tolerance_init(&t);
	if (asph_tolerance_parse_callout(text, 546.07, &t, &column, &err) < 0) {
		fuzz_check_error(&err);
		if (column < 1 || (size_t)column > strlen(text) + 1)
			fuzz_die("call-out column %d outside the text", column);
	} else if (!limits_ok(&t)) {
		fuzz_die("an accepted call-out has a limit that is not positive, or none");
	}
	free(text);
	return 0;
}
