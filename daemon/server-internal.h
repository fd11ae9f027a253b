/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the server's files share: server.c the connections,
 * server-listen.c the listeners, server-peer.c who is connecting. Calls go
 * one way: server-listen.c → server.c → server-peer.c.
 */
#ifndef ASPHD_SERVER_INTERNAL_H
#define ASPHD_SERVER_INTERNAL_H

#include <stdbool.h>
#include <stdint.h>

#include <systemd/sd-event.h>

#include "access.h"
#include "asph-proto.h"
#include "ratelimit.h"
#include "rpc.h"
#include "settings.h"
#include "turns.h"

/* TCP addresses listened on at once (a host name may have several). */
#define MAX_TCP_LISTENERS 16

struct client {
	struct server *srv;
	struct client *next, *prev;
	struct rpc_session session;
	uint64_t serial;
	int fd;
	bool tcp;
	sd_event_source *io;
	sd_event_source *timer;         /* the nearest of client_deadline() */
	struct turn turn;               /* its requests wait for their turn */
	bool waiting;                   /* its line waits for a computation */
	struct proto_lines in;
	bool have_lines;                /* input not yet cut into lines */
	struct rpc_line *line;          /* being answered */
	char *out;                      /* pending output */
	size_t out_off, out_len, out_cap;
	/* Notifications that came while a batch's answer line was open, sent
	 * after its end so that they do not split it. */
	char *held;
	size_t held_len, held_cap;
	bool closing;                   /* flush what is queued, then close */
	bool eof;
	uint64_t connected_usec;
	uint64_t partial_usec;          /* since when an incomplete line waits, or 0 */
	uint64_t request_usec;          /* the last line taken */
	uint64_t stalled_usec;          /* since when output waits unread, or 0 */
};

struct listener {
	struct server *srv;
	int fd;
	sd_event_source *src;
	bool tcp;
	bool activated;                 /* from systemd: not ours to unlink */
};

struct server {
	sd_event *event;
	struct rpc *rpc;
	const struct settings_limits *limits;
	struct listener listeners[1 + MAX_TCP_LISTENERS];
	size_t n_listeners;
	char *socket_path;              /* bound by us: unlinked at the end */
	char *tcp_listen;               /* as it was bound */
	struct client *clients;
	struct client *dead;            /* dropped, freed by the reaper */
	sd_event_source *reaper;
	struct turns *turns;
	uint64_t next_serial;
	bool refusing;
	/* EMFILE: a descriptor kept to be given up, the pause, its log. */
	int reserve_fd;
	sd_event_source *accept_timer;
	uint64_t accept_backoff;
	struct ratelimit *log_limit;
};

/* A connection on a listener (data): its peer, a client or a refusal. */
int server_accept(sd_event_source *s, int fd, uint32_t revents, void *data);
/* An error of the transport to c, which closes the connection or drops a
 * line (an answer line still open is cut off first). */
void server_send_error(struct client *c, int code, const char *detail);
/* Ends c (why: for the log); it is freed once the callback that dropped
 * it has returned. */
void server_client_drop(struct client *c, const char *why);

/* The peer of an accepted connection fd: a TCP one's address
 * (server_tcp_peer()), a unix socket's uid, gid, pid, groups and name. */
void server_peer_identity(int fd, bool tcp, struct peer *p);

#endif
