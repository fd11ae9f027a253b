/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <getopt.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/scanfile.h"
#include "asph-tool.h"

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph export SCAN -o FILE [--exclude FLAGS]\n\n"
		     "Writes the measured points of a recorded scan, in recording order and at\n"
		     "full precision, as CSV, PLY or JSON by FILE's extension (\"-\": CSV on stdout).\n"
		     "Points flagged out of range are left out; a damaged or cut-off scan gives\n"
		     "the points recovered from it, with a warning.\n\n"
		     "  -o, --output FILE   where to write the points\n"
		     "  --exclude FLAGS     also leave out points with any of these flags\n"
		     "                      (comma separated: low-signal, retried, tip-compensated)\n");
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
};

static int take(int opt, const char *arg, void *data)
{
	struct export_args *a = data;

	if (opt == 'o')
		a->output = arg;
	else
		a->exclude = arg;
	return 0;
}

int cmd_export(int argc, char **argv)
{
	static const struct option options[] = {
		{ "output", required_argument, NULL, 'o' },
		{ "exclude", required_argument, NULL, 'x' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 }
	};
	struct export_args a = { .exclude = "" };
	struct asph_scanfile_report rep;
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
	if (asph_scanfile_export(argv[optind], a.output, mask, &rep, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	warn_damage(argv[optind], &rep);
	return EXIT_OK;
}
