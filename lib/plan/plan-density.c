/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The names of a plan's densities (h, spacing, points): one table, which
 * the plan's methods, its JSON and the option errors all read. */
#include <errno.h>
#include <string.h>

#include "asph/plan.h"
#include "util-mem.h"
#include "util-suggest.h"

static const char *const density_names[ASPH_PLAN_N_DENSITIES] = {
	[ASPH_DENSITY_H] = "h",
	[ASPH_DENSITY_SPACING] = "spacing",
	[ASPH_DENSITY_POINTS] = "points",
};

int asph_plan_density_names(char *buf, size_t size)
{
	return suggest_join(buf, size, density_names, ARRAY_SIZE(density_names), ", ");
}

const char *asph_plan_density_name(enum asph_plan_density_kind k)
{
	return (unsigned)k < ARRAY_SIZE(density_names) ? density_names[k] : "unknown";
}

int asph_plan_density_from_name(const char *name, enum asph_plan_density_kind *out)
{
	for (unsigned i = 0; name && i < ARRAY_SIZE(density_names); i++) {
		if (!strcmp(name, density_names[i])) {
			*out = (enum asph_plan_density_kind)i;
			return 0;
		}
	}
	return -EINVAL;
}
