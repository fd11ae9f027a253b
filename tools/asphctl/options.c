/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The options every command shares: --json and --help. */
#include <getopt.h>
#include <stdio.h>

#include "asphctl.h"

int ctl_usage_error(const char *usage)
{
	fprintf(stderr, "Usage: asphctl %s\n", usage);
	return CTL_EXIT_USAGE;
}

int ctl_option(struct ctl *ctl, int argc, char **argv, const char *shortopts,
	       const struct option *opts, const char *usage)
{
	char optstring[64];

	snprintf(optstring, sizeof(optstring), "%sjh", shortopts);
	for (;;) {
		int c = getopt_long(argc, argv, optstring, opts, NULL);

		switch (c) {
		case -1:
			return CTL_OPTIONS_END;
		case 'j':
			ctl->json = true;
			break;
		case 'h':
			printf("Usage: asphctl %s\n", usage);
			return CTL_OPTIONS_HELP;
		case '?':
		case ':':
			ctl_usage_error(usage);
			return CTL_OPTIONS_BAD;
		default:
			return c;
		}
	}
}

int ctl_options_exit(int c)
{
	return c == CTL_OPTIONS_END ? -1 : c == CTL_OPTIONS_HELP ? CTL_EXIT_OK : CTL_EXIT_USAGE;
}

int ctl_common_options(struct ctl *ctl, int argc, char **argv, const char *usage)
{
	static const struct option opts[] = { CTL_JSON_OPTION, CTL_HELP_OPTION, { NULL, 0, NULL, 0 } };
	int c;

	while ((c = ctl_option(ctl, argc, argv, "", opts, usage)) > 0)
		;       /* only --json and --help, which ctl_option() takes */
	return ctl_options_exit(c);
}
