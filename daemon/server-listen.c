/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The listeners: the unix socket asphd binds (its directory, a stale
 * socket file, its mode and group), the TCP addresses of tcp_listen and
 * the web listener's (server_listen_tcp()), the sockets systemd passed,
 * and what a reload changes of them. A connection on a listener goes to
 * server.c (server_accept()). Event loop thread.
 */
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <systemd/sd-daemon.h>

#include "account.h"
#include "dirs.h"
#include "log.h"
#include "server.h"
#include "server-internal.h"
#include "util-mem.h"

/* -------------------------------------------------------------- listen */

static struct listener *add_listener(struct server *srv, int fd, bool tcp, bool activated)
{
	struct listener *l;

	if (srv->n_listeners == ARRAY_SIZE(srv->listeners))
		return NULL;
	l = &srv->listeners[srv->n_listeners++];
	*l = (struct listener){ .srv = srv, .fd = fd, .tcp = tcp, .activated = activated };
	return l;
}

/* Gives the socket at path its group and mode as the settings say. */
static void socket_access(const struct settings *s, const char *path)
{
	if (s->socket_group) {
		gid_t gid;
		int r = account_group_id(s->socket_group, &gid);
		if (r == 0 && chown(path, (uid_t)-1, gid) < 0)
			r = -errno;
		if (r < 0)
			log_warning("cannot give %s to group %s: %s", path, s->socket_group,
				    r == -ENOENT ? "no such group" : strerror(-r));
	}
	if (chmod(path, s->socket_mode) < 0)
		log_warning("chmod %s: %s", path, strerror(errno));
}

/*
 * A socket file left by a daemon that died is replaced; a live one is not,
 * and nothing that is not a socket is ever removed (--socket names a path
 * that may be anything).
 */
static int clear_socket_path(const struct sockaddr_un *sa)
{
	const char *path = sa->sun_path;
	_cleanup_close_ int probe = -1;
	struct stat st;

	if (lstat(path, &st) < 0)
		return errno == ENOENT ? 0 : -errno;
	if (!S_ISSOCK(st.st_mode)) {
		log_error("%s exists and is not a socket: refusing to remove it", path);
		return -EEXIST;
	}
	probe = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
	if (probe >= 0 && connect(probe, (const struct sockaddr *)sa, sizeof(*sa)) == 0) {
		log_error("another daemon listens on %s", path);
		return -EADDRINUSE;
	}
	if (unlink(path) < 0 && errno != ENOENT)
		return -errno;
	return 0;
}

static int bind_unix(struct server *srv, const struct settings *s)
{
	struct sockaddr_un sa = { .sun_family = AF_UNIX };
	const char *path = s->socket_path;
	_cleanup_close_ int fd = -1;
	int r;

	if (strlen(path) >= sizeof(sa.sun_path)) {
		log_error("socket path %s is too long", path);
		return -ENAMETOOLONG;
	}
	r = dirs_check_socket_dir(path);
	if (r < 0)
		return r;
	memcpy(sa.sun_path, path, strlen(path));
	fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
	if (fd < 0)
		return -errno;
	r = clear_socket_path(&sa);
	if (r < 0)
		return r;
	mode_t old = umask(0777 & ~s->socket_mode);
	r = bind(fd, (struct sockaddr *)&sa, sizeof(sa));
	umask(old);
	if (r < 0) {
		r = -errno;
		log_error("cannot bind %s: %s", path, strerror(-r));
		return r;
	}
	srv->socket_path = strdup(path);
	if (!srv->socket_path)
		return -ENOMEM;
	socket_access(s, path);
	if (listen(fd, 128) < 0)
		return -errno;
	add_listener(srv, steal_fd(fd), false, false);
	return 0;
}

/* Whether ai's address came earlier in the list (a name may resolve to
 * the same address twice). */
static bool seen_before(const struct addrinfo *list, const struct addrinfo *ai)
{
	for (const struct addrinfo *p = list; p != ai; p = p->ai_next)
		if (p->ai_addrlen == ai->ai_addrlen && !memcmp(p->ai_addr, ai->ai_addr, ai->ai_addrlen))
			return true;
	return false;
}

/* Whether a bind's error means this host has no such address (a name
 * that resolves to an IPv6 address on a host without IPv6). */
static bool address_unavailable(int r)
{
	return r == -EADDRNOTAVAIL || r == -EAFNOSUPPORT;
}

static in_port_t *port_of(struct sockaddr_storage *sa)
{
	return sa->ss_family == AF_INET6 ? &((struct sockaddr_in6 *)sa)->sin6_port
					 : &((struct sockaddr_in *)sa)->sin_port;
}

