/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A recorded scan's points, and their export as a points file. */
#include <errno.h>
#include <math.h>

#include "asph/scanfile.h"
#include "asph/x3p.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

static bool point_kept(const struct asph_scanfile_point *pt, uint32_t exclude)
{
	return !(pt->flags & (exclude | ASPH_SCANFILE_NOT_MEASURED));
}

int asph_scanfile_to_points(const struct asph_scanfile *s,
			    uint32_t exclude_flags, struct asph_points **out,
			    struct asph_error *err)
{
	size_t n = 0, k = 0;

	for (size_t i = 0; i < s->n; i++) {
		const struct asph_scanfile_point *pt = &s->points[i];
		if (!point_kept(pt, exclude_flags))
			continue;
		if (!isfinite(pt->x) || !isfinite(pt->y) || !isfinite(pt->z))
			return asph_error_set(err, -EBADMSG,
					      "point %zu (plan index %llu) has non-finite coordinates "
					      "but is not flagged out of range or invalid",
					      i, (unsigned long long)pt->plan_index);
		n++;
	}
	_cleanup_(asph_points_freep) struct asph_points *p = asph_points_alloc(n);
	if (!p)
		return asph_error_set(err, -ENOMEM, "cannot allocate %zu points", n);
	for (size_t i = 0; i < s->n; i++) {
		const struct asph_scanfile_point *pt = &s->points[i];
		if (!point_kept(pt, exclude_flags))
			continue;
		p->xyz[3 * k + 0] = pt->x;
		p->xyz[3 * k + 1] = pt->y;
		p->xyz[3 * k + 2] = pt->z;
		k++;
	}
	*out = steal_ptr(p);
	return 0;
}

int asph_scanfile_export(const char *scan_path, const char *out_path,
			 uint32_t exclude_flags,
			 struct asph_scanfile_report *report,
			 struct asph_error *err)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	_cleanup_(asph_points_freep) struct asph_points *p = NULL;
	/* precision 0: 17 significant digits, which read back bit for bit */
	struct asph_points_write_options wopts = { 0 };
	struct asph_x3p_info x3p = { 0 };
	int r;

	r = asph_scanfile_read(scan_path, &s, err);
	if (r < 0)
		return r;
	/* an X3P names the instrument that measured, and when */
	x3p.instrument_json = s->header.instrument;
	x3p.date_ns = s->header.created_ns;
	wopts.x3p = &x3p;
	if (report) {
		*report = s->report;
		report->reason = NULL;
	}
	r = asph_scanfile_to_points(s, exclude_flags, &p, err);
	if (r < 0) {
		asph_error_locate(err, scan_path, 0, 0, NULL);
		return r;
	}
	return asph_points_write(out_path, p, &wopts, err);
}
