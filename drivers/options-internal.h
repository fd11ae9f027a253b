/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Option parsing and name hints shared by the registry, the options and the
 * configuration. Internal. */
#ifndef ASPH_OPTIONS_INTERNAL_H
#define ASPH_OPTIONS_INTERNAL_H

#include "asph-driver/instrument.h"

/* A descriptor is sane and its default parses. */
int option_desc_validate(const struct asph_option_desc *d,
			 struct asph_error *err);

/* Parses text for d into v (strings point into text's copy held by the
 * caller). Errors name d->name. */
int option_parse(const struct asph_option_desc *d, const char *text,
		 struct asph_option_value *v, struct asph_error *err);

/* " (did you mean 'NAME'?)" for an option name drv does not have, from its
 * option descriptors, or "" (into buf). */
const char *option_hint(const struct asph_driver *drv, const char *name, char *buf,
			size_t size);
/* The same for a driver name among those of reg (registry.c). */
const char *driver_hint(const struct asph_registry *reg, const char *name, char *buf,
			size_t size);

#endif
