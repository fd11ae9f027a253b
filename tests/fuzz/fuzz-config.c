/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Instrument configuration parser, against the built-in drivers. An
 * accepted configuration must describe itself as JSON (the scan header
 * stores that text).
 */
#include <stdint.h>
#include <stdlib.h>

#include "asph-driver/instrument.h"
#include "fuzz.h"

static struct asph_registry *registry;

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
	struct asph_error err;

	if (asph_registry_new(&registry, &err) < 0)
		fuzz_die("no registry: %s", err.message);
	return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct asph_config *c = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_config_parse(registry, (const char *)data, size, "fuzz.json", &c, &err) < 0) {
		fuzz_check_error(&err);
		return 0;
	}
	if (c->n == 0)
		fuzz_die("accepted a configuration without instruments");
	for (size_t i = 0; i < c->n; i++) {
		char *json = NULL;
		if (asph_instrument_config_to_json(&c->instruments[i], &json) < 0)
			fuzz_die("instrument %zu does not describe itself", i);
		free(json);
	}
	asph_config_free(c);
	return 0;
}
