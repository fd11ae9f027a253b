/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Listeners and clients: non-blocking sockets on the event loop, one JSON
 * text per line in, bounded output per client. A client whose output
 * passes the limit is dropped rather than waited for.
 */
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <unistd.h>

#include <systemd/sd-daemon.h>

#include "account.h"
#include "asphd.h"
#include "dirs.h"
#include "log.h"
#include "util-mem.h"

#define READ_CHUNK 65536
/* Bytes read from one client per wake-up, so that one fast writer cannot
 * starve the others. */
#define READ_BUDGET (256 * 1024)

static int client_io(sd_event_source *s, int fd, uint32_t revents, void *data);

static void client_unlink(struct client *c)
{
	struct daemon *d = c->d;

	if (c->prev)
		c->prev->next = c->next;
	else if (d->clients == c)
		d->clients = c->next;
	if (c->next)
		c->next->prev = c->prev;
	c->next = c->prev = NULL;
}

void client_free(struct client *c)
{
	if (!c)
		return;
	sd_event_source_disable_unref(c->io);
	sd_event_source_disable_unref(c->timeout);
	if (c->fd >= 0)
		close(c->fd);
	proto_lines_release(&c->in);
	free(c->out);
	free(c->groups);
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
	struct daemon *d = data;

	free_list(d->dead);
	d->dead = NULL;
	return 0;
}

static void client_drop(struct client *c, const char *why)
{
	struct daemon *d = c->d;

	if (c->fd < 0)
		return;
	log_debug("client %" PRIu64 " (%s) dropped: %s", c->serial, c->name, why);
	sd_event_source_set_enabled(c->io, SD_EVENT_OFF);
	sd_event_source_set_enabled(c->timeout, SD_EVENT_OFF);
	close(c->fd);
	c->fd = -1;
	client_unlink(c);
	d->n_clients--;
	if (c->events)
		d->n_subscribed--;
	c->next = d->dead;
	d->dead = c;
	sd_event_source_set_enabled(d->reaper, SD_EVENT_ONESHOT);
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

	if (c->out_len - c->out_off + n > c->d->config->limits.max_output_bytes)
		return -1;
	if (out_reserve(c, n) < 0)
		return -1;
	memcpy(c->out + c->out_len, buf, n);
	c->out_len += n;
	return 0;
}

