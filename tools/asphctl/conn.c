/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A blocking JSON-RPC connection to asphd over its unix socket. */
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "asphctl.h"
#include "util-mem.h"

struct conn {
	int fd;
	int timeout_ms;         /* for each answer; -1: none */
	struct proto_lines in;
	json_int_t next_id;
	json_t *events;         /* array of notifications not yet taken */
};

static int io_error(struct ctl_error *e, int r, const char *what)
{
	if (e) {
		e->code = 0;
		snprintf(e->message, sizeof(e->message), "%s", what);
		snprintf(e->detail, sizeof(e->detail), "%s", strerror(-r));
	}
	return r;
}

int conn_open(const char *path, struct conn **out, struct ctl_error *e)
{
	return conn_open_within(path, -1, out, e);
}

int conn_open_within(const char *path, int timeout_ms, struct conn **out, struct ctl_error *e)
{
	struct sockaddr_un sa = { .sun_family = AF_UNIX };
	struct timeval tv = { .tv_sec = timeout_ms / 1000, .tv_usec = timeout_ms % 1000 * 1000 };
	struct conn *c;
	int fd;

	if (strlen(path) >= sizeof(sa.sun_path))
		return io_error(e, -ENAMETOOLONG, path);
	memcpy(sa.sun_path, path, strlen(path));
	fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
	if (fd < 0)
		return io_error(e, -errno, "socket");
	/* a daemon whose backlog is full makes connect() wait: at most this */
	if (timeout_ms >= 0)
		setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof(tv));
	if (connect(fd, (struct sockaddr *)&sa, sizeof(sa)) < 0) {
		int r = errno == EAGAIN ? -ETIMEDOUT : -errno;
		close(fd);
		if (e) {
			e->code = 0;
			snprintf(e->message, sizeof(e->message), "cannot reach asphd");
			snprintf(e->detail, sizeof(e->detail), "%.400s: %s", path, strerror(-r));
		}
		return r;
	}
	c = calloc(1, sizeof(*c));
	if (!c) {
		close(fd);
		return -ENOMEM;
	}
	c->fd = fd;
	c->timeout_ms = timeout_ms;
	c->events = json_array();
	proto_lines_init(&c->in, 64u << 20);
	*out = c;
	return 0;
}

void conn_close(struct conn *c)
{
	if (!c)
		return;
	close(c->fd);
	proto_lines_release(&c->in);
	json_decref(c->events);
	free(c);
}

static int send_all(int fd, const char *s, size_t n)
{
	while (n > 0) {
		ssize_t k = send(fd, s, n, MSG_NOSIGNAL);
		if (k < 0) {
			if (errno == EINTR)
				continue;
			return -errno;
		}
		s += k;
		n -= (size_t)k;
	}
	return 0;
}

/* The first byte of a request with descriptors passed (SCM_RIGHTS), so
 * that they arrive with the request's line; then the rest as send_all(). */
static int send_with_fds(int fd, const char *s, size_t n, const int *fds, size_t n_fds)
{
	union {
		struct cmsghdr align;
		char buf[CMSG_SPACE(sizeof(int) * CONN_MAX_FDS)];
	} control;
	struct iovec iov = { .iov_base = (void *)s, .iov_len = 1 };
	struct msghdr msg = { .msg_iov = &iov, .msg_iovlen = 1, .msg_control = control.buf,
			      .msg_controllen = CMSG_SPACE(sizeof(int) * n_fds) };
	struct cmsghdr *cm;
	ssize_t k;

	if (!n_fds)
		return send_all(fd, s, n);
	if (n_fds > CONN_MAX_FDS || n == 0)
		return -EINVAL;
	memset(&control, 0, sizeof(control));
	cm = CMSG_FIRSTHDR(&msg);
	cm->cmsg_level = SOL_SOCKET;
	cm->cmsg_type = SCM_RIGHTS;
	cm->cmsg_len = CMSG_LEN(sizeof(int) * n_fds);
	memcpy(CMSG_DATA(cm), fds, sizeof(int) * n_fds);
	do
		k = sendmsg(fd, &msg, MSG_NOSIGNAL);
	while (k < 0 && errno == EINTR);
	if (k < 0)
		return -errno;
	return send_all(fd, s + 1, n - 1);
}