/* A listening socket on sa (an IPv6 one for IPv6 only). */
static int bind_address(const struct sockaddr_storage *sa, socklen_t len, int *out)
{
	_cleanup_close_ int fd = -1;
	int one = 1;

	fd = socket(sa->ss_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
	if (fd < 0 || setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) < 0 ||
	    (sa->ss_family == AF_INET6 &&
	     setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &one, sizeof(one)) < 0) ||
	    bind(fd, (const struct sockaddr *)sa, len) < 0 || listen(fd, 128) < 0)
		return -errno;
	*out = steal_fd(fd);
	return 0;
}

/* One pass of server_listen_tcp(): the sockets into fds, their number
 * into *n (closed again on an error). */
static int bind_each(const struct addrinfo *list, const char *field, const char *text,
		     int *fds, size_t max, size_t *n)
{
	struct sockaddr_storage sa;
	char where[INET6_ADDRSTRLEN + 8];
	in_port_t port = 0;
	int r = 0;

	*n = 0;
	for (const struct addrinfo *ai = list; ai; ai = ai->ai_next) {
		if (seen_before(list, ai) || ai->ai_addrlen > sizeof(sa) ||
		    (ai->ai_family != AF_INET && ai->ai_family != AF_INET6))
			continue;
		memcpy(&sa, ai->ai_addr, ai->ai_addrlen);
		if (getnameinfo(ai->ai_addr, ai->ai_addrlen, where, sizeof(where), NULL, 0,
				NI_NUMERICHOST) != 0)
			snprintf(where, sizeof(where), "?");
		/* port 0: the one chosen at the first address, for all */
		if (*port_of(&sa) == 0)
			*port_of(&sa) = port;
		if (*n == max) {
			log_error("%s %s: more than %zu addresses", field, text, max);
			r = -E2BIG;
			break;
		}
		r = bind_address(&sa, ai->ai_addrlen, &fds[*n]);
		if (r < 0) {
			log_job(address_unavailable(r) ? LOG_WARNING : LOG_ERR, 0,
				"%s %s: cannot listen on %s: %s", field, text, where, strerror(-r));
			if (!address_unavailable(r))
				break;
			r = 0;
			continue;
		}
		if (!port) {
			socklen_t len = sizeof(sa);
			getsockname(fds[*n], (struct sockaddr *)&sa, &len);
			port = *port_of(&sa);
		}
		log_debug("%s %s: listening on %s port %u", field, text, where, ntohs(port));
		(*n)++;
	}
	if (r < 0)
		while (*n)
			close(fds[--*n]);
	return r;
}

static bool port_zero(const struct addrinfo *ai)
{
	struct sockaddr_storage sa = { 0 };

	memcpy(&sa, ai->ai_addr, ai->ai_addrlen <= sizeof(sa) ? ai->ai_addrlen : 0);
	return *port_of(&sa) == 0;
}

int server_listen_tcp(const struct addrinfo *list, const char *field, const char *text,
		      int *fds, size_t max, size_t *n)
{
	int r;

	/* A port 0 chose at the first address may be taken at another: a
	 * few more tries pick another. */
	for (int tries = 0;; tries++) {
		r = bind_each(list, field, text, fds, max, n);
		if (r != -EADDRINUSE || tries == 8 || !port_zero(list))
			break;
	}
	if (r < 0)
		return r;
	if (*n)
		return 0;
	log_error("%s %s: no address of it is on this host", field, text);
	return -EADDRNOTAVAIL;
}

/* Every address of tcp_listen. */
static int bind_tcp_all(struct server *srv, const struct settings *s, const struct addrinfo *tcp)
{
	int fds[MAX_TCP_LISTENERS];
	size_t n;
	int r = server_listen_tcp(tcp, "tcp_listen", s->tcp_listen, fds,
				  MAX_TCP_LISTENERS, &n);

	for (size_t i = 0; r == 0 && i < n; i++)
		add_listener(srv, fds[i], true, false);
	return r;
}

static bool has_unix(const struct server *srv)
{
	for (size_t i = 0; i < srv->n_listeners; i++)
		if (!srv->listeners[i].tcp)
			return true;
	return false;
}

static bool has_tcp(const struct server *srv, bool activated)
{
	for (size_t i = 0; i < srv->n_listeners; i++)
		if (srv->listeners[i].tcp && srv->listeners[i].activated == activated)
			return true;
	return false;
}

