/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Points-file readers; POINTS_SOURCE (a file name) picks the format as its
 * extension does for asph_points_read(). An accepted set holds only finite
 * coordinates and triangles whose vertices exist.
 */
#include <math.h>
#include <stdint.h>

#include "asph/points.h"
#include "fuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_points *p = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_points_read_memory(data, size, POINTS_SOURCE, &p, &err) < 0) {
		fuzz_check_error(&err);
		if (p)
			fuzz_die("refused, but returned points");
		return 0;
	}
	for (size_t i = 0; i < 3 * p->n; i++)
		if (!isfinite(p->xyz[i]))
			fuzz_die("accepted a non-finite coordinate at point %zu", i / 3);
	for (size_t t = 0; t < 3 * p->n_triangles; t++)
		if (p->triangles[t] >= p->n)
			fuzz_die("accepted a triangle with vertex %u of %zu", p->triangles[t], p->n);
	asph_points_free(p);
	return 0;
}
