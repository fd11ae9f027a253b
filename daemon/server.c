/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread. Non-blocking sockets, one JSON text per line in,
 * bounded output per client: a client whose output passes the limit is
 * dropped rather than waited for.
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
#include "asph-proto.h"
#include "dirs.h"
#include "log.h"
#include "server.h"
#include "util-mem.h"

#define READ_CHUNK 65536
/* Bytes read from one client per wake-up, so that one fast writer cannot
 * starve the others. */
#define READ_BUDGET (256 * 1024)
/* TCP addresses listened on at once (a host name may have several). */
#define MAX_TCP_LISTENERS 16

struct client {
	struct server *srv;
	struct client *next, *prev;
	struct rpc_session session;
	uint64_t serial;
	int fd;
	sd_event_source *io;
	sd_event_source *timeout;       /* an incomplete request waits */
	struct proto_lines in;
	char *out;                      /* pending output */
	size_t out_off, out_len, out_cap;
	bool closing;                   /* flush what is queued, then close */
	bool eof;
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
	struct client *clients;
	struct client *dead;            /* dropped, freed by the reaper */
	sd_event_source *reaper;
	uint64_t next_serial;
	bool refusing;
};

static int reap(sd_event_source *s, void *data);

int server_new(const struct server_setup *setup, struct server **out)
{
	struct server *srv = calloc(1, sizeof(*srv));
	int r;

	if (!srv)
		return -ENOMEM;
	srv->event = setup->event;
	srv->rpc = setup->rpc;
	srv->limits = setup->limits;
	r = sd_event_add_defer(srv->event, &srv->reaper, reap, srv);
	if (r < 0) {
		free(srv);
		return r;
	}
	sd_event_source_set_enabled(srv->reaper, SD_EVENT_OFF);
	*out = srv;
	return 0;
}

/* ------------------------------------------------------------ clients */

static void client_unlink(struct client *c)
{
	struct server *srv = c->srv;

	if (c->prev)
		c->prev->next = c->next;
	else if (srv->clients == c)
		srv->clients = c->next;
	if (c->next)
		c->next->prev = c->prev;
	c->next = c->prev = NULL;
}

static void client_free(struct client *c)
{
	if (!c)
		return;
	rpc_session_close(c->srv->rpc, &c->session);
	sd_event_source_disable_unref(c->io);
	sd_event_source_disable_unref(c->timeout);
	if (c->fd >= 0)
		close(c->fd);
	proto_lines_release(&c->in);
	free(c->out);
	free(c->session.peer.groups);
	free(c);
}

static void free_list(struct client *c)
{
	while (c) {
		struct client *next = c->next;
		client_free(c);
		c = next;
	}
}

/* Frees dropped clients once the callback that dropped them has returned. */
static int reap(sd_event_source *s, void *data)
{
	struct server *srv = data;

	free_list(srv->dead);
	srv->dead = NULL;
	return 0;
}

static void client_drop(struct client *c, const char *why)
{
	struct server *srv = c->srv;

	if (c->fd < 0)
		return;
	log_debug("client %" PRIu64 " (%s) dropped: %s", c->serial, c->session.peer.name, why);
	sd_event_source_set_enabled(c->io, SD_EVENT_OFF);
	sd_event_source_set_enabled(c->timeout, SD_EVENT_OFF);
	close(c->fd);
	c->fd = -1;
	client_unlink(c);
	rpc_session_close(srv->rpc, &c->session);
	c->next = srv->dead;
	srv->dead = c;
	sd_event_source_set_enabled(srv->reaper, SD_EVENT_ONESHOT);
}

static bool client_dead(const struct client *c)
{
	return c->fd < 0;
}

static void update_events(struct client *c)
{
	uint32_t ev = 0;

	if (client_dead(c))
		return;
	if (!c->closing && !c->eof)
		ev |= EPOLLIN;
	if (c->out_len > c->out_off)
		ev |= EPOLLOUT;
	if (!ev) {
		/* Nothing more to read or write. */
		client_drop(c, c->closing ? "closed" : "end of input");
		return;
	}
	sd_event_source_set_io_events(c->io, ev);
}

static int flush_output(struct client *c)
{
	while (c->out_len > c->out_off) {
		ssize_t n = send(c->fd, c->out + c->out_off, c->out_len - c->out_off,
				 MSG_NOSIGNAL | MSG_DONTWAIT);
		if (n < 0) {
			if (errno == EINTR)
				continue;
			if (errno == EAGAIN)
				break;
			client_drop(c, strerror(errno));
			return -ECONNRESET;
		}
		c->out_off += (size_t)n;
	}
	if (c->out_off == c->out_len)
		c->out_off = c->out_len = 0;
	update_events(c);
	return 0;
}

