/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The options every command shares: --json and --help. */
#include <getopt.h>
#include <stdbool.h>
#include <stdio.h>

#include "asphctl.h"
#include "util-suggest.h"

int ctl_usage_error(const char *usage)
{
	fprintf(stderr, "Usage: asphctl %s\n", usage);
	return EXIT_USAGE;
}

/* --help: the usage, then what the command's entry says. */
static void help(const struct ctl *ctl, const char *usage)
{
	printf("Usage: asphctl %s\n", usage);
	if (ctl->command && ctl->command->help)
		printf("\n%s", ctl->command->help);
	if (ctl->command && ctl->command->help_values) {
		putchar('\n');
		ctl->command->help_values(stdout);
	}
	printf("\nEvery command takes --json (print the answer as JSON) and --help. The manual\n"
	       "page asphctl(1) describes the commands; 'asphctl help exit-status' the exit\n"
	       "codes.\n");
}

int ctl_option(struct ctl *ctl, int argc, char **argv, const char *shortopts,
	       const struct option *opts, const char *usage)
{
	char optstring[64], why[256];

	snprintf(optstring, sizeof(optstring), "%sjh", shortopts);
	opterr = 0;
	for (;;) {
		int c = getopt_long(argc, argv, optstring, opts, NULL);

		switch (c) {
		case -1:
			return CTL_OPTIONS_END;
		case 'j':
			ctl->json = true;
			break;
		case 'h':
			help(ctl, usage);
			return CTL_OPTIONS_HELP;
		case '?':
		case ':':
			fprintf(stderr, "asphctl %s: %s\n", ctl->command ? ctl->command->name : "",
				suggest_getopt_error(argv, optstring, opts, why, sizeof(why)));
			ctl_usage_error(usage);
			return CTL_OPTIONS_BAD;
		default:
			return c;
		}
	}
}

int ctl_options_exit(int c)
{
	return c == CTL_OPTIONS_END ? -1 : c == CTL_OPTIONS_HELP ? EXIT_OK : EXIT_USAGE;
}

int ctl_common_options(struct ctl *ctl, int argc, char **argv, const char *usage)
{
	static const struct option opts[] = { CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 } };
	int c;

	while ((c = ctl_option(ctl, argc, argv, "", opts, usage)) > 0)
		;       /* only --json and --help, which ctl_option() takes */
	return ctl_options_exit(c);
}

int ctl_flag_option(struct ctl *ctl, int argc, char **argv, const char *name, char short_name,
		    bool *set, const char *usage)
{
	/* the flag's value: its short form, else one no short option has */
	int val = short_name ? short_name : 1;
	const struct option opts[] = {
		{ name, no_argument, NULL, val }, CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 },
	};
	const char shortopts[2] = { short_name, '\0' };
	int c;

	while ((c = ctl_option(ctl, argc, argv, shortopts, opts, usage)) > 0)
		*set |= c == val;
	return ctl_options_exit(c);
}
