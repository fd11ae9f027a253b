/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A CANopen client over SocketCAN (or a descriptor or a unix socket
 * standing in for it). */
#include <errno.h>
#include <fcntl.h>
#include <net/if.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>

#include "bus.h"
#include "transport.h"
#include "util-time.h"

struct node {
	bool used;
	bool expect_boot;       /* an NMT reset was sent */
	bool booted;            /* boot-up seen since */
	bool restarted;         /* boot-up seen unasked */
	bool started;           /* NMT start sent: a boot-up now is a restart */
	bool lost;
	uint8_t state;          /* last heartbeat */
	uint16_t emcy;
	unsigned hb_timeout_ms; /* 0 = not watched */
	uint64_t last_hb_ns;
	char name[40];
};

/* "unix:" and the longest socket path: every name open_*() accepts fits */
#define IFACE_MAX (5 + sizeof(((struct sockaddr_un *)0)->sun_path))

struct can_bus {
	struct transport *t;
	char iface[IFACE_MAX];
	bool bus_fault;
	char fault[200];
	char warning[160];      /* the last harmless error frame, for hints */
	uint32_t last_abort;    /* of the last SDO transfer; 0: none */
	struct node nodes[CANOPEN_NODE_MAX + 1];
};

/* ------------------------------------------------------------ open */

static int open_socketcan(const char *iface, const uint8_t *nodes, unsigned n, int *out,
			  struct asph_error *err)
{
	struct can_filter filters[3 * CANOPEN_NODE_MAX];
	struct ifreq ifr;
	const uint32_t mask = CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG;
	can_err_mask_t errors = CAN_ERR_BUSOFF | CAN_ERR_CRTL | CAN_ERR_ACK | CAN_ERR_TX_TIMEOUT |
				CAN_ERR_RESTARTED;

	if (strlen(iface) >= IFNAMSIZ)
		return asph_error_set(err, -EINVAL, "%s: interface name too long", iface);
	int fd = socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC, CAN_RAW);
	if (fd < 0 && (errno == EAFNOSUPPORT || errno == EPROTONOSUPPORT))
		return asph_error_set(err, -ENODEV,
				      "%s: CAN is not supported by this kernel (socket(PF_CAN): %s): "
				      "a kernel with SocketCAN and the can_raw module is needed",
				      iface, strerror(errno));
	if (fd < 0)
		return asph_error_set(err, -EIO, "%s: cannot open a CAN socket: %s", iface,
				      strerror(errno));
	memset(&ifr, 0, sizeof(ifr));
	memcpy(ifr.ifr_name, iface, strlen(iface));
	int r = 0;
	if (ioctl(fd, SIOCGIFINDEX, &ifr) < 0)
		r = asph_error_set(err, -ENODEV, "%s: no such CAN interface (ip link show type can)",
				   iface);
	int ifindex = ifr.ifr_ifindex;
	if (r == 0 && ioctl(fd, SIOCGIFFLAGS, &ifr) == 0 && !(ifr.ifr_flags & IFF_UP))
		r = asph_error_set(err, -ENODEV, "%s is down: ip link set %s up type can bitrate 500000",
				   iface, iface);
	for (unsigned i = 0; i < n; i++) {
		filters[3 * i] = (struct can_filter){ CANOPEN_COB_SDO_TX + nodes[i], mask };
		filters[3 * i + 1] = (struct can_filter){ CANOPEN_COB_EMCY + nodes[i], mask };
		filters[3 * i + 2] = (struct can_filter){ CANOPEN_COB_HEARTBEAT + nodes[i], mask };
	}
	struct sockaddr_can addr = { .can_family = AF_CAN, .can_ifindex = ifindex };
	if (r == 0 && (setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters,
				  (socklen_t)(3 * n * sizeof(filters[0]))) < 0 ||
		       setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &errors, sizeof(errors)) < 0 ||
		       bind(fd, (struct sockaddr *)&addr, sizeof(addr)) < 0))
		r = asph_error_set(err, -EIO, "%s: cannot set up the CAN socket: %s", iface,
				   strerror(errno));
	if (r < 0) {
		close(fd);
		return r;
	}
	*out = fd;
	return 0;
}

