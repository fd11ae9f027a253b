/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Prescription parser. What it accepts must serialize and parse back to the
 * same prescription (the daemon stores and re-reads them that way).
 */
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "asph/prescription.h"
#include "fuzz.h"

/* Equal as numbers (a coefficient of -0 is written as none). */
static bool same(const struct asph_prescription *a, const struct asph_prescription *b)
{
	if (a->type != b->type || strcmp(a->name, b->name) || a->R != b->R || a->k != b->k ||
	    a->aperture_diameter != b->aperture_diameter)
		return false;
	for (size_t i = 0; i < sizeof(a->A) / sizeof(a->A[0]); i++)
		if (a->A[i] != b->A[i])
			return false;
	return true;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_prescription p, q;
	struct asph_error err;
	char *json = NULL;

	if (asph_prescription_parse((const char *)data, size, "fuzz.json", &p, &err) < 0) {
		fuzz_check_error(&err);
		return 0;
	}
	if (asph_prescription_to_json(&p, &json) < 0)
		fuzz_die("an accepted prescription does not serialize");
	if (asph_prescription_parse(json, strlen(json), "round-trip", &q, &err) < 0)
		fuzz_die("the serialized prescription is refused: %s\n%s", err.message, json);
	if (!same(&p, &q))
		fuzz_die("the round trip changed the prescription:\n%s", json);
	free(json);
	return 0;
}
