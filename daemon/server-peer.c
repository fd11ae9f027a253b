/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Who is at the other end of a connection: a unix socket's credentials
 * and groups as the kernel has them, a TCP peer's address (server.h's
 * server_tcp_peer(), server_addr_peer()). Calls nothing of the server's.
 * Event loop thread.
 */
#include <arpa/inet.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

#include "account.h"
#include "server.h"
#include "server-internal.h"

/* The peer's supplementary groups as the kernel has them for the
 * connecting process, not as /etc/group says: room for 32 first, then
 * the size the kernel says it needs (ERANGE). None when it cannot tell. */
static void peer_groups(int fd, struct peer *p)
{
	socklen_t len = 32 * sizeof(gid_t);

	for (int tries = 0; tries < 2; tries++) {
		gid_t *g = realloc(p->groups, len > 0 ? len : 1);
		if (!g)
			return;
		p->groups = g;
		if (getsockopt(fd, SOL_SOCKET, SO_PEERGROUPS, g, &len) == 0) {
			p->n_groups = (int)(len / sizeof(gid_t));
			return;
		}
		if (errno != ERANGE)
			return;
	}
}

/* A TCP peer: its address, and its key (an IPv6 address by its /64). */
void server_tcp_peer(int fd, struct peer *p)
{
	struct sockaddr_storage sa = { 0 };
	socklen_t len = sizeof(sa);

	if (getpeername(fd, (struct sockaddr *)&sa, &len) < 0)
		sa.ss_family = AF_UNSPEC;
	server_addr_peer((const struct sockaddr *)&sa, p);
}

void server_addr_peer(const struct sockaddr *addr, struct peer *p)
{
	struct sockaddr_storage sa = { 0 };
	char host[INET6_ADDRSTRLEN] = "?";

	p->uid = (uid_t)-1;
	p->gid = (gid_t)-1;
	if (addr->sa_family == AF_INET6 || addr->sa_family == AF_INET) {
		memcpy(&sa, addr, addr->sa_family == AF_INET6 ? sizeof(struct sockaddr_in6)
							      : sizeof(struct sockaddr_in));
		if (sa.ss_family == AF_INET6) {
			struct in6_addr a = ((struct sockaddr_in6 *)&sa)->sin6_addr;
			if (IN6_IS_ADDR_V4MAPPED(&a)) {
				inet_ntop(AF_INET, &a.s6_addr[12], host, sizeof(host));
				snprintf(p->key, sizeof(p->key), "tcp %s", host);
			} else {
				inet_ntop(AF_INET6, &a, host, sizeof(host));
				memset(&a.s6_addr[8], 0, 8);
				char prefix[INET6_ADDRSTRLEN];
				inet_ntop(AF_INET6, &a, prefix, sizeof(prefix));
				snprintf(p->key, sizeof(p->key), "tcp %s/64", prefix);
			}
		} else if (sa.ss_family == AF_INET) {
			inet_ntop(AF_INET, &((struct sockaddr_in *)&sa)->sin_addr, host, sizeof(host));
			snprintf(p->key, sizeof(p->key), "tcp %s", host);
		}
	}
	if (!p->key[0])
		snprintf(p->key, sizeof(p->key), "tcp ?");
	snprintf(p->name, sizeof(p->name), "tcp %s", host);
}

void server_peer_identity(int fd, bool tcp, struct peer *p)
{
	struct ucred cred;
	socklen_t len = sizeof(cred);

	p->tcp = tcp;
	if (tcp) {
		server_tcp_peer(fd, p);
		return;
	}
	if (getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) < 0) {
		p->uid = (uid_t)-1;
		p->gid = (gid_t)-1;
		snprintf(p->name, sizeof(p->name), "unknown");
		snprintf(p->key, sizeof(p->key), "uid ?");
		return;
	}
	p->uid = cred.uid;
	p->gid = cred.gid;
	p->pid = cred.pid;
	peer_groups(fd, p);
	if (account_user_name(cred.uid, p->name, sizeof(p->name)) < 0)
		snprintf(p->name, sizeof(p->name), "uid %u", (unsigned)cred.uid);
	snprintf(p->key, sizeof(p->key), "uid %u", (unsigned)cred.uid);
}
