/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Lens importer (OpticStudio .zmx, CSV); LENS_SOURCE (a file name) picks the
 * format as its extension does. An accepted file lists at least one surface;
 * each surface becomes a prescription that passes the check and survives the
 * JSON round trip, or is refused with a reason.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "asph/lens-import.h"
#include "fuzz.h"

static void surface(const struct asph_lens_import *im, int number)
{
	struct asph_prescription p, q;
	struct asph_error err;
	char *json = NULL;

	asph_error_clear(&err);
	if (asph_lens_import_prescription(im, number, &p, &err) < 0) {
		fuzz_check_error(&err);
		return;
	}
	if (asph_prescription_check(&p, &err) < 0)
		fuzz_die("surface %d imported, but the check refuses it: %s", number, err.message);
	if (asph_prescription_to_json(&p, &json) < 0)
		fuzz_die("surface %d does not serialize", number);
	if (asph_prescription_parse(json, strlen(json), "round-trip", &q, &err) < 0)
		fuzz_die("surface %d serialized is refused: %s\n%s", number, err.message, json);
	free(json);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_lens_import *im = NULL;
	struct asph_lens_surface s;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_lens_import_parse(data, size, LENS_SOURCE, &im, &err) < 0) {
		fuzz_check_error(&err);
		if (im)
			fuzz_die("refused, but returned a file");
		return 0;
	}
	size_t n = asph_lens_import_count(im);
	if (n == 0)
		fuzz_die("accepted a file without a surface");
	for (size_t i = 0; i < n; i++) {
		asph_lens_import_surface(im, i, &s);
		if (s.line < 1)
			fuzz_die("surface %zu has no line", i);
		surface(im, s.number);
	}
	surface(im, -1);
	asph_lens_import_free(im);
	return 0;
}
