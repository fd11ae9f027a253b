/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>
#include <string.h>

#include "command.h"
#include "exit-codes.h"
#include "util-suggest.h"

static const char *name_at(const void *table, size_t stride, size_t i)
{
	return *(const char *const *)((const char *)table + i * stride);
}

const void *command_find(const void *table, size_t n, size_t stride, const char *name)
{
	for (size_t i = 0; i < n; i++)
		if (!strcmp(name, name_at(table, stride, i)))
			return (const char *)table + i * stride;
	return NULL;
}

int command_unknown(const char *tool, const char *name, const void *table, size_t n,
		    size_t stride)
{
	struct suggest s;
	char hint[96];

	suggest_init(&s, name);
	for (size_t i = 0; i < n; i++)
		suggest_offer(&s, name_at(table, stride, i));
	fprintf(stderr, "%s: unknown command '%s'%s\nRun '%s help' for the commands.\n", tool, name,
		suggest_hint(&s, hint, sizeof(hint)), tool);
	return EXIT_USAGE;
}

int command_help_words(const char *tool, int argc, char **argv, char *words[4], int *n)
{
	if (argc == 2 && !strcmp(argv[1], "exit-status")) {
		tool_exit_codes_print(stdout);
		return EXIT_OK;
	}
	if (argc > 3) {
		fprintf(stderr, "Usage: %s help [COMMAND [SUBCOMMAND]]\n"
				"       %s help exit-status\n", tool, tool);
		return EXIT_USAGE;
	}
	*n = 0;
	for (int i = 1; i < argc; i++)
		words[(*n)++] = argv[i];
	words[(*n)++] = (char *)"--help";
	words[*n] = NULL;
	return -1;
}
