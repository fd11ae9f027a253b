/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The socket server: the listeners (the unix socket, the optional TCP
 * addresses, or what systemd passed) and the connections. It reads lines,
 * hands each to the methods (rpc.h) and queues their answers, with bounded
 * output per client; it knows nothing of the methods. main.c plugs
 * server_notify() into the event sink (events.h), which is how
 * notifications reach the subscribed clients. Event loop thread.
 */
#ifndef ASPHD_SERVER_H
#define ASPHD_SERVER_H

#include <netdb.h>
#include <stdbool.h>

#include <systemd/sd-event.h>

#include "asph/error.h"
#include "events.h"
#include "rpc.h"
#include "settings.h"

struct server_setup {
	sd_event *event;
	struct rpc *rpc;
	const struct settings_limits *limits;   /* read at each use: may change */
};

struct server;

int server_new(const struct server_setup *setup, struct server **out);
/* Closes every connection and the listeners (unlinks a socket it bound). */
void server_free(struct server *srv);

/*
 * Listens: on the sockets systemd passed (sd_listen_fds; TCP ones only
 * when s has a token_file), else binds s's unix socket (its directory
 * must be private; mode and group as s says) and the TCP addresses tcp
 * (may be NULL). Returns 0 or -errno, having logged why.
 */
int server_listen(struct server *srv, const struct settings *s, const struct addrinfo *tcp);

/* Shutdown: new connections are answered -32001 and closed. */
void server_refuse_clients(struct server *srv);

/* The event watch (events_watch_add()): sends ev to every client
 * subscribed to it. data is the server. */
void server_notify(const struct event *ev, void *data);

/*
 * The addresses of tcp_listen's host and port (a host name, or a numeric
 * IPv4 or IPv6 address), for server_listen(); free them with freeaddrinfo().
 * -EINVAL (err says why) when the host does not resolve.
 */
int server_resolve_tcp(const char *host, const char *port, struct addrinfo **out,
		       struct asph_error *err);

#endif
