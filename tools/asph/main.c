/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>
#include <string.h>

#include <gsl/gsl_errno.h>

#include "config.h"
#include "asph/prescription.h"
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

/* The command being run, for messages ("lens" for asph lens import). */
static const char *command_name = "";

int tool_option_error(char **argv, const char *shortopts, const struct option *longopts)
{
	char why[256];

	fprintf(stderr, "asph %s: %s\nRun 'asph help %s' for its options.\n", command_name,
		suggest_getopt_error(argv, shortopts, longopts, why, sizeof(why)), command_name);
	return EXIT_USAGE;
}

int tool_getopt(int argc, char **argv, const char *shortopts,
		const struct option *longopts, void (*usage)(FILE *out),
		tool_option_fn *take, void *data)
{
	int c;

	optind = 0;   /* 0: getopt starts afresh (main read its options in order) */
	opterr = 0;
	while ((c = getopt_long(argc, argv, shortopts, longopts, NULL)) != -1) {
		if (c == 'h') {
			usage(stdout);
			return EXIT_OK;
		}
		if (c == '?' || c == ':')
			return tool_option_error(argv, shortopts, longopts);
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
	command_name = c->name;
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
	command_name = c->name;
	return c->run(argc - optind, argv + optind);
}
