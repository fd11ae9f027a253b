/* SPDX-License-Identifier: GPL-3.0-or-later */
/* An instrument: the stage and probe devices of a configuration, open. */
#include <errno.h>
#include <stdlib.h>

#include "asph/instrument.h"

void asph_instrument_close(struct asph_instrument *inst)
{
	if (!inst)
		return;
	if (inst->probe)
		inst->probe_driver->probe->close(inst->probe);
	if (inst->stage)
		inst->stage_driver->stage->close(inst->stage);
	free(inst);
}

static int open_devices(struct asph_instrument *in, unsigned timeout_ms,
			struct asph_error *err)
{
	const struct asph_instrument_config *c = in->config;
	int r = c->stage_driver->stage->open(c->stage_driver,
					     asph_options_values(c->stage_options),
					     timeout_ms, &in->stage, err);
	if (r < 0)
		return r;
	r = c->probe_driver->probe->open(c->probe_driver,
					 asph_options_values(c->probe_options),
					 timeout_ms, &in->probe, err);
	if (r < 0)
		return r;
	r = c->stage_driver->stage->info(in->stage, &in->stage_info, err);
	if (r < 0)
		return r;
	if (in->stage_info.n_axes != 3)
		return asph_error_set(err, -EPROTO, "stage '%s' reports %u axes; 3 are needed",
				      c->stage_driver->name, in->stage_info.n_axes);
	return c->probe_driver->probe->info(in->probe, &in->probe_info, err);
}

int asph_instrument_open(const struct asph_instrument_config *c,
			 unsigned timeout_ms, struct asph_instrument **out,
			 struct asph_error *err)
{
	struct asph_instrument *in = calloc(1, sizeof(*in));

	if (!in)
		return asph_error_set(err, -ENOMEM, "out of memory");
	in->config = c;
	in->stage_driver = c->stage_driver;
	in->probe_driver = c->probe_driver;
	int r = open_devices(in, timeout_ms, err);
	if (r < 0) {
		asph_instrument_close(in);
		return r;
	}
	*out = in;
	return 0;
}
