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
#include <stdio.h>

#define COMMAND_TABLE(table) (table), sizeof(table) / sizeof((table)[0]), sizeof((table)[0])

/* The entry of table named name, or NULL. */
const void *command_find(const void *table, size_t n, size_t stride, const char *name);

/* "TOOL: unknown command 'NAME' (did you mean 'NEAR'?)" and where to see
 * the commands, on stderr. EXIT_USAGE. */
int command_unknown(const char *tool, const char *name, const void *table, size_t n,
		    size_t stride);

/*
 * `TOOL help ARGS...` (argv[0] is "help"): the tool's usage for no
 * argument and the exit codes for `help exit-status` (EXIT_OK); refuses
 * more than a command and a subcommand and a command not in table (after
 * saying so: EXIT_USAGE); else returns -1 with *entry, the command's entry,
 * and words holding the command, its subcommand if any and "--help" (*n
 * of them, at most 3, then NULL), for the command to show its own help.
 */
int command_help(const char *tool, const void *table, size_t n, size_t stride,
		 void (*usage)(FILE *out), int argc, char **argv, const void **entry,
		 char *words[4], int *n_words);

/*
 * One option of a help text: "  TERM", then TEXT from column HELP_COLUMN
 * (after two spaces when TERM reaches it), wrapped at spaces to lines of at
 * most HELP_WIDTH columns, each further line indented to HELP_COLUMN. For
 * an option whose text is made from a table (a list of names).
 */
#define HELP_COLUMN 22
#define HELP_WIDTH 79
void command_help_option(FILE *out, const char *term, const char *text);

#endif
