/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The offline command line tool `asph`: one file per command. */
#ifndef ASPH_TOOL_H
#define ASPH_TOOL_H

#include <stdbool.h>

#include "asph/error.h"
#include "asph/surface.h"

/* Exit codes, documented in docs/asph.1.md. */
enum {
	EXIT_OK = 0,
	EXIT_FAILURE_RUN = 1,   /* the command ran and failed (bad data, I/O) */
	EXIT_USAGE = 2,         /* bad command line */
};

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
int cmd_scan(int argc, char **argv);
int cmd_scaninfo(int argc, char **argv);
int cmd_synth(int argc, char **argv);

/* Prints "asph: <formatted error>" to stderr. */
void tool_print_error(const char *context, const struct asph_error *err);

/* Loads LENS (preset name or file) and builds its surface; prints the error
 * and returns a negative errno on failure. */
int tool_load_surface(const char *lens, struct asph_surface **out);

#endif
