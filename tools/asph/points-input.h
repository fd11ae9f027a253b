/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Measured points in: the file of asph fit in any format asph reads, with
 * --format and --units, and what reading it dropped said aloud. */
#ifndef ASPH_TOOL_POINTS_INPUT_H
#define ASPH_TOOL_POINTS_INPUT_H

#include "asph/points.h"

struct points_input {
	struct asph_points_read_options opts;
	const char *format_arg, *units_arg;   /* as given, NULL if not */
};

/* --format NAME and --units UNIT: 0, or -1 after saying why (prog names
 * the command in the message). */
int points_input_format(struct points_input *in, const char *prog, const char *arg);
int points_input_units(struct points_input *in, const char *prog, const char *arg);

/* Reads path; prints the error, or a note to stderr when map nodes were
 * invalid or preamble lines skipped. 0, or a negative errno. */
int points_input_read(const struct points_input *in, const char *prog, const char *path,
		      struct asph_points **out);

/* The same of a file's bytes (len of data), path naming it in messages. */
int points_input_read_memory(const struct points_input *in, const char *prog,
			     const void *data, size_t len, const char *path,
			     struct asph_points **out);

/* The options' help lines. */
#define POINTS_INPUT_HELP \
	"  --format F          the points file's format: auto (default: found from the\n" \
	"                      content), text (csv), ply, json, x3p, sdf, metropro (dat),\n" \
	"                      datx\n" \
	"  --units U           unit of text columns whose header names none (all of them\n" \
	"                      without a header): nm, um, mm (default), cm, m, in\n"

#endif
