/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Points-file readers; POINTS_FORMAT names the format read ("auto": found
 * from the content, as asph_points_read() does). An accepted set holds
 * only finite coordinates and triangles whose vertices exist, and a map's
 * invalid nodes are counted, never more than it has.
 */
#include <math.h>
#include <stdint.h>

#include "asph/points.h"
#include "fuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_points_read_options o = { 0 };
	struct asph_points_read_info info;
	struct asph_points *p = NULL;
	struct asph_error err;

	if (asph_points_format_parse(POINTS_FORMAT, &o.format) < 0)
		fuzz_die("unknown format %s", POINTS_FORMAT);
	asph_error_clear(&err);
	if (asph_points_read_memory_as(data, size, "fuzz", &o, &p, &info, &err) < 0) {
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
	if (info.nx && info.n_invalid + p->n > info.nx * info.ny)
		fuzz_die("%zu points and %zu invalid of a %zu x %zu map", p->n, info.n_invalid,
			 info.nx, info.ny);
	asph_points_free(p);
	return 0;
}
