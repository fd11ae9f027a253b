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

int cmd_export(int argc, char **argv)
{
	static const struct option options[] = {
		{ "output", required_argument, NULL, 'o' },
		{ "exclude", required_argument, NULL, 'x' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 }
	};
	const char *output = NULL, *exclude = "";
	struct asph_scanfile_report rep;
	struct asph_error err;
	uint32_t mask;
	int c;

	optind = 1;
	while ((c = getopt_long(argc, argv, "o:h", options, NULL)) != -1) {
		switch (c) {
		case 'o':
			output = optarg;
			break;
		case 'x':
			exclude = optarg;
			break;
		case 'h':
			usage(stdout);
			return EXIT_OK;
		default:
			usage(stderr);
			return EXIT_USAGE;
		}
	}
	if (optind + 1 != argc || !output) {
		usage(stderr);
		return EXIT_USAGE;
	}
	asph_error_clear(&err);
	if (asph_scanfile_flags_parse(exclude, &mask, &err) < 0) {
		tool_print_error("--exclude", &err);
		return EXIT_USAGE;
	}
	if (asph_scanfile_export(argv[optind], output, mask, &rep, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	warn_damage(argv[optind], &rep);
	return EXIT_OK;
}
