/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the daemon tells the lab's monitoring (docs/admin.md): its health
 * (daemon.health, `asphctl health`, GET /healthz) and its metrics (GET
 * /metrics, in the Prometheus text format). Both are read, when asked,
 * from the modules that own the state: the jobs and the instruments'
 * activity (jobs.h), the outbox and its sinks, the state directory. The
 * counters it keeps itself are the errors of each kind, which it hears of
 * from the events (failed jobs) and from main.c (the sinks' links).
 *
 * Health is "ok", or "degraded" with a reason per finding, each under
 * the name of its check:
 *   instrument_fault  an instrument's last job stopped on a fault (until
 *                     its next job starts)
 *   sink_down         the MQTT broker or the PostgreSQL database has been
 *                     out of reach for more than health.sink_down_s
 *   outbox_backlog    a sink's oldest message has waited for more than
 *                     health.outbox_age_s
 *   outbox_held       messages a sink refused for good wait for the next start
 *   disk_low          the state directory has less than twice
 *                     limits.min_free_disk_mb free (at once it, jobs are refused)
 *   store_reserve     the job store's reserve is used up (the disk was full)
 *   queue_stopped     the queue is stopped while jobs wait in it
 * Event loop thread.
 */
#ifndef ASPHD_MONITOR_H
#define ASPHD_MONITOR_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include "events.h"
#include "instruments.h"
#include "jobs.h"
#include "outbox.h"
#include "settings.h"

struct monitor_setup {
	struct jobs *jobs;
	const struct instruments *instruments;
	const struct settings_limits *limits;   /* read at each use */
	const struct settings_health *health;   /* read at each use */
	const char *state_dir;
	const char *version;
	int64_t started_ns;                     /* realtime: the daemon's start */
};

/* The errors counted by kind (asphd_errors_total). */
enum monitor_error {
	MONITOR_JOB_FAILED,             /* a job ended failed */
	MONITOR_MQTT_CONNECTION,        /* the broker could not be reached, or the link broke */
	MONITOR_POSTGRES_CONNECTION,    /* the same of the database */
	MONITOR_POSTGRES_REFUSED,       /* a row the database refused for good */
	MONITOR_N_ERRORS,
};

struct monitor;

int monitor_new(const struct monitor_setup *setup, struct monitor **out);
void monitor_free(struct monitor *m);

/* The outbox, once the fleet runs, and each sink it sends to. */
void monitor_set_outbox(struct monitor *m, struct outbox *o);
void monitor_add_sink(struct monitor *m, enum outbox_sink_kind k);
/* Sink k is connected (up), or not. */
void monitor_sink_link(struct monitor *m, enum outbox_sink_kind k, bool up);
void monitor_count_error(struct monitor *m, enum monitor_error kind);

/* The event watch (events_watch_add()): failed jobs. data is the monitor. */
void monitor_watch(const struct event *ev, void *data);

/* The findings that make the daemon degraded now, as [{"check": NAME,
 * "detail": TEXT}] (empty: ok; and without a monitor, m NULL); NULL when
 * out of memory. */
json_t *monitor_health(struct monitor *m);

/* The metrics in the Prometheus text exposition format, version 0.0.4
 * (malloc'd, *len bytes), or NULL when out of memory. */
char *monitor_metrics(struct monitor *m, size_t *len);

#endif
