/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A driver built outside the tree: only asph-driver/driver.h, no library
 * symbol.
 * A probe that reads a constant height above whatever stage carries it, one
 * reading at a time or streamed along a sweep. Built against this tree's
 * header, against the ABI 1.0 header (tests/drivers/abi-1.0: plugins of an
 * older minor version must load and measure), and with PLUGIN_ABI set to
 * versions the host refuses. Its constructor leaves a mark where
 * $ASPH_TEST_PLUGIN_MARK says, so that a test can tell whether any of its
 * code ran (a plugin that is refused must not run at all). Built with
 * PLUGIN_OLD_INCLUDE, it includes the header as plugins did before it had
 * a prefix of its own (asph/driver.h, which still works).
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>

#ifdef PLUGIN_OLD_INCLUDE
#include "asph/driver.h"
#else
#include "asph-driver/driver.h"
#endif

#ifndef PLUGIN_ABI
#define PLUGIN_ABI ASPH_DRIVER_ABI_VERSION
#endif

__attribute__((constructor)) static void mark_loaded(void)
{
	const char *mark = getenv("ASPH_TEST_PLUGIN_MARK");
	FILE *f = mark ? fopen(mark, "a") : NULL;

	if (f) {
		fputs("loaded\n", f);
		fclose(f);
	}
}

struct asph_device {
	double height;
};

static int fail(struct asph_error *err, int code, const char *msg)
{
	if (err) {
		err->code = code;
		snprintf(err->message, sizeof(err->message), "%s", msg);
	}
	return code;
}

static int echo_open(const struct asph_driver *drv, const struct asph_option_value *o,
		     unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return fail(err, -ENOMEM, "out of memory");
	d->height = o[0].d;
	*out = d;
	return 0;
}

static void echo_close(struct asph_device *d)
{
	free(d);
}

static int echo_info(struct asph_device *d, struct asph_probe_info *out,
		     struct asph_error *err)
{
	*out = (struct asph_probe_info){ .type = ASPH_PROBE_OPTICAL, .range_min = -1,
					 .range_max = 1, .standoff = 0, .can_stream = true };
	snprintf(out->model, sizeof(out->model), "echo");
	return 0;
}

static int echo_read(struct asph_device *d, const struct asph_probe_context *ctx,
		     struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	*out = (struct asph_reading){ .value = d->height, .raw = d->height };
	return 0;
}

static int echo_stream(struct asph_device *d, const struct asph_probe_context *ctx, size_t n,
		       struct asph_reading *out, size_t *n_done, unsigned timeout_ms,
		       struct asph_error *err)
{
	/* each reading says which plan point it was for: its raw number */
	for (size_t i = 0; i < n; i++)
		out[i] = (struct asph_reading){ .value = d->height,
						.raw = (double)ctx[i].plan_index };
	*n_done = n;
	return 0;
}

static int echo_stop(struct asph_device *d, struct asph_error *err)
{
	return 0;
}

static const struct asph_option_desc echo_options[] = {
	{ "height", ASPH_OPTION_DOUBLE, "0.25", .ranged = true, .min = -1, .max = 1,
	  .unit = "mm", .help = "the constant reading" },
};

static const struct asph_probe_ops echo_probe = {
	.open = echo_open, .close = echo_close, .info = echo_info,
	.read = echo_read, .stream = echo_stream, .stop = echo_stop,
};

static const struct asph_driver echo_driver = {
	.abi_version = PLUGIN_ABI,
	.name = "echo",
	.description = "constant-height probe (test plugin)",
	.version = "0.1",
	.roles = ASPH_ROLE_PROBE,
	.options = echo_options,
	.n_options = 1,
	.probe = &echo_probe,
};

static const struct asph_driver *const drivers[] = { &echo_driver };

__attribute__((visibility("default")))
const struct asph_driver *const *asph_driver_plugin(uint32_t *abi_version, size_t *n);

const struct asph_driver *const *asph_driver_plugin(uint32_t *abi_version, size_t *n)
{
	*abi_version = PLUGIN_ABI;
	*n = 1;
	return drivers;
}
