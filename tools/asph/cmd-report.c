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
		     "Writes the measurement report (one PDF page): part, lot and serial (--part,\n"
		     "--lot, --serial), the lens, plan and instrument with their SHA-256, the verdict\n"
		     "table with values, uncertainties and tolerances (--tolerance), the residual\n"
		     "map, the radial profiles, the Zernike terms and the PSD. From a recorded scan\n"
		     "(as asph replay characterizes it) or from a lens and a points file (as asph fit\n"
		     "does). FIT OPTIONS are those of asph fit; the exit status is asph fit's.\n");
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
