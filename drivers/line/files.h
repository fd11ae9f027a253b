/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Where line profiles live, in the order they are searched:
 * $ASPH_LINE_PROFILE_PATH (colon-separated directories), the lab's
 * directory (SYSCONFDIR/asphd/line-profiles) and the installed one
 * (DATADIR/asphd/line-profiles); NAME is NAME.profile in the first
 * directory that has it. Internal to drivers/line/.
 */
#ifndef ASPH_LINE_FILES_H
#define ASPH_LINE_FILES_H

#include <stddef.h>

#include "asph-driver/instrument.h"
#include "profile.h"

/* A profile by name (searched as above) or by path (a name with a '/').
 * -ENOENT naming the directories searched; a malformed file is refused
 * with its file, line, column and reason. */
int line_profile_load(const char *name, struct line_profile *p, struct asph_error *err);

/* Every profile the search finds, one per name (the one a name would
 * load), sorted by name; one that does not parse is listed with its
 * reason. The registry's lister for the line driver (builtin-drivers.h). */
int line_profiles_list(struct asph_driver_profile **out, size_t *n, struct asph_error *err);

#endif
