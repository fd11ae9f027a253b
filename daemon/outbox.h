/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The outbox: what must leave the PC and may not be lost, waiting in the
 * job store until its receiver acknowledged it (docs/fleet.md).
 *
 * Its source is the history of job states, which the queue writes in the
 * transaction of each change: outbox_catch_up() reads the changes after
 * the last one it took and turns each into the messages of each sink (for
 * MQTT the job's state, and the result of a completed job; for the
 * central database the row of a job that ended), written in one
 * transaction with the mark of the last change taken. A daemon killed
 * between a change and its message finds the change at its next start,
 * and a message's text is fixed once written, so one sent again is the
 * same message with the same message id.
 *
 * A sink (mqtt.h, pgsink.h) is handed at most its window of messages at a
 * time, oldest first; it says when one is acknowledged (outbox_done(),
 * which deletes it) and when it lost its connection (outbox_reset(): the
 * messages it held are handed again once it is back). Nothing is dropped
 * here: what a sink cannot take waits in the store, and what it refuses
 * for good (outbox_hold()) waits there too, set aside, until the next start.
 *
 * Event loop thread.
 */
#ifndef ASPHD_OUTBOX_H
#define ASPHD_OUTBOX_H

#include <stdbool.h>
#include <stdint.h>

#include "asph/error.h"

enum outbox_sink_kind {
	OUTBOX_MQTT,
	OUTBOX_POSTGRES,
	OUTBOX_N_SINKS,
};

/* An item of the outbox as the store keeps it. */
struct store_outbox_item {
	int64_t id;             /* assigned by store_outbox_add() */
	const char *sink;       /* "mqtt", "postgres" */
	const char *topic;      /* MQTT; NULL for the database */
	const char *payload;
	int qos;
	bool retain;
	const char *message_id;
	int64_t created_ns;
};

/* A receiver: send() takes an item (0) or not now (< 0: it is handed
 * again later). The item's strings live only during the call. */
struct outbox_sink {
	int (*send)(void *data, const struct store_outbox_item *it);
	void *data;
	unsigned window;        /* items handed and not yet acknowledged */
};

struct outbox_setup {
	const char *store_path;         /* the job store */
	const char *host;               /* this PC's name, in every message */
	const char *mqtt_prefix;        /* NULL: no MQTT messages */
	int mqtt_qos;                   /* of the state messages; at least 1 */
	bool postgres;                  /* rows for the central database */
};

struct outbox;

/* Opens the outbox (its own connection to the store) and the daemon's id
 * (made once, kept in the store). */
int outbox_new(const struct outbox_setup *setup, struct outbox **out, struct asph_error *err);
void outbox_free(struct outbox *o);

/* The daemon's id: a UUID made at the first start, the same ever after
 * (the central database's key with the job id). */
const char *outbox_daemon_id(const struct outbox *o);

/* The sink of kind k (NULL: none; its messages wait). */
void outbox_set_sink(struct outbox *o, enum outbox_sink_kind k, const struct outbox_sink *s);

/* Turns the job changes not yet taken into messages, then hands what the
 * sinks can take. 0, or -errno when the store could not be written (the
 * changes are taken at the next call). */
int outbox_catch_up(struct outbox *o);
/* Hands a sink what its window allows. */
void outbox_pump(struct outbox *o, enum outbox_sink_kind k);
/* Item id was acknowledged by sink k: it is deleted, and the next handed. */
void outbox_done(struct outbox *o, enum outbox_sink_kind k, int64_t id);
/* Sink k refused item id for good (why): it is set aside, kept in the
 * store, so that the items behind it go on; the next start hands it again. */
void outbox_hold(struct outbox *o, enum outbox_sink_kind k, int64_t id, const char *why);
/* Items sink k refused, waiting for the next start. */
int64_t outbox_held(struct outbox *o, enum outbox_sink_kind k);
/* Sink k lost what it held: hand it all again from the oldest. */
void outbox_reset(struct outbox *o, enum outbox_sink_kind k);
/* Items waiting for sink k (in the store, handed or not). */
int64_t outbox_waiting(struct outbox *o, enum outbox_sink_kind k);
/* When the oldest item waiting for sink k was made (realtime ns): 0 when
 * none waits, -1 when the store cannot be read. */
int64_t outbox_oldest_ns(struct outbox *o, enum outbox_sink_kind k);
/* "mqtt", "postgres": a sink's name in messages and metrics. */
const char *outbox_sink_name(enum outbox_sink_kind k);

#endif