static int out_reserve(struct client *c, size_t n)
{
	if (c->out_off > 0 && c->out_len + n > c->out_cap) {
		memmove(c->out, c->out + c->out_off, c->out_len - c->out_off);
		c->out_len -= c->out_off;
		c->out_off = 0;
	}
	if (c->out_len + n > c->out_cap) {
		size_t cap = c->out_cap ? c->out_cap : 4096;
		while (cap < c->out_len + n)
			cap *= 2;
		char *b = realloc(c->out, cap);
		if (!b)
			return -ENOMEM;
		c->out = b;
		c->out_cap = cap;
	}
	return 0;
}

/* jansson writes the text straight into the output buffer. */
static int out_append(const char *buf, size_t n, void *data)
{
	struct client *c = data;

	if (c->out_len - c->out_off + n > c->srv->limits->max_output_bytes)
		return -1;
	if (out_reserve(c, n) < 0)
		return -1;
	memcpy(c->out + c->out_len, buf, n);
	c->out_len += n;
	return 0;
}

/* Queues a message to c; drops c when its output would pass the limit.
 * Returns 0 or -ECONNRESET (dropped). */
static int client_send(struct client *c, const json_t *msg)
{
	size_t start;

	if (client_dead(c))
		return -ECONNRESET;
	start = c->out_len;
	if (json_dump_callback(msg, out_append, c, JSON_COMPACT) < 0 ||
	    out_append("\n", 1, c) < 0) {
		/* Either the limit or memory: the client goes. */
		if (c->out_len - c->out_off > c->srv->limits->max_output_bytes / 2)
			log_info("client %" PRIu64 " (%s) does not read its output: dropped",
				 c->serial, c->session.peer.name);
		c->out_len = start < c->out_off ? c->out_off : start;
		client_drop(c, "output buffer full");
		return -ECONNRESET;
	}
	return flush_output(c);
}

static void send_error(struct client *c, int code, const char *detail)
{
	_cleanup_(json_decrefp) json_t *e = proto_make_error(NULL, code, NULL,
		detail ? json_pack("{s:s}", "detail", detail) : NULL);

	if (e)
		client_send(c, e);
}

static void handle_line(struct client *c, const char *line, size_t len)
{
	_cleanup_(json_decrefp) json_t *reply = rpc_handle_line(c->srv->rpc, &c->session,
								line, len);

	if (reply && !client_dead(c))
		client_send(c, reply);
}

static int request_timeout(sd_event_source *s, uint64_t usec, void *data)
{
	struct client *c = data;

	send_error(c, PROTO_REQUEST_TIMEOUT, "an incomplete request waited too long");
	if (!client_dead(c)) {
		c->closing = true;
		update_events(c);
	}
	return 0;
}

static void arm_timeout(struct client *c)
{
	bool pending = proto_lines_pending(&c->in) > 0;
	uint64_t now;

	if (!pending) {
		sd_event_source_set_enabled(c->timeout, SD_EVENT_OFF);
		return;
	}
	if (sd_event_source_get_enabled(c->timeout, NULL) > 0)
		return;
	sd_event_now(c->srv->event, CLOCK_MONOTONIC, &now);
	sd_event_source_set_time(c->timeout,
		now + (uint64_t)c->srv->limits->request_timeout_ms * 1000);
	sd_event_source_set_enabled(c->timeout, SD_EVENT_ONESHOT);
}

/* The complete lines read so far, each handled. */
static void handle_lines(struct client *c)
{
	char *line;
	size_t len;
	int r;

	while (!client_dead(c) && (r = proto_lines_next(&c->in, &line, &len)) != 0) {
		if (r == -EMSGSIZE) {
			char why[96];
			snprintf(why, sizeof(why), "a request is longer than %u bytes",
				 c->srv->limits->max_request_bytes);
			send_error(c, PROTO_REQUEST_TOO_LARGE, why);
			continue;
		}
		handle_line(c, line, len);
	}
}

static void read_input(struct client *c)
{
	size_t budget = READ_BUDGET;

	while (budget > 0 && !client_dead(c) && !c->closing) {
		char *dst;
		ssize_t n;

		if (proto_lines_reserve(&c->in, READ_CHUNK, &dst) < 0) {
			client_drop(c, "out of memory");
			return;
		}
		n = recv(c->fd, dst, READ_CHUNK, MSG_DONTWAIT);
		if (n < 0) {
			if (errno == EINTR)
				continue;
			if (errno != EAGAIN)
				client_drop(c, strerror(errno));
			break;
		}
		if (n == 0) {
			c->eof = true;
			break;
		}
		budget -= (size_t)n < budget ? (size_t)n : budget;
		proto_lines_commit(&c->in, (size_t)n);
		/* A short read drained the socket: no second recv() just to
		 * hear EAGAIN (the loop calls again when more arrives). */
		if ((size_t)n < READ_CHUNK)
			budget = 0;
		handle_lines(c);
	}
	if (client_dead(c))
		return;
	if (c->eof && proto_lines_pending(&c->in) > 0) {
		send_error(c, PROTO_PARSE_ERROR, "the input ended inside a request");
		proto_lines_release(&c->in);
		proto_lines_init(&c->in, c->srv->limits->max_request_bytes);
	}
	if (client_dead(c))
		return;
	arm_timeout(c);
	update_events(c);
}

