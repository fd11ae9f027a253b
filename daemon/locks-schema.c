/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The table of the operator locks (queried in locks-store.c): one row per
 * locked instrument, kept over a restart. Schema 2.
 */
#include "store-schema.h"
#include "util-mem.h"

static const struct store_step steps[] = {
	{ .version = 2, .tables =
	  "CREATE TABLE IF NOT EXISTS locks ("
	  " instrument TEXT PRIMARY KEY, holder TEXT NOT NULL, holder_uid INTEGER NOT NULL,"
	  " reason TEXT NOT NULL, since_ns INTEGER NOT NULL, pause INTEGER NOT NULL,"
	  " paused_job INTEGER NOT NULL);" },
};

const struct store_schema locks_schema = {
	.module = "locks", .steps = steps, .n_steps = ARRAY_SIZE(steps),
};
