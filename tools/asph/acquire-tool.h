/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What the acquisition commands (drivers, scan) share: the driver registry
 * with the plugins loaded. */
#ifndef ASPH_TOOL_ACQUIRE_H
#define ASPH_TOOL_ACQUIRE_H

#include "asph-driver/instrument.h"

/* The built-in drivers, plugins from plugin_dir (or, when NULL, the default
 * directories) with a warning per plugin that does not load. Prints the
 * error and returns a negative errno on failure. */
int tool_registry_new(const char *plugin_dir, struct asph_registry **out);

#endif
