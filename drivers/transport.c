/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A file descriptor transport with timeouts and cross-thread cancel. */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "transport.h"
#include "util-time.h"

struct transport {
	int fd;
	bool own;
	int cancel_fd;          /* eventfd: readable once cancelled */
	bool tty;               /* a serial line (or a pty), not a socket */
	char name[128];         /* room for a unix socket path */
};

uint64_t transport_deadline(unsigned timeout_ms)
{
	return now_monotonic_ns() + (uint64_t)timeout_ms * (uint64_t)NS_PER_MS;
}

unsigned transport_ms_left(uint64_t deadline)
{
	uint64_t now = now_monotonic_ns();
	/* rounded up, so a wait never ends before the deadline */
	return deadline > now ? (unsigned)((deadline - now + 999999u) / 1000000u) : 0;
}

int transport_new(int fd, bool own, const char *name, struct transport **out,
		  struct asph_error *err)
{
	struct transport *t = calloc(1, sizeof(*t));
	int flags = fcntl(fd, F_GETFL);

	if (!t)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (flags < 0 || fcntl(fd, F_SETFL, flags | O_NONBLOCK) < 0 ||
	    (t->cancel_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK)) < 0) {
		int e = -errno;
		free(t);
		return asph_error_set(err, e, "%s: cannot set up the transport: %s", name,
				      strerror(-e));
	}
	t->fd = fd;
	t->own = own;
	t->tty = isatty(fd);
	snprintf(t->name, sizeof(t->name), "%s", name);
	*out = t;
	return 0;
}

void transport_free(struct transport *t)
{
	if (!t)
		return;
	if (t->own)
		close(t->fd);
	close(t->cancel_fd);
	free(t);
}

int transport_fd(const struct transport *t)
{
	return t->fd;
}

void transport_cancel(struct transport *t)
{
	uint64_t one = 1;
	/* an eventfd write of 1 cannot fail short of overflow */
	if (write(t->cancel_fd, &one, sizeof(one)) < 0)
		return;
}

/* Waits for events on fd until the deadline: 0 ready, or the reason. */
static int wait_for(struct transport *t, short events, uint64_t deadline,
		    const char *what, struct asph_error *err)
{
	for (;;) {
		struct pollfd p[2] = { { t->fd, events, 0 }, { t->cancel_fd, POLLIN, 0 } };
		int n = poll(p, 2, (int)transport_ms_left(deadline));
		if (n < 0 && errno == EINTR)
			continue;
		if (n < 0)
			return asph_error_set(err, -errno, "%s: %s: %s", t->name, what, strerror(errno));
		if (p[1].revents)
			return asph_error_set(err, -ECANCELED, "%s: %s stopped", t->name, what);
		if (p[0].revents & (events | POLLHUP | POLLERR))
			return (p[0].revents & events) ? 0
			       : asph_error_set(err, -ENODEV, "%s: the device went away during %s",
						t->name, what);
		if (n == 0)
			return asph_error_set(err, -ETIMEDOUT, "%s: no %s within the timeout",
					      t->name, what);
	}
}

static int io_error(struct transport *t, const char *what, struct asph_error *err)
{
	int e = errno;
	/* EIO: a terminal hung up (a serial adapter unplugged, a pty whose
	 * other end closed) */
	if (e == EPIPE || e == ECONNRESET || e == ENXIO || e == ENODEV || e == ENETDOWN || e == EIO)
		return asph_error_set(err, -ENODEV, "%s: the device went away (%s)", t->name,
				      strerror(e));
	return asph_error_set(err, -EIO, "%s: %s failed: %s", t->name, what, strerror(e));
}

int transport_send(struct transport *t, const void *buf, size_t len,
		   unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	const char *p = buf;

	while (len > 0) {
		int r = wait_for(t, POLLOUT, deadline, "sending", err);
		if (r < 0)
			return r;
		ssize_t n = send(t->fd, p, len, MSG_NOSIGNAL);
		if (n < 0 && errno == ENOTSOCK)
			n = write(t->fd, p, len);
		if (n < 0 && (errno == EAGAIN || errno == EINTR))
			continue;
		if (n < 0)
			return io_error(t, "sending", err);
		p += n;
		len -= (size_t)n;
	}
	return 0;
}

int transport_recv(struct transport *t, void *buf, size_t size, size_t *got,
		   unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);

	*got = 0;
	for (;;) {
		int r = wait_for(t, POLLIN, deadline, "answer", err);
		if (r < 0)
			return r;
		ssize_t n = read(t->fd, buf, size);
		if (n < 0 && (errno == EAGAIN || errno == EINTR))
			continue;
		if (n < 0)
			return io_error(t, "receiving", err);
		if (n == 0)
			return asph_error_set(err, -ENODEV, t->tty
					      ? "%s: the device went away (the line hung up)"
					      : "%s: the device closed the connection", t->name);
		*got = (size_t)n;
		return 0;
	}
}

int transport_recv_exact(struct transport *t, void *buf, size_t len,
			 unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	char *p = buf;

	while (len > 0) {
		size_t got;
		int r = transport_recv(t, p, len, &got, transport_ms_left(deadline), err);
		if (r < 0)
			return r;
		p += got;
		len -= got;
	}
	return 0;
}
