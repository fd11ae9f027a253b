/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asph replay: characterization of a recorded scan, as asphd makes it at
 * the end of a job: the lens of the scan's header, the points `asph
 * export` writes (the drift model fitted to the scan's references and
 * applied, asph_drift_scan_points()), the fit of asph fit; and the
 * acquisition's account (position sources, commanded points, the drift
 * correction and its size).
 */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph-tool.h"
#include "asph/drift.h"
#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "fit-summary.h"
#include "fit-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph replay SCAN [FIT OPTIONS...]\n\n"
		     "Characterizes a recorded scan as asphd does: the best fit of its points,\n"
		     "corrected for the drift its references measured, to the lens in its header;\n"
		     "exactly `asph fit LENS points.csv` on the points `asph export SCAN -o\n"
		     "points.csv` writes, with the acquisition's account added (where the\n"
		     "positions came from, commanded points, the drift correction and its size).\n"
		     "FIT OPTIONS are those of asph fit (--json, --dof, --residual, --robust,\n"
		     "--residuals OUT, --map OUT.png, --uncertainty with the contributions the\n"
		     "scan's instrument declares); see asph fit --help. A scan that did not\n"
		     "complete is characterized on the points it kept; a note on standard error\n"
		     "says so.\n");
}

static void show_acquisition(void *data)
{
	_cleanup_(json_decrefp) json_t *a = json_loads(data, 0, NULL);

	fit_summary_print_acquisition(stdout, a, "");
}

int cmd_replay(int argc, char **argv)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	_cleanup_(asph_surface_freep) struct asph_surface *surf = NULL;
	_cleanup_free_ char *acq = NULL;
	struct asph_drift_summary sum;
	struct asph_prescription p;
	struct fit_cli c = { 0 };
	struct asph_error err;

	if (argc >= 2 && argv[1][0] == '-' && strcmp(argv[1], "--help") && strcmp(argv[1], "-h")) {
		fprintf(stderr, "asph replay: SCAN comes first (see --help)\n");
		return EXIT_USAGE;
	}
	int r = fit_cli_parse(&c, argc, argv, 1, usage);
	if (r != EXIT_OK)
		return r < 0 ? EXIT_OK : r;
	/* the report's provenance and --uncertainty's instrument: the scan's */
	if (!c.scan)
		c.scan = c.points;
	asph_error_clear(&err);
	if (asph_drift_scan_points(c.points, 0, 0, &s, &pts, &sum, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	const char *text = s->header.prescription;
	if (asph_prescription_parse(text, strlen(text), c.points, &p, &err) < 0 ||
	    asph_surface_alloc(&p, &surf, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	if (!s->report.ended || s->report.outcome != ASPH_SCANFILE_COMPLETED)
		fprintf(stderr, "asph replay: note: the scan did not complete (%s); characterizing the %zu points it kept\n",
			asph_scanfile_outcome_name(s->report.ended ? s->report.outcome
								    : ASPH_SCANFILE_UNFINISHED),
			s->n);
	if (asph_drift_report_json(s, &sum, 1, &acq) < 0) {
		fprintf(stderr, "asph replay: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	return fit_cli_run(&c, surf, pts, acq, show_acquisition, acq);
}