static int open_fd(const char *iface, int *out, struct asph_error *err)
{
	char *end;
	long n = strtol(iface + 3, &end, 10);

	if (end == iface + 3 || *end || n < 0 || n > 1000000 || strlen(iface) >= IFACE_MAX)
		return asph_error_set(err, -EINVAL, "%s: expected fd:N with a descriptor number", iface);
	int fd = fcntl((int)n, F_DUPFD_CLOEXEC, 0);
	if (fd < 0)
		return asph_error_set(err, -ENODEV, "%s: not an open descriptor: %s", iface,
				      strerror(errno));
	*out = fd;
	return 0;
}

/* A gateway or simulator listening on a SOCK_SEQPACKET unix socket, one
 * struct can_frame per datagram. Nothing filters what it sends: frames of
 * other nodes are ignored here as on an unfiltered bus. */
static int open_unix(const char *iface, int *out, struct asph_error *err)
{
	struct sockaddr_un addr = { .sun_family = AF_UNIX };
	const char *path = iface + 5;
	size_t len = strlen(path);

	if (len == 0 || len >= sizeof(addr.sun_path))
		return asph_error_set(err, -EINVAL, "%s: expected unix:PATH with a socket path of 1 to "
				      "%zu bytes", iface, sizeof(addr.sun_path) - 1);
	memcpy(addr.sun_path, path, len);
	/* non-blocking: a listener whose queue is full must not hold up open */
	int fd = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
	if (fd < 0)
		return asph_error_set(err, -EIO, "%s: cannot create a socket: %s", iface,
				      strerror(errno));
	if (connect(fd, (struct sockaddr *)&addr, sizeof(addr)) == 0) {
		*out = fd;
		return 0;
	}
	int e = errno, r;
	if (e == ENOENT || e == ECONNREFUSED || e == ENOTDIR)
		r = asph_error_set(err, -ENODEV, "%s: no CAN gateway listens there (%s): is the "
				   "gateway or simulator running?", iface, strerror(e));
	else if (e == EPROTOTYPE)
		r = asph_error_set(err, -ENODEV, "%s: not a SOCK_SEQPACKET socket: the gateway must "
				   "carry one struct can_frame per datagram", iface);
	else if (e == EAGAIN)
		r = asph_error_set(err, -EIO, "%s: the gateway accepts no more connections", iface);
	else
		r = asph_error_set(err, -EIO, "%s: cannot connect: %s", iface, strerror(e));
	close(fd);
	return r;
}

int can_bus_open(const char *iface, const uint8_t *nodes, unsigned n, struct can_bus **out,
		 struct asph_error *err)
{
	int fd = -1, r;