static int client_io(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	struct client *c = data;

	if (revents & EPOLLOUT)
		flush_output(c);
	if (!client_dead(c) && (revents & (EPOLLIN | EPOLLHUP | EPOLLERR)))
		read_input(c);
	return 0;
}

/* ------------------------------------------------------------ accept */

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

static void peer_identity(int fd, bool tcp, struct peer *p)
{
	struct ucred cred;
	socklen_t len = sizeof(cred);

	p->tcp = tcp;
	if (tcp) {
		p->uid = (uid_t)-1;
		p->gid = (gid_t)-1;
		snprintf(p->name, sizeof(p->name), "tcp peer");
		return;
	}
	if (getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) < 0) {
		p->uid = (uid_t)-1;
		p->gid = (gid_t)-1;
		snprintf(p->name, sizeof(p->name), "unknown");
		return;
	}
	p->uid = cred.uid;
	p->gid = cred.gid;
	p->pid = cred.pid;
	peer_groups(fd, p);
	if (account_user_name(cred.uid, p->name, sizeof(p->name)) < 0)
		snprintf(p->name, sizeof(p->name), "uid %u", (unsigned)cred.uid);
}

/* A connection that cannot be taken gets the reason and is closed. */
static void refuse(struct server *srv, int fd)
{
	_cleanup_(json_decrefp) json_t *e = proto_make_error(NULL,
		srv->refusing ? PROTO_SHUTTING_DOWN : PROTO_TOO_MANY_CLIENTS, NULL, NULL);
	_cleanup_free_ char *t = proto_dump(e, NULL);

	if (t && send(fd, t, strlen(t), MSG_NOSIGNAL | MSG_DONTWAIT) < 0)
		log_debug("refused client: %s", strerror(errno));
	close(fd);
}

static int on_accept(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	const struct listener *l = data;
	struct server *srv = l->srv;
	struct client *c;
	int cfd;

	cfd = accept4(fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
	if (cfd < 0) {
		if (errno != EAGAIN && errno != EINTR)
			log_warning("accept: %s", strerror(errno));
		return 0;
	}
	if (srv->refusing || rpc_sessions(srv->rpc) >= srv->limits->max_clients) {
		refuse(srv, cfd);
		return 0;
	}
	c = calloc(1, sizeof(*c));
	if (!c) {
		close(cfd);
		return 0;
	}
	c->srv = srv;
	c->fd = cfd;
	c->serial = ++srv->next_serial;
	proto_lines_init(&c->in, srv->limits->max_request_bytes);
	peer_identity(cfd, l->tcp, &c->session.peer);
	c->session.authenticated = !l->tcp;
	rpc_session_open(srv->rpc, &c->session);
	c->next = srv->clients;
	if (srv->clients)
		srv->clients->prev = c;
	srv->clients = c;
	if (sd_event_add_io(srv->event, &c->io, cfd, EPOLLIN, client_io, c) < 0 ||
	    sd_event_add_time(srv->event, &c->timeout, CLOCK_MONOTONIC, UINT64_MAX, 0,
			      request_timeout, c) < 0) {
		client_drop(c, "out of memory");
		return 0;
	}
	sd_event_source_set_enabled(c->timeout, SD_EVENT_OFF);
	log_debug("client %" PRIu64 " connected: %s (uid %d, pid %d)", c->serial,
		  c->session.peer.name, (int)c->session.peer.uid, (int)c->session.peer.pid);
	return 0;
}

void server_refuse_clients(struct server *srv)
{
	srv->refusing = true;
}

void server_notify(const struct event *ev, void *data)
{
	struct server *srv = data;
	_cleanup_(json_decrefp) json_t *msg = NULL;
	struct client *c, *next;

	for (c = srv->clients; c; c = next) {
		next = c->next;
		if (client_dead(c) || !events_subscription_matches(&c->session.events, ev))
			continue;
		/* Built for the first client that wants it. */
		if (!msg)
			msg = proto_make_notification(ev->method, json_incref(ev->params));
		if (!msg)
			return;
		client_send(c, msg);
	}
}

/* -------------------------------------------------------------- listen */

/* The directory of the socket must not be writable by other users, or
 * anyone could replace the socket. */
static int check_socket_dir(const char *path)
{
	_cleanup_free_ char *dir = strdup(path);
	char *slash;
	struct stat st;

	if (!dir)
		return -ENOMEM;
	slash = strrchr(dir, '/');
	if (!slash)
		return 0;
	*(slash == dir ? slash + 1 : slash) = '\0';
	if (stat(dir, &st) < 0) {
		if (errno != ENOENT)
			return -errno;
		if (mkdir(dir, 0755) < 0 && errno != EEXIST)
			return -errno;
		return 0;
	}
	return dirs_check_private(dir, &st, true, "to put the socket there");
}

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
	r = check_socket_dir(path);
	if (r < 0)
		return r;
	memcpy(sa.sun_path, path, strlen(path));
	fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
	if (fd < 0)
		return -errno;
	/* A socket file left by a daemon that died is replaced; a live one
	 * is not. */
	{
		_cleanup_close_ int probe = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
		if (probe >= 0 && connect(probe, (struct sockaddr *)&sa, sizeof(sa)) == 0) {
			log_error("another daemon listens on %s", path);
			return -EADDRINUSE;
		}
	}
	unlink(path);
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

/* Whether bind_tcp()'s error means this host has no such address (a name
 * that resolves to an IPv6 address on a host without IPv6). */
static bool address_unavailable(int r)
{
	return r == -EADDRNOTAVAIL || r == -EAFNOSUPPORT;
}

static int bind_tcp(struct server *srv, const struct settings *s, const struct addrinfo *ai)
{
	_cleanup_close_ int fd = -1;
	char where[INET6_ADDRSTRLEN + 8];
	int one = 1, r;

	if (getnameinfo(ai->ai_addr, ai->ai_addrlen, where, sizeof(where), NULL, 0,
			NI_NUMERICHOST) != 0)
		snprintf(where, sizeof(where), "?");
	fd = socket(ai->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
	if (fd < 0 || setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) < 0 ||
	    (ai->ai_family == AF_INET6 &&
	     setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &one, sizeof(one)) < 0) ||
	    bind(fd, ai->ai_addr, ai->ai_addrlen) < 0 || listen(fd, 128) < 0) {
		r = -errno;
		log_job(address_unavailable(r) ? LOG_WARNING : LOG_ERR, 0,
			"tcp_listen %s: cannot listen on %s: %s", s->tcp_listen, where,
			strerror(-r));
		return r;
	}
	if (!add_listener(srv, fd, true, false)) {
		log_error("tcp_listen %s: more than %d addresses", s->tcp_listen,
			  MAX_TCP_LISTENERS);
		return -E2BIG;
	}
	log_debug("tcp_listen %s: listening on %s", s->tcp_listen, where);
	steal_fd(fd);
	return 0;
}