/* Reads one message; 1 with *msg, 0 on timeout, -errno. */
static int read_message(struct conn *c, int timeout_ms, json_t **msg)
{
	for (;;) {
		char *line, *dst;
		size_t len;
		int r = proto_lines_next(&c->in, &line, &len);

		if (r == -EMSGSIZE)
			return -EMSGSIZE;
		if (r == 1) {
			*msg = proto_parse(line, len, NULL);
			if (!*msg)
				return -EBADMSG;
			return 1;
		}
		struct pollfd p = { .fd = c->fd, .events = POLLIN };
		r = poll(&p, 1, timeout_ms);
		if (r < 0) {
			if (errno == EINTR)
				continue;
			return -errno;
		}
		if (r == 0)
			return 0;
		if (proto_lines_reserve(&c->in, 65536, &dst) < 0)
			return -ENOMEM;
		ssize_t n = recv(c->fd, dst, 65536, 0);
		if (n < 0) {
			if (errno == EINTR)
				continue;
			return -errno;
		}
		if (n == 0)
			return -ECONNRESET;
		proto_lines_commit(&c->in, (size_t)n);
	}
}

int conn_call(struct conn *c, const char *method, json_t *params,
	      json_t **result, struct ctl_error *e)
{
	return conn_call_fds(c, method, params, NULL, 0, result, e);
}

int conn_call_fds(struct conn *c, const char *method, json_t *params, const int *fds,
		  size_t n_fds, json_t **result, struct ctl_error *e)
{
	json_int_t id = ++c->next_id;
	_cleanup_(json_decrefp) json_t *req = proto_make_request(id, method, params);
	_cleanup_free_ char *text = req ? proto_dump(req, NULL) : NULL;
	int r;

	if (!text)
		return io_error(e, -ENOMEM, "out of memory");
	r = send_with_fds(c->fd, text, strlen(text), fds, n_fds);
	if (r < 0)
		return io_error(e, r, "the connection to asphd broke");
	for (;;) {
		_cleanup_(json_decrefp) json_t *msg = NULL;
		struct proto_message m;

		r = read_message(c, c->timeout_ms, &msg);
		if (r == 0)
			return io_error(e, -ETIMEDOUT, "asphd did not answer");
		if (r < 0)
			return io_error(e, r, "the connection to asphd broke");
		if (proto_check_incoming(msg, &m, NULL) != 0)
			return io_error(e, -EBADMSG, "asphd sent a malformed message");
		if (m.kind == PROTO_KIND_NOTIFICATION) {
			json_array_append(c->events, msg);
			continue;
		}
		if (!json_is_integer(m.id) || json_integer_value(m.id) != id) {
			if (json_is_null(m.id) && m.error) {
				/* An error the daemon could not tie to a request
				 * (e.g. too many clients). */
			} else {
				continue;
			}
		}
		if (m.error) {
			if (e) {
				json_t *detail = json_object_get(json_object_get(m.error, "data"), "detail");
				e->code = m.error_code;
				snprintf(e->message, sizeof(e->message), "%s", m.error_message);
				snprintf(e->detail, sizeof(e->detail), "%s",
					 json_is_string(detail) ? json_string_value(detail) : "");
			}
			return -EPROTO;
		}
		*result = json_incref(m.result);
		return 0;
	}
}

int conn_next_event(struct conn *c, int timeout_ms, json_t **msg)
{
	if (json_array_size(c->events) > 0) {
		*msg = json_incref(json_array_get(c->events, 0));
		json_array_remove(c->events, 0);
		return 1;
	}
	for (;;) {
		struct proto_message m;
		int r = read_message(c, timeout_ms, msg);

		if (r <= 0)
			return r;
		if (proto_check_incoming(*msg, &m, NULL) == 0 && m.kind == PROTO_KIND_NOTIFICATION)
			return 1;
		json_decref(*msg);
		*msg = NULL;
	}
}