	if (n > CANOPEN_NODE_MAX)
		return asph_error_set(err, -EINVAL, "too many nodes");
	if (strncmp(iface, "fd:", 3) == 0)
		r = open_fd(iface, &fd, err);
	else if (strncmp(iface, "unix:", 5) == 0)
		r = open_unix(iface, &fd, err);
	else
		r = open_socketcan(iface, nodes, n, &fd, err);
	if (r < 0)
		return r;
	struct can_bus *b = calloc(1, sizeof(*b));
	if (!b) {
		close(fd);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	snprintf(b->iface, sizeof(b->iface), "%s", iface);
	r = transport_new(fd, true, b->iface, &b->t, err);
	if (r < 0) {
		close(fd);
		free(b);
		return r;
	}
	for (unsigned i = 0; i < n; i++) {
		b->nodes[nodes[i]].used = true;
		snprintf(b->nodes[nodes[i]].name, sizeof(b->nodes[0].name), "node %u", nodes[i]);
	}
	*out = b;
	return 0;
}

void can_bus_free(struct can_bus *b)
{
	if (!b)
		return;
	transport_free(b->t);
	free(b);
}

void can_bus_label(struct can_bus *b, uint8_t node, const char *label)
{
	unsigned id = node & 0x7fu;

	snprintf(b->nodes[id].name, sizeof(b->nodes[0].name), "%s (node %u)", label, id);
}

const char *can_bus_node_name(const struct can_bus *b, uint8_t node)
{
	return b->nodes[node & 0x7f].name;
}

uint16_t can_bus_last_emcy(const struct can_bus *b, uint8_t node)
{
	return b->nodes[node & 0x7f].emcy;
}

bool can_bus_node_lost(const struct can_bus *b, uint8_t node)
{
	return b->nodes[node & 0x7f].lost;
}

/* ------------------------------------------------- frames arriving */

/* The faults seen so far; they stay. */
static int check_faults(struct can_bus *b, struct asph_error *err)
{
	if (b->bus_fault)
		return asph_error_set(err, -EIO, "%s: %s", b->iface, b->fault);
	for (unsigned i = 1; i <= CANOPEN_NODE_MAX; i++) {
		struct node *n = &b->nodes[i];
		if (n->restarted)
			return asph_error_set(err, -EPROTO,
					      "%s restarted (boot-up message): it lost its state and "
					      "its home", n->name);
		if (n->lost)
			return asph_error_set(err, -ENODEV,
					      "%s: heartbeat lost (none for %u ms): the drive is off, "
					      "disconnected or reset", n->name, n->hb_timeout_ms);
	}
	return 0;
}

/* Marks the nodes whose heartbeat is overdue as lost. Call it with nothing
 * left to read: heartbeats waiting for a client that was busy elsewhere
 * (a slow probe) are no silence. */
static void heartbeat_timeouts(struct can_bus *b)
{
	uint64_t now = now_monotonic_ns();

	for (unsigned i = 1; i <= CANOPEN_NODE_MAX; i++) {
		struct node *n = &b->nodes[i];
		if (n->hb_timeout_ms && now > n->last_hb_ns + n->hb_timeout_ms * 1000000ull)
			n->lost = true;
	}
}

/* ms until the first watched heartbeat is due (UINT32_MAX: none). */
static unsigned heartbeat_due_ms(const struct can_bus *b)
{
	uint64_t now = now_monotonic_ns(), first = UINT64_MAX;

	for (unsigned i = 1; i <= CANOPEN_NODE_MAX; i++) {
		const struct node *n = &b->nodes[i];
		if (n->hb_timeout_ms) {
			uint64_t due = n->last_hb_ns + n->hb_timeout_ms * 1000000ull;
			first = due < first ? due : first;
		}
	}
	if (first == UINT64_MAX)
		return UINT32_MAX;
	return first > now ? (unsigned)((first - now) / 1000000u) + 1 : 0;
}

/* Takes note of a frame that is not the answer awaited. */
static int handle(struct can_bus *b, const struct can_frame *f, struct asph_error *err)
{
	struct can_event ev;
	char text[160];
	bool fatal;

	if (canopen_decode(f, &ev) < 0)
		return 0;       /* noise from a node we do not talk to */
	struct node *n = &b->nodes[ev.node];
	switch (ev.type) {
	case CAN_EV_HEARTBEAT:
		n->state = ev.u.state;
		n->last_hb_ns = now_monotonic_ns();
		if (ev.u.state == CANOPEN_STATE_BOOTUP) {
			if (n->used && n->started && !n->expect_boot)
				n->restarted = true;
			n->booted = true;
		}
		break;
	case CAN_EV_EMCY:
		n->emcy = ev.u.emcy.code;
		break;
	case CAN_EV_BUS_ERROR:
		canopen_bus_error_text(&ev, &fatal, text, sizeof(text));
		if (fatal) {
			b->bus_fault = true;
			snprintf(b->fault, sizeof(b->fault), "%s", text);
		} else {
			snprintf(b->warning, sizeof(b->warning), "%s", text);
		}
		break;
	default:
		break;
	}
	return check_faults(b, err);
}

/* One message; *is_frame says whether it is a classic frame. A byte more
 * than a frame is read: a datagram socket cuts a longer message (CAN FD,
 * a gateway's garbage) to the size asked for, which would pass it off as
 * a frame. */
static int recv_message(struct can_bus *b, struct can_frame *f, bool *is_frame,
			unsigned timeout_ms, struct asph_error *err)
{
	union {
		struct can_frame f;
		unsigned char bytes[sizeof(struct can_frame) + 1];
	} m;
	size_t got;
	int r = transport_recv(b->t, m.bytes, sizeof(m.bytes), &got, timeout_ms, err);

	*is_frame = r == 0 && got == sizeof(*f) && m.f.can_dlc <= 8;
	if (*is_frame)
		*f = m.f;
	return r;
}

/* Handles what already arrived, so that a late answer to an earlier
 * request (SDO has no transaction id) cannot pass for the next one, and
 * then looks for overdue heartbeats. */
static int drain(struct can_bus *b, struct asph_error *err)
{
	struct can_frame f;
	bool is_frame;

	for (;;) {
		int r = check_faults(b, err);
		if (r < 0)
			return r;
		r = recv_message(b, &f, &is_frame, 0, err);
		if (r == -ETIMEDOUT) {
			heartbeat_timeouts(b);
			return check_faults(b, err);
		}
		if (r < 0)
			return r;
		if (is_frame && (f.can_id & CAN_ERR_FLAG || f.can_id < CANOPEN_COB_SDO_TX ||
				 f.can_id > CANOPEN_COB_SDO_TX + CANOPEN_NODE_MAX))
			r = handle(b, &f, err);
		if (r < 0)
			return r;
	}
}

int can_bus_check(struct can_bus *b, struct asph_error *err)
{
	return drain(b, err);
}

/* One frame, waiting at most until deadline, noticing a heartbeat that
 * falls due meanwhile. */
static int recv_frame(struct can_bus *b, struct can_frame *f, uint64_t deadline,
		      struct asph_error *err)
{
	for (;;) {
		unsigned left = transport_ms_left(deadline), hb = heartbeat_due_ms(b);
		bool is_frame;
		int r = recv_message(b, f, &is_frame, hb < left ? hb : left, err);
		if (r == -ETIMEDOUT && hb < left) {
			/* nothing came: the queue is empty */
			heartbeat_timeouts(b);
			r = check_faults(b, err);
			if (r < 0)
				return r;
			continue;
		}
		if (r < 0)
			return r;
		if (is_frame)
			return 0;
		/* CAN FD, a short or a long message: not a frame of ours */
	}
}

int can_bus_idle(struct can_bus *b, unsigned ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(ms);
	struct can_frame f;

	for (;;) {
		int r = can_bus_check(b, err);
		if (r < 0)
			return r;
		r = recv_frame(b, &f, deadline, err);
		if (r == -ETIMEDOUT)
			return can_bus_check(b, err);
		if (r < 0)
			return r;
		r = handle(b, &f, err);
		if (r < 0)
			return r;
	}
}

/* ------------------------------------------------------- sending */

int can_bus_send(struct can_bus *b, const struct can_frame *f, unsigned timeout_ms,
		 struct asph_error *err)
{
	return transport_send(b->t, f, sizeof(*f), timeout_ms, err);
}

int can_bus_nmt(struct can_bus *b, uint8_t command, uint8_t node, struct asph_error *err)
{
	struct can_frame f;

	canopen_nmt_frame(&f, command, node);
	int r = can_bus_send(b, &f, 100, err);
	for (unsigned i = 1; i <= CANOPEN_NODE_MAX && r == 0; i++)
		if (node == 0 || node == i)
			b->nodes[i].started = command == CANOPEN_NMT_START;
	return r;
}

void can_bus_cancel(struct can_bus *b, const struct can_frame *frames, unsigned n)
{
	int fd = transport_fd(b->t);

	transport_cancel(b->t);
	for (unsigned i = 0; i < n; i++) {
		ssize_t w = send(fd, &frames[i], sizeof(frames[i]), MSG_DONTWAIT | MSG_NOSIGNAL);
		if (w < 0 && errno == ENOTSOCK)
			w = write(fd, &frames[i], sizeof(frames[i]));
		(void)w;        /* best effort: the bus may be gone */
	}
}

void can_bus_expect_bootup(struct can_bus *b)
{
	for (unsigned i = 1; i <= CANOPEN_NODE_MAX; i++) {
		b->nodes[i].expect_boot = true;
		b->nodes[i].booted = false;
	}
}

static bool all_booted(const struct can_bus *b, const uint8_t *nodes, unsigned n)
{
	for (unsigned i = 0; i < n; i++)
		if (!b->nodes[nodes[i]].booted)
			return false;
	return true;
}

int can_bus_wait_bootup(struct can_bus *b, const uint8_t *nodes, unsigned n,
			unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	struct can_frame f;
	int r = 0;

	while (r == 0 && !all_booted(b, nodes, n)) {
		r = recv_frame(b, &f, deadline, err);
		if (r == 0)
			r = handle(b, &f, err);
	}
	for (unsigned i = 1; i <= CANOPEN_NODE_MAX; i++)
		b->nodes[i].expect_boot = false;
	if (r != -ETIMEDOUT)
		return r;
	for (unsigned i = 0; i < n; i++)
		if (!b->nodes[nodes[i]].booted)
			return asph_error_set(err, -ETIMEDOUT,
					      "%s sent no boot-up message within %u ms after the NMT "
					      "reset: is it powered, connected, on this node id and "
					      "bit rate?%s%s", b->nodes[nodes[i]].name, timeout_ms,
					      b->warning[0] ? " The bus says: " : "", b->warning);
	return 0;
}

void can_bus_watch(struct can_bus *b, uint8_t node, unsigned timeout_ms)
{
	struct node *n = &b->nodes[node & 0x7f];

	n->hb_timeout_ms = timeout_ms;
	n->last_hb_ns = now_monotonic_ns();
	n->lost = false;
}

/* ------------------------------------------------------------ SDO */

static const char *sdo_kind_name(enum canopen_sdo_kind k)
{
	switch (k) {
	case SDO_UPLOAD: return "upload (read)";
	case SDO_DOWNLOAD: return "download (write)";
	case SDO_ABORT: return "abort";
	default: return "segmented or block transfer";
	}
}

static int sdo_abort_error(struct can_bus *b, uint8_t node, const struct canopen_sdo *s,
			   enum canopen_sdo_kind kind, struct asph_error *err)
{
	const char *text = canopen_abort_text(s->abort_code);

