/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The socket server: the listeners (the unix socket, the optional TCP
 * addresses, or what systemd passed) and the connections. It reads lines,
 * hands each to the methods (rpc.h) and sends their answers as they come;
 * it knows nothing of the methods. main.c plugs server_notify() into the
 * event sink (events.h), which is how notifications reach the subscribed
 * clients. Event loop thread.
 *
 * What bounds a connection (the limits of settings.h, docs/daemon.md):
 * - connections: max_clients in all (the web page's sessions included),
 *   the last reserved_clients of them for root and operators,
 *   max_clients_per_user per uid (TCP: per address), and
 *   SERVER_ROOT_CLIENTS more for root; past max_clients a TCP client that
 *   has not sent its token makes room for a new one;
 * - time: an incomplete line or unread output may wait request_timeout_ms,
 *   a TCP client without the token auth_timeout_ms, a client that sends
 *   nothing and is not subscribed idle_timeout_ms;
 * - work: one request of a line at a time, a few milliseconds of them per
 *   turn of the loop, so that every connection is served in turn; a new
 *   request is taken only while the client's unread output is under half
 *   of max_output_bytes, so what one connection's unanswered requests cost
 *   is bounded by its socket buffer, one line and one answer.
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
#include "turns.h"

struct server_setup {
	sd_event *event;
	struct rpc *rpc;
	struct turns *turns;                    /* shared with the web listener */
	const struct settings_limits *limits;   /* read at each use: may change */
};

struct server;

int server_new(const struct server_setup *setup, struct server **out);
/* Closes every connection and the listeners (unlinks a socket it bound). */
void server_free(struct server *srv);

/*
 * Listens: on the sockets systemd passed (sd_listen_fds; TCP ones only
 * when s has a token_file), else binds s's unix socket (its directory
 * must be private; a file at its path that is not a socket is refused;
 * mode and group as s says) and the TCP addresses tcp (may be NULL).
 * Returns 0 or -errno, having logged why.
 */
int server_listen(struct server *srv, const struct settings *s, const struct addrinfo *tcp);

/*
 * A reload: whether s (the new settings) can be applied to the listeners
 * without a restart; if not, names in why (size bytes) what needs one and
 * returns -EBUSY. Call before server_reload(), which then cannot fail.
 */
int server_check_reload(const struct server *srv, const struct settings *s, char *why,
			size_t size);
/* Applies s: the socket's mode and group (of a socket asphd bound), and
 * with tcp_listen removed closes the TCP listeners and connections. */
void server_reload(struct server *srv, const struct settings *s);
/* Ends the connections whose session no longer stands (rpc_session_valid():
 * a TCP client that proved a token that was changed or removed). */
void server_revalidate(struct server *srv);

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

/* A TCP peer (of the connection fd): "tcp ADDRESS", its uid unknown, its
 * key its address (an IPv6 address by its /64). The web listener's too. */
void server_tcp_peer(int fd, struct peer *p);
/* The same from the peer's address (AF_INET or AF_INET6; another: "tcp ?"). */
void server_addr_peer(const struct sockaddr *addr, struct peer *p);

/*
 * Listening sockets (non-blocking, close-on-exec) on every address of
 * list, the addresses of the setting field ("tcp_listen", "http_listen")
 * whose text is text, into fds (at most max), their number into *n. An
 * address this host does not have (an IPv6 one without IPv6) is left out,
 * with a warning, while another is there; a port of 0 is chosen at the
 * first address and kept for the others, so that the name has one port.
 * 0, or -errno having logged why (nothing left open).
 */
int server_listen_tcp(const struct addrinfo *list, const char *field, const char *text,
		      int *fds, size_t max, size_t *n);

/* The descriptors asphd needs besides its clients' (listeners, the job
 * store, workers, devices, the log, the scans the web page's live map
 * reads): what LimitNOFILE= must leave above the clients'. */
#define SERVER_FIXED_FDS 64
/* Connections root has on the unix socket beyond limits.max_clients: root
 * always gets in, whatever the other users and listeners hold. */
#define SERVER_ROOT_CLIENTS 4

#endif
