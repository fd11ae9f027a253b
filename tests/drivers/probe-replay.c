/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Replays recorded device traffic through a probe driver:
 *
 *   umockdev-run --device D.umockdev --ioctl NODE=D.ioctl [--script ...] \
 *       -- probe-replay DRIVER OPTIONS EXPECT...
 *
 * DRIVER is the driver's name, OPTIONS its options (k=v,k=v); each EXPECT
 * is the value in mm of one reading (to 1e-9 mm; "R" after it: flagged
 * out of range) or the errno name the reading must fail with (EPROTO,
 * ENODEV, ETIMEDOUT, EIO). Exits 0 when every reading is as expected, 77
 * outside umockdev-run.
 */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph-driver/instrument.h"

/* Opens drv's probe with opts; *o must outlive the device. */
static int open_probe(const struct asph_driver *drv, char *opts, struct asph_options **o,
		      struct asph_device **d)
{
	struct asph_error err;
	char *save = NULL;

	if (asph_options_new(drv, o, &err) < 0)
		return -1;
	for (char *kv = strtok_r(opts, ",", &save); kv; kv = strtok_r(NULL, ",", &save)) {
		char *eq = strchr(kv, '=');
		if (!eq || (*eq = 0, asph_options_set(*o, kv, eq + 1, &err) < 0)) {
			fprintf(stderr, "probe-replay: option %s: %s\n", kv, eq ? err.message : "no '='");
			return -1;
		}
	}
	int r = drv->probe->open(drv, asph_options_values(*o), 1000, d, &err);
	if (r < 0)
		fprintf(stderr, "probe-replay: open: %s\n", err.message);
	return r;
}

static int check(const char *expect, int r, const struct asph_reading *rd,
		 const struct asph_error *err)
{
	static const struct { const char *name; int code; } codes[] = {
		{ "EPROTO", -EPROTO }, { "ENODEV", -ENODEV }, { "ETIMEDOUT", -ETIMEDOUT },
		{ "EIO", -EIO },
	};

	for (size_t k = 0; k < sizeof(codes) / sizeof(codes[0]); k++)
		if (!strcmp(expect, codes[k].name)) {
			printf("%s: %d %s\n", expect, r, r < 0 ? err->message : "");
			return r == codes[k].code ? 0 : -1;
		}
	if (r < 0) {
		fprintf(stderr, "probe-replay: expected %s, got %d: %s\n", expect, r, err->message);
		return -1;
	}
	char *end;
	double v = strtod(expect, &end);
	bool range = *end == 'R';
	printf("%.9f%s\n", rd->value, rd->flags & ASPH_READING_OUT_OF_RANGE ? " R" : "");
	if (fabs(rd->value - v) > 1e-9 || range != !!(rd->flags & ASPH_READING_OUT_OF_RANGE)) {
		fprintf(stderr, "probe-replay: expected %s\n", expect);
		return -1;
	}
	return 0;
}

int main(int argc, char **argv)
{
	struct asph_registry *reg;
	struct asph_options *o = NULL;
	struct asph_device *d;
	int fails = 0;

	if (!getenv("UMOCKDEV_DIR")) {
		fprintf(stderr, "SKIP: run under umockdev-run\n");
		return 77;
	}
	if (argc < 3 || asph_registry_new(&reg, NULL) < 0)
		return 2;
	const struct asph_driver *drv = asph_registry_find(reg, argv[1]);
	if (!drv || !drv->probe || open_probe(drv, argv[2], &o, &d) < 0) {
		if (!drv || !drv->probe)
			fprintf(stderr, "probe-replay: no probe driver '%s'\n", argv[1]);
		asph_options_free(o);
		asph_registry_free(reg);
		return 1;
	}
	for (int i = 3; i < argc; i++) {
		struct asph_probe_context ctx = { .plan_index = (uint64_t)(i - 3) };
		struct asph_reading rd;
		struct asph_error err;
		int r = drv->probe->read(d, &ctx, &rd, 1000, &err);
		if (check(argv[i], r, &rd, &err) < 0)
			fails++;
	}
	drv->probe->close(d);
	asph_options_free(o);
	asph_registry_free(reg);
	return fails ? 1 : 0;
}
