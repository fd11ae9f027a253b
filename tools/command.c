/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdbool.h>
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

int command_help(const char *tool, const void *table, size_t n, size_t stride,
		 void (*usage)(FILE *out), int argc, char **argv, const void **entry,
		 char *words[4], int *n_words)
{
	if (argc < 2) {
		usage(stdout);
		return EXIT_OK;
	}
	if (argc == 2 && !strcmp(argv[1], "exit-status")) {
		tool_exit_codes_print(stdout);
		return EXIT_OK;
	}
	if (argc > 3) {
		fprintf(stderr, "Usage: %s help [COMMAND [SUBCOMMAND]]\n"
				"       %s help exit-status\n", tool, tool);
		return EXIT_USAGE;
	}
	if (!(*entry = command_find(table, n, stride, argv[1])))
		return command_unknown(tool, argv[1], table, n, stride);
	*n_words = 0;
	for (int i = 1; i < argc; i++)
		words[(*n_words)++] = argv[i];
	words[(*n_words)++] = (char *)"--help";
	words[*n_words] = NULL;
	return -1;
}

void command_help_option(FILE *out, const char *term, const char *text)
{
	int col = fprintf(out, "  %s", term);
	bool first = true;      /* no word on this line yet */

	col += fprintf(out, "%*s", col + 2 > HELP_COLUMN ? 2 : HELP_COLUMN - col, "");
	while (*text) {
		int len = (int)strcspn(text, " ");
		if (!first && col + 1 + len > HELP_WIDTH) {
			fprintf(out, "\n%*s", HELP_COLUMN, "");
			col = HELP_COLUMN;
			first = true;
		}
		col += fprintf(out, "%s%.*s", first ? "" : " ", len, text);
		first = false;
		text += len;
		text += strspn(text, " ");
	}
	fputc('\n', out);
}
