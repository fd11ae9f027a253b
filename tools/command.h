/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The command tables of asph and asphctl: finding a command, the message
 * for one that is not there (with the command meant, from the table), and
 * `help [COMMAND [SUBCOMMAND]]`. A table is an array of structs whose
 * first member is the command's name (const char *).
 */
#ifndef ASPH_TOOLS_COMMAND_H
#define ASPH_TOOLS_COMMAND_H

#include <stddef.h>

#define COMMAND_TABLE(table) (table), sizeof(table) / sizeof((table)[0]), sizeof((table)[0])

/* The entry of table named name, or NULL. */
const void *command_find(const void *table, size_t n, size_t stride, const char *name);

/* "TOOL: unknown command 'NAME' (did you mean 'NEAR'?)" and where to see
 * the commands, on stderr. EXIT_USAGE. */
int command_unknown(const char *tool, const char *name, const void *table, size_t n,
		    size_t stride);

/*
 * `TOOL help ARGS...` (argv[0] is "help"): prints the exit codes for
 * `help exit-status` and returns EXIT_OK; refuses more than a command and
 * a subcommand (EXIT_USAGE); else returns -1 with words holding the
 * command, its subcommand if any and "--help" (*n of them, at most 3, then
 * NULL), for the command to show its own help.
 */
int command_help_words(const char *tool, int argc, char **argv, char *words[4], int *n);

#endif
