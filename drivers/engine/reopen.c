/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Going on with an interrupted scan: the one place that decides where, for
 * asph scan --resume and asphd's resumed jobs. */
#include <errno.h>
#include <fcntl.h>
#include <string.h>

#include "asph-engine/executor.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_reader *, asph_scanfile_reader_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

/* The header's plan is plan: read before anything is written. */
static int check_plan(int dirfd, const char *path, const struct asph_plan *plan,
		      struct asph_error *err)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;
	struct asph_plan_info was;
	int ret = asph_scanfile_reader_open_at(dirfd, path, &r, err);

	if (ret < 0)
		return ret;
	const char *text = asph_scanfile_reader_header(r)->plan;
	ret = asph_plan_info_from_json(text, strlen(text), path, &was, err);
	if (ret < 0)
		return ret;
	if (was.method == plan->method && was.density.kind == plan->density.kind &&
	    was.density.value == plan->density.value && was.points == plan->n &&
	    was.profiles == plan->profiles)
		return 0;
	return asph_error_set_at(err, -EINVAL, path, 0, 0, "plan",
				 "recorded with the plan %s %s=%.17g (%llu points), not %s %s=%.17g "
				 "(%zu points): the points of two plans cannot share a scan",
				 asph_plan_method_name(was.method),
				 asph_plan_density_name(was.density.kind), was.density.value,
				 (unsigned long long)was.points, asph_plan_method_name(plan->method),
				 asph_plan_density_name(plan->density.kind), plan->density.value,
				 plan->n);
}

int asph_scan_reopen(const char *path, const struct asph_plan *plan,
		     const struct asph_scanfile_writer_options *opts,
		     struct asph_scanfile_writer **w, uint64_t *start_index,
		     struct asph_scanfile **recovered, struct asph_error *err)
{
	return asph_scan_reopen_at(AT_FDCWD, path, plan, opts, w, start_index, recovered, err);
}

int asph_scan_reopen_at(int dirfd, const char *path, const struct asph_plan *plan,
			const struct asph_scanfile_writer_options *opts,
			struct asph_scanfile_writer **w, uint64_t *start_index,
			struct asph_scanfile **recovered, struct asph_error *err)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *rec = NULL;
	int ret = check_plan(dirfd, path, plan, err);

	if (ret == 0)
		ret = asph_scanfile_writer_resume_at(dirfd, path, opts, &rec, w, err);
	if (ret < 0)
		return ret;
	*start_index = 0;
	for (size_t i = 0; i < rec->n; i++)
		if (rec->points[i].plan_index + 1 > *start_index)
			*start_index = rec->points[i].plan_index + 1;
	if (recovered)
		*recovered = steal_ptr(rec);
	return 0;
}
