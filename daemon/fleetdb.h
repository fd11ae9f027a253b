/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The central results store of a fleet: PostgreSQL through libpq
 * (docs/fleet.md). Its schema is versioned (the table
 * asphd.schema_version) and made or migrated by `asphd --db-migrate`,
 * never by a running daemon. A running daemon writes each job that ended
 * as one row of asphd.results, keyed by (daemon id, job id), with an
 * upsert that a message delivered twice leaves as it was.
 *
 * The writer is a thread of its own that owns the connection: it
 * connects (with a growing delay, 1 s doubling to 30 s, after a failure),
 * checks the schema's version, and writes the rows handed to it one by
 * one, each in its own transaction, telling the loop (through an eventfd)
 * which were committed. A row whose write failed is tried again, unless the
 * server refused it for what it holds (a data exception or a constraint):
 * that one is handed back as refused, and the rows behind it go on.
 * Nothing here blocks the event loop.
 *
 * Event loop thread (the writer thread excepted).
 */
#ifndef ASPHD_FLEETDB_H
#define ASPHD_FLEETDB_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include <systemd/sd-event.h>

#include "asph/error.h"
#include "settings.h"

/* The schema this asphd writes; --db-migrate brings a database to it. */
#define FLEETDB_SCHEMA_VERSION 1

/*
 * Reads s->postgres's password file (owned by the user running this,
 * readable by it only; the password on its first line) into *password
 * (NULL without a file). Problems are reported with the setting's place.
 * 0 or -EINVAL.
 */
int fleetdb_password_load(const struct settings *s, char **password, settings_error_fn report,
			  void *data);

/* The connection string as it may be shown (a message, the log): its
 * parameters without any password, into buf (size bytes). */
void fleetdb_conninfo_shown(const char *conninfo, char *buf, size_t size);

/* asphd --db-migrate: creates or migrates the schema, in one transaction
 * under an advisory lock (several daemons may run it at once); says what
 * it did on out. 0, or -errno with err. */
int fleetdb_migrate(const struct settings_postgres *cfg, const char *password, FILE *out,
		    struct asph_error *err);

struct fleetdb_setup {
	sd_event *event;
	const struct settings_postgres *cfg;
	const char *password;           /* may be NULL */
	/* On the loop's thread: row id was committed; the link went up or
	 * down (why); row id was refused for what it holds (why), and the
	 * writer went on with the rows behind it. */
	void (*acked)(void *data, int64_t id);
	void (*link)(void *data, bool up, const char *why);
	void (*refused)(void *data, int64_t id, const char *why);
	void *data;
};

struct fleetdb;

int fleetdb_new(const struct fleetdb_setup *setup, struct fleetdb **out, struct asph_error *err);
void fleetdb_free(struct fleetdb *f);
/* Hands the writer one row (the outbox's payload, JSON): 0 or -ENOMEM. */
int fleetdb_send(struct fleetdb *f, int64_t id, const char *payload);

#endif
