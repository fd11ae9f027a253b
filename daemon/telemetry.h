/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The live part of the MQTT telemetry (docs/fleet.md, proto/mqtt/): an
 * event watch that keeps the retained <prefix>/status and
 * <prefix>/instrument/<name>/state as the daemon is, and publishes
 * <prefix>/job/<id>/progress at most twice a second per job. None of it
 * is kept: the retained topics are published again whole when the link
 * comes back, and progress is the first thing dropped when the link is
 * down or the broker slow (more than TELEMETRY_PROGRESS_BACKLOG
 * publications waiting). Job states and results go through the outbox.
 *
 * Event loop thread.
 */
#ifndef ASPHD_TELEMETRY_H
#define ASPHD_TELEMETRY_H

#include <stdint.h>

#include "events.h"
#include "instruments.h"
#include "jobs.h"
#include "mqtt.h"

/* Progress is dropped while more publications than this wait. */
#define TELEMETRY_PROGRESS_BACKLOG 64
/* Between two progress messages of one job, at least. */
#define TELEMETRY_PROGRESS_INTERVAL_NS (500 * 1000000LL)

struct telemetry_setup {
	const char *prefix;
	const char *daemon_id;
	const char *host;
	int qos;
	int64_t started_ns;                     /* the daemon's start, realtime */
	const struct jobs *jobs;
	const struct instruments *instruments;
};

struct telemetry;

int telemetry_new(const struct telemetry_setup *setup, struct telemetry **out);
void telemetry_free(struct telemetry *t);
/* The link to publish through (NULL: none yet). */
void telemetry_set_mqtt(struct telemetry *t, struct mqtt *m);

/* <prefix>/status, the last will's topic; and its payloads. */
const char *telemetry_status_topic(const struct telemetry *t);
/* The status "offline" (malloc'd): the will, and the goodbye. */
char *telemetry_offline(const struct telemetry *t);

/* The link is up: the retained topics are published again. */
void telemetry_link_up(struct telemetry *t);
/* The event watch (events_watch_add()); data is the telemetry. */
void telemetry_watch(const struct event *ev, void *data);

#endif
