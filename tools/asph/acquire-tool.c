/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>

#include "acquire-tool.h"
#include "asph-tool.h"

static void warn_plugin(const struct asph_error *err, void *data)
{
	char buf[1024];

	fprintf(stderr, "asph: warning: driver plugin skipped: %s\n",
		asph_error_format(err, buf, sizeof(buf)));
}

int tool_registry_new(const char *plugin_dir, struct asph_registry **out)
{
	struct asph_registry *reg = NULL;
	struct asph_error err;
	int r;

	asph_error_clear(&err);
	r = asph_registry_new(&reg, &err);
	if (r == 0 && plugin_dir)
		r = asph_registry_load_dir(reg, plugin_dir, warn_plugin, NULL, &err);
	else if (r == 0)
		r = asph_registry_load_default_dirs(reg, warn_plugin, NULL, &err);
	if (r < 0) {
		tool_print_error(NULL, &err);
		asph_registry_free(reg);
		return r;
	}
	*out = reg;
	return 0;
}
