/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The offline command line tool `asph`: one file per command. */
#ifndef ASPH_TOOL_H
#define ASPH_TOOL_H

#include <getopt.h>
#include <stdbool.h>
#include <stdio.h>

#include "asph/error.h"
#include "asph/surface.h"
#include "exit-codes.h"

struct tool_command {
	const char *name;
	const char *summary;
	int (*run)(int argc, char **argv);   /* argv[0] is the command name */
};

int cmd_drivers(int argc, char **argv);
int cmd_export(int argc, char **argv);
int cmd_fit(int argc, char **argv);
int cmd_lens(int argc, char **argv);
int cmd_lens_import(int argc, char **argv);   /* argv[0] is "import" */
int cmd_plan(int argc, char **argv);
int cmd_plot(int argc, char **argv);
int cmd_quality(int argc, char **argv);
int cmd_replay(int argc, char **argv);
int cmd_report(int argc, char **argv);
int cmd_scan(int argc, char **argv);
int cmd_scaninfo(int argc, char **argv);
int cmd_synth(int argc, char **argv);

/* Prints "asph: <formatted error>" to stderr. */
void tool_print_error(const char *context, const struct asph_error *err);

/* The command being run, which the messages of the option loop name. */
void tool_set_command(const char *name);

/* Takes one option of a command: 0, or < 0 for a value it refuses (after
 * saying why). */
typedef int tool_option_fn(int opt, const char *arg, void *data);

/*
 * The option loop of a command (getopt_long() from argv[1]): -h/--help
 * prints usage to stdout and the command exits 0; an unknown option or a
 * missing value prints usage to stderr and a refused value ends it, both
 * as a usage error. Returns -1 once the options are read (the operands
 * start at optind), else the exit code.
 */
int tool_getopt(int argc, char **argv, const char *shortopts,
		const struct option *longopts, void (*usage)(FILE *out),
		tool_option_fn *take, void *data);

/* After getopt_long() (with opterr = 0) refused an option: says what was
 * wrong with it, with the option meant when it is near, and how to see the
 * command's options. EXIT_USAGE. */
int tool_option_error(char **argv, const char *shortopts, const struct option *longopts);

/* For a command whose one option is a flag: sets the int at data. */
tool_option_fn tool_take_flag;

/* Loads LENS (preset name or file) and builds its surface; prints the error
 * and returns a negative errno on failure. */
int tool_load_surface(const char *lens, struct asph_surface **out);

#endif
