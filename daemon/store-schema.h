/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The tables of the job store as their modules define them: each module
 * that keeps a table in the store (jobs-schema.c, locks-schema.c,
 * tokens-schema.c, outbox-schema.c) describes its tables in a struct
 * store_schema, data only, and store.c creates and upgrades all of them
 * together: one file, one schema version, one backup before an upgrade.
 */
#ifndef ASPHD_STORE_SCHEMA_H
#define ASPHD_STORE_SCHEMA_H

#include <stddef.h>

/* The version of the store's schema this daemon writes. 2: part, lot and
 * serial of jobs, the actor's name in the history, API tokens, instrument
 * locks, the outbox. */
#define STORE_SCHEMA_VERSION 2

/* A column a version adds to a table it did not create (type TEXT). */
struct store_column {
	const char *table;
	const char *column;
};

/*
 * What one version of the schema brings a module's tables to. tables are
 * CREATE ... IF NOT EXISTS statements, run on every open (a new store
 * gets them all, an older one those it lacks); columns are added to an
 * older table when it lacks them, then indexes run (IF NOT EXISTS), on a
 * new store and in the upgrade's transaction. Any of them may be NULL.
 */
struct store_step {
	int version;
	const char *tables;
	const struct store_column *columns;
	size_t n_columns;
	const char *indexes;
};

/* A module's tables: its steps, by increasing version. */
struct store_schema {
	const char *module;
	const struct store_step *steps;
	size_t n_steps;
};

extern const struct store_schema jobs_schema;
extern const struct store_schema locks_schema;
extern const struct store_schema tokens_schema;
extern const struct store_schema outbox_schema;

/* Every module's schema, in the order store.c runs them (store.c). */
extern const struct store_schema *const store_schemas[];
extern const size_t store_n_schemas;

#endif
