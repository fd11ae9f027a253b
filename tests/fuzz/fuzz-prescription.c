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

static bool same_numbers(const double *a, const double *b, size_t n)
{
	for (size_t i = 0; i < n; i++)
		if (a[i] != b[i])
			return false;
	return true;
}

#define SAME(f) same_numbers((const double *)&a->f, (const double *)&b->f, \
			     sizeof(a->f) / sizeof(double))

/* Equal as numbers (a coefficient of -0 is written as none). */
static bool same(const struct asph_prescription *a, const struct asph_prescription *b)
{
	if (a->type != b->type || strcmp(a->name, b->name) || a->aperture.shape != b->aperture.shape)
		return false;
	return SAME(R) && SAME(k) && SAME(A) && SAME(aperture_diameter) && SAME(norm_radius) &&
	       SAME(Q) && SAME(Rx) && SAME(Ry) && SAME(kx) && SAME(ky) && SAME(R_rotation) &&
	       SAME(C) && SAME(Zernike) && SAME(zernike_decenter) && SAME(q2d_a) && SAME(q2d_b) &&
	       SAME(aperture.width) && SAME(aperture.height) && SAME(aperture.offset);
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
