/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread. Non-blocking sockets, one JSON text per line in; the
 * lines are answered in turns (turns.h) that the web listener's requests
 * share: the clients with requests waiting, first come first served, a
 * slice of a few milliseconds each, so that one batch cannot hold the loop
 * (or the watchdog) for longer than one step and every connection is
 * served between two of another's. A line whose request waits for a
 * computation (tasks.h) leaves the turns until it is ready.
 */
#include <errno.h>
#include <fcntl.h>
#include <malloc.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "asph-proto.h"
#include "log.h"
#include "ratelimit.h"
#include "server.h"
#include "server-internal.h"
#include "turns.h"
#include "util-mem.h"

#define READ_CHUNK 65536
/* Bytes read from one client per wake-up, so that one fast writer cannot
 * starve the others. */
#define READ_BUDGET (256 * 1024)
/* An output buffer this large is given back once it has drained, and the
 * heap trimmed, so that a spike does not stay in the daemon's RSS. */
#define OUT_KEEP_BYTES (256 * 1024)
/* Accepting pauses this long when the process has no descriptor left,
 * doubling up to the maximum while it lasts. */
#define ACCEPT_BACKOFF_MIN_USEC 50000
#define ACCEPT_BACKOFF_MAX_USEC 2000000

static int reap(sd_event_source *s, void *data);
static int accept_resume(sd_event_source *s, uint64_t usec, void *data);
static void keep_reserve(struct server *srv);

static uint64_t now_usec(const struct server *srv)
{
	uint64_t now = 0;

	sd_event_now(srv->event, CLOCK_MONOTONIC, &now);
	return now;
}