	b->last_abort = s->abort_code;
	return asph_error_set(err, -EPROTO, "%s refused the %s of 0x%04x:%02x: SDO abort 0x%08x (%s)",
			      b->nodes[node].name, kind == SDO_UPLOAD ? "read" : "write",
			      s->index, s->subindex, s->abort_code,
			      text ? text : "a code CiA 301 does not define");
}

/* Sends req and waits for the response of node about index:sub. */
static int sdo_exchange(struct can_bus *b, uint8_t node, const struct can_frame *req,
			enum canopen_sdo_kind kind, uint16_t index, uint8_t sub,
			struct canopen_sdo *resp, unsigned timeout_ms, struct asph_error *err)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	const char *name = b->nodes[node].name;
	struct can_frame f;
	bool stale = false;
	int r = drain(b, err);

	b->last_abort = 0;
	if (r == 0)
		r = transport_send(b->t, req, sizeof(*req), timeout_ms, err);
	while (r == 0) {
		r = recv_frame(b, &f, deadline, err);
		if (r == -ETIMEDOUT)
			return asph_error_set(err, -ETIMEDOUT,
					      "%s: no answer to the SDO %s of 0x%04x:%02x within %u ms%s%s%s",
					      name, sdo_kind_name(kind), index, sub, timeout_ms,
					      stale ? " (it answered about another object)" : "",
					      b->warning[0] ? "; the bus says: " : "", b->warning);
		if (r < 0)
			return r;
		if ((f.can_id & (CAN_ERR_FLAG | CAN_EFF_FLAG | CAN_RTR_FLAG)) ||
		    f.can_id != CANOPEN_COB_SDO_TX + node) {
			r = handle(b, &f, err);
			continue;
		}
		struct can_event ev;
		if (canopen_decode(&f, &ev) < 0)
			return asph_error_set(err, -EPROTO,
					      "%s: malformed SDO response (length %u) to 0x%04x:%02x",
					      name, f.can_dlc, index, sub);
		const struct canopen_sdo *s = &ev.u.sdo;
		if (s->kind == SDO_ABORT && (s->index == index || s->index == 0))
			return sdo_abort_error(b, node, s, kind, err);
		if (s->index != index || s->subindex != sub) {
			stale = true;   /* a late answer to an earlier request */
			continue;
		}
		if (s->kind != kind)
			return asph_error_set(err, -EPROTO,
					      "%s answered the SDO %s of 0x%04x:%02x with a %s "
					      "(expected an expedited %s)", name, sdo_kind_name(kind),
					      index, sub, sdo_kind_name(s->kind), sdo_kind_name(kind));
		*resp = *s;
		return 0;
	}
	return r;
}

