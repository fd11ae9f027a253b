/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What asph's commands share (asph-tool.h): errors printed, the option
 * loop and its usage errors, a lens loaded. main.c dispatches to the
 * commands, which call these. */
#include <getopt.h>
#include <stdio.h>

#include "asph/prescription.h"
#include "asph-tool.h"
#include "util-suggest.h"

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

void tool_set_command(const char *name)
{
	command_name = name;
}

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
