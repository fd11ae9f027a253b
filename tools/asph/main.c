/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>
#include <string.h>

#include <gsl/gsl_errno.h>

#include "config.h"
#include "asph-tool.h"
#include "command.h"
#include "util-mem.h"
#include "util-suggest.h"

static int cmd_help(int argc, char **argv);

/* Keep sorted as `asph --help` shows it. */
static const struct tool_command commands[] = {
	{ "drivers", "list the instrument drivers with their roles and options", cmd_drivers },
	{ "export", "write the points of a recorded scan as CSV, PLY or JSON", cmd_export },
	{ "fit", "best-fit measured points to the lens; residual, PV, PVr, Zernike", cmd_fit },
	{ "help", "the usage of asph or of a command; help exit-status: the exit codes", cmd_help },
	{ "lens", "show or check a lens prescription", cmd_lens },
	{ "plan", "compute a sampling plan: points in scan order", cmd_plan },
	{ "plot", "draw a plan and a heatmap of its triangles' area ratio or q (PNG)", cmd_plot },
	{ "quality", "triangle quality of a plan: q and A_i / mean A statistics", cmd_quality },
	{ "replay", "characterize a recorded scan, or measured data, as asphd does", cmd_replay },
	{ "report", "the measurement report of a scan or a fit, as PDF", cmd_report },
	{ "scan", "measure a plan with an instrument into a scan file", cmd_scan },
	{ "scaninfo", "show a recorded scan: header, points, outcome, recovery", cmd_scaninfo },
	{ "synth", "synthetic measurement: plan points of a misaligned part with form error", cmd_synth },
};

static void usage(FILE *f)
{
	fprintf(f, "Usage: asph COMMAND [OPTIONS...]\n"
		   "       asph help [COMMAND]\n"
		   "       asph --version\n\n"
		   "Offline tool of asphd: lenses, sampling plans, quality, fitting, scans.\n\n"
		   "Commands:\n");
	for (size_t i = 0; i < ARRAY_SIZE(commands); i++)
		fprintf(f, "  %-10s %s\n", commands[i].name, commands[i].summary);
	fprintf(f, "\nRun 'asph help COMMAND' (or 'asph COMMAND --help') for the options of a\n"
		   "command. Operations that take more than a second show their progress on\n"
		   "a terminal; --quiet turns it off. The manual page is asph(1).\n");
}

/* asph help [COMMAND [SUBCOMMAND]]: the command's own --help. */
static int cmd_help(int argc, char **argv)
{
	const struct tool_command *c;
	char *words[4];
	int n, r;

	if ((r = command_help("asph", COMMAND_TABLE(commands), usage, argc, argv,
			      (const void **)&c, words, &n)) >= 0)
		return r;
	if (c->run == cmd_help)
		return cmd_help(1, argv);
	tool_set_command(c->name);
	optind = 0;
	return c->run(n, words);
}

int main(int argc, char **argv)
{
	static const struct option top[] = {
		{ "help", no_argument, NULL, 'h' }, { "version", no_argument, NULL, 'V' },
		{ NULL, 0, NULL, 0 },
	};
	const struct tool_command *c;
	int o;

	/* GSL's default handler aborts; every caller checks return codes. */
	gsl_set_error_handler_off();
	opterr = 0;
	while ((o = getopt_long(argc, argv, "+h", top, NULL)) != -1) {
		char why[256];

		switch (o) {
		case 'h':
			usage(stdout);
			return EXIT_OK;
		case 'V':
			printf("asph %s\n", ASPH_VERSION);
			return EXIT_OK;
		default:
			fprintf(stderr, "asph: %s\nRun 'asph help' for the commands.\n",
				suggest_getopt_error(argv, "h", top, why, sizeof(why)));
			return EXIT_USAGE;
		}
	}
	if (optind >= argc) {
		usage(stderr);
		return EXIT_USAGE;
	}
	if (!(c = command_find(COMMAND_TABLE(commands), argv[optind])))
		return command_unknown("asph", argv[optind], COMMAND_TABLE(commands));
	tool_set_command(c->name);
	return c->run(argc - optind, argv + optind);
}