/* Every address of tcp_listen; one this host does not have is left out
 * while another is there to listen on. */
static int bind_tcp_all(struct server *srv, const struct settings *s, const struct addrinfo *tcp)
{
	int r = 0, bound = 0;

	for (const struct addrinfo *ai = tcp; ai; ai = ai->ai_next) {
		if (seen_before(tcp, ai))
			continue;
		r = bind_tcp(srv, s, ai);
		if (r < 0 && !address_unavailable(r))
			return r;
		bound += r == 0;
	}
	if (bound)
		return 0;
	log_error("tcp_listen %s: no address of it is on this host", s->tcp_listen);
	return -EADDRNOTAVAIL;
}

static bool has_unix(const struct server *srv)
{
	for (size_t i = 0; i < srv->n_listeners; i++)
		if (!srv->listeners[i].tcp)
			return true;
	return false;
}

static bool has_tcp(const struct server *srv)
{
	for (size_t i = 0; i < srv->n_listeners; i++)
		if (srv->listeners[i].tcp)
			return true;
	return false;
}

/* What a socket systemd passed is for: 0 the unix socket, 1 TCP (only
 * with a token to check), -1 nothing. */
static int passed_kind(const struct server *srv, const struct settings *s, int fd)
{
	if (sd_is_socket_unix(fd, SOCK_STREAM, 1, NULL, 0) > 0 && !has_unix(srv))
		return 0;
	if (sd_is_socket_inet(fd, AF_UNSPEC, SOCK_STREAM, 1, 0) > 0 && s->token_file)
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
	if (s->tcp_listen && !has_tcp(srv)) {
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
		r = sd_event_add_io(srv->event, &l->src, l->fd, EPOLLIN, on_accept, l);
		if (r < 0)
			return r;
	}
	return 0;
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

void server_free(struct server *srv)
{
	if (!srv)
		return;
	free_list(srv->clients);
	free_list(srv->dead);
	sd_event_source_disable_unref(srv->reaper);
	for (size_t i = 0; i < srv->n_listeners; i++) {
		struct listener *l = &srv->listeners[i];
		sd_event_source_disable_unref(l->src);
		close(l->fd);
		if (!l->tcp && !l->activated && srv->socket_path)
			unlink(srv->socket_path);
	}
	free(srv->socket_path);
	free(srv);
}
