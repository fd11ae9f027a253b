/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The exit codes of asph and asphctl: one table for both tools. Scripts and
 * monitoring code against these values: never renumber one. The EXIT
 * STATUS tables of docs/asph.1.md and docs/asphctl.1.md are this table
 * (tests/integration/test-cli-help.py compares them with what `asph help
 * exit-status` and `asphctl help exit-status` print from it).
 */
#ifndef ASPH_TOOLS_EXIT_CODES_H
#define ASPH_TOOLS_EXIT_CODES_H

#include <stdio.h>

/* X(NAME, value, meaning) */
#define TOOL_EXIT_CODES(X)                                                            \
	X(OK, 0, "success (the part passes its tolerance; health: ok)")               \
	X(FAILURE_RUN, 1, "the command ran and failed: bad data, an I/O error, an "    \
			  "instrument fault, no convergence, an error the daemon reported") \
	X(USAGE, 2, "bad command line")                                                \
	X(VERDICT_FAIL, 3, "the part fails its tolerance")                             \
	X(VERDICT_UNDECIDED, 4, "the verdict is undecided (conformance proven neither way)") \
	X(JOB_FAILED, 5, "the watched job ended failed, cancelled or interrupted")     \
	X(DENIED, 6, "permission denied")                                              \
	X(UNREACHABLE, 7, "the daemon cannot be reached, or the connection broke (health: down)") \
	X(DEGRADED, 8, "degraded (health)")

#define TOOL_EXIT_ENUM(name, value, meaning) EXIT_##name = (value),
enum tool_exit { TOOL_EXIT_CODES(TOOL_EXIT_ENUM) };
#undef TOOL_EXIT_ENUM

/* The table for `help exit-status`: "  0  meaning" lines. */
static inline void tool_exit_codes_print(FILE *f)
{
#define TOOL_EXIT_ROW(name, value, meaning) fprintf(f, "  %d  %s\n", (value), (meaning));
	fprintf(f, "Exit status:\n");
	TOOL_EXIT_CODES(TOOL_EXIT_ROW)
#undef TOOL_EXIT_ROW
}

#endif
