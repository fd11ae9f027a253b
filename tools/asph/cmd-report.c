/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asph report: the measurement report of a recorded scan or of a points
 * file. It is `asph replay SCAN --report OUT --scan SCAN` or `asph fit LENS
 * POINTS --report OUT`, so the report shows exactly what those compute.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph-tool.h"
#include "asph/scanfile.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_reader *, asph_scanfile_reader_free)

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph report OUT.pdf SCAN [FIT OPTIONS...]\n"
		     "       asph report OUT.pdf LENS POINTS_FILE [FIT OPTIONS...]\n\n"
		     "Writes the measurement report (A4 PDF). Page 1: what was measured (--part,\n"
		     "--lot, --serial), when (the scan's start and end, or --measured TIME), by whom\n"
		     "(--operator; default the job's submitter the scan records, else the user\n"
		     "running asph), on which instrument; the lens, plan and data with their\n"
		     "SHA-256; the verdict table with values, uncertainties and limits\n"
		     "(--tolerance); the residual map and the radial profiles. Page 2: the fit,\n"
		     "the Zernike terms and the PSD. Then the lens, plan and instrument\n"
		     "descriptions in full. From a recorded scan (as asph replay characterizes it,\n"
		     "its part, lot, serial and operator as asphd recorded them) or from a lens and\n"
		     "a points file (as asph fit does). FIT OPTIONS are those of asph fit; the exit\n"
		     "status is asph fit's.\n");
}

static int is_scan(const char *path)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;

	return asph_scanfile_reader_open(path, &r, NULL) == 0;
}

int cmd_report(int argc, char **argv)
{
	_cleanup_free_ char **args = NULL;
	int scan, n = 0;

	if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
		usage(argc < 2 ? stderr : stdout);
		return argc < 2 ? EXIT_USAGE : EXIT_OK;
	}
	if (argc < 3 || argv[1][0] == '-' || argv[2][0] == '-') {
		fprintf(stderr, "asph report: OUT.pdf and then SCAN or LENS POINTS_FILE come first\n");
		return EXIT_USAGE;
	}
	scan = is_scan(argv[2]);
	if (!scan && (argc < 4 || argv[3][0] == '-')) {
		fprintf(stderr, "asph report: %s is not a recorded scan; give LENS POINTS_FILE\n",
			argv[2]);
		return EXIT_USAGE;
	}
	args = calloc((size_t)argc + 8, sizeof(char *));
	if (!args)
		return EXIT_FAILURE_RUN;
	args[n++] = (char *)(scan ? "replay" : "fit");
	args[n++] = argv[2];
	if (!scan)
		args[n++] = argv[3];
	args[n++] = (char *)"--report";
	args[n++] = argv[1];
	if (scan) {
		args[n++] = (char *)"--scan";
		args[n++] = argv[2];
	}
	for (int i = scan ? 3 : 4; i < argc; i++)
		args[n++] = argv[i];
	optind = 0;
	return scan ? cmd_replay(n, args) : cmd_fit(n, args);
}
