/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What every built-in driver would otherwise write again (libsigrok's
 * src/std.c): a probe's geometry from its usual options, the out-of-range
 * flag of a reading, and a stream made of single reads. Time (now, sleeps)
 * is util-time.h's. Internal to drivers/.
 */
#ifndef ASPH_DRIVERS_STD_H
#define ASPH_DRIVERS_STD_H

#include <stdbool.h>
#include <stddef.h>

#include "asph-driver/driver.h"

/* Type, tip radius (0 for an optical probe) and the measuring range of
 * width range centred on the standoff. */
void std_probe_geometry(struct asph_probe_info *pi, bool tactile, double tip_radius,
			double standoff, double range);

/* Flags r as out of range when its value lies outside the probe's range
 * (NaN included). */
void std_reading_check_range(struct asph_reading *r, const struct asph_probe_info *pi);

typedef int (*std_read_fn)(struct asph_device *d, const struct asph_probe_context *ctx,
			   struct asph_reading *out, unsigned timeout_ms,
			   struct asph_error *err);

/*
 * The probe ops' stream as one read per position, for a probe whose reads
 * already belong to the positions they are given (a recording looked up by
 * plan index). Not for a physical probe under a moving stage: its reading
 * would be paired with a position it was not taken at.
 */
int std_stream_by_read(struct asph_device *d, std_read_fn read,
		       const struct asph_probe_context *ctx, size_t n,
		       struct asph_reading *out, size_t *n_done, unsigned timeout_ms,
		       struct asph_error *err);

#endif