int can_bus_sdo_upload(struct can_bus *b, uint8_t node, uint16_t index, uint8_t sub,
		       uint32_t *value, unsigned timeout_ms, struct asph_error *err)
{
	struct can_frame req;
	struct canopen_sdo s;

	canopen_sdo_frame(&req, node, true, SDO_UPLOAD, index, sub, 0, 0);
	int r = sdo_exchange(b, node, &req, SDO_UPLOAD, index, sub, &s, timeout_ms, err);
	if (r == 0)
		*value = s.value;
	return r;
}

int can_bus_sdo_download(struct can_bus *b, uint8_t node, uint16_t index, uint8_t sub,
			 uint32_t value, uint8_t size, unsigned timeout_ms,
			 struct asph_error *err)
{
	struct can_frame req;
	struct canopen_sdo s;

	canopen_sdo_frame(&req, node, true, SDO_DOWNLOAD, index, sub, value, size);
	return sdo_exchange(b, node, &req, SDO_DOWNLOAD, index, sub, &s, timeout_ms, err);
}

uint32_t can_bus_last_abort(const struct can_bus *b)
{
	return b->last_abort;
}

int can_bus_sdo_download_all(struct can_bus *b, const uint8_t *nodes, unsigned n,
			     uint16_t index, uint8_t sub, uint32_t value, uint8_t size,
			     unsigned timeout_ms)
{
	uint64_t deadline = transport_deadline(timeout_ms);
	bool waiting[CANOPEN_NODE_MAX + 1] = { false };
	unsigned sent = 0, heard = 0, answered = 0;
	struct can_frame f;

	for (unsigned i = 0; i < n; i++) {
		canopen_sdo_frame(&f, nodes[i], true, SDO_DOWNLOAD, index, sub, value, size);
		if (transport_send(b->t, &f, sizeof(f), 10, NULL) == 0 && !waiting[nodes[i] & 0x7f]) {
			waiting[nodes[i] & 0x7f] = true;
			sent++;
		}
	}
	while (heard < sent && recv_frame(b, &f, deadline, NULL) == 0) {
		struct can_event ev;
		if (f.can_id & (CAN_ERR_FLAG | CAN_EFF_FLAG | CAN_RTR_FLAG) ||
		    canopen_decode(&f, &ev) < 0 || ev.type != CAN_EV_SDO_RESPONSE) {
			handle(b, &f, NULL);
			continue;
		}
		if (ev.u.sdo.index == index && waiting[ev.node]) {
			waiting[ev.node] = false;
			heard++;
			answered += ev.u.sdo.kind == SDO_DOWNLOAD;
		}
	}
	return (int)answered;
}
