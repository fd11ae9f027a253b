/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>
#include <string.h>

#include <gsl/gsl_errno.h>

#include "config.h"
#include "asph/prescription.h"
#include "asph-tool.h"
#include "util-mem.h"

/* Keep sorted as `asph --help` shows it. */
static const struct tool_command commands[] = {
	{ "drivers", "list the instrument drivers with their roles and options", cmd_drivers },
	{ "export", "write the points of a recorded scan as CSV, PLY or JSON", cmd_export },
	{ "fit", "best-fit measured points to the lens; residual, PV, PVr, Zernike", cmd_fit },
	{ "lens", "show or check a lens prescription", cmd_lens },
	{ "plan", "compute a sampling plan: points in scan order", cmd_plan },
	{ "plot", "draw a plan and a heatmap of its triangles' area ratio or q (PNG)", cmd_plot },
	{ "quality", "triangle quality of a plan: q and A_i / mean A statistics", cmd_quality },
	{ "replay", "characterize a recorded scan (asph fit on its points)", cmd_replay },
	{ "report", "the measurement report of a scan or a fit, as PDF", cmd_report },
	{ "scan", "measure a plan with an instrument into a scan file", cmd_scan },
	{ "scaninfo", "show a recorded scan: header, points, outcome, recovery", cmd_scaninfo },
	{ "synth", "synthetic measurement: plan points of a misaligned part with form error", cmd_synth },
};

void tool_print_error(const char *context, const struct asph_error *err)
{
	char buf[1024];

	asph_error_format(err, buf, sizeof(buf));
	if (context)
		fprintf(stderr, "asph: %s: %s\n", context, buf);
	else
		fprintf(stderr, "asph: %s\n", buf);
}

int tool_getopt(int argc, char **argv, const char *shortopts,
		const struct option *longopts, void (*usage)(FILE *out),
		tool_option_fn *take, void *data)
{
	int c;

	optind = 1;
	while ((c = getopt_long(argc, argv, shortopts, longopts, NULL)) != -1) {
		if (c == 'h') {
			usage(stdout);
			return EXIT_OK;
		}
		if (c == '?' || c == ':') {
			usage(stderr);
			return EXIT_USAGE;
		}
		if (take(c, optarg, data) < 0)
			return EXIT_USAGE;
	}
	return -1;
}

int tool_take_flag(int opt, const char *arg, void *data)
{
	*(int *)data = 1;
	return 0;
}

int tool_load_surface(const char *lens, struct asph_surface **out)
{
	struct asph_prescription p;
	struct asph_error err;
	int r;

	asph_error_clear(&err);
	r = asph_prescription_load(lens, &p, &err);
	if (r == 0)
		r = asph_surface_alloc(&p, out, &err);
	if (r < 0)
		tool_print_error(NULL, &err);
	return r;
}

static void usage(FILE *f)
{
	fprintf(f, "Usage: asph COMMAND [OPTIONS...]\n\n"
		   "Offline tool of asphd: lenses, sampling plans, quality, fitting, scans.\n\n"
		   "Commands:\n");
	for (size_t i = 0; i < ARRAY_SIZE(commands); i++)
		fprintf(f, "  %-10s %s\n", commands[i].name, commands[i].summary);
	fprintf(f, "\nRun 'asph COMMAND --help' for the options of a command.\n");
}

int main(int argc, char **argv)
{
	/* GSL's default handler aborts; every caller checks return codes. */
	gsl_set_error_handler_off();
	if (argc < 2) {
		usage(stderr);
		return EXIT_USAGE;
	}
	if (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
		usage(stdout);
		return EXIT_OK;
	}
	if (!strcmp(argv[1], "--version")) {
		printf("asph %s\n", ASPH_VERSION);
		return EXIT_OK;
	}
	for (size_t i = 0; i < ARRAY_SIZE(commands); i++)
		if (!strcmp(argv[1], commands[i].name))
			return commands[i].run(argc - 1, argv + 1);
	fprintf(stderr, "asph: unknown command '%s'\n", argv[1]);
	usage(stderr);
	return EXIT_USAGE;
}
