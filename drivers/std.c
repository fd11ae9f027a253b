/* SPDX-License-Identifier: GPL-3.0-or-later */
#include "std.h"

void std_probe_geometry(struct asph_probe_info *pi, bool tactile, double tip_radius,
			double standoff, double range)
{
	pi->type = tactile ? ASPH_PROBE_TACTILE : ASPH_PROBE_OPTICAL;
	pi->tip_radius = tactile ? tip_radius : 0;
	pi->standoff = standoff;
	pi->range_min = standoff - range / 2;
	pi->range_max = standoff + range / 2;
}

void std_reading_check_range(struct asph_reading *r, const struct asph_probe_info *pi)
{
	if (!(r->value >= pi->range_min && r->value <= pi->range_max))
		r->flags |= ASPH_READING_OUT_OF_RANGE;
}

int std_stream_by_read(struct asph_device *d, std_read_fn read,
		       const struct asph_probe_context *ctx, size_t n,
		       struct asph_reading *out, size_t *n_done, unsigned timeout_ms,
		       struct asph_error *err)
{
	*n_done = 0;
	for (size_t i = 0; i < n; i++) {
		int r = read(d, ctx + i, out + i, timeout_ms, err);
		if (r < 0)
			return r;
		*n_done = i + 1;
	}
	return 0;
}
