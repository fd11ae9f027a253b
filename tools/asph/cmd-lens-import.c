/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * asph lens import: one surface of an OpticStudio .zmx lens file or a row of
 * a CSV table as our JSON prescription (libasph's asph/lens-import.h reads
 * the file; docs/prescriptions.md, "Importing", lists what is read), or the
 * list of the file's surfaces and whether each imports.
 */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/lens-import.h"
#include "asph-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_lens_import *, asph_lens_import_free)

/* Whether the surface numbered `number` imports, and as what or why not. */
static void print_imports(const struct asph_lens_import *im, int number)
{
	struct asph_prescription p;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_lens_import_prescription(im, number, &p, &err) == 0) {
		printf("yes (%s)\n", asph_surface_type_name(p.type));
		return;
	}
	if (err.line > 0)
		printf("no: line %d: %s\n", err.line, err.message);
	else
		printf("no: %s\n", err.message);
}

/* The surfaces of a file with several, for choosing one with --surface:
 * each with its type, radius and size in mm, and whether it imports. */
static void list(const struct asph_lens_import *im)
{
	struct asph_lens_surface s;
	size_t n = asph_lens_import_count(im);

	if (asph_lens_import_format(im) == ASPH_LENS_CSV) {
		printf("%-8s %16s %10s %14s  %s\n", "row", "R (mm)", "k", "diameter (mm)",
		       "imports");
		for (size_t i = 0; i < n; i++) {
			asph_lens_import_surface(im, i, &s);
			printf("%-8d %16.10g %10.6g %14.10g  ", s.number, s.R, s.k,
			       s.aperture_diameter);
			print_imports(im, s.number);
		}
		return;
	}
	printf("%-8s %-12s %16s %14s  %s\n", "surface", "type", "radius (mm)", "semi-diam (mm)",
	       "imports");
	for (size_t i = 0; i < n; i++) {
		char rad[32];
		asph_lens_import_surface(im, i, &s);
		if (isinf(s.R))
			snprintf(rad, sizeof(rad), "inf");
		else
			snprintf(rad, sizeof(rad), "%.10g", s.R);
		printf("%-8d %-12s %16s %14.10g  ", s.number, s.type, rad, s.aperture_diameter / 2);
		print_imports(im, s.number);
	}
}

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph lens import FILE [--surface N] [-o OUT.json]\n\n"
		     "FILE is an OpticStudio lens file (.zmx, UTF-8 or UTF-16) or a CSV table\n"
		     "with the header R,k,A4,A6,...,aperture_diameter.\n"
		     "  --surface N   the surface (its SURF number; a CSV row, from 1) to import;\n"
		     "                without it a file with several surfaces lists them, each\n"
		     "                with whether it imports and why not\n"
		     "  -o OUT.json   write the prescription there instead of to stdout\n");
}

static int write_out(const struct asph_prescription *p, const char *out)
{
	_cleanup_free_ char *json = NULL;

	if (asph_prescription_to_json(p, &json) < 0)
		return EXIT_FAILURE_RUN;
	if (!out) {
		printf("%s\n", json);
		return EXIT_OK;
	}
	_cleanup_fclose_ FILE *f = fopen(out, "we");
	if (!f || fprintf(f, "%s\n", json) < 0 || fflush(f) != 0) {
		fprintf(stderr, "asph: lens import: %s: %s\n", out, strerror(errno));
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

static int import(const char *path, int want, const char *out)
{
	_cleanup_(asph_lens_import_freep) struct asph_lens_import *im = NULL;
	struct asph_prescription p;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_lens_import_load(path, &im, &err) < 0) {
		tool_print_error("lens import", &err);
		return EXIT_FAILURE_RUN;
	}
	if (want < 0 && asph_lens_import_count(im) > 1) {
		list(im);
		if (strcmp(asph_lens_import_unit(im), "MM") && asph_lens_import_unit(im)[0])
			fprintf(stderr, "asph: lens import: lens units %s, shown and imported in mm\n",
				asph_lens_import_unit(im));
		fprintf(stderr, "asph: lens import: several surfaces; choose one with --surface N\n");
		return EXIT_OK;
	}
	if (asph_lens_import_prescription(im, want, &p, &err) < 0) {
		tool_print_error("lens import", &err);
		return EXIT_FAILURE_RUN;
	}
	return write_out(&p, out);
}

struct import_args {
	const char *out;
	int want;               /* -1: the only surface */
};

static int take(int opt, const char *arg, void *data)
{
	struct import_args *a = data;
	char *end;

	if (opt == 'o') {
		a->out = arg;
		return 0;
	}
	errno = 0;
	long v = strtol(arg, &end, 10);
	if (arg[0] < '0' || arg[0] > '9' || *end || errno || v > INT_MAX) {
		fprintf(stderr, "asph: lens import: --surface wants a number from 0 to %d, "
			"not '%s'\n", INT_MAX, arg);
		return -EINVAL;
	}
	a->want = (int)v;
	return 0;
}

int cmd_lens_import(int argc, char **argv)
{
	static const struct option options[] = {
		{ "surface", required_argument, NULL, 's' },
		{ "output", required_argument, NULL, 'o' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 }
	};
	struct import_args a = { .want = -1 };
	int code = tool_getopt(argc, argv, "o:h", options, usage, take, &a);

	if (code >= 0)
		return code;
	if (optind + 1 != argc) {
		usage(stderr);
		return EXIT_USAGE;
	}
	return import(argv[optind], a.want, a.out);
}
