/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>

#include "asph-tool.h"
#include "points-input.h"

int points_input_format(struct points_input *in, const char *prog, const char *arg)
{
	if (asph_points_format_parse(arg, &in->opts.format) < 0) {
		char names[128];
		asph_points_format_names(names, sizeof(names));
		fprintf(stderr, "asph %s: --format: unknown format '%s' (%s)\n", prog, arg, names);
		return -1;
	}
	in->format_arg = arg;
	return 0;
}

int points_input_units(struct points_input *in, const char *prog, const char *arg)
{
	if (asph_points_unit_parse(arg, &in->opts.unit_mm) < 0) {
		char names[128];
		asph_points_unit_names(names, sizeof(names));
		fprintf(stderr, "asph %s: --units: unknown unit '%s' (%s)\n", prog, arg, names);
		return -1;
	}
	in->units_arg = arg;
	return 0;
}

/* What reading dropped, said aloud; 0, or the error printed. */
static int told(int r, const struct asph_error *err, const char *prog,
		const struct asph_points_read_info *info, const struct asph_points *p)
{
	if (r < 0) {
		tool_print_error(NULL, err);
		return err->code ? err->code : -1;
	}
	if (info->n_invalid)
		fprintf(stderr, "asph %s: note: %s map of %zu x %zu: %zu invalid points left out, %zu read\n",
			prog, asph_points_format_name(info->format), info->nx, info->ny,
			info->n_invalid, p->n);
	if (info->n_preamble)
		fprintf(stderr, "asph %s: note: %zu preamble line%s before the %s skipped\n", prog,
			info->n_preamble, info->n_preamble == 1 ? "" : "s",
			info->has_header ? "header" : "data");
	return 0;
}

int points_input_read(const struct points_input *in, const char *prog, const char *path,
		      struct asph_points **out)
{
	struct asph_points_read_info info;
	struct asph_error err;
	int r;

	asph_error_clear(&err);
	r = asph_points_read_as(path, &in->opts, out, &info, &err);
	return told(r, &err, prog, &info, *out);
}

int points_input_read_memory(const struct points_input *in, const char *prog,
			     const void *data, size_t len, const char *path,
			     struct asph_points **out)
{
	struct asph_points_read_info info;
	struct asph_error err;
	int r;

	asph_error_clear(&err);
	r = asph_points_read_memory_as(data, len, path, &in->opts, out, &info, &err);
	return told(r, &err, prog, &info, *out);
}
