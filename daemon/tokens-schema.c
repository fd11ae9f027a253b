/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The table of the API tokens (queried in tokens.c): a token's digest,
 * never the token, with its role, expiry and revocation. Schema 2.
 */
#include "store-schema.h"
#include "util-mem.h"

static const struct store_step steps[] = {
	{ .version = 2, .tables =
	  "CREATE TABLE IF NOT EXISTS tokens ("
	  " name TEXT PRIMARY KEY, role INTEGER NOT NULL, digest BLOB NOT NULL,"
	  " created_ns INTEGER NOT NULL, expires_ns INTEGER NOT NULL,"
	  " revoked_ns INTEGER NOT NULL, created_by TEXT);" },
};

const struct store_schema tokens_schema = {
	.module = "tokens", .steps = steps, .n_steps = ARRAY_SIZE(steps),
};
