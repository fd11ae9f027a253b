/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The JSON-RPC methods of proto/README.md, for one session (a connection)
 * at a time: a line in, the response out. Each method maps its parameters
 * in, calls the module that owns what it asks about (jobs.h,
 * instruments.h, events.h, access.h) and maps the outcome, or the error,
 * out. Mutating methods are refused before they run unless the peer is an
 * operator. The sessions are counted here (the "clients" of
 * daemon.status), and the lines handled (its "requests").
 *
 * A transport (server.c) fills a session's peer, opens it, hands over its
 * lines and closes it once; nothing here calls the transport.
 *
 * Event loop thread.
 */
#ifndef ASPHD_RPC_H
#define ASPHD_RPC_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>
#include <systemd/sd-event.h>

#include "access.h"
#include "events.h"
#include "instruments.h"
#include "jobs.h"
#include "settings.h"

struct rpc_session {
	struct peer peer;               /* the transport fills it */
	bool authenticated;             /* unix peers at once; TCP after hello */
	struct event_subscription events;
	bool open;                      /* rpc.c's */
};

struct rpc_setup {
	sd_event *event;                        /* the clock of the uptime */
	uint64_t started_usec;                  /* CLOCK_MONOTONIC: the daemon's start */
	struct jobs *jobs;
	const struct instruments *instruments;
	struct events *events;
	const struct access *access;
	const struct settings_limits *limits;   /* read at each use: may change */
};

struct rpc;

int rpc_new(const struct rpc_setup *setup, struct rpc **out);
void rpc_free(struct rpc *rpc);
/* Who may do what, after a reload. */
void rpc_set_access(struct rpc *rpc, const struct access *access);

/* A session starts (counted) and ends (its subscription with it);
 * closing a closed session changes nothing. */
void rpc_session_open(struct rpc *rpc, struct rpc_session *s);
void rpc_session_close(struct rpc *rpc, struct rpc_session *s);
size_t rpc_sessions(const struct rpc *rpc);

/*
 * Handles one line (without its "\n"): a request, a notification or a
 * batch. Returns what to answer (a response, or an array of them), or
 * NULL when nothing is to be answered.
 */
json_t *rpc_handle_line(struct rpc *rpc, struct rpc_session *s, const char *line, size_t len);

#endif