/* What a socket systemd passed is for: 0 the unix socket, 1 TCP (whose
 * clients must show a token), -1 nothing. */
static int passed_kind(const struct server *srv, const struct settings *s, int fd)
{
	if (sd_is_socket_unix(fd, SOCK_STREAM, 1, NULL, 0) > 0 && !has_unix(srv))
		return 0;
	if (sd_is_socket_inet(fd, AF_UNSPEC, SOCK_STREAM, 1, 0) > 0)
		return 1;
	return -1;
}

static void take_activated(struct server *srv, const struct settings *s)
{
	int n = sd_listen_fds(1);

	for (int i = 0; i < (n > 0 ? n : 0); i++) {
		int fd = SD_LISTEN_FDS_START + i;
		int kind = passed_kind(srv, s, fd);

		if (kind < 0 || !add_listener(srv, fd, kind == 1, true)) {
			log_warning("ignoring passed file descriptor %d", fd);
			close(fd);
			continue;
		}
		fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
	}
}

int server_listen(struct server *srv, const struct settings *s, const struct addrinfo *tcp)
{
	int r;

	take_activated(srv, s);
	/* The unix socket last: once it answers, everything listens, and a
	 * bad TCP setting leaves no socket behind. */
	if (s->tcp_listen && !has_tcp(srv, true)) {
		r = bind_tcp_all(srv, s, tcp);
		if (r < 0)
			return r;
	}
	if (!has_unix(srv)) {
		r = bind_unix(srv, s);
		if (r < 0)
			return r;
	}
	for (size_t i = 0; i < srv->n_listeners; i++) {
		struct listener *l = &srv->listeners[i];
		r = sd_event_add_io(srv->event, &l->src, l->fd, EPOLLIN, server_accept, l);
		if (r < 0)
			return r;
	}
	srv->tcp_listen = s->tcp_listen ? strdup(s->tcp_listen) : NULL;
	return s->tcp_listen && !srv->tcp_listen ? -ENOMEM : 0;
}

/* ------------------------------------------------------------- reload */

int server_check_reload(const struct server *srv, const struct settings *s, char *why,
			size_t size)
{
	/* Listening on a new address needs a restart; ceasing to does not. */
	if (!s->tcp_listen || has_tcp(srv, true))
		return 0;
	if (srv->tcp_listen && !strcmp(srv->tcp_listen, s->tcp_listen))
		return 0;
	snprintf(why, size, "tcp_listen (from %s to %s)", srv->tcp_listen ? srv->tcp_listen : "off",
		 s->tcp_listen);
	return -EBUSY;
}

static void close_tcp(struct server *srv)
{
	struct client *c, *next;
	size_t k = 0;

	for (size_t i = 0; i < srv->n_listeners; i++) {
		struct listener *l = &srv->listeners[i];
		if (!l->tcp) {
			srv->listeners[k++] = *l;
			continue;
		}
		sd_event_source_disable_unref(l->src);
		close(l->fd);
	}
	srv->n_listeners = k;
	/* The sources point at their listener: the array moved. */
	for (size_t i = 0; i < srv->n_listeners; i++)
		if (srv->listeners[i].src)
			sd_event_source_set_userdata(srv->listeners[i].src, &srv->listeners[i]);
	for (c = srv->clients; c; c = next) {
		next = c->next;
		if (!c->tcp)
			continue;
		server_send_error(c, PROTO_SHUTTING_DOWN, "the TCP listener was turned off");
		server_client_drop(c, "TCP turned off");
	}
	free(srv->tcp_listen);
	srv->tcp_listen = NULL;
	log_info("TCP listener closed (tcp_listen removed)");
}

void server_reload(struct server *srv, const struct settings *s)
{
	if (srv->socket_path)
		socket_access(s, srv->socket_path);
	else if (s->socket_group || s->socket_mode != 0660)
		log_notice("socket_mode and socket_group apply to a socket asphd binds itself; "
			   "systemd's (asphd.socket: SocketMode=, SocketGroup=) keeps its own");
	if (!s->tcp_listen && has_tcp(srv, false))
		close_tcp(srv);
}

int server_resolve_tcp(const char *host, const char *port, struct addrinfo **out,
		       struct asph_error *err)
{
	struct addrinfo hints = { .ai_socktype = SOCK_STREAM, .ai_protocol = IPPROTO_TCP };
	int r = getaddrinfo(host, port, &hints, out);

	if (r != 0)
		return asph_error_set(err, -EINVAL, "%s: %s", host,
				      r == EAI_SYSTEM ? strerror(errno) : gai_strerror(r));
	return 0;
}