int server_new(const struct server_setup *setup, struct server **out)
{
	struct server *srv = calloc(1, sizeof(*srv));
	int r;

	if (!srv)
		return -ENOMEM;
	srv->event = setup->event;
	srv->rpc = setup->rpc;
	srv->limits = setup->limits;
	srv->turns = setup->turns;
	srv->reserve_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
	r = ratelimit_new(1, 10 * 1000000ull, 16, &srv->log_limit);
	if (r == 0)
		r = sd_event_add_defer(srv->event, &srv->reaper, reap, srv);
	if (r == 0)
		r = sd_event_add_time(srv->event, &srv->accept_timer, CLOCK_MONOTONIC, UINT64_MAX,
				      0, accept_resume, srv);
	if (r < 0) {
		server_free(srv);
		return r;
	}
	sd_event_source_set_enabled(srv->reaper, SD_EVENT_OFF);
	sd_event_source_set_enabled(srv->accept_timer, SD_EVENT_OFF);
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

/* c waits for its turn (nothing when it waits already). */
static void turn_queue(struct client *c)
{
	/* A line not yet begun is fresh (turns.h). */
	turns_queue(c->srv->turns, &c->turn, !c->line);
}

static void turn_remove(struct client *c)
{
	turns_remove(c->srv->turns, &c->turn);
}

static void client_free(struct client *c)
{
	if (!c)
		return;
	turn_remove(c);
	rpc_line_free(c->line);
	rpc_session_close(c->srv->rpc, &c->session);
	rpc_session_close_fds(&c->session);
	sd_event_source_disable_unref(c->io);
	sd_event_source_disable_unref(c->timer);
	if (c->fd >= 0)
		close(c->fd);
	proto_lines_release(&c->in);
	free(c->out);
	free(c->held);
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
	keep_reserve(srv);
	return 0;
}

void server_client_drop(struct client *c, const char *why)
{
	struct server *srv = c->srv;

	if (c->fd < 0)
		return;
	log_debug("client %" PRIu64 " (%s) dropped: %s", c->serial, c->session.peer.name, why);
	sd_event_source_set_enabled(c->io, SD_EVENT_OFF);
	sd_event_source_set_enabled(c->timer, SD_EVENT_OFF);
	turn_remove(c);
	close(c->fd);
	c->fd = -1;
	client_unlink(c);
	rpc_line_free(c->line);
	c->line = NULL;
	rpc_session_close(srv->rpc, &c->session);
	rpc_session_close_fds(&c->session);
	c->next = srv->dead;
	srv->dead = c;
	sd_event_source_set_enabled(srv->reaper, SD_EVENT_ONESHOT);
}

static bool client_dead(const struct client *c)
{
	return c->fd < 0;
}

static size_t output_pending(const struct client *c)
{
	return c->out_len - c->out_off;
}

/* Unread output this large holds the client's next request back. */
static bool output_blocked(const struct client *c)
{
	return output_pending(c) >= c->srv->limits->max_output_bytes / 2;
}

static bool work_pending(const struct client *c)
{
	return !c->closing && !c->waiting &&
	       (c->line || c->have_lines || (c->eof && c->partial_usec));
}

/* ------------------------------------------------------------ timers */

enum deadline {
	DEADLINE_NONE,
	DEADLINE_PARTIAL,       /* an incomplete request waits */
	DEADLINE_OUTPUT,        /* the client does not read its output */
	DEADLINE_AUTH,          /* a TCP client has not sent the token */
	DEADLINE_IDLE,          /* nothing sent, nothing subscribed */
};

static void nearest(enum deadline *which, uint64_t *at, enum deadline d, uint64_t t)
{
	if (t < *at) {
		*at = t;
		*which = d;
	}
}

/* The first thing c is waiting too long for, and when it is due. */
static enum deadline client_deadline(const struct client *c, uint64_t *at)
{
	const struct settings_limits *l = c->srv->limits;
	enum deadline which = DEADLINE_NONE;

	*at = UINT64_MAX;
	if (c->partial_usec)
		nearest(&which, at, DEADLINE_PARTIAL,
			c->partial_usec + (uint64_t)l->request_timeout_ms * 1000);
	if (c->stalled_usec)
		nearest(&which, at, DEADLINE_OUTPUT,
			c->stalled_usec + (uint64_t)l->request_timeout_ms * 1000);
	if (c->tcp && !c->session.authenticated)
		nearest(&which, at, DEADLINE_AUTH,
			c->connected_usec + (uint64_t)l->auth_timeout_ms * 1000);
	if (l->idle_timeout_ms && !c->session.events.classes && !c->line && !c->have_lines)
		nearest(&which, at, DEADLINE_IDLE,
			c->request_usec + (uint64_t)l->idle_timeout_ms * 1000);
	return which;
}

/* The timer fires at the nearest deadline or before it: one armed
 * earlier is left (client_timer() looks again when it fires), so that a
 * busy client does not move it at every request. */
static void arm_timer(struct client *c)
{
	uint64_t at, armed;
	int on;

	if (client_dead(c))
		return;
	if (client_deadline(c, &at) == DEADLINE_NONE) {
		sd_event_source_set_enabled(c->timer, SD_EVENT_OFF);
		return;
	}
	on = sd_event_source_get_enabled(c->timer, NULL);
	if (on > 0 && sd_event_source_get_time(c->timer, &armed) >= 0 && armed <= at)
		return;
	sd_event_source_set_time(c->timer, at);
	sd_event_source_set_enabled(c->timer, SD_EVENT_ONESHOT);
}

/* ------------------------------------------------------------ output */

static void update_events(struct client *c);
static void client_turn(void *data);
static void line_ready(void *data);

static int flush_output(struct client *c)
{
	size_t before = output_pending(c);

	while (c->out_len > c->out_off) {
		ssize_t n = send(c->fd, c->out + c->out_off, c->out_len - c->out_off,
				 MSG_NOSIGNAL | MSG_DONTWAIT);
		if (n < 0) {
			if (errno == EINTR)
				continue;
			if (errno == EAGAIN)
				break;
			server_client_drop(c, strerror(errno));
			return -ECONNRESET;
		}
		c->out_off += (size_t)n;
	}
	if (c->out_off == c->out_len) {
		c->out_off = c->out_len = 0;
		if (c->out_cap > OUT_KEEP_BYTES) {
			/* A spike's buffer goes back to the system. */
			free(c->out);
			c->out = NULL;
			c->out_cap = 0;
			malloc_trim(0);
		}
	}
	/* Output that waits counts from when the client last took some. */
	if (!output_pending(c))
		c->stalled_usec = 0;
	else if (!c->stalled_usec || output_pending(c) < before)
		c->stalled_usec = now_usec(c->srv);
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

static int out_put(struct client *c, const char *buf, size_t n)
{
	if (out_reserve(c, n) < 0)
		return -1;
	memcpy(c->out + c->out_len, buf, n);
	c->out_len += n;
	return 0;
}

/* An answer: its size is bounded by the work that made it (one request
 * taken only under half of max_output_bytes), not refused here. */
static int out_answer(const char *buf, size_t n, void *data)
{
	struct client *c = data;

	return client_dead(c) ? -1 : out_put(c, buf, n);
}

/* A notification or an error of the transport: refused past the limit. */
static int out_message(const char *buf, size_t n, void *data)
{
	struct client *c = data;

	if (output_pending(c) + n > c->srv->limits->max_output_bytes)
		return -1;
	return out_put(c, buf, n);
}

/* Queues a message to c; drops c when its output would pass the limit.
 * Returns 0 or -ECONNRESET (dropped). */
static int client_send(struct client *c, const json_t *msg)
{
	size_t start;

	if (client_dead(c))
		return -ECONNRESET;
	start = c->out_len;
	if (json_dump_callback(msg, out_message, c, JSON_COMPACT) < 0 ||
	    out_message("\n", 1, c) < 0) {
		/* Either the limit or memory: the client goes. */
		if (output_pending(c) > c->srv->limits->max_output_bytes / 2)
			log_info("client %" PRIu64 " (%s) does not read its output: dropped",
				 c->serial, c->session.peer.name);
		c->out_len = start < c->out_off ? c->out_off : start;
		server_client_drop(c, "output buffer full");
		return -ECONNRESET;
	}
	return flush_output(c);
}

/* An error of the transport, which closes the connection or drops a line:
 * a batch's answer line still open is cut off first, so that the error has
 * a line of its own. */
void server_send_error(struct client *c, int code, const char *detail)
{
	_cleanup_(json_decrefp) json_t *e = proto_make_error(NULL, code, NULL,
		detail ? json_pack("{s:s}", "detail", detail) : NULL);

	if (!e || client_dead(c))
		return;
	if (c->line && rpc_line_open(c->line) && out_put(c, "\n", 1) < 0) {
		server_client_drop(c, "out of memory");
		return;
	}
	client_send(c, e);
}

/* A notification to c while its answer line is open: kept until the
 * line ends, counted against limits.max_output_bytes as if it were out. */
static void hold_notification(struct client *c, const json_t *msg)
{
	_cleanup_free_ char *text = json_dumps(msg, JSON_COMPACT);
	size_t n = text ? strlen(text) + 1 : 0;

	if (!text || output_pending(c) + c->held_len + n > c->srv->limits->max_output_bytes) {
		log_info("client %" PRIu64 " (%s) does not read its output: dropped",
			 c->serial, c->session.peer.name);
		server_client_drop(c, "output buffer full");
		return;
	}
	if (c->held_len + n > c->held_cap) {
		size_t cap = c->held_cap ? c->held_cap : 1024;
		while (cap < c->held_len + n)
			cap *= 2;
		char *b = realloc(c->held, cap);
		if (!b) {
			server_client_drop(c, "out of memory");
			return;
		}
		c->held = b;
		c->held_cap = cap;
	}
	memcpy(c->held + c->held_len, text, n - 1);
	c->held[c->held_len + n - 1] = '\n';
	c->held_len += n;
}

/* The notifications held while c's answer line was open, now that it is
 * complete. */
static void release_held(struct client *c)
{
	if (!c->held_len || client_dead(c))
		return;
	if (out_put(c, c->held, c->held_len) < 0) {
		server_client_drop(c, "out of memory");
		return;
	}
	c->held_len = 0;
	if (c->held_cap > OUT_KEEP_BYTES) {
		free(c->held);
		c->held = NULL;
		c->held_cap = 0;
	}
}

/* ------------------------------------------------------------ input */

static void update_events(struct client *c)
{
	uint32_t ev = 0;

	if (client_dead(c))
		return;
	if (!c->closing && !c->eof && !c->line && !c->have_lines)
		ev |= EPOLLIN;
	if (c->out_len > c->out_off)
		ev |= EPOLLOUT;
	if (!ev && !work_pending(c) && !c->waiting) {
		/* Nothing more to read, answer or write. */
		server_client_drop(c, c->closing ? "closed" : "end of input");
		return;
	}
	/* A client whose request is computed is not read, but its hang-up
	 * is heard, which cancels the computation. */
	if (!ev && c->waiting)
		ev = EPOLLHUP;
	sd_event_source_set_io_events(c->io, ev ? ev : EPOLLOUT);
	sd_event_source_set_enabled(c->io, ev ? SD_EVENT_ON : SD_EVENT_OFF);
	if (work_pending(c) && !output_blocked(c))
		turn_queue(c);
	arm_timer(c);
}

/* Takes the next complete line: 1 with c->line, 0 when there is none. */
static int take_line(struct client *c)
{
	char *line;
	size_t len;
	int r;

	while ((r = proto_lines_next(&c->in, &line, &len)) == -EMSGSIZE) {
		char why[96];
		snprintf(why, sizeof(why), "a request is longer than %u bytes",
			 c->srv->limits->max_request_bytes);
		server_send_error(c, PROTO_REQUEST_TOO_LARGE, why);
		if (client_dead(c))
			return 0;
	}
	if (r == 0) {
		c->have_lines = false;
		c->partial_usec = proto_lines_pending(&c->in) == 0 ? 0
				: c->partial_usec ? c->partial_usec : now_usec(c->srv);
		return 0;
	}
	c->request_usec = now_usec(c->srv);
	/* A whole line came: what follows it is waited for from when the
	 * daemon next reads, not while it answers this one. */
	c->partial_usec = 0;
	if (rpc_line_new(c->srv->rpc, &c->session, line, len, &c->line) < 0) {
		server_client_drop(c, "out of memory");
		return 0;
	}
	rpc_line_on_ready(c->line, line_ready, c);
	return 1;
}

/* The input ended: what is left of a line is refused. */
static void end_of_input(struct client *c)
{
	server_send_error(c, PROTO_PARSE_ERROR, "the input ended inside a request");
	if (client_dead(c))
		return;
	proto_lines_release(&c->in);
	proto_lines_init(&c->in, c->srv->limits->max_request_bytes);
	c->partial_usec = 0;
}

/* A computation that c's line waited for is done: its turn again. */
static void line_ready(void *data)
{
	struct client *c = data;

	c->waiting = false;
	update_events(c);
}

/* One turn (turns.h): the requests of c's lines, for about TURN_SLICE_USEC. */
static void client_turn(void *data)
{
	struct client *c = data;
	uint64_t start = turns_now_usec();
	int n = 0, r;

	while (!client_dead(c) && !c->closing && !c->waiting && !output_blocked(c) &&
	       n < TURN_SLICE_STEPS) {
		if (!c->line && (!c->have_lines || !take_line(c)))
			break;
		r = rpc_line_step(c->line, out_answer, c);
		if (r == RPC_LINE_WAITING) {
			c->waiting = true;
			break;
		}
		if (r <= 0) {
			rpc_line_free(c->line);
			c->line = NULL;
			release_held(c);
		}
		if (r < 0) {
			server_client_drop(c, r == -ENOMEM ? "out of memory" : "connection lost");
			return;
		}
		n++;
		if (turns_now_usec() - start > TURN_SLICE_USEC)
			break;
	}
	if (client_dead(c))
		return;
	if (c->eof && !c->line && !c->have_lines && c->partial_usec)
		end_of_input(c);
	if (!client_dead(c))
		flush_output(c);
}

/*
 * recv() of up to len bytes; on a unix socket recvmsg(), whose descriptors
 * (SCM_RIGHTS) the session keeps for the requests that name them, up to
 * RPC_SESSION_MAX_FDS, closing the rest. The kernel closes those that did
 * not fit the buffer (MSG_CTRUNC); credentials are not asked for.
 */
static ssize_t receive(struct client *c, char *dst, size_t len)
{
	union {
		struct cmsghdr align;
		char buf[CMSG_SPACE(sizeof(int) * RPC_SESSION_MAX_FDS)];
	} control;
	struct iovec iov = { .iov_base = dst, .iov_len = len };
	struct msghdr msg = { .msg_iov = &iov, .msg_iovlen = 1,
			      .msg_control = control.buf, .msg_controllen = sizeof(control.buf) };
	ssize_t n;

	if (c->tcp)
		return recv(c->fd, dst, len, MSG_DONTWAIT);
	n = recvmsg(c->fd, &msg, MSG_DONTWAIT | MSG_CMSG_CLOEXEC);
	if (n < 0)
		return n;
	for (struct cmsghdr *cm = CMSG_FIRSTHDR(&msg); cm; cm = CMSG_NXTHDR(&msg, cm)) {
		size_t k;

		if (cm->cmsg_level != SOL_SOCKET || cm->cmsg_type != SCM_RIGHTS)
			continue;
		k = (cm->cmsg_len - CMSG_LEN(0)) / sizeof(int);
		for (size_t i = 0; i < k; i++) {
			int fd;
			memcpy(&fd, CMSG_DATA(cm) + i * sizeof(int), sizeof(int));
			if (!rpc_session_add_fd(&c->session, fd))
				log_debug("client %" PRIu64 " (%s): a descriptor past the %d held "
					  "closed", c->serial, c->session.peer.name,
					  RPC_SESSION_MAX_FDS);
		}
	}
	return n;
}

static void read_input(struct client *c)
{
	size_t budget = READ_BUDGET;

	while (budget > 0 && !client_dead(c) && !c->closing) {
		char *dst;
		ssize_t n;

		if (proto_lines_reserve(&c->in, READ_CHUNK, &dst) < 0) {
			server_client_drop(c, "out of memory");
			return;
		}
		n = receive(c, dst, READ_CHUNK);
		if (n < 0) {
			if (errno == EINTR)
				continue;
			if (errno != EAGAIN)
				server_client_drop(c, strerror(errno));
			break;
		}
		if (n == 0) {
			c->eof = true;
			break;
		}
		budget -= (size_t)n < budget ? (size_t)n : budget;
		proto_lines_commit(&c->in, (size_t)n);
		c->have_lines = true;
		/* A short read drained the socket: no second recv() just to
		 * hear EAGAIN (the loop calls again when more arrives). */
		if ((size_t)n < READ_CHUNK)
			break;
	}
	if (client_dead(c))
		return;
	if (c->eof && !c->have_lines && !c->line && proto_lines_pending(&c->in) > 0)
		c->partial_usec = c->partial_usec ? c->partial_usec : now_usec(c->srv);
	/* Nobody waits for a turn: this one is taken now (a turn is the
	 * same whether it starts here or from the turns' source). */
	if (!turns_waiting(c->srv->turns) && work_pending(c) && !output_blocked(c)) {
		client_turn(c);
		return;
	}
	update_events(c);
}

static int client_io(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	struct client *c = data;

	if (c->waiting && (revents & (EPOLLHUP | EPOLLERR))) {
		server_client_drop(c, "hung up while its request was computed");
		return 0;
	}
	if (revents & EPOLLOUT)
		flush_output(c);
	if (!client_dead(c) && (revents & (EPOLLIN | EPOLLHUP | EPOLLERR)) &&
	    !c->line && !c->have_lines)
		read_input(c);
	return 0;
}

static int client_timer(sd_event_source *s, uint64_t usec, void *data)
{
	struct client *c = data;
	uint64_t at;
	enum deadline which = client_deadline(c, &at);

	if (at > now_usec(c->srv)) {
		arm_timer(c);
		return 0;
	}
	switch (which) {
	case DEADLINE_PARTIAL:
		server_send_error(c, PROTO_REQUEST_TIMEOUT, "an incomplete request waited too long");
		break;
	case DEADLINE_OUTPUT:
		log_info("client %" PRIu64 " (%s) does not read its output: dropped",
			 c->serial, c->session.peer.name);
		server_client_drop(c, "output not read");
		return 0;
	case DEADLINE_AUTH:
		server_send_error(c, PROTO_REQUEST_TIMEOUT, "no hello with the token in time "
			   "(limits.auth_timeout_ms)");
		break;
	case DEADLINE_IDLE:
		server_send_error(c, PROTO_REQUEST_TIMEOUT, "no request for limits.idle_timeout_ms");
		break;
	case DEADLINE_NONE:
		return 0;
	}
	if (!client_dead(c)) {
		c->closing = true;
		c->partial_usec = 0;
		update_events(c);
	}
	return 0;
}

/* ------------------------------------------------------------ accept */

/* A connection that cannot be taken gets the reason and is closed. */
static void refuse(struct server *srv, int fd, int code, const char *detail)
{
	_cleanup_(json_decrefp) json_t *e = proto_make_error(NULL, code, NULL,
		detail ? json_pack("{s:s}", "detail", detail) : NULL);
	_cleanup_free_ char *t = proto_dump(e, NULL);

	if (t && send(fd, t, strlen(t), MSG_NOSIGNAL | MSG_DONTWAIT) < 0)
		log_debug("refused client: %s", strerror(errno));
	close(fd);
}

static size_t connections_of(const struct server *srv, const char *key)
{
	size_t n = 0;

	for (const struct client *c = srv->clients; c; c = c->next)
		if (!strcmp(c->session.peer.key, key))
			n++;
	return n;
}

/* The TCP client that connected longest ago and has not sent its token:
 * a full listener closes it to make room, so that connections that never
 * authenticate cannot keep an operator's token out. NULL: none. */
static struct client *oldest_anonymous(struct server *srv)
{
	struct client *old = NULL;

	for (struct client *c = srv->clients; c; c = c->next)
		if (c->tcp && !c->session.authenticated && !c->closing && !client_dead(c) &&
		    (!old || c->connected_usec < old->connected_usec))
			old = c;
	return old;
}

/*
 * Why p may not connect now (into why), or false when it may. root has
 * SERVER_ROOT_CLIENTS connections of its own beyond limits.max_clients;
 * the last limits.reserved_clients are root's and the operators'; a TCP
 * peer, who it is unknown until its hello, may take them, and past
 * limits.max_clients the anonymous TCP client waiting longest makes room
 * (rpc.c refuses a viewer's token that would hold a reserved one).
 */
static bool refused(struct server *srv, const struct peer *p, char *why, size_t size)
{
	const struct settings_limits *l = srv->limits;
	size_t n = rpc_sessions(srv->rpc);
	struct client *old;

	if (!p->tcp && p->uid == 0) {
		if (n < (size_t)l->max_clients + SERVER_ROOT_CLIENTS)
			return false;
		snprintf(why, size, "%zu clients are connected, limits.max_clients and the %d "
			 "connections kept for root", n, SERVER_ROOT_CLIENTS);
		return true;
	}
	if (p->tcp && n >= l->max_clients && (old = oldest_anonymous(srv))) {
		server_send_error(old, PROTO_TOO_MANY_CLIENTS, "closed to make room: no hello with the "
			   "token came, and limits.max_clients are connected");
		server_client_drop(old, "made room for a new connection");
		n = rpc_sessions(srv->rpc);
	}
	if (n >= l->max_clients) {
		snprintf(why, size, "%zu clients are connected, limits.max_clients", n);
		return true;
	}
	if (!p->tcp && n + l->reserved_clients >= l->max_clients &&
	    !rpc_peer_operator(srv->rpc, p)) {
		snprintf(why, size, "the last %u of limits.max_clients (%u) are kept for root "
			 "and operators", l->reserved_clients, l->max_clients);
		return true;
	}
	n = connections_of(srv, p->key);
	if (!(!p->tcp && p->uid == 0) && n >= l->max_clients_per_user) {
		snprintf(why, size, "%s has %zu connections, limits.max_clients_per_user", p->key, n);
		return true;
	}
	return false;
}

/* At most one line of key's every 10 s, saying how many were left out. */
static void log_limited(struct server *srv, const char *key, const char *what)
{
	unsigned left_out = 0;

	if (!ratelimit_take(srv->log_limit, key, now_usec(srv), &left_out))
		return;
	if (left_out)
		log_warning("%s (and %u such message(s) left out)", what, left_out);
	else
		log_warning("%s", what);
}

static void pause_accepting(struct server *srv, bool pause)
{
	for (size_t i = 0; i < srv->n_listeners; i++)
		if (srv->listeners[i].src)
			sd_event_source_set_enabled(srv->listeners[i].src,
						    pause ? SD_EVENT_OFF : SD_EVENT_ON);
}

static int accept_resume(sd_event_source *s, uint64_t usec, void *data)
{
	pause_accepting(data, false);
	return 0;
}

/* The descriptor kept in reserve, taken again once one is free. */
static void keep_reserve(struct server *srv)
{
	if (srv->reserve_fd < 0)
		srv->reserve_fd = open("/dev/null", O_RDONLY | O_CLOEXEC);
}

/*
 * No descriptor left (EMFILE, ENFILE): the connection waiting would wake
 * the loop again at once, for ever. The descriptor kept in reserve is
 * given up to take it and tell it why, and accepting pauses a while.
 * (The descriptors' budget of the start, which counts root's own
 * connections and the web listener's, keeps clients from getting here.)
 */
static void out_of_descriptors(struct server *srv, int listen_fd, int err)
{
	char what[128];

	if (srv->reserve_fd >= 0) {
		close(srv->reserve_fd);
		srv->reserve_fd = -1;
		int fd = accept4(listen_fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
		if (fd >= 0)
			refuse(srv, fd, PROTO_TOO_MANY_CLIENTS,
			       "the daemon has no file descriptor left (LimitNOFILE=)");
		keep_reserve(srv);
	}
	srv->accept_backoff = srv->accept_backoff ? 2 * srv->accept_backoff
						  : ACCEPT_BACKOFF_MIN_USEC;
	if (srv->accept_backoff > ACCEPT_BACKOFF_MAX_USEC)
		srv->accept_backoff = ACCEPT_BACKOFF_MAX_USEC;
	pause_accepting(srv, true);
	sd_event_source_set_time(srv->accept_timer, now_usec(srv) + srv->accept_backoff);
	sd_event_source_set_enabled(srv->accept_timer, SD_EVENT_ONESHOT);
	snprintf(what, sizeof(what), "accept: %s: new connections wait %.2f s",
		 strerror(err), (double)srv->accept_backoff / 1e6);
	log_limited(srv, "accept", what);
}

/* A client for cfd and p (taking both, even when it fails). */
static struct client *client_new(struct server *srv, int cfd, bool tcp, struct peer *p)
{
	struct client *c = calloc(1, sizeof(*c));

	if (!c) {
		close(cfd);
		free(p->groups);
		return NULL;
	}
	c->srv = srv;
	c->fd = cfd;
	c->tcp = tcp;
	c->turn.run = client_turn;
	c->turn.data = c;
	c->serial = ++srv->next_serial;
	c->connected_usec = c->request_usec = now_usec(srv);
	proto_lines_init(&c->in, srv->limits->max_request_bytes);
	c->session.peer = *p;
	c->session.authenticated = !tcp;
	rpc_session_open(srv->rpc, &c->session);
	c->next = srv->clients;
	if (srv->clients)
		srv->clients->prev = c;
	srv->clients = c;
	if (sd_event_add_io(srv->event, &c->io, cfd, EPOLLIN, client_io, c) < 0 ||
	    sd_event_add_time(srv->event, &c->timer, CLOCK_MONOTONIC, UINT64_MAX, 0,
			      client_timer, c) < 0) {
		server_client_drop(c, "out of memory");
		return NULL;
	}
	arm_timer(c);
	return c;
}

int server_accept(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	const struct listener *l = data;
	struct server *srv = l->srv;
	struct peer p = { 0 };
	struct client *c;
	char why[160];
	int cfd;

	cfd = accept4(fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
	if (cfd < 0) {
		if (errno == EMFILE || errno == ENFILE) {
			out_of_descriptors(srv, fd, errno);
		} else if (errno != EAGAIN && errno != EINTR) {
			snprintf(why, sizeof(why), "accept: %s", strerror(errno));
			log_limited(srv, "accept", why);
		}
		return 0;
	}
	srv->accept_backoff = 0;
	if (srv->refusing) {
		refuse(srv, cfd, PROTO_SHUTTING_DOWN, NULL);
		return 0;
	}
	server_peer_identity(cfd, l->tcp, &p);
	if (refused(srv, &p, why, sizeof(why))) {
		char what[256];
		snprintf(what, sizeof(what), "refused a connection of %.63s: %.160s", p.name, why);
		log_limited(srv, p.key, what);
		free(p.groups);
		refuse(srv, cfd, PROTO_TOO_MANY_CLIENTS, why);
		return 0;
	}
	c = client_new(srv, cfd, l->tcp, &p);
	if (!c)
		return 0;
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
		if (c->line && rpc_line_open(c->line))
			hold_notification(c, msg);
		else
			client_send(c, msg);
	}
}

void server_revalidate(struct server *srv)
{
	struct client *c, *next;

	for (c = srv->clients; c; c = next) {
		next = c->next;
		if (client_dead(c) || rpc_session_valid(srv->rpc, &c->session))
			continue;
		log_info("client %" PRIu64 " (%s): its token was changed or removed: "
			 "disconnected", c->serial, c->session.peer.name);
		server_send_error(c, PROTO_PERMISSION_DENIED, "the token this connection sent was "
			   "changed or removed: connect again with the new one");
		if (!client_dead(c)) {
			c->closing = true;
			update_events(c);
		}
	}
}

void server_free(struct server *srv)
{
	if (!srv)
		return;
	free_list(srv->clients);
	free_list(srv->dead);
	sd_event_source_disable_unref(srv->reaper);
	sd_event_source_disable_unref(srv->accept_timer);
	for (size_t i = 0; i < srv->n_listeners; i++) {
		struct listener *l = &srv->listeners[i];
		sd_event_source_disable_unref(l->src);
		close(l->fd);
		if (!l->tcp && !l->activated && srv->socket_path)
			unlink(srv->socket_path);
	}
	if (srv->reserve_fd >= 0)
		close(srv->reserve_fd);
	ratelimit_free(srv->log_limit);
	free(srv->tcp_listen);
	free(srv->socket_path);
	free(srv);
}
