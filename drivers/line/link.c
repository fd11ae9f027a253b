/* SPDX-License-Identifier: GPL-3.0-or-later */
/* TCP and serial (termios) connections of line devices. */
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <stdio.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>
#include <netinet/in.h>
#include <netinet/tcp.h>

#include "link.h"
#include "util-time.h"

static int tcp_connect(const struct line_link_params *p, unsigned timeout_ms, int *fd_out,
		       struct asph_error *err)
{
	struct addrinfo hints = { .ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM }, *res = NULL;
	char port[16];
	int e = 0;

	snprintf(port, sizeof(port), "%d", p->port);
	int g = getaddrinfo(p->host, port, &hints, &res);
	if (g)
		return asph_error_set(err, -ENODEV, "%s:%d: %s", p->host, p->port, gai_strerror(g));
	uint64_t deadline = transport_deadline(timeout_ms);
	for (struct addrinfo *a = res; a; a = a->ai_next) {
		int fd = socket(a->ai_family, a->ai_socktype | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
		if (fd < 0) {
			e = errno;
			continue;
		}
		if (connect(fd, a->ai_addr, a->ai_addrlen) < 0 && errno == EINPROGRESS) {
			struct pollfd pf = { fd, POLLOUT, 0 };
			int n;
			do
				n = poll(&pf, 1, (int)transport_ms_left(deadline));
			while (n < 0 && errno == EINTR);
			socklen_t l = sizeof(e);
			if (n <= 0)
				e = n == 0 ? ETIMEDOUT : errno;
			else if (getsockopt(fd, SOL_SOCKET, SO_ERROR, &e, &l) < 0)
				e = errno;
		} else {
			e = errno == EINPROGRESS ? 0 : (errno ? errno : 0);
		}
		if (e == 0) {
			int one = 1;
			/* a command is one short write: no Nagle delay */
			setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
			freeaddrinfo(res);
			*fd_out = fd;
			return 0;
		}
		close(fd);
	}
	freeaddrinfo(res);
	return asph_error_set(err, e == ETIMEDOUT ? -ETIMEDOUT : -ENODEV,
			      "cannot connect to %s:%d: %s", p->host, p->port, strerror(e));
}

static speed_t baud_constant(int baud)
{
	static const struct { int b; speed_t s; } table[] = {
		{ 50, B50 }, { 110, B110 }, { 300, B300 }, { 600, B600 }, { 1200, B1200 },
		{ 2400, B2400 }, { 4800, B4800 }, { 9600, B9600 }, { 19200, B19200 },
		{ 38400, B38400 }, { 57600, B57600 }, { 115200, B115200 }, { 230400, B230400 },
		{ 460800, B460800 }, { 921600, B921600 }, { 1000000, B1000000 },
		{ 2000000, B2000000 }, { 4000000, B4000000 },
	};
	for (size_t i = 0; i < sizeof(table) / sizeof(table[0]); i++)
		if (table[i].b == baud)
			return table[i].s;
	return 0;
}

static int serial_setup(int fd, const struct line_link_params *p, struct asph_error *err)
{
	struct termios tio;
	speed_t sp = baud_constant(p->baud);

	if (!sp)
		return asph_error_set(err, -EINVAL, "%s: %d baud is not a rate the port supports",
				      p->device, p->baud);
	if (tcgetattr(fd, &tio) < 0)
		return asph_error_set(err, -EINVAL, "%s is not a serial port: %s", p->device,
				      strerror(errno));
	cfmakeraw(&tio);
	tio.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | PARODD | CSTOPB | CRTSCTS);
	tio.c_cflag |= CLOCAL | CREAD;
	tio.c_cflag |= p->data_bits == 5 ? CS5 : p->data_bits == 6 ? CS6 : p->data_bits == 7 ? CS7 : CS8;
	if (p->parity != 'N')
		tio.c_cflag |= PARENB | (p->parity == 'O' ? PARODD : 0);
	if (p->stop_bits == 2)
		tio.c_cflag |= CSTOPB;
	if (p->rtscts)
		tio.c_cflag |= CRTSCTS;
	tio.c_cc[VMIN] = 1;
	tio.c_cc[VTIME] = 0;
	if (cfsetispeed(&tio, sp) < 0 || cfsetospeed(&tio, sp) < 0 ||
	    tcsetattr(fd, TCSANOW, &tio) < 0)
		return asph_error_set(err, -EINVAL, "%s: the port refuses the settings: %s", p->device,
				      strerror(errno));
	if (p->dtr >= 0) {
		int bit = TIOCM_DTR;
		/* a pseudo-terminal has no modem lines: nothing to set there */
		if (ioctl(fd, p->dtr ? TIOCMBIS : TIOCMBIC, &bit) < 0 && errno != ENOTTY &&
		    errno != EINVAL)
			return asph_error_set(err, -EIO, "%s: cannot set DTR: %s", p->device,
					      strerror(errno));
	}
	tcflush(fd, TCIOFLUSH);
	return 0;
}

int line_link_open(const struct line_link_params *p, unsigned timeout_ms,
		   struct transport **out, struct asph_error *err)
{
	char name[128];
	int fd = -1, r;

	if (p->serial) {
		fd = open(p->device, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
		if (fd < 0) {
			int e = errno;
			return asph_error_set(err, e == EACCES ? -EACCES : -ENODEV,
					      "cannot open %s: %s%s", p->device, strerror(e),
					      e == EACCES ? " (the user needs the dialout group; docs/driver-line.md)" : "");
		}
		r = serial_setup(fd, p, err);
		snprintf(name, sizeof(name), "%s", p->device);
	} else {
		r = tcp_connect(p, timeout_ms, &fd, err);
		snprintf(name, sizeof(name), "%s:%d", p->host, p->port);
	}
	if (r == 0)
		r = transport_new(fd, true, name, out, err);
	if (r < 0 && fd >= 0)
		close(fd);
	return r;
}

int line_link_dtr_pulse(struct transport *t, unsigned ms, struct asph_error *err)
{
	int fd = transport_fd(t), bit = TIOCM_DTR;

	if (ioctl(fd, TIOCMBIS, &bit) < 0)
		return asph_error_set(err, -ENOTSUP,
				      "this line has no DTR to request a reading with (%s)",
				      strerror(errno));
	msleep(ms);
	if (ioctl(fd, TIOCMBIC, &bit) < 0)
		return asph_error_set(err, -EIO, "cannot lower DTR: %s", strerror(errno));
	return 0;
}

void line_link_send_raw(struct transport *t, const char *buf, size_t len, unsigned ms)
{
	int fd = transport_fd(t);
	uint64_t deadline = transport_deadline(ms);

	while (len > 0) {
		struct pollfd pf = { fd, POLLOUT, 0 };
		if (poll(&pf, 1, (int)transport_ms_left(deadline)) <= 0 || !(pf.revents & POLLOUT))
			return;
		ssize_t n = send(fd, buf, len, MSG_NOSIGNAL);
		if (n < 0 && errno == ENOTSOCK)
			n = write(fd, buf, len);
		if (n <= 0)
			return;
		buf += n;
		len -= (size_t)n;
	}
}