int client_send(struct client *c, const json_t *msg)
{
	size_t start;

	if (client_dead(c))
		return -ECONNRESET;
	start = c->out_len;
	if (json_dump_callback(msg, out_append, c, JSON_COMPACT) < 0 ||
	    out_append("\n", 1, c) < 0) {
		/* Either the limit or memory: the client goes. */
		if (c->out_len - c->out_off > c->d->config->limits.max_output_bytes / 2)
			log_info("client %" PRIu64 " (%s) does not read its output: dropped",
				 c->serial, c->name);
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
	char why[160];
	_cleanup_(json_decrefp) json_t *msg = NULL;
	_cleanup_(json_decrefp) json_t *reply = NULL;

	c->d->requests++;
	msg = proto_parse(line, len, why, sizeof(why));
	if (!msg) {
		send_error(c, PROTO_PARSE_ERROR, why);
		return;
	}
	if (!json_is_array(msg)) {
		reply = rpc_handle(c, msg);
	} else if (json_array_size(msg) == 0) {
		send_error(c, PROTO_INVALID_REQUEST, "an empty batch");
		return;
	} else if (json_array_size(msg) > PROTO_MAX_BATCH) {
		snprintf(why, sizeof(why), "a batch of %zu requests, more than %d",
			 json_array_size(msg), PROTO_MAX_BATCH);
		send_error(c, PROTO_INVALID_REQUEST, why);
		return;
	} else {
		size_t i;
		json_t *e;
		reply = json_array();
		json_array_foreach(msg, i, e) {
			json_t *r = rpc_handle(c, e);
			if (r && reply)
				json_array_append_new(reply, r);
			else
				json_decref(r);
		}
		if (reply && json_array_size(reply) == 0) {
			json_decref(reply);
			reply = NULL;
		}
	}
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
	sd_event_now(c->d->event, CLOCK_MONOTONIC, &now);
	sd_event_source_set_time(c->timeout,
		now + (uint64_t)c->d->config->limits.request_timeout_ms * 1000);
	sd_event_source_set_enabled(c->timeout, SD_EVENT_ONESHOT);
}

static void read_input(struct client *c)
{
	size_t budget = READ_BUDGET;

	while (budget > 0 && !client_dead(c) && !c->closing) {
		char *dst, *line;
		size_t len;
		ssize_t n;
		int r;

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
		while (!client_dead(c) && (r = proto_lines_next(&c->in, &line, &len)) != 0) {
			if (r == -EMSGSIZE) {
				char why[96];
				snprintf(why, sizeof(why), "a request is longer than %u bytes",
					 c->d->config->limits.max_request_bytes);
				send_error(c, PROTO_REQUEST_TOO_LARGE, why);
				continue;
			}
			handle_line(c, line, len);
		}
	}
	if (client_dead(c))
		return;
	if (c->eof && proto_lines_pending(&c->in) > 0) {
		send_error(c, PROTO_PARSE_ERROR, "the input ended inside a request");
		proto_lines_release(&c->in);
		proto_lines_init(&c->in, c->d->config->limits.max_request_bytes);
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

/* The peer's supplementary groups as the kernel has them for the
 * connecting process, not as /etc/group says: room for 32 first, then
 * the size the kernel says it needs (ERANGE). None when it cannot tell. */
static void peer_groups(struct client *c)
{
	socklen_t len = 32 * sizeof(gid_t);

	for (int tries = 0; tries < 2; tries++) {
		gid_t *g = realloc(c->groups, len > 0 ? len : 1);
		if (!g)
			return;
		c->groups = g;
		if (getsockopt(c->fd, SOL_SOCKET, SO_PEERGROUPS, g, &len) == 0) {
			c->n_groups = (int)(len / sizeof(gid_t));
			return;
		}
		if (errno != ERANGE)
			return;
	}
}

static void peer_identity(struct client *c)
{
	struct ucred cred;
	socklen_t len = sizeof(cred);

	if (getsockopt(c->fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) < 0) {
		c->uid = (uid_t)-1;
		c->gid = (gid_t)-1;
		snprintf(c->name, sizeof(c->name), "unknown");
		return;
	}
	c->uid = cred.uid;
	c->gid = cred.gid;
	c->pid = cred.pid;
	peer_groups(c);
	if (account_user_name(cred.uid, c->name, sizeof(c->name)) < 0)
		snprintf(c->name, sizeof(c->name), "uid %u", (unsigned)cred.uid);
}

static int on_accept(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	struct daemon *d = data;
	bool tcp = fd == d->tcp_fd;
	struct client *c;
	int cfd;

	cfd = accept4(fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
	if (cfd < 0) {
		if (errno != EAGAIN && errno != EINTR)
			log_warning("accept: %s", strerror(errno));
		return 0;
	}
	if (d->n_clients >= d->config->limits.max_clients || d->shutting_down) {
		_cleanup_(json_decrefp) json_t *e = proto_make_error(NULL,
			d->shutting_down ? PROTO_SHUTTING_DOWN : PROTO_TOO_MANY_CLIENTS, NULL, NULL);
		_cleanup_free_ char *t = proto_dump(e, NULL);
		if (t && send(cfd, t, strlen(t), MSG_NOSIGNAL | MSG_DONTWAIT) < 0)
			log_debug("refused client: %s", strerror(errno));
		close(cfd);
		return 0;
	}
	c = calloc(1, sizeof(*c));
	if (!c) {
		close(cfd);
		return 0;
	}
	c->d = d;
	c->fd = cfd;
	c->tcp = tcp;
	c->serial = ++d->next_serial;
	proto_lines_init(&c->in, d->config->limits.max_request_bytes);
	if (tcp) {
		c->uid = (uid_t)-1;
		c->gid = (gid_t)-1;
		snprintf(c->name, sizeof(c->name), "tcp peer");
	} else {
		peer_identity(c);
		c->authenticated = true;
	}
	c->next = d->clients;
	if (d->clients)
		d->clients->prev = c;
	d->clients = c;
	d->n_clients++;
	if (sd_event_add_io(d->event, &c->io, cfd, EPOLLIN, client_io, c) < 0 ||
	    sd_event_add_time(d->event, &c->timeout, CLOCK_MONOTONIC, UINT64_MAX, 0,
			      request_timeout, c) < 0) {
		client_drop(c, "out of memory");
		return 0;
	}
	sd_event_source_set_enabled(c->timeout, SD_EVENT_OFF);
	log_debug("client %" PRIu64 " connected: %s (uid %d, pid %d)", c->serial,
		  c->name, (int)c->uid, (int)c->pid);
	return 0;
}

void server_broadcast(struct daemon *d, unsigned class, int64_t job,
		      const char *method, json_t *params)
{
	_cleanup_(json_decrefp) json_t *msg = proto_make_notification(method, params);
	struct client *c, *next;

	if (!msg || d->n_subscribed == 0)
		return;
	for (c = d->clients; c; c = next) {
		next = c->next;
		if (client_dead(c) || !(c->events & class))
			continue;
		if (job && c->event_job && c->event_job != job)
			continue;
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

static int bind_unix(struct daemon *d)
{
	struct sockaddr_un sa = { .sun_family = AF_UNIX };
	const char *path = d->socket_path;
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
	mode_t old = umask(0777 & ~d->config->socket_mode);
	r = bind(fd, (struct sockaddr *)&sa, sizeof(sa));
	umask(old);
	if (r < 0) {
		r = -errno;
		log_error("cannot bind %s: %s", path, strerror(-r));
		return r;
	}
	if (d->config->socket_group) {
		gid_t gid;
		r = account_group_id(d->config->socket_group, &gid);
		if (r == 0 && chown(path, (uid_t)-1, gid) < 0)
			r = -errno;
		if (r < 0)
			log_warning("cannot give %s to group %s: %s", path, d->config->socket_group,
				    r == -ENOENT ? "no such group" : strerror(-r));
	}
	if (chmod(path, d->config->socket_mode) < 0)
		log_warning("chmod %s: %s", path, strerror(errno));
	if (listen(fd, 128) < 0)
		return -errno;
	d->unix_fd = steal_fd(fd);
	return 0;
}

static int bind_tcp(struct daemon *d)
{
	_cleanup_free_ char *spec = strdup(d->config->tcp_listen);
	struct addrinfo hints = { .ai_socktype = SOCK_STREAM, .ai_flags = AI_NUMERICHOST };
	struct addrinfo *ai = NULL;
	char *colon;
	int fd, one = 1, r;

	if (!spec)
		return -ENOMEM;
	colon = strrchr(spec, ':');
	if (!colon) {
		log_error("tcp_listen must be HOST:PORT, not %s", spec);
		return -EINVAL;
	}
	*colon = '\0';
	char *host = spec;
	if (host[0] == '[' && colon[-1] == ']') {
		host++;
		colon[-1] = '\0';
	}
	r = getaddrinfo(host, colon + 1, &hints, &ai);
	if (r != 0) {
		log_error("tcp_listen %s: %s", d->config->tcp_listen, gai_strerror(r));
		return -EINVAL;
	}
	fd = socket(ai->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
	if (fd < 0 || setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one)) < 0 ||
	    bind(fd, ai->ai_addr, ai->ai_addrlen) < 0 || listen(fd, 128) < 0) {
		r = -errno;
		log_error("cannot listen on %s: %s", d->config->tcp_listen, strerror(errno));
		if (fd >= 0)
			close(fd);
		freeaddrinfo(ai);
		return r;
	}
	freeaddrinfo(ai);
	d->tcp_fd = fd;
	return 0;
}

static int read_token(struct daemon *d)
{
	_cleanup_fclose_ FILE *f = fopen(d->config->token_file, "re");
	char buf[512];
	struct stat st;

	if (!f) {
		int e = errno;
		log_error("cannot read the token file %s: %s", d->config->token_file,
			  strerror(e));
		return -e;
	}
	if (fstat(fileno(f), &st) < 0 || (st.st_mode & 0077) || st.st_uid != geteuid()) {
		log_error("the token file %s must belong to the daemon's user (uid %u) and be "
			  "readable by its owner only", d->config->token_file, (unsigned)geteuid());
		return -EPERM;
	}
	if (!fgets(buf, sizeof(buf), f))
		return -EINVAL;
	buf[strcspn(buf, "\r\n")] = '\0';
	if (strlen(buf) < 16) {
		log_error("the token in %s is shorter than 16 characters", d->config->token_file);
		return -EINVAL;
	}
	free(d->token);
	d->token = strdup(buf);
	return d->token ? 0 : -ENOMEM;
}

int server_listen(struct daemon *d)
{
	int n = sd_listen_fds(1), r;

	d->unix_fd = d->tcp_fd = -1;
	for (int i = 0; i < (n > 0 ? n : 0); i++) {
		int fd = SD_LISTEN_FDS_START + i;
		if (sd_is_socket_unix(fd, SOCK_STREAM, 1, NULL, 0) > 0 && d->unix_fd < 0) {
			d->unix_fd = fd;
			d->unix_activated = true;
		} else if (sd_is_socket_inet(fd, AF_UNSPEC, SOCK_STREAM, 1, 0) > 0 &&
			   d->tcp_fd < 0 && d->config->token_file) {
			d->tcp_fd = fd;
		} else {
			log_warning("ignoring passed file descriptor %d", fd);
			close(fd);
			continue;
		}
		fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
	}
	/* The unix socket last: once it answers, everything listens, and a
	 * bad TCP setting leaves no socket behind. */
	if (d->config->tcp_listen && d->tcp_fd < 0) {
		if (!d->config->token_file) {
			log_error("tcp_listen needs a token_file");
			return -EINVAL;
		}
		r = bind_tcp(d);
		if (r < 0)
			return r;
	}
	if (d->tcp_fd >= 0 && (r = read_token(d)) < 0)
		return r;
	if (d->unix_fd < 0) {
		r = bind_unix(d);
		if (r < 0)
			return r;
	}
	r = sd_event_add_defer(d->event, &d->reaper, reap, d);
	if (r < 0)
		return r;
	sd_event_source_set_enabled(d->reaper, SD_EVENT_OFF);
	r = sd_event_add_io(d->event, &d->unix_src, d->unix_fd, EPOLLIN, on_accept, d);
	if (r >= 0 && d->tcp_fd >= 0)
		r = sd_event_add_io(d->event, &d->tcp_src, d->tcp_fd, EPOLLIN, on_accept, d);
	return r < 0 ? r : 0;
}

void server_close(struct daemon *d)
{
	free_list(d->clients);
	free_list(d->dead);
	d->clients = d->dead = NULL;
	d->n_clients = d->n_subscribed = 0;
	d->reaper = sd_event_source_disable_unref(d->reaper);
	d->unix_src = sd_event_source_disable_unref(d->unix_src);
	d->tcp_src = sd_event_source_disable_unref(d->tcp_src);
	if (d->unix_fd >= 0) {
		close(d->unix_fd);
		if (!d->unix_activated && d->socket_path)
			unlink(d->socket_path);
	}
	if (d->tcp_fd >= 0)
		close(d->tcp_fd);
	d->unix_fd = d->tcp_fd = -1;
	free(d->token);
	d->token = NULL;
}
