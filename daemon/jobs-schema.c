/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The tables of the job queue (queried in jobs-store.c): jobs, with their
 * states, and history, every transition of them. store.c creates and
 * upgrades them with the other modules' tables.
 */
#include "store-schema.h"
#include "util-mem.h"

static const char tables_1[] =
	"CREATE TABLE IF NOT EXISTS jobs ("
	" id INTEGER PRIMARY KEY AUTOINCREMENT,"
	" state INTEGER NOT NULL, priority INTEGER NOT NULL, seq INTEGER NOT NULL,"
	" label TEXT, instrument TEXT NOT NULL, uid INTEGER NOT NULL, user TEXT,"
	" spec TEXT NOT NULL, submitted_ns INTEGER NOT NULL, started_ns INTEGER NOT NULL,"
	" finished_ns INTEGER NOT NULL, points_done INTEGER NOT NULL,"
	" points_total INTEGER NOT NULL, reason TEXT, result TEXT, scan_path TEXT,"
	" resume INTEGER NOT NULL, attempts INTEGER NOT NULL);"
	"CREATE INDEX IF NOT EXISTS jobs_queue ON jobs (state, instrument, priority DESC, seq);"
	/* The queue in the order it runs, for listings taken a few jobs at a
	 * time (store_list()); the states are those of QUEUE_STATES (jobs-store.c). */
	"CREATE INDEX IF NOT EXISTS jobs_queue_order ON jobs (priority DESC, seq, id)"
	" WHERE state IN (0,1,2);"
	"CREATE TABLE IF NOT EXISTS history ("
	" job INTEGER NOT NULL REFERENCES jobs(id), t_ns INTEGER NOT NULL,"
	" state INTEGER NOT NULL, reason TEXT, actor_uid INTEGER NOT NULL);"
	"CREATE INDEX IF NOT EXISTS history_job ON history (job);";

/* Schema 2 adds the part a job measures and who acted on it by name;
 * a new store gets these columns the same way, by ALTER TABLE, so that
 * its tables read as an upgraded one's. */
static const struct store_column columns_2[] = {
	{ "jobs", "part" }, { "jobs", "lot" }, { "jobs", "serial" }, { "history", "actor" },
};

static const struct store_step steps[] = {
	{ .version = 1, .tables = tables_1 },
	{ .version = 2, .columns = columns_2, .n_columns = ARRAY_SIZE(columns_2),
	  .indexes = "CREATE INDEX IF NOT EXISTS jobs_part ON jobs (part)" },
};

const struct store_schema jobs_schema = {
	.module = "jobs", .steps = steps, .n_steps = ARRAY_SIZE(steps),
};
