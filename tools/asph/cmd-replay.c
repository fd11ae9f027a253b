/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asph replay: characterization of a recorded scan, as asphd makes it at
 * the end of a job (asph_characterize_scan()): the lens of the scan's
 * header, the points `asph export` writes (the drift model fitted to the
 * scan's references and applied), the fit of asph fit; and the
 * acquisition's account (position sources, commanded points, the drift
 * correction and its size). Or of measured data on a lens, as asphd
 * characterizes a measured job (asph_characterize_points()). --out
 * writes the job's result folder.
 */
#include <errno.h>
#include <getopt.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph-tool.h"
#include "config.h"
#include "fileio.h"
#include "fit-report.h"
#include "fit-summary.h"
#include "asph/points.h"
#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "fit-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph replay SCAN [FIT OPTIONS...]\n"
		     "       asph replay LENS MEASURED [--format F] [--units U] [FIT OPTIONS...]\n\n"
		     "Characterizes a recorded scan as asphd does: the best fit of its points,\n"
		     "corrected for the drift its references measured, to the lens in its header;\n"
		     "exactly `asph fit LENS points.csv` on the points `asph export SCAN -o\n"
		     "points.csv` writes, with the acquisition's account added (where the\n"
		     "positions came from, commanded points, the drift correction and its size).\n"
		     "A scan that did not complete is characterized on the points it kept; a note\n"
		     "on standard error says so.\n\n"
		     "MEASURED is data a lab already has, in any format asph fit reads (found from\n"
		     "the content; --format and --units as asph fit's): it names no lens, so LENS\n"
		     "(a preset or a prescription file) comes first, as in asph fit and `asphctl\n"
		     "submit LENS --measured MEASURED`. It is characterized as asphd's measured job\n"
		     "characterizes it. A recorded scan names its lens and is not given one.\n\n"
		     "FIT OPTIONS are those of asph fit (--json, --dof, --residual, --robust,\n"
		     "--residuals OUT, --map OUT.png, --uncertainty with the contributions the\n"
		     "scan's instrument declares); see asph fit --help.\n\n"
		     "  --out DIR           write into DIR the files asphd writes into a job's folder:\n"
		     "                      result.json (asphd's, but for the time, the program and\n"
		     "                      the job, given the job's fit options and tolerance),\n"
		     "                      residuals.csv, residual-map.png, residual.x3p, psd.csv,\n"
		     "                      report.pdf\n");
}

static void show_acquisition(const struct asph_characterize_result *res)
{
	_cleanup_(json_decrefp) json_t *a = json_loads(res->acquisition_json, 0, NULL);

	fit_summary_print_acquisition(stdout, a, "");
}

/* The scan, read into memory (the report and result.json hash its
 * bytes), and the surface of its lens; -ENODATA (nothing printed) when
 * the file is not a scan but reads as measured data. */
static int read_scan(const char *path, char **data, size_t *len, struct asph_scanfile **s,
		     struct asph_surface **surf)
{
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	struct asph_prescription p;
	struct asph_error err;

	asph_error_clear(&err);
	if (file_read_all(path, SIZE_MAX / 2, data, len, &err) < 0)
		goto fail;
	if (asph_scanfile_read_memory(*data, *len, path, s, &err) < 0) {
		if (asph_points_read_memory_as(*data, *len, path, NULL, &pts, NULL, NULL) == 0)
			return -ENODATA;
		goto fail;
	}
	if (asph_prescription_parse((*s)->header.prescription, strlen((*s)->header.prescription),
				    path, &p, &err) < 0 ||
	    asph_surface_alloc(&p, surf, &err) < 0)
		goto fail;
	return EXIT_OK;
fail:
	tool_print_error(NULL, &err);
	return EXIT_FAILURE_RUN;
}

/* The lens's name when it is a preset's, as asphd names the lens of a job
 * that gave a preset (a prescription sent whole has none). */
static const char *preset_name(const struct asph_surface *s)
{
	const char *name = asph_surface_prescription(s)->name;
	struct asph_prescription p;

	return asph_prescription_preset(name, &p) == 0 ? name : NULL;
}

