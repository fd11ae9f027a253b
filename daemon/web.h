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
 *   GET  /, /NAME            the page's files (built in, or http_root's)
 *   POST /api/login          {"token": ...}: a session cookie
 *   POST /api/logout         ends the session
 *   POST /api/rpc            a JSON-RPC line (request, notification, batch)
 *   GET  /api/events         Server-Sent Events: the notifications the
 *                            session subscribed to with events.subscribe
 *   GET  /api/jobs/ID/files/NAME   a result file (job.file's names)
 *   GET  /api/jobs/ID/points?from=N  measured points from the Nth on
 *   GET  /healthz            "ok" or "degraded" (monitor.h), without login
 *   GET  /metrics            the Prometheus text format, to a viewer's token
 *                            in "Authorization: Bearer TOKEN"
 *
 * A session is an rpc_session of a peer that proved a token (a named
 * token's role, as over TCP); its cookie is HttpOnly and SameSite=Strict.
 * A POST whose Origin is not the page's own is refused (403). Bodies over
 * limits.max_request_bytes are refused (413); connections are bounded by
 * limits.max_clients and limits.max_clients_per_user (of one address),
 * sessions by limits.max_clients, a stream's unsent events by
 * limits.max_output_bytes; all read at each use, so that a reload applies.
 * Event loop thread.
 */
#ifndef ASPHD_WEB_H
#define ASPHD_WEB_H

#include <netdb.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>

#include <systemd/sd-event.h>

#include "embedded.h"
#include "events.h"
#include "jobs.h"
#include "monitor.h"
#include "rpc.h"
#include "settings.h"

/* The page's files (daemon/web/), compiled in by scripts/embed-files. */
extern const struct embedded_file web_builtin_files[];
extern const size_t web_builtin_files_count;

struct web_setup {
	sd_event *event;
	struct rpc *rpc;
	struct jobs *jobs;
	struct monitor *monitor;                /* /healthz, /metrics */
	const struct settings_limits *limits;   /* read at each use: may change */
	const char *state_dir;                  /* the jobs' scans, for points */
};

struct web;

int web_new(const struct web_setup *setup, struct web **out);
/* Ends every session and stops listening. */
void web_free(struct web *w);

/* Listens on every address of addr (from server_resolve_tcp(); text is
 * http_listen's, for messages), all on one port (server_listen_tcp()),
 * and serves the files of root (http_root), or the built-in page when
 * root is NULL. 0, or -errno having logged why. */
int web_listen(struct web *w, const struct addrinfo *addr, const char *text, const char *root);
/* The port listened on (after web_listen()), 0 when not listening. */
unsigned web_port(const struct web *w);
/* The number of addresses listened on. */
size_t web_listeners(const struct web *w);

/* Ends the sessions whose token no longer stands (rpc_session_valid()). */
void web_revalidate(struct web *w);

/* The event watch (events_watch_add()): queues ev to each session's
 * stream that subscribed to it. data is the web listener. */
void web_notify(const struct event *ev, void *data);

/* --- the parts of a request the listener reads itself (HTTP is
 * libmicrohttpd's); pure, unit-tested and fuzzed (tests/fuzz/fuzz-web.c) */

/* Whether a POST may be served: Sec-Fetch-Site (may be NULL) says
 * same-origin or none, and Origin (NULL: a client that is not a browser)
 * is http:// or https:// and the Host header, without case. */
bool web_origin_allowed(const char *origin, const char *host, const char *fetch_site);
/* A count in decimal (1 to 18 digits, no sign, no leading zero): a job id,
 * a point index. */
bool web_parse_count(const char *text, size_t len, int64_t *out);
/* "ID/REST" (after "/api/jobs/"): 0 with the job's id and *rest at the
 * "/", or -ENOENT. */
int web_job_route(const char *path, int64_t *id, const char **rest);
/* A file name the listener serves: letters, digits, "._-", not starting
 * with ".", at most 128 bytes. */
bool web_plain_name(const char *name);
/* The token of an "Authorization: Bearer TOKEN" header (the scheme in any
 * case, TOKEN visible ASCII without blanks, shorter than size) copied into
 * token: true, or false for any other header (or none). */
bool web_bearer_token(const char *authorization, char *token, size_t size);
/* The token of a login body {"token": TOKEN} (nothing else), borrowed from
 * *doc, which the caller frees (json_decref); NULL when the body is not
 * that. */
json_t *web_login_token(const char *body, size_t len, json_t **doc);

#endif
