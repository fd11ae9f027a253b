/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Where line profiles live, in the order they are searched:
 * $ASPH_LINE_PROFILE_PATH (colon-separated directories), the lab's
 * directory (SYSCONFDIR/asphd/line-profiles), then the built-in ones,
 * compiled in from drivers/line/profiles/; NAME is NAME.profile in the
 * first that has it. A directory $ASPH_LINE_PROFILE_PATH names must be
 * there; the lab's may be absent, but not unreadable. Internal to
 * drivers/line/.
 */
#ifndef ASPH_LINE_FILES_H
#define ASPH_LINE_FILES_H

#include <stddef.h>

#include "asph-driver/instrument.h"
#include "embedded.h"
#include "profile.h"

/* drivers/line/profiles/, compiled in by scripts/embed-files. */
extern const struct embedded_file line_builtin_profiles[];
extern const size_t line_builtin_profiles_count;

/* A profile by name (searched as above) or by path (a name with a '/').
 * -ENOENT naming the directories searched and the built-in profiles; a
 * directory that cannot be searched is named with what to change; a
 * malformed file is refused with its file, line, column and reason. */
int line_profile_load(const char *name, struct line_profile *p, struct asph_error *err);

/* Every profile the search finds, one per name (the one a name would
 * load; a built-in one with the path "built-in"), sorted by name; one
 * that does not parse is listed with its reason. A directory that cannot
 * be searched fails the listing as line_profile_load() would. The
 * registry's lister for the line driver (builtin-drivers.h). */
int line_profiles_list(struct asph_driver_profile **out, size_t *n, struct asph_error *err);

#endif
