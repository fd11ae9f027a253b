/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Recorded-scan reader. Built with FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
 * the reader skips the checksum comparison, so mutations reach the block
 * decoding behind it. A scan that reads must account for every byte and
 * convert to points as export and replay do.
 */
#include <stdint.h>

#include "asph/scanfile.h"
#include "fuzz.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_scanfile *s = NULL;
	struct asph_points *p = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_scanfile_read_memory(data, size, "fuzz.scan", &s, &err) < 0) {
		fuzz_check_error(&err);
		return 0;
	}
	const struct asph_scanfile_report *rep = &s->report;
	if (rep->file_size != size || rep->valid_bytes > size ||
	    rep->valid_bytes + rep->discarded_bytes != size || rep->n_points != s->n)
		fuzz_die("inconsistent report: size %zu, valid %llu, discarded %llu, points %llu/%zu",
			 size, (unsigned long long)rep->valid_bytes,
			 (unsigned long long)rep->discarded_bytes,
			 (unsigned long long)rep->n_points, s->n);
	if (asph_scanfile_to_points(s, 0, &p, &err) < 0)
		fuzz_check_error(&err);
	asph_points_free(p);
	asph_scanfile_free(s);
	return 0;
}
