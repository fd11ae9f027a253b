/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The table of the outbox (queried in outbox.c): what must leave the PC,
 * per sink in the order it was made, until the sink acknowledges it.
 * Schema 2.
 */
#include "store-schema.h"
#include "util-mem.h"

static const struct store_step steps[] = {
	{ .version = 2, .tables =
	  "CREATE TABLE IF NOT EXISTS outbox ("
	  " id INTEGER PRIMARY KEY AUTOINCREMENT, sink TEXT NOT NULL, topic TEXT,"
	  " payload TEXT NOT NULL, qos INTEGER NOT NULL, retain INTEGER NOT NULL,"
	  " message_id TEXT NOT NULL, created_ns INTEGER NOT NULL);"
	  "CREATE INDEX IF NOT EXISTS outbox_sink ON outbox (sink, id);" },
};

const struct store_schema outbox_schema = {
	.module = "outbox", .steps = steps, .n_steps = ARRAY_SIZE(steps),
};
