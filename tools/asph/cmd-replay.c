/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asph replay: characterization of a recorded scan. It is `asph fit` run
 * on the lens of the scan's header and on the points `asph export` writes
 * (the same conversion, asph_scanfile_export), so the two agree by
 * construction, to the byte.
 */
#include <ftw.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph-tool.h"
#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_reader *, asph_scanfile_reader_free)

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph replay SCAN [FIT OPTIONS...]\n\n"
		     "Characterizes a recorded scan: the best fit of its points to the lens in its\n"
		     "header, exactly as `asph fit LENS points.csv` on the points `asph export SCAN\n"
		     "-o points.csv` writes. FIT OPTIONS are those of asph fit (--json, --dof,\n"
		     "--residual, --robust, --residuals OUT, --map OUT.png, --uncertainty with the\n"
		     "contributions the scan's instrument declares); see asph fit --help.\n"
		     "A scan that did not complete is characterized on the points it kept; a note\n"
		     "on standard error says so.\n");
}

/* The header's prescription as a file asph fit can load. */
static int write_lens(const char *scan, const char *path)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_scanfile_reader_open(scan, &r, &err) < 0) {
		tool_print_error(NULL, &err);
		return -1;
	}
	const char *json = asph_scanfile_reader_header(r)->prescription;
	_cleanup_fclose_ FILE *f = fopen(path, "we");
	if (!f || fputs(json, f) < 0 || fflush(f) != 0) {
		fprintf(stderr, "asph replay: cannot write %s\n", path);
		return -1;
	}
	return 0;
}

static int export_points(const char *scan, const char *path)
{
	struct asph_scanfile_report rep;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_scanfile_export(scan, path, 0, &rep, &err) < 0) {
		tool_print_error(NULL, &err);
		return -1;
	}
	if (!rep.ended || rep.outcome != ASPH_SCANFILE_COMPLETED)
		fprintf(stderr, "asph replay: note: the scan did not complete (%s); characterizing the %llu points it kept\n",
			asph_scanfile_outcome_name(rep.ended ? rep.outcome : ASPH_SCANFILE_UNFINISHED),
			(unsigned long long)rep.n_points);
	return 0;
}

static int remove_entry(const char *path, const struct stat *st, int flag, struct FTW *ftw)
{
	return remove(path);
}

int cmd_replay(int argc, char **argv)
{
	char dir[] = "/tmp/asph-replay-XXXXXX", lens[64], csv[64];
	int r = EXIT_FAILURE_RUN;

	if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
		usage(argc < 2 ? stderr : stdout);
		return argc < 2 ? EXIT_USAGE : EXIT_OK;
	}
	if (argv[1][0] == '-') {
		fprintf(stderr, "asph replay: SCAN comes first (see --help)\n");
		return EXIT_USAGE;
	}
	if (!mkdtemp(dir)) {
		perror("asph replay: temporary directory");
		return EXIT_FAILURE_RUN;
	}
	snprintf(lens, sizeof(lens), "%s/lens.json", dir);
	snprintf(csv, sizeof(csv), "%s/points.csv", dir);
	if (write_lens(argv[1], lens) == 0 && export_points(argv[1], csv) == 0) {
		_cleanup_free_ char **fit_argv = calloc((size_t)argc + 4, sizeof(char *));
		if (fit_argv) {
			/* --scan: the report's provenance and --uncertainty's
			 * instrument come from the scan itself */
			fit_argv[0] = (char *)"fit";
			fit_argv[1] = lens;
			fit_argv[2] = csv;
			fit_argv[3] = (char *)"--scan";
			fit_argv[4] = argv[1];
			for (int i = 2; i < argc; i++)
				fit_argv[i + 3] = argv[i];
			optind = 0;   /* asph fit parses its own options from scratch */
			r = cmd_fit(argc + 3, fit_argv);
		}
	}
	nftw(dir, remove_entry, 8, FTW_DEPTH | FTW_PHYS);
	return r;
}
