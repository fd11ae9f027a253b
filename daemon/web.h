/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The web listener (http_listen, docs/web.md): the operator's page and the
 * same JSON-RPC methods as the socket, over HTTP. libmicrohttpd parses
 * HTTP; it runs without a thread of its own, driven from the event loop
 * (its epoll descriptor is an sd-event source, its timeout an sd-event
 * timer), so that every call reaches rpc.c on the event loop thread as
 * the socket's do.
 *
 * Routes:
 *   GET  /, /NAME            the page's files (http_root)
 *   POST /api/login          {"token": ...}: a session cookie
 *   POST /api/logout         ends the session
 *   POST /api/rpc            a JSON-RPC line (request, notification, batch)
 *   GET  /api/events         Server-Sent Events: the notifications the
 *                            session subscribed to with events.subscribe
 *   GET  /api/jobs/ID/files/NAME   a result file (job.file's names)
 *   GET  /api/jobs/ID/points?from=N  measured points from the Nth on
 *
 * A session is an rpc_session of a peer that proved a token (a named
 * token's role, as over TCP); its cookie is HttpOnly and SameSite=Strict.
 * A POST whose Origin is not the page's own is refused (403). Bodies over
 * limits.max_request_bytes are refused (413); sessions are bounded by
 * limits.max_clients, a stream's unsent events by limits.max_output_bytes.
 * Event loop thread.
 */
#ifndef ASPHD_WEB_H
#define ASPHD_WEB_H

#include <netdb.h>

#include <systemd/sd-event.h>

#include "events.h"
#include "jobs.h"
#include "rpc.h"
#include "settings.h"

struct web_setup {
	sd_event *event;
	struct rpc *rpc;
	struct jobs *jobs;
	const struct settings_limits *limits;   /* read at each use: may change */
	const char *state_dir;                  /* the jobs' scans, for points */
};

struct web;

int web_new(const struct web_setup *setup, struct web **out);
/* Ends every session and stops listening. */
void web_free(struct web *w);

/* Listens on addr (from server_resolve_tcp()) and serves the files of
 * root. 0, or -errno having logged why. */
int web_listen(struct web *w, const struct addrinfo *addr, const char *root);
/* The port listened on (after web_listen()), 0 when not listening. */
unsigned web_port(const struct web *w);

/* Ends the sessions whose token no longer stands (rpc_session_valid()). */
void web_revalidate(struct web *w);

/* The event watch (events_watch_add()): queues ev to each session's
 * stream that subscribed to it. data is the web listener. */
void web_notify(const struct event *ev, void *data);

#endif
