/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the server's files share (server.c the connections,
 * server-peer.c who is connecting). Calls go one way:
 * server.c → server-peer.c.
 */
#ifndef ASPHD_SERVER_INTERNAL_H
#define ASPHD_SERVER_INTERNAL_H

#include <stdbool.h>

#include "access.h"

/* The peer of an accepted connection fd: a TCP one's address
 * (server_tcp_peer()), a unix socket's uid, gid, pid, groups and name. */
void server_peer_identity(int fd, bool tcp, struct peer *p);

#endif
