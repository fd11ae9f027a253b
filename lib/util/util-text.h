/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Other people's text shown to someone: the characters that would act on a
 * terminal or a log instead of being read (C0 controls, DEL, C1 controls,
 * the bidirectional overrides and isolates) are written as escapes.
 * asphctl escapes what it prints, asphd what it logs. Internal header.
 */
#ifndef ASPH_UTIL_TEXT_H
#define ASPH_UTIL_TEXT_H

#include <stdbool.h>
#include <stddef.h>

/* The length of the character at s that must be escaped, and its code
 * point in *cp, or 0. */
size_t text_control_at(const char *s, unsigned *cp);
/* Whether s holds one. */
bool text_has_controls(const char *s);
/*
 * s with each such character escaped (malloc'd, or NULL): as \n, \t, \xNN
 * or \uNNNN; with json, the C0 characters are left (in JSON text they are
 * layout: jansson has escaped those inside strings).
 */
char *text_escape_controls(const char *s, bool json);

#endif
