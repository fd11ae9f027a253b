/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <getopt.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/drift.h"
#include "asph/scanfile.h"
#include "asph/x3p.h"
#include "config.h"
#include "asph-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph export SCAN -o FILE [--exclude FLAGS] [--raw]\n\n"
		     "Writes the measured points of a recorded scan, in recording order and at\n"
		     "full precision, as CSV, PLY or JSON by FILE's extension (\"-\": CSV on stdout):\n"
		     "the points characterization sees, corrected for the drift the scan's\n"
		     "references measured (docs/characterization.md). Points flagged out of range\n"
		     "or invalid are left out; a damaged or cut-off scan gives the points\n"
		     "recovered from it, with a warning.\n\n"
		     "  -o, --output FILE   where to write the points\n"
		     "  --exclude FLAGS     also leave out points with any of these flags (comma\n"
		     "                      separated: low-signal, retried, tip-compensated,\n"
		     "                      commanded-position)\n"
		     "  --raw               the points as recorded, without the drift correction\n");
}

static void warn_damage(const char *path, const struct asph_scanfile_report *rep)
{
	if (rep->stop != ASPH_SCANFILE_STOP_END)
		fprintf(stderr, "asph: warning: %s: kept %" PRIu64 " points, discarded %" PRIu64
			" bytes: %s\n", path, rep->n_points, rep->discarded_bytes,
			rep->stop_detail);
	if (!rep->ended)
		fprintf(stderr, "asph: warning: %s: the scan has no end block (it was cut off)\n",
			path);
}

struct export_args {
	const char *output, *exclude;
	int raw;
};

static int take(int opt, const char *arg, void *data)
{
	struct export_args *a = data;

	if (opt == 'o')
		a->output = arg;
	else if (opt == 'r')
		a->raw = 1;
	else
		a->exclude = arg;
	return 0;
}

int cmd_export(int argc, char **argv)
{
	static const struct option options[] = {
		{ "output", required_argument, NULL, 'o' },
		{ "exclude", required_argument, NULL, 'x' },
		{ "raw", no_argument, NULL, 'r' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 }
	};
	struct export_args a = { .exclude = "" };
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	/* precision 0: 17 significant digits, which read back bit for bit */
	struct asph_points_write_options wo = { 0 };
	struct asph_x3p_info x3p = { .creator = "asph " ASPH_VERSION };
	struct asph_error err;
	uint32_t mask;
	int code = tool_getopt(argc, argv, "o:h", options, usage, take, &a);

	if (code >= 0)
		return code;
	if (optind + 1 != argc || !a.output) {
		usage(stderr);
		return EXIT_USAGE;
	}
	asph_error_clear(&err);
	if (asph_scanfile_flags_parse(a.exclude, &mask, &err) < 0) {
		tool_print_error("--exclude", &err);
		return EXIT_USAGE;
	}
	if (asph_drift_scan_points(argv[optind], mask, a.raw, &s, &pts, NULL, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	/* an X3P names the instrument that measured, and when */
	x3p.instrument_json = s->header.instrument;
	x3p.date_ns = s->header.created_ns;
	wo.x3p = &x3p;
	if (asph_points_write(a.output, pts, &wo, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	warn_damage(argv[optind], &s->report);
	return EXIT_OK;
}