/* The run of a file read whole: it names and hashes the data. */
static struct asph_characterize_run run_of(const struct fit_cli *c,
					   const struct asph_surface *surf, const char *data,
					   size_t len)
{
	return (struct asph_characterize_run){
		.program = "asph " ASPH_VERSION, .lens_name = preset_name(surf),
		.data_name = c->points, .data = data, .data_len = len,
	};
}

/* LENS MEASURED: the data read as asph fit reads it, unless it is a
 * recorded scan, whose header names its lens. */
static int read_measured(const struct fit_cli *c, char **data, size_t *len,
			 struct asph_surface **surf, struct asph_points **pts)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (file_read_all(c->points, SIZE_MAX / 2, data, len, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	if (asph_scanfile_read_memory(*data, *len, c->points, &s, NULL) == 0) {
		fprintf(stderr, "asph replay: %s is a recorded scan, whose header names its lens: "
			"asph replay %s, with no LENS\n", c->points, c->points);
		return EXIT_USAGE;
	}
	if (tool_load_surface(c->lens, surf) < 0 ||
	    points_input_read_memory(&c->input, "replay", *data, *len, c->points, pts) < 0)
		return EXIT_FAILURE_RUN;
	return EXIT_OK;
}

/* SCAN alone: measured data needs its lens named. */
static int read_scan_only(const struct fit_cli *c, char **data, size_t *len,
			  struct asph_scanfile **s, struct asph_surface **surf)
{
	int r;

	if (c->input.format_arg || c->input.units_arg) {
		fprintf(stderr, "asph replay: --format and --units are for measured data (asph replay "
			"LENS MEASURED); a scan carries its own\n");
		return EXIT_USAGE;
	}
	r = read_scan(c->points, data, len, s, surf);
	if (r == -ENODATA) {
		fprintf(stderr, "asph replay: %s is measured data, which names no lens: asph replay "
			"LENS %s\n", c->points, c->points);
		return EXIT_USAGE;
	}
	return r;
}

int cmd_replay(int argc, char **argv)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	_cleanup_(asph_surface_freep) struct asph_surface *surf = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	_cleanup_free_ char *data = NULL;
	_cleanup_(fit_cli_release) struct fit_cli c = { 0 };
	struct fit_input in;
	char user[256];
	size_t len = 0;

	if (argc >= 2 && argv[1][0] == '-' && strcmp(argv[1], "--help") && strcmp(argv[1], "-h")) {
		fprintf(stderr, "asph replay: SCAN, or LENS and MEASURED, come first (see --help)\n");
		return EXIT_USAGE;
	}
	int r = fit_cli_parse(&c, argc, argv, 1, usage);
	if (r != EXIT_OK)
		return r < 0 ? EXIT_OK : r;
	if (c.lens) {
		r = read_measured(&c, &data, &len, &surf, &pts);
		if (r != EXIT_OK)
			return r;
		in = (struct fit_input){ .surface = surf, .points = pts, .name = c.points,
					 .run = run_of(&c, surf, data, len) };
		fit_report_run(&c, user, sizeof(user), &in.run);
		return fit_cli_run(&c, &in, NULL);
	}
	r = read_scan_only(&c, &data, &len, &s, &surf);
	if (r != EXIT_OK)
		return r;
	if (!s->report.ended || s->report.outcome != ASPH_SCANFILE_COMPLETED)
		fprintf(stderr, "asph replay: note: the scan did not complete (%s); characterizing the %zu points it kept\n",
			asph_scanfile_outcome_name(s->report.ended ? s->report.outcome
								    : ASPH_SCANFILE_UNFINISHED),
			s->n);
	in = (struct fit_input){ .surface = surf, .scan = s, .name = c.points,
				 .run = run_of(&c, surf, data, len) };
	fit_report_run(&c, user, sizeof(user), &in.run);
	return fit_cli_run(&c, &in, show_acquisition);
}
