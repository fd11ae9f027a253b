/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The web listener (web.h). libmicrohttpd runs in its "external" mode:
 * no thread of its own; its epoll descriptor is watched by the event loop
 * and MHD_run() is called from there, so every handler below runs on the
 * event loop thread, the only one that may touch the jobs, the sessions
 * and the events.
 *
 * A request that takes more than a moment does not hold the loop: its
 * connection is suspended (MHD_suspend_connection) while the work goes
 * on, and resumed when there is something to send. A JSON-RPC line is
 * answered in turns (turns.h) shared with the socket's clients, its answer
 * streamed as it is made, no further step taken while half of
 * limits.max_output_bytes of it waits unsent; the live map's points are
 * read by a task (livemap.h); a Server-Sent Events stream with nothing to
 * send waits suspended until an event is queued for it.
 */
#include "config.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include <microhttpd.h>
#include <nettle/memops.h>

#include "asph-proto.h"
#include "livemap.h"
#include "log.h"
#include "runner.h"
#include "server.h"
#include "util-mem.h"
#include "util-time.h"
#include "web.h"

#define SESSION_COOKIE "asph_session"
/* A session not used for this long ends (the page polls while open). */
#define SESSION_IDLE_NS (12 * 3600 * (int64_t)1000000000)
/* The most addresses http_listen listens on. */
#define WEB_MAX_LISTENERS 16
/* libmicrohttpd's own ceiling on connections: the limits are ours
 * (on_accept()), read at each connection; this is the largest
 * limits.max_clients. */
#define MHD_CONNECTIONS_CEILING 65536
/* libmicrohttpd's memory for one connection's request head and its
 * buffers (its default). */
#define MHD_CONNECTION_MEMORY (32 * 1024)
/* How often the time limits of connections and sessions are looked at. */
#define SWEEP_USEC 1000000
/* The live map's reads of one owner at once. */
#define LIVEMAP_TASKS_PER_OWNER 2

/* Only the page's own origin: scripts, styles, images, connections. */
#define CSP "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; " \
	    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; " \
	    "frame-ancestors 'none'"

struct stream;
struct request;

struct session {
	struct session *next;
	char id[44];                    /* base64url of 32 random bytes */
	struct rpc_session rpc;
	int64_t last_used_ns;
	struct stream *stream;          /* the event stream, or NULL */
	struct request *requests;       /* its requests in flight */
};

/* One Server-Sent Events response: what is queued for it and not sent. */
struct stream {
	struct web *web;
	struct session *session;        /* NULL once the session ended */
	struct MHD_Connection *conn;
	bool suspended;
	bool overflow;                  /* more queued than max_output_bytes: ends */
	char *buf;
	size_t len, sent, size;
};

/* What a request is once its head and body are in. */
enum request_kind {
	REQUEST_PLAIN,                  /* answered at once */
	REQUEST_RPC,                    /* a JSON-RPC line, answered in turns */
	REQUEST_LOGIN,                  /* a hello, answered in turns */
	REQUEST_POINTS,                 /* the live map's points, read by a task */
	REQUEST_REFUSED,                /* a wrong token's 401, held back a while */
};

/*
 * One request, from its head to its end. libmicrohttpd holds it (its
 * con_cls) and so does a streamed answer's response: it goes when both
 * let it go. A request in flight for a session is on the session's list,
 * so that a session that ends ends its requests.
 */
struct request {
	struct web *web;
	struct MHD_Connection *conn;
	unsigned refs;
	char *body;
	size_t len;
	bool too_large;
	enum request_kind kind;
	bool suspended;                 /* waits for its work */
	bool responded;                 /* a response is queued */
	struct session *session;        /* in flight for it (NULL: none, or it ended) */
	struct request *next_in, *prev_in;
	struct request *next_all, *prev_all;    /* every suspended-capable one */
	/* REQUEST_RPC, REQUEST_LOGIN */
	struct rpc_line *line;
	struct turn turn;
	bool started;                   /* the line had a turn */
	bool waiting;                   /* the line waits for a computation */
	bool done;                      /* the line is answered (or abandoned) */
	bool failed;                    /* ... abandoned: the answer is cut off */
	char *out;                      /* made, not yet sent */
	size_t out_len, out_sent, out_cap;
	struct session *login;          /* REQUEST_LOGIN: the session it makes */
	bool https;                     /* through the trusted proxy, over TLS */
	/* REQUEST_REFUSED: the wait */
	sd_event_source *delay;
	/* REQUEST_POINTS */
	struct task *task;
	unsigned status;
	char *text;
};

/* One address of http_listen: a libmicrohttpd daemon of its own. */
struct listener {
	struct web *web;
	struct MHD_Daemon *mhd;
	sd_event_source *io;
};

/* One open connection, from libmicrohttpd's connection notice to its
 * close: what the limits count. */
struct conn {
	struct conn *next, *prev;
	char key[RATELIMIT_KEY_MAX];    /* the peer's address (an IPv6 one by its /64) */
	int fd;
	bool proxy;                     /* the peer is http_trust_proxy */
	bool in_request;                /* a request's head came, its answer is not done */
	bool body_done;                 /* ... and its body */
	bool displaced;                 /* shut down to make room, not yet gone */
	uint64_t since_usec;            /* of the head it waits for, or of the request */
};

struct web {
	sd_event *event;
	struct rpc *rpc;
	struct jobs *jobs;
	struct turns *turns;
	struct tasks *tasks;
	struct monitor *monitor;
	const struct settings_limits *limits;
	char *state_dir;
	struct listener listeners[WEB_MAX_LISTENERS];
	size_t n_listeners;
	sd_event_source *timer;
	sd_event_source *sweep;
	int root_fd;
	unsigned port;
	char **allowed_hosts;           /* NULL-terminated */
	struct sockaddr_storage proxy;  /* http_trust_proxy (AF_UNSPEC: none) */
	struct conn *conns;
	size_t n_conns, n_displaced;
	int64_t refused_logged_ns;      /* the last refusal logged (one a second) */
	struct session *sessions;
	size_t n_sessions;
	struct request *requests;       /* those that may be suspended */
	/* The surface of the job whose points were asked for last: the live
	 * map asks twice a second, and a surface's tables take time to build. */
	struct livemap_surface *surface;
};

/* ------------------------------------------------------- the event loop */

/* Arms the timer for the nearest of the listeners' next timeouts (0:
 * work is waiting). */
static void rearm(struct web *w)
{
	MHD_UNSIGNED_LONG_LONG ms, nearest = ULLONG_MAX;
	uint64_t now;

	for (size_t i = 0; i < w->n_listeners; i++)
		if (MHD_get_timeout(w->listeners[i].mhd, &ms) == MHD_YES && ms < nearest)
			nearest = ms;
	if (nearest == ULLONG_MAX) {
		sd_event_source_set_enabled(w->timer, SD_EVENT_OFF);
		return;
	}
	sd_event_now(w->event, CLOCK_MONOTONIC, &now);
	sd_event_source_set_time(w->timer, nearest ? now + nearest * 1000 : 1);
	sd_event_source_set_enabled(w->timer, SD_EVENT_ONESHOT);
}

/* Runs libmicrohttpd at the next turn of the loop: a resumed connection
 * is taken up by MHD_run(), which its epoll descriptor may not ask for. */
static void kick(struct web *w)
{
	sd_event_source_set_time(w->timer, 1);
	sd_event_source_set_enabled(w->timer, SD_EVENT_ONESHOT);
}

static int on_io(sd_event_source *s, int fd, uint32_t revents, void *data)
{
	struct listener *l = data;

	MHD_run(l->mhd);
	rearm(l->web);
	return 0;
}

/* A timeout, or a resumed stream: every listener has its turn. */
static int on_timer(sd_event_source *s, uint64_t usec, void *data)
{
	struct web *w = data;

	for (size_t i = 0; i < w->n_listeners; i++)
		MHD_run(w->listeners[i].mhd);
	rearm(w);
	return 0;
}

/* ---------------------------------------------------------- responses */

static void secure_headers(struct MHD_Response *r)
{
	MHD_add_response_header(r, "Content-Security-Policy", CSP);
	MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
	MHD_add_response_header(r, "X-Frame-Options", "DENY");
	MHD_add_response_header(r, "Referrer-Policy", "no-referrer");
}

static enum MHD_Result send_text(struct MHD_Connection *c, unsigned status, const char *type,
				 const char *text, size_t len, const char *cookie)
{
	struct MHD_Response *r;
	enum MHD_Result ret;

	r = MHD_create_response_from_buffer(len, (void *)text, MHD_RESPMEM_MUST_COPY);
	if (!r)
		return MHD_NO;
	secure_headers(r);
	MHD_add_response_header(r, "Content-Type", type);
	MHD_add_response_header(r, "Cache-Control", "no-store");
	if (cookie)
		MHD_add_response_header(r, "Set-Cookie", cookie);
	ret = MHD_queue_response(c, status, r);
	MHD_destroy_response(r);
	return ret;
}

static enum MHD_Result send_json(struct MHD_Connection *c, unsigned status, json_t *v,
				 const char *cookie)
{
	_cleanup_free_ char *text = json_dumps(v, JSON_COMPACT);

	json_decref(v);
	if (!text)
		return MHD_NO;
	return send_text(c, status, "application/json", text, strlen(text), cookie);
}

/* {"error": why} with status. */
static enum MHD_Result __attribute__((format(printf, 3, 4)))
send_error(struct MHD_Connection *c, unsigned status, const char *fmt, ...)
{
	char why[512];
	va_list ap;

	va_start(ap, fmt);
	vsnprintf(why, sizeof(why), fmt, ap);
	va_end(ap);
	return send_json(c, status, json_pack("{s:s}", "error", why), NULL);
}

static enum MHD_Result send_fd(struct MHD_Connection *c, int fd, const char *type,
			       const char *download)
{
	struct MHD_Response *r;
	enum MHD_Result ret;
	struct stat st;
	char disposition[320];

	if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode)) {
		close(fd);
		return send_error(c, MHD_HTTP_NOT_FOUND, "not a file");
	}
	r = MHD_create_response_from_fd((uint64_t)st.st_size, fd);
	if (!r) {
		close(fd);
		return MHD_NO;
	}
	secure_headers(r);
	MHD_add_response_header(r, "Content-Type", type);
	if (download) {
		snprintf(disposition, sizeof(disposition), "attachment; filename=\"%s\"", download);
		MHD_add_response_header(r, "Content-Disposition", disposition);
		MHD_add_response_header(r, "Cache-Control", "no-store");
	} else
		MHD_add_response_header(r, "Cache-Control", "no-cache");
	ret = MHD_queue_response(c, MHD_HTTP_OK, r);
	MHD_destroy_response(r);
	return ret;
}

/* ------------------------------------------------------------ requests */

static void request_unref(struct request *req);

/* The request's connection is taken up again at the next turn of the loop. */
static void request_resume(struct request *req)
{
	if (!req->suspended)
		return;
	req->suspended = false;
	MHD_resume_connection(req->conn);
	kick(req->web);
}

static void request_suspend(struct request *req)
{
	if (req->suspended)
		return;
	req->suspended = true;
	MHD_suspend_connection(req->conn);
}

/* Whether the request's answer has as much waiting unsent as it may. */
static bool request_full(const struct request *req)
{
	return req->out_len - req->out_sent >= req->web->limits->max_output_bytes / 2;
}

/* Queues the turn of a line that can go on. */
static void request_more(struct request *req)
{
	if (req->line && !req->done && !req->waiting && !request_full(req))
		turns_queue(req->web->turns, &req->turn, !req->started);
}

/* The request's work ends: its line (a computation it waits for is
 * cancelled), its task, its place on its session's list. */
static void request_end_work(struct request *req)
{
	struct session *s = req->session;

	turns_remove(req->web->turns, &req->turn);
	rpc_line_free(req->line);
	req->line = NULL;
	if (req->task)
		tasks_cancel(req->web->tasks, req->task);
	req->task = NULL;
	req->delay = sd_event_source_disable_unref(req->delay);
	if (s) {
		if (req->prev_in)
			req->prev_in->next_in = req->next_in;
		else
			s->requests = req->next_in;
		if (req->next_in)
			req->next_in->prev_in = req->prev_in;
		req->next_in = req->prev_in = NULL;
		req->session = NULL;
	}
}

/* The request works for s until it is answered. */
static void request_attach(struct request *req, struct session *s)
{
	req->session = s;
	req->next_in = s->requests;
	req->prev_in = NULL;
	if (s->requests)
		s->requests->prev_in = req;
	s->requests = req;
}

static void session_release(struct web *w, struct session *s);

static void request_unref(struct request *req)
{
	struct web *w = req->web;

	if (--req->refs)
		return;
	request_end_work(req);
	if (req->prev_all)
		req->prev_all->next_all = req->next_all;
	else if (w->requests == req)
		w->requests = req->next_all;
	if (req->next_all)
		req->next_all->prev_all = req->prev_all;
	if (req->login)
		session_release(w, req->login);
	free(req->body);
	free(req->out);
	free(req->text);
	free(req);
}

/* ----------------------------------------------------------- sessions */

static void stream_wake(struct stream *st)
{
	if (st->suspended) {
		st->suspended = false;
		MHD_resume_connection(st->conn);
		kick(st->web);
	}
}

/* A session's memory, once nothing uses it (its rpc_session closed). */
static void session_release(struct web *w, struct session *s)
{
	rpc_session_close(w->rpc, &s->rpc);
	free(s);
}

static void session_free(struct web *w, struct session *s)
{
	struct session **p;

	for (p = &w->sessions; *p; p = &(*p)->next)
		if (*p == s) {
			*p = s->next;
			break;
		}
	w->n_sessions--;
	if (s->stream) {
		s->stream->session = NULL;
		stream_wake(s->stream);
	}
	/* Its requests in flight end; what they sent is cut off. */
	while (s->requests) {
		struct request *req = s->requests;
		request_end_work(req);
		req->done = req->failed = true;
		request_resume(req);
	}
	session_release(w, s);
}

/* Whether s ends now (now_ns realtime, now_usec monotonic): unused for
 * 12 hours; unused for limits.idle_timeout_ms with no stream and no
 * request open (a page that went away, its subscription with it); its
 * token revoked, expired or changed. */
static const char *session_over(const struct web *w, const struct session *s, int64_t now)
{
	uint32_t idle_ms = w->limits->idle_timeout_ms;

	if (!rpc_session_valid(w->rpc, &s->rpc))
		return "its token was revoked, expired or changed";
	if (now - s->last_used_ns > SESSION_IDLE_NS)
		return "unused for 12 hours";
	if (idle_ms && !s->stream && !s->requests &&
	    now - s->last_used_ns > (int64_t)idle_ms * 1000000)
		return "unused and without an event stream for limits.idle_timeout_ms";
	return NULL;
}

static void expire_sessions(struct web *w)
{
	int64_t now = now_realtime_ns();
	struct session *s, *next;
	const char *why;

	for (s = w->sessions; s; s = next) {
		next = s->next;
		if ((why = session_over(w, s, now))) {
			log_info("web session of %s (%s) ended: %s", s->rpc.peer.name,
				 s->rpc.grant.credential, why);
			session_free(w, s);
		}
	}
}

static struct session *find_session(struct web *w, struct MHD_Connection *c)
{
	const char *id = MHD_lookup_connection_value(c, MHD_COOKIE_KIND, SESSION_COOKIE);
	struct session *s;

	if (!id)
		return NULL;
	expire_sessions(w);
	if (strlen(id) != sizeof(s->id) - 1)
		return NULL;
	for (s = w->sessions; s; s = s->next) {
		/* compared in full: the time says nothing of where they differ */
		if (memeql_sec(id, s->id, sizeof(s->id) - 1)) {
			s->last_used_ns = now_realtime_ns();
			return s;
		}
	}
	return NULL;
}

void web_revalidate(struct web *w)
{
	expire_sessions(w);
}

/* ------------------------------------------------------------- peers */

/* The connection's own record (on_connection()). */
static struct conn *conn_of(struct MHD_Connection *c)
{
	const union MHD_ConnectionInfo *info =
		MHD_get_connection_info(c, MHD_CONNECTION_INFO_SOCKET_CONTEXT);

	return info ? info->socket_context : NULL;
}

/* The last address of an X-Forwarded-For list, the one the proxy itself
 * added, into sa; false when it is none. */
static bool forwarded_address(const char *list, struct sockaddr_storage *sa)
{
	const char *last = strrchr(list, ',');
	char text[INET6_ADDRSTRLEN + 1];
	size_t n;

	last = last ? last + 1 : list;
	last += strspn(last, " \t");
	n = strcspn(last, " \t");
	if (n == 0 || n >= sizeof(text))
		return false;
	memcpy(text, last, n);
	text[n] = '\0';
	memset(sa, 0, sizeof(*sa));
	if (inet_pton(AF_INET, text, &((struct sockaddr_in *)sa)->sin_addr) == 1) {
		sa->ss_family = AF_INET;
		return true;
	}
	if (inet_pton(AF_INET6, text, &((struct sockaddr_in6 *)sa)->sin6_addr) == 1) {
		sa->ss_family = AF_INET6;
		return true;
	}
	return false;
}

/* Who sent the request: the connection's peer, or through the trusted
 * proxy the browser's address it forwards ("http ADDRESS" in the log, the
 * key the address's). *https: the proxy says the browser came over TLS. */
static void request_peer(struct MHD_Connection *c, struct peer *p, bool *https)
{
	const union MHD_ConnectionInfo *info =
		MHD_get_connection_info(c, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
	const struct conn *conn = conn_of(c);
	const char *fwd = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "X-Forwarded-For");
	const char *proto = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "X-Forwarded-Proto");
	struct sockaddr_storage sa;

	memset(p, 0, sizeof(*p));
	p->tcp = true;
	*https = conn && conn->proxy && proto && !strcasecmp(proto, "https");
	if (conn && conn->proxy && fwd && forwarded_address(fwd, &sa))
		server_addr_peer((const struct sockaddr *)&sa, p);
	else if (info && info->client_addr)
		server_addr_peer(info->client_addr, p);
	else
		server_addr_peer((const struct sockaddr *)&(struct sockaddr_storage){ 0 }, p);
	memmove(p->name + 1, p->name, sizeof(p->name) - 1);
	p->name[sizeof(p->name) - 1] = '\0';
	memcpy(p->name, "http", 4);
}

/* ------------------------------------------------------------- the RPC */

static int request_write(const char *text, size_t len, void *data)
{
	struct request *req = data;

	if (req->out_sent == req->out_len)
		req->out_sent = req->out_len = 0;
	if (req->out_len + len > req->out_cap) {
		size_t cap = req->out_cap ? req->out_cap : 4096;
		while (cap < req->out_len + len)
			cap *= 2;
		char *p = realloc(req->out, cap);
		if (!p)
			return -1;
		req->out = p;
		req->out_cap = cap;
	}
	memcpy(req->out + req->out_len, text, len);
	req->out_len += len;
	return 0;
}

/* A computation the line waited for is done: its turn again. */
static void request_ready(void *data)
{
	struct request *req = data;

	req->waiting = false;
	request_more(req);
}

/* One turn (turns.h): the line's steps for about TURN_SLICE_USEC, or until
 * half of max_output_bytes waits unsent. */
static void request_turn(void *data)
{
	struct request *req = data;
	uint64_t start = turns_now_usec();
	int n = 0, r;

	req->started = true;
	while (req->line && !req->waiting && !request_full(req) && n++ < TURN_SLICE_STEPS) {
		r = rpc_line_step(req->line, request_write, req);
		if (r == RPC_LINE_WAITING) {
			req->waiting = true;
		} else if (r <= 0) {
			req->done = true;
			req->failed = r < 0;
			rpc_line_free(req->line);
			req->line = NULL;
		}
		if (turns_now_usec() - start > TURN_SLICE_USEC)
			break;
	}
	if (req->done && req->kind == REQUEST_RPC)
		request_end_work(req);
	request_more(req);
	if (req->done || req->out_len > req->out_sent)
		request_resume(req);
}

/* The line's answer as libmicrohttpd sends it: what is made, and a wait
 * (suspended) while more is being made. */
static ssize_t request_read(void *cls, uint64_t pos, char *buf, size_t max)
{
	struct request *req = cls;
	size_t n = req->out_len - req->out_sent;

	if (!n) {
		if (req->done)
			return req->failed ? MHD_CONTENT_READER_END_WITH_ERROR
					   : MHD_CONTENT_READER_END_OF_STREAM;
		request_suspend(req);
		request_more(req);
		return 0;
	}
	n = n < max ? n : max;
	memcpy(buf, req->out + req->out_sent, n);
	req->out_sent += n;
	request_more(req);
	return (ssize_t)n;
}

static void request_read_free(void *cls)
{
	request_unref(cls);
}

/* A line's request, taken up again: its answer, streamed (200) or none
 * (204, notifications only). */
static enum MHD_Result rpc_respond(struct request *req)
{
	struct MHD_Response *r;
	enum MHD_Result ret;

	if (req->done && req->failed && !req->out_len)
		return send_error(req->conn, MHD_HTTP_GONE, "the session ended");
	if (req->done && !req->out_len)
		return send_text(req->conn, MHD_HTTP_NO_CONTENT, "application/json", "", 0, NULL);
	r = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 16384, request_read, req,
					      request_read_free);
	if (!r)
		return MHD_NO;
	req->refs++;
	secure_headers(r);
	MHD_add_response_header(r, "Content-Type", "application/json");
	MHD_add_response_header(r, "Cache-Control", "no-store");
	ret = MHD_queue_response(req->conn, MHD_HTTP_OK, r);
	MHD_destroy_response(r);
	return ret;
}

/* Starts answering text as a line of s (for its session, or a login):
 * the connection waits until there is something to send. */
static enum MHD_Result start_line(struct request *req, struct rpc_session *s, const char *text,
				  size_t len)
{
	if (rpc_line_new(req->web->rpc, s, text, len, &req->line) < 0)
		return send_error(req->conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
	rpc_line_on_ready(req->line, request_ready, req);
	req->turn.run = request_turn;
	req->turn.data = req;
	request_more(req);
	request_suspend(req);
	return MHD_YES;
}

static enum MHD_Result route_rpc(struct web *w, struct request *req, struct session *s)
{
	req->kind = REQUEST_RPC;
	request_attach(req, s);
	return start_line(req, &s->rpc, req->body ? req->body : "", req->len);
}

/* ------------------------------------------------------------- login */

static int new_session_id(char id[44])
{
	uint8_t bytes[32];
	_cleanup_free_ char *b64 = NULL;

	if (getrandom(bytes, sizeof(bytes), 0) != sizeof(bytes))
		return -errno;
	b64 = proto_base64url_encode(bytes, sizeof(bytes));
	if (!b64)
		return -ENOMEM;
	snprintf(id, 44, "%s", b64);
	return 0;
}

json_t *web_login_token(const char *body, size_t len, json_t **doc)
{
	json_t *token;

	*doc = body ? json_loadb(body, len, JSON_REJECT_DUPLICATES, NULL) : NULL;
	token = json_object_get(*doc, "token");
	if (!json_is_string(token) || json_object_size(*doc) != 1)
		return NULL;
	return token;
}

static enum MHD_Result route_login(struct web *w, struct request *req)
{
	_cleanup_(json_decrefp) json_t *body = NULL, *hello = NULL;
	_cleanup_free_ char *line = NULL;
	struct session *s;
	json_t *token;

	token = web_login_token(req->body, req->len, &body);
	if (!token)
		return send_error(req->conn, MHD_HTTP_BAD_REQUEST, "the body must be {\"token\": TOKEN}");
	s = calloc(1, sizeof(*s));
	if (!s || new_session_id(s->id) < 0) {
		free(s);
		return send_error(req->conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "no memory");
	}
	request_peer(req->conn, &s->rpc.peer, &req->https);
	req->kind = REQUEST_LOGIN;
	req->login = s;
	/* The same hello as over TCP: its checks, its pace on wrong tokens
	 * and its log. The session counts once it is admitted. */
	hello = json_pack("{s:s, s:i, s:s, s:{s:O, s:s}}", "jsonrpc", "2.0", "id", 1, "method",
			  "hello", "params", "token", token, "client", "web");
	line = hello ? json_dumps(hello, JSON_COMPACT) : NULL;
	if (!line)
		return send_error(req->conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "no memory");
	return start_line(req, &s->rpc, line, strlen(line));
}

static size_t sessions_where(const struct web *w, bool (*same)(const struct session *,
							       const struct session *),
			     const struct session *like)
{
	size_t n = 0;

	for (const struct session *s = w->sessions; s; s = s->next)
		n += same(s, like);
	return n;
}

static bool same_token(const struct session *a, const struct session *b)
{
	return !strcmp(a->rpc.grant.credential, b->rpc.grant.credential);
}

static bool same_address(const struct session *a, const struct session *b)
{
	return !strcmp(a->rpc.peer.key, b->rpc.peer.key);
}

/* The token's session used longest ago. */
static struct session *oldest_of_token(struct web *w, const struct session *like)
{
	struct session *old = NULL;

	for (struct session *s = w->sessions; s; s = s->next)
		if (same_token(s, like) && (!old || s->last_used_ns < old->last_used_ns))
			old = s;
	return old;
}

/*
 * Whether s may open (why not into why): limits.max_clients sessions and
 * connections in all, the last limits.reserved_clients of them for
 * operators and admins, limits.max_clients_per_user of one address. A
 * token at limits.max_clients_per_user gives up its session used longest
 * ago, so that a user never locks itself out and one token holds no more.
 */
static bool session_refused(struct web *w, const struct session *s, char *why, size_t size)
{
	const struct settings_limits *l = w->limits;
	bool operator = s->rpc.grant.role >= ROLE_OPERATOR;
	size_t n = rpc_sessions(w->rpc);

	if (n >= l->max_clients) {
		snprintf(why, size, "%zu clients are connected (limits.max_clients): log out elsewhere",
			 n);
		return true;
	}
	if (!operator && n + l->reserved_clients >= l->max_clients) {
		snprintf(why, size, "the last %u of limits.max_clients (%u) are kept for operators "
			 "and admins", l->reserved_clients, l->max_clients);
		return true;
	}
	if (sessions_where(w, same_address, s) >= l->max_clients_per_user) {
		snprintf(why, size, "%s has %u sessions (limits.max_clients_per_user)",
			 s->rpc.peer.key, l->max_clients_per_user);
		return true;
	}
	while (sessions_where(w, same_token, s) >= l->max_clients_per_user) {
		struct session *old = oldest_of_token(w, s);
		log_info("web session of %s (%s) ended: the token has limits.max_clients_per_user "
			 "sessions and logged in again", old->rpc.peer.name, old->rpc.grant.credential);
		session_free(w, old);
	}
	return false;
}

/* The hello is answered: the session opens with its cookie, or the login
 * is refused with the reason. */
static enum MHD_Result login_respond(struct web *w, struct request *req)
{
	_cleanup_(json_decrefp) json_t *answer = NULL;
	struct session *s = req->login;
	json_t *err;
	char cookie[192], why[256];

	answer = req->out_len ? json_loadb(req->out, req->out_len, 0, NULL) : NULL;
	err = json_object_get(answer, "error");
	if (!answer || err || !s->rpc.authenticated) {
		json_t *detail = json_object_get(json_object_get(err, "data"), "detail");
		const char *text = json_string_value(detail ? detail : json_object_get(err, "message"));
		return send_error(req->conn, MHD_HTTP_UNAUTHORIZED, "%s",
				  text ? text : "not authenticated");
	}
	if (session_refused(w, s, why, sizeof(why))) {
		log_notice("web login of %s with %s refused: %s", s->rpc.peer.name,
			   s->rpc.grant.credential, why);
		return send_error(req->conn, MHD_HTTP_SERVICE_UNAVAILABLE, "%s", why);
	}
	req->login = NULL;
	s->last_used_ns = now_realtime_ns();
	rpc_session_open(w->rpc, &s->rpc);
	s->next = w->sessions;
	w->sessions = s;
	w->n_sessions++;
	snprintf(cookie, sizeof(cookie), SESSION_COOKIE "=%s; Path=/; HttpOnly; SameSite=Strict%s",
		 s->id, req->https ? "; Secure" : "");
	return send_json(req->conn, MHD_HTTP_OK, json_pack("{s:s, s:s}", "role",
			 access_role_name(s->rpc.grant.role), "token", s->rpc.grant.credential),
			 cookie);
}

static enum MHD_Result route_logout(struct web *w, struct MHD_Connection *c, struct session *s)
{
	session_free(w, s);
	return send_text(c, MHD_HTTP_NO_CONTENT, "application/json", "", 0,
			 SESSION_COOKIE "=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0");
}

/* ------------------------------------------------------------ events */

static void stream_queue(struct stream *st, const char *text, size_t len)
{
	size_t need;

	if (st->overflow)
		return;
	if (st->sent == st->len)
		st->sent = st->len = 0;
	need = st->len + len;
	if (need - st->sent > st->web->limits->max_output_bytes) {
		/* Like a socket client that does not read: the stream ends, the
		 * page reconnects and reads the state afresh. */
		st->overflow = true;
		stream_wake(st);
		return;
	}
	if (need > st->size) {
		char *p = realloc(st->buf, need * 2);
		if (!p) {
			st->overflow = true;
			stream_wake(st);
			return;
		}
		st->buf = p;
		st->size = need * 2;
	}
	memcpy(st->buf + st->len, text, len);
	st->len += len;
	stream_wake(st);
}

void web_notify(const struct event *ev, void *data)
{
	struct web *w = data;
	_cleanup_(json_decrefp) json_t *msg = NULL;
	_cleanup_free_ char *text = NULL, *frame = NULL;
	int n = 0;

	for (struct session *s = w->sessions; s; s = s->next) {
		if (!s->stream || !events_subscription_matches(&s->rpc.events, ev))
			continue;
		if (!frame) {
			msg = proto_make_notification(ev->method, json_incref(ev->params));
			text = msg ? json_dumps(msg, JSON_COMPACT) : NULL;
			n = text ? asprintf(&frame, "data: %s\n\n", text) : -1;
			if (n < 0) {
				frame = NULL;
				return;
			}
		}
		stream_queue(s->stream, frame, (size_t)n);
	}
}

static ssize_t stream_read(void *cls, uint64_t pos, char *buf, size_t max)
{
	struct stream *st = cls;
	size_t n;

	if (!st->session)
		return MHD_CONTENT_READER_END_OF_STREAM;
	if (st->overflow)
		return MHD_CONTENT_READER_END_WITH_ERROR;
	if (st->sent == st->len) {
		st->suspended = true;
		MHD_suspend_connection(st->conn);
		return 0;
	}
	n = st->len - st->sent < max ? st->len - st->sent : max;
	memcpy(buf, st->buf + st->sent, n);
	st->sent += n;
	return (ssize_t)n;
}

static void stream_free(void *cls)
{
	struct stream *st = cls;

	if (st->session)
		st->session->stream = NULL;
	free(st->buf);
	free(st);
}

static enum MHD_Result route_events(struct web *w, struct MHD_Connection *c, struct session *s)
{
	struct MHD_Response *r;
	struct stream *st;
	enum MHD_Result ret;

	if (s->stream) {        /* one stream per session: the newest */
		s->stream->session = NULL;
		stream_wake(s->stream);
		s->stream = NULL;
	}
	st = calloc(1, sizeof(*st));
	if (!st)
		return MHD_NO;
	*st = (struct stream){ .web = w, .session = s, .conn = c };
	r = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 16384, stream_read, st,
					      stream_free);
	if (!r) {
		free(st);
		return MHD_NO;
	}
	s->stream = st;
	/* A first comment, so that the page knows the stream is open. */
	stream_queue(st, ": asphd\n\n", 9);
	secure_headers(r);
	MHD_add_response_header(r, "Content-Type", "text/event-stream");
	MHD_add_response_header(r, "Cache-Control", "no-store");
	MHD_add_response_header(r, "X-Accel-Buffering", "no");
	ret = MHD_queue_response(c, MHD_HTTP_OK, r);
	MHD_destroy_response(r);
	return ret;
}

/* --------------------------------------------------------------- files */

static const char *content_type(const char *name)
{
	static const char *const types[][2] = {
		{ ".html", "text/html; charset=utf-8" }, { ".js", "text/javascript" },
		{ ".css", "text/css" }, { ".svg", "image/svg+xml" }, { ".png", "image/png" },
		{ ".csv", "text/csv" }, { ".json", "application/json" },
		{ ".pdf", "application/pdf" }, { ".txt", "text/plain; charset=utf-8" },
	};
	const char *dot = strrchr(name, '.');

	for (size_t i = 0; dot && i < sizeof(types) / sizeof(types[0]); i++)
		if (!strcmp(dot, types[i][0]))
			return types[i][1];
	return NULL;
}

bool web_plain_name(const char *name)
{
	if (!name[0] || name[0] == '.' || strlen(name) > 128)
		return false;
	return strspn(name, "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-") ==
	       strlen(name);
}

/* One of the page's files compiled in (no copy: they live as long as
 * the program). */
static enum MHD_Result send_builtin(struct MHD_Connection *c, const struct embedded_file *f,
				   const char *type)
{
	struct MHD_Response *r;
	enum MHD_Result ret;

	r = MHD_create_response_from_buffer(f->size, (void *)f->data, MHD_RESPMEM_PERSISTENT);
	if (!r)
		return MHD_NO;
	secure_headers(r);
	MHD_add_response_header(r, "Content-Type", type);
	MHD_add_response_header(r, "Cache-Control", "no-cache");
	ret = MHD_queue_response(c, MHD_HTTP_OK, r);
	MHD_destroy_response(r);
	return ret;
}

/* The page's files: http_root's when it is set, else the built-in ones. */
static enum MHD_Result route_static(struct web *w, struct MHD_Connection *c, const char *url)
{
	const char *name = strcmp(url, "/") ? url + 1 : "index.html";
	const char *type = content_type(name);
	const struct embedded_file *f;
	int fd;

	if (!web_plain_name(name) || !type)
		return send_error(c, MHD_HTTP_NOT_FOUND, "no such page: %s", url);
	if (w->root_fd < 0) {
		f = embedded_file_find(web_builtin_files, web_builtin_files_count, name);
		if (!f)
			return send_error(c, MHD_HTTP_NOT_FOUND, "no such page: %s", url);
		return send_builtin(c, f, type);
	}
	fd = openat(w->root_fd, name, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
	if (fd < 0)
		return send_error(c, MHD_HTTP_NOT_FOUND, "no such page: %s", url);
	return send_fd(c, fd, type, NULL);
}

bool web_parse_count(const char *text, size_t len, int64_t *out)
{
	int64_t v = 0;

	if (len == 0 || len > 18 || text[0] == '0')
		return false;
	for (size_t i = 0; i < len; i++) {
		if (text[i] < '0' || text[i] > '9')
			return false;
		v = v * 10 + (text[i] - '0');
	}
	*out = v;
	return true;
}

static enum MHD_Result route_file(struct web *w, struct MHD_Connection *c, int64_t id,
				  const char *name)
{
	struct asph_error err;
	char download[300];
	const char *type;
	int fd, r;

	asph_error_clear(&err);
	if (!web_plain_name(name))
		return send_error(c, MHD_HTTP_NOT_FOUND, "no such file: %s", name);
	r = jobs_result_file(w->jobs, id, name, &fd, &err);
	if (r < 0)
		return send_error(c, r == -ENOMEM ? MHD_HTTP_INTERNAL_SERVER_ERROR : MHD_HTTP_NOT_FOUND,
				  "%s", err.message[0] ? err.message : strerror(-r));
	type = content_type(name);
	snprintf(download, sizeof(download), "job%" PRId64 "-%s", id, name);
	return send_fd(c, fd, type ? type : "application/octet-stream", download);
}

/* ------------------------------------------------------------- points */

/* A task's done(): the points read, or the deadline passed. The surface
 * built is kept for the next answer. */
static void points_done(void *work, int r, void *data)
{
	struct livemap_read *rd = work;
	struct request *req = data;
	struct web *w = req->web;

	req->task = NULL;
	if (r == -ETIMEDOUT) {  /* (its thread still has rd) */
		_cleanup_(json_decrefp) json_t *e = json_pack("{s:s}", "error", "reading the scan "
							      "took longer than limits.request_timeout_ms");
		req->status = MHD_HTTP_SERVICE_UNAVAILABLE;
		req->text = e ? json_dumps(e, JSON_COMPACT) : NULL;
	} else {
		req->status = rd->status;
		req->text = steal_ptr(rd->text);
		if (rd->built && livemap_surface_job(rd->built) != livemap_surface_job(w->surface)) {
			if (rd->warning[0])
				log_job(LOG_WARNING, rd->job, "%s", rd->warning);
			livemap_surface_unref(w->surface);
			w->surface = steal_ptr(rd->built);
		}
	}
	request_end_work(req);
	request_resume(req);
}

/* The points measured so far from the from-th on (the live map), read by
 * a task: the connection waits meanwhile. */
static enum MHD_Result route_points(struct web *w, struct request *req, struct session *s,
				    int64_t id)
{
	const char *arg = MHD_lookup_connection_value(req->conn, MHD_GET_ARGUMENT_KIND, "from");
	struct livemap_read *rd = NULL;
	_cleanup_free_ char *path = NULL;
	int64_t from = 0;
	int r;

	if (arg && strcmp(arg, "0") && !web_parse_count(arg, strlen(arg), &from))
		return send_error(req->conn, MHD_HTTP_BAD_REQUEST, "from must be a count of points");
	if (asprintf(&path, "%s/jobs/%" PRId64 "/" RUNNER_SCAN_FILE, w->state_dir, id) < 0) {
		path = NULL;
		return MHD_NO;
	}
	if (livemap_read_new(path, id, from, livemap_surface_job(w->surface) == id ? w->surface
				: NULL, &rd) < 0)
		return MHD_NO;
	req->kind = REQUEST_POINTS;
	request_attach(req, s);
	r = tasks_submit(w->tasks, &(struct task_spec){
		.owner = s->rpc.owner, .max_per_owner = LIVEMAP_TASKS_PER_OWNER,
		.deadline_usec = turns_now_usec() + (uint64_t)w->limits->request_timeout_ms * 1000,
		.run = livemap_read_run, .done = points_done, .free = livemap_read_free,
		.work = rd, .data = req }, &req->task);
	if (r == -EDQUOT || r == -EAGAIN)
		return send_error(req->conn, MHD_HTTP_TOO_MANY_REQUESTS, "%s: wait for the "
				  "answers before", r == -EDQUOT ? "this session's user reads "
				  "points already" : "too many reads of points wait");
	if (r < 0)
		return MHD_NO;
	request_suspend(req);
	return MHD_YES;
}

int web_job_route(const char *path, int64_t *id, const char **rest)
{
	const char *slash = strchr(path, '/');

	if (!slash || !web_parse_count(path, (size_t)(slash - path), id) || *id == 0)
		return -ENOENT;
	*rest = slash;
	return 0;
}

static enum MHD_Result route_job(struct web *w, struct request *req, struct session *s,
				 const char *path)
{
	const char *rest;
	int64_t id;

	if (web_job_route(path, &id, &rest) < 0)
		return send_error(req->conn, MHD_HTTP_NOT_FOUND, "no such job");
	if (!strcmp(rest, "/points"))
		return route_points(w, req, s, id);
	if (!strncmp(rest, "/files/", 7))
		return route_file(w, req->conn, id, rest + 7);
	return send_error(req->conn, MHD_HTTP_NOT_FOUND, "no such route");
}

/* ---------------------------------------------------------- monitoring */

/* GET /healthz: "ok" (200) or "degraded" (503), to anyone, and nothing
 * more; the reasons are daemon.health's, for those who may read them. */
static enum MHD_Result route_healthz(struct web *w, struct MHD_Connection *c)
{
	_cleanup_(json_decrefp) json_t *reasons = monitor_health(w->monitor);
	bool ok = reasons && json_array_size(reasons) == 0;

	return send_text(c, ok ? MHD_HTTP_OK : MHD_HTTP_SERVICE_UNAVAILABLE,
			 "text/plain; charset=utf-8", ok ? "ok\n" : "degraded\n", ok ? 3 : 9, NULL);
}

/* 401 with the challenge of RFC 6750: the scheme, and invalid_token when
 * a token was sent and refused. */
static enum MHD_Result send_unauthorized(struct MHD_Connection *c, bool sent, const char *why)
{
	_cleanup_free_ char *text = NULL;
	struct MHD_Response *r;
	enum MHD_Result ret;
	int n = asprintf(&text, "%s\n", why);

	if (n < 0)
		return MHD_NO;
	r = MHD_create_response_from_buffer((size_t)n, text, MHD_RESPMEM_MUST_COPY);
	if (!r)
		return MHD_NO;
	secure_headers(r);
	MHD_add_response_header(r, "Content-Type", "text/plain; charset=utf-8");
	MHD_add_response_header(r, "Cache-Control", "no-store");
	MHD_add_response_header(r, "WWW-Authenticate", sent
				? "Bearer realm=\"asphd\", error=\"invalid_token\""
				: "Bearer realm=\"asphd\"");
	ret = MHD_queue_response(c, MHD_HTTP_UNAUTHORIZED, r);
	MHD_destroy_response(r);
	return ret;
}

bool web_bearer_token(const char *authorization, char *token, size_t size)
{
	const char *t;
	size_t n;

	if (!authorization || strncasecmp(authorization, "Bearer ", 7))
		return false;
	t = authorization + 7;
	t += strspn(t, " ");
	n = strcspn(t, " ");
	if (n == 0 || n >= size || t[n + strspn(t + n, " ")])
		return false;
	for (size_t i = 0; i < n; i++)
		if (t[i] < 0x21 || t[i] > 0x7e)
			return false;
	memcpy(token, t, n);
	token[n] = '\0';
	return true;
}

/* The wait of a wrong token is over: its 401 goes out. */
static int on_refusal_due(sd_event_source *src, uint64_t usec, void *data)
{
	struct request *req = data;

	req->delay = sd_event_source_disable_unref(req->delay);
	request_resume(req);
	return 0;
}

/* GET /metrics: the Prometheus text format, to a viewer's token sent as
 * "Authorization: Bearer TOKEN" (what Prometheus sends with its scrape
 * configuration's authorization). The token is checked as a hello's is,
 * at the same pace on wrong ones (the 401 waits, the connection
 * suspended), and no session is made. */
static enum MHD_Result route_metrics(struct web *w, struct request *req)
{
	struct MHD_Connection *c = req->conn;
	const char *auth = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Authorization");
	struct rpc_session s = { 0 };
	struct proto_why why = { 0 };
	_cleanup_free_ char *text = NULL;
	char token[520];
	uint64_t wait = 0;
	size_t len = 0;
	bool sent, https;

	sent = web_bearer_token(auth, token, sizeof(token));
	if (!sent)
		return send_unauthorized(c, false, "send a viewer token as \"Authorization: Bearer "
					 "TOKEN\"");
	request_peer(c, &s.peer, &https);
	if (rpc_check_token(w->rpc, &s, token, "/metrics", &why, &wait)) {
		explicit_bzero(token, sizeof(token));
		if (!wait || sd_event_add_time_relative(w->event, &req->delay, CLOCK_MONOTONIC,
							wait, 0, on_refusal_due, req) < 0)
			return send_unauthorized(c, true, why.text);
		req->kind = REQUEST_REFUSED;
		req->text = strdup(why.text);
		request_suspend(req);
		return MHD_YES;
	}
	explicit_bzero(token, sizeof(token));
	if (s.grant.role < ROLE_VIEWER)
		return send_error(c, MHD_HTTP_FORBIDDEN, "the token \"%s\" may not read",
				  s.grant.credential);
	text = monitor_metrics(w->monitor, &len);
	if (!text)
		return send_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "no memory");
	return send_text(c, MHD_HTTP_OK, "text/plain; version=0.0.4; charset=utf-8", text, len,
			 NULL);
}

/* ------------------------------------------------------------ checks */

bool web_origin_allowed(const char *origin, const char *host, const char *fetch_site)
{
	if (fetch_site && strcmp(fetch_site, "same-origin") && strcmp(fetch_site, "none"))
		return false;
	if (!origin)
		return true;
	if (!host)
		return false;
	if (!strncmp(origin, "http://", 7))
		origin += 7;
	else if (!strncmp(origin, "https://", 8))
		origin += 8;
	else
		return false;
	return !strcasecmp(origin, host);
}

/* Whether the n bytes of name (a trailing dot of a fully qualified name
 * taken off) are one of allowed, without case. */
static bool host_listed(const char *name, size_t n, char *const *allowed)
{
	if (n > 0 && name[n - 1] == '.')
		n--;
	for (size_t i = 0; n && allowed && allowed[i]; i++)
		if (strlen(allowed[i]) == n && !strncasecmp(allowed[i], name, n))
			return true;
	return false;
}

bool web_host_allowed(const char *host, char *const *allowed)
{
	const char *colon, *end;

	if (!host)
		return true;
	if (host[0] == '[') {           /* [IPv6] or [IPv6]:port */
		end = strchr(host, ']');
		return end && (!end[1] || (end[1] == ':' && strspn(end + 2, "0123456789") ==
						strlen(end + 2))) &&
		       host_listed(host + 1, (size_t)(end - host - 1), allowed);
	}
	/* NAME, NAME:PORT (and a client's bare IPv6 address, with a port or not) */
	colon = strrchr(host, ':');
	if (host_listed(host, strlen(host), allowed))
		return true;
	return colon && colon[1] && strspn(colon + 1, "0123456789") == strlen(colon + 1) &&
	       host_listed(host, (size_t)(colon - host), allowed);
}

static bool same_origin(struct MHD_Connection *c)
{
	return web_origin_allowed(MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Origin"),
				  MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Host"),
				  MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Sec-Fetch-Site"));
}

static bool json_body(struct MHD_Connection *c)
{
	const char *type = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Content-Type");
	size_t n = strlen("application/json");

	return type && !strncasecmp(type, "application/json", n) && (!type[n] || type[n] == ';');
}

/* ------------------------------------------------------------ routes */

static enum MHD_Result route_post(struct web *w, struct request *req, const char *url)
{
	struct MHD_Connection *c = req->conn;
	struct session *s;

	if (!same_origin(c))
		return send_error(c, MHD_HTTP_FORBIDDEN, "cross-origin request refused");
	if (req->too_large)
		return send_error(c, MHD_HTTP_CONTENT_TOO_LARGE, "the body is over limits."
				  "max_request_bytes (%u)", w->limits->max_request_bytes);
	if (!json_body(c))
		return send_error(c, MHD_HTTP_UNSUPPORTED_MEDIA_TYPE, "the body must be "
				  "application/json");
	if (!strcmp(url, "/api/login"))
		return route_login(w, req);
	s = find_session(w, c);
	if (!s)
		return send_error(c, MHD_HTTP_UNAUTHORIZED, "log in first");
	if (!strcmp(url, "/api/rpc"))
		return route_rpc(w, req, s);
	return route_logout(w, c, s);
}

static enum MHD_Result route_get(struct web *w, struct request *req, const char *url)
{
	struct MHD_Connection *c = req->conn;
	struct session *s;

	if (!strcmp(url, "/healthz"))
		return route_healthz(w, c);
	if (!strcmp(url, "/metrics"))
		return route_metrics(w, req);
	if (strncmp(url, "/api/", 5))
		return route_static(w, c, url);
	s = find_session(w, c);
	if (!s)
		return send_error(c, MHD_HTTP_UNAUTHORIZED, "log in first");
	if (!strcmp(url, "/api/events"))
		return route_events(w, c, s);
	if (!strncmp(url, "/api/jobs/", 10))
		return route_job(w, req, s, url + 10);
	return send_error(c, MHD_HTTP_NOT_FOUND, "no such route: %s", url);
}

static bool post_route(const char *url)
{
	return !strcmp(url, "/api/login") || !strcmp(url, "/api/logout") ||
	       !strcmp(url, "/api/rpc");
}

/* A request whose work was suspended, taken up again: its answer. */
static enum MHD_Result respond(struct web *w, struct request *req)
{
	req->responded = true;
	switch (req->kind) {
	case REQUEST_RPC:
		return rpc_respond(req);
	case REQUEST_LOGIN:
		if (req->failed)
			return send_error(req->conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "no memory");
		return login_respond(w, req);
	case REQUEST_POINTS:
		if (!req->text)
			return send_error(req->conn, MHD_HTTP_GONE, "the session ended");
		return send_text(req->conn, req->status, "application/json", req->text,
				 strlen(req->text), NULL);
	case REQUEST_REFUSED:
		return send_unauthorized(req->conn, true, req->text ? req->text : "wrong token");
	case REQUEST_PLAIN:
		break;
	}
	return MHD_NO;
}

/* The first call of a request: its head is in. */
static struct request *request_new(struct web *w, struct MHD_Connection *c)
{
	struct request *req = calloc(1, sizeof(*req));
	struct conn *conn = conn_of(c);

	if (!req)
		return NULL;
	req->web = w;
	req->conn = c;
	req->refs = 1;
	req->next_all = w->requests;
	if (w->requests)
		w->requests->prev_all = req;
	w->requests = req;
	if (conn) {
		conn->in_request = true;
		conn->body_done = false;
		conn->since_usec = turns_now_usec();
	}
	return req;
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *c, const char *url,
				  const char *method, const char *version,
				  const char *upload, size_t *upload_size, void **con_cls)
{
	struct web *w = cls;
	struct request *req = *con_cls;
	bool get = !strcmp(method, "GET") || !strcmp(method, "HEAD");
	struct conn *conn;

	if (!req) {
		req = request_new(w, c);
		*con_cls = req;
		return req ? MHD_YES : MHD_NO;
	}
	if (req->kind != REQUEST_PLAIN)         /* resumed: the work is done */
		return req->responded ? MHD_YES : respond(w, req);
	if (*upload_size) {     /* a piece of the body */
		if (!req->too_large && req->len + *upload_size <= w->limits->max_request_bytes) {
			char *p = realloc(req->body, req->len + *upload_size + 1);
			if (!p)
				return MHD_NO;
			req->body = p;
			memcpy(req->body + req->len, upload, *upload_size);
			req->len += *upload_size;
			req->body[req->len] = '\0';
		} else
			req->too_large = true;
		*upload_size = 0;
		return MHD_YES;
	}
	if ((conn = conn_of(c)))
		conn->body_done = true;
	/* (/healthz and /metrics carry no cookie: a page of another name
	 * gains nothing from them, and scrapers may use any address) */
	if (strcmp(url, "/healthz") && strcmp(url, "/metrics") &&
	    !web_host_allowed(MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Host"),
			      w->allowed_hosts))
		return send_error(c, MHD_HTTP_MISDIRECTED_REQUEST, "this host name is not served "
				  "here (http_allowed_hosts)");
	if (post_route(url)) {
		if (strcmp(method, "POST"))
			return send_error(c, MHD_HTTP_METHOD_NOT_ALLOWED, "%s takes POST", url);
		return route_post(w, req, url);
	}
	if (!get)
		return send_error(c, MHD_HTTP_METHOD_NOT_ALLOWED, "%s takes GET", url);
	return route_get(w, req, url);
}

static void on_completed(void *cls, struct MHD_Connection *c, void **con_cls,
			 enum MHD_RequestTerminationCode why)
{
	struct request *req = *con_cls;
	struct conn *conn = conn_of(c);

	if (conn) {
		conn->in_request = false;
		conn->since_usec = turns_now_usec();
	}
	if (req) {
		request_end_work(req);
		req->done = true;
		req->suspended = false;
		*con_cls = NULL;
		request_unref(req);
	}
}

static void on_mhd_log(void *cls, const char *fmt, va_list ap)
{
	char text[512];

	vsnprintf(text, sizeof(text), fmt, ap);
	text[strcspn(text, "\n")] = '\0';
	log_debug("http: %s", text);
}

/* --------------------------------------------------------- connections */

static size_t conns_of(const struct web *w, const char *key)
{
	size_t n = 0;

	for (const struct conn *c = w->conns; c; c = c->next)
		n += !strcmp(c->key, key) && !c->displaced;
	return n;
}

static void displace(struct web *w, struct conn *c, const char *why)
{
	log_debug("http: a connection of %s closed: %s", c->key, why);
	c->displaced = true;
	w->n_displaced++;
	/* libmicrohttpd sees the end at its next read, and closes it. */
	shutdown(c->fd, SHUT_RDWR);
}

/* The connection that has waited longest for a request's head (a slow
 * one, or an idle keep-alive), or NULL. */
static struct conn *longest_waiting(struct web *w)
{
	struct conn *old = NULL;

	for (struct conn *c = w->conns; c; c = c->next)
		if (!c->in_request && !c->displaced && c->fd >= 0 &&
		    (!old || c->since_usec < old->since_usec))
			old = c;
	return old;
}

static bool is_proxy(const struct web *w, const struct sockaddr *addr)
{
	const struct sockaddr_storage *p = &w->proxy;

	if (p->ss_family == AF_INET && addr->sa_family == AF_INET)
		return !memcmp(&((const struct sockaddr_in *)p)->sin_addr,
			       &((const struct sockaddr_in *)addr)->sin_addr, sizeof(struct in_addr));
	if (p->ss_family == AF_INET6 && addr->sa_family == AF_INET6)
		return !memcmp(&((const struct sockaddr_in6 *)p)->sin6_addr,
			       &((const struct sockaddr_in6 *)addr)->sin6_addr,
			       sizeof(struct in6_addr));
	return false;
}

/*
 * Whether a connection from addr may be taken: the limits as they are now
 * (a reload may have changed them), limits.max_clients_per_user from one
 * address (but the trusted proxy, which brings everyone's), and
 * limits.max_clients in all, where the connection that has waited longest
 * for a request's head makes room: a flood of slow or idle connections
 * cannot keep a user out. One that cannot be taken is closed at once.
 */
static enum MHD_Result on_accept(void *cls, const struct sockaddr *addr, socklen_t len)
{
	struct web *w = cls;
	const struct settings_limits *l = w->limits;
	struct peer p = { 0 };
	struct conn *old;
	char why[128] = "";
	int64_t now;

	server_addr_peer(addr, &p);
	if (!is_proxy(w, addr) && conns_of(w, p.key) >= l->max_clients_per_user)
		snprintf(why, sizeof(why), "%s has %u connections, limits.max_clients_per_user",
			 p.key, l->max_clients_per_user);
	else if (w->n_conns - w->n_displaced >= l->max_clients) {
		old = w->n_displaced < WEB_DISPLACED_MAX ? longest_waiting(w) : NULL;
		if (old)
			displace(w, old, "room for a new one (limits.max_clients)");
		else
			snprintf(why, sizeof(why), "%zu connections with requests, "
				 "limits.max_clients", w->n_conns);
	}
	if (!why[0])
		return MHD_YES;
	now = now_realtime_ns();
	if (now - w->refused_logged_ns >= 1000000000) {
		w->refused_logged_ns = now;
		log_notice("http: connection refused: %s", why);
	}
	return MHD_NO;
}

static void sweep_arm(struct web *w)
{
	uint64_t now;

	if (sd_event_source_get_enabled(w->sweep, NULL) > 0)
		return;
	sd_event_now(w->event, CLOCK_MONOTONIC, &now);
	sd_event_source_set_time(w->sweep, now + SWEEP_USEC);
	sd_event_source_set_enabled(w->sweep, SD_EVENT_ONESHOT);
}

/* A connection opens or closes: counted, and given the idle timeout the
 * limits say now. */
static void on_connection(void *cls, struct MHD_Connection *c, void **socket_context,
			  enum MHD_ConnectionNotificationCode what)
{
	struct web *w = cls;
	const union MHD_ConnectionInfo *info;
	struct conn *conn = *socket_context;
	struct peer p = { 0 };

	if (what == MHD_CONNECTION_NOTIFY_CLOSED) {
		if (!conn)
			return;
		if (conn->prev)
			conn->prev->next = conn->next;
		else
			w->conns = conn->next;
		if (conn->next)
			conn->next->prev = conn->prev;
		w->n_conns--;
		w->n_displaced -= conn->displaced;
		free(conn);
		*socket_context = NULL;
		return;
	}
	MHD_set_connection_option(c, MHD_CONNECTION_OPTION_TIMEOUT,
				  (unsigned)(w->limits->request_timeout_ms + 999) / 1000);
	info = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
	conn = calloc(1, sizeof(*conn));
	if (!conn)
		return;         /* (not counted: the limits err on the open side) */
	if (info && info->client_addr) {
		server_addr_peer(info->client_addr, &p);
		conn->proxy = is_proxy(w, info->client_addr);
	} else
		snprintf(p.key, sizeof(p.key), "tcp ?");
	snprintf(conn->key, sizeof(conn->key), "%s", p.key);
	info = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
	conn->fd = info ? info->connect_fd : -1;
	conn->since_usec = turns_now_usec();
	conn->next = w->conns;
	if (w->conns)
		w->conns->prev = conn;
	w->conns = conn;
	w->n_conns++;
	*socket_context = conn;
	sweep_arm(w);
}

/*
 * Every second while anything is open: a connection must bring a
 * request's head within limits.auth_timeout_ms of opening (or of its last
 * answer), and the body within limits.request_timeout_ms of the head (a
 * connection idle longer is libmicrohttpd's to close); sessions end as
 * session_over() says.
 */
static int on_sweep(sd_event_source *s, uint64_t usec, void *data)
{
	struct web *w = data;
	uint64_t now = turns_now_usec();
	const struct settings_limits *l = w->limits;

	for (struct conn *c = w->conns; c; c = c->next) {
		if (c->displaced || c->fd < 0)
			continue;
		if (!c->in_request && now - c->since_usec > (uint64_t)l->auth_timeout_ms * 1000)
			displace(w, c, "no request's head within limits.auth_timeout_ms");
		else if (c->in_request && !c->body_done &&
			 now - c->since_usec > (uint64_t)l->request_timeout_ms * 1000)
			displace(w, c, "no request's body within limits.request_timeout_ms");
	}
	expire_sessions(w);
	if (w->conns || w->sessions)
		sweep_arm(w);
	return 0;
}

/* -------------------------------------------------------------- setup */

int web_new(const struct web_setup *setup, struct web **out)
{
	struct web *w = calloc(1, sizeof(*w));
	int r;

	if (!w)
		return -ENOMEM;
	w->event = setup->event;
	w->rpc = setup->rpc;
	w->jobs = setup->jobs;
	w->turns = setup->turns;
	w->tasks = setup->tasks;
	w->monitor = setup->monitor;
	w->limits = setup->limits;
	w->root_fd = -1;
	w->state_dir = strdup(setup->state_dir);
	r = w->state_dir ? 0 : -ENOMEM;
	if (r == 0)
		r = sd_event_add_time(w->event, &w->sweep, CLOCK_MONOTONIC, UINT64_MAX, 0, on_sweep,
				      w);
	if (r < 0) {
		web_free(w);
		return r;
	}
	sd_event_source_set_enabled(w->sweep, SD_EVENT_OFF);
	*out = w;
	return 0;
}

void web_free(struct web *w)
{
	if (!w)
		return;
	while (w->sessions)
		session_free(w, w->sessions);
	/* libmicrohttpd stops only with no connection suspended. */
	for (struct request *req = w->requests; req; req = req->next_all) {
		request_end_work(req);
		req->done = req->failed = true;
		if (req->suspended) {
			req->suspended = false;
			MHD_resume_connection(req->conn);
		}
	}
	sd_event_source_disable_unref(w->timer);
	sd_event_source_disable_unref(w->sweep);
	for (size_t i = 0; i < w->n_listeners; i++) {
		sd_event_source_disable_unref(w->listeners[i].io);
		MHD_stop_daemon(w->listeners[i].mhd);   /* (closes its socket) */
	}
	if (w->root_fd >= 0)
		close(w->root_fd);
	livemap_surface_unref(w->surface);
	for (size_t i = 0; w->allowed_hosts && w->allowed_hosts[i]; i++)
		free(w->allowed_hosts[i]);
	free(w->allowed_hosts);
	free(w->state_dir);
	free(w);
}

static int listen_on(struct web *w, int fd)
{
	struct listener *l = &w->listeners[w->n_listeners];
	const union MHD_DaemonInfo *info;
	struct sockaddr_storage sa = { 0 };
	socklen_t len = sizeof(sa);

	getsockname(fd, (struct sockaddr *)&sa, &len);
	l->web = w;
	l->mhd = MHD_start_daemon(MHD_USE_EPOLL | MHD_ALLOW_SUSPEND_RESUME | MHD_USE_ERROR_LOG |
				  (sa.ss_family == AF_INET6 ? MHD_USE_IPv6 : 0),
				  0, on_accept, w, on_request, w,
				  MHD_OPTION_LISTEN_SOCKET, fd,
				  MHD_OPTION_CONNECTION_LIMIT, (unsigned)MHD_CONNECTIONS_CEILING,
				  /* ours counts an IPv6 address by its /64, and reloads;
				   * libmicrohttpd's holds each address as well */
				  MHD_OPTION_PER_IP_CONNECTION_LIMIT,
				  w->proxy.ss_family != AF_UNSPEC ? 0u
				  : (unsigned)w->limits->max_clients_per_user + WEB_DISPLACED_MAX,
				  MHD_OPTION_CONNECTION_MEMORY_LIMIT, (size_t)MHD_CONNECTION_MEMORY,
				  MHD_OPTION_CONNECTION_TIMEOUT,
				  (unsigned)(w->limits->request_timeout_ms + 999) / 1000,
				  MHD_OPTION_NOTIFY_COMPLETED, on_completed, w,
				  MHD_OPTION_NOTIFY_CONNECTION, on_connection, w,
				  MHD_OPTION_EXTERNAL_LOGGER, on_mhd_log, w,
				  MHD_OPTION_END);
	if (!l->mhd) {
		close(fd);
		log_error("http_listen: libmicrohttpd does not start");
		return -EIO;
	}
	w->n_listeners++;
	info = MHD_get_daemon_info(l->mhd, MHD_DAEMON_INFO_EPOLL_FD);
	if (!info)
		return -EIO;
	return sd_event_add_io(w->event, &l->io, info->epoll_fd, EPOLLIN, on_io, l);
}

/* Adds a copy of host to the list, of n so far. */
static int allow(struct web *w, size_t *n, const char *host)
{
	char **v = realloc(w->allowed_hosts, (*n + 2) * sizeof(*v));

	if (!v)
		return -ENOMEM;
	w->allowed_hosts = v;
	v[*n] = host ? strdup(host) : NULL;
	if (host && !v[*n])
		return -ENOMEM;
	if (host)
		++*n;
	v[*n] = NULL;
	return 0;
}

/* The Host names served: http_allowed_hosts, or by default the listen
 * address as written and as each address it resolved to, localhost and
 * this host's name. */
static int allowed_hosts(struct web *w, const struct web_listen_setup *ls)
{
	char name[256], text[INET6_ADDRSTRLEN];
	size_t n = 0;
	int r = allow(w, &n, NULL);     /* an empty list */

	if (ls->allowed_hosts) {
		for (size_t i = 0; r == 0 && ls->allowed_hosts[i]; i++)
			r = allow(w, &n, ls->allowed_hosts[i]);
		return r;
	}
	if (r == 0)
		r = allow(w, &n, "localhost");
	if (r == 0 && ls->host)
		r = allow(w, &n, ls->host);
	if (r == 0 && gethostname(name, sizeof(name)) == 0) {
		name[sizeof(name) - 1] = '\0';
		r = allow(w, &n, name);
	}
	for (const struct addrinfo *ai = ls->addr; r == 0 && ai; ai = ai->ai_next)
		if (getnameinfo(ai->ai_addr, ai->ai_addrlen, text, sizeof(text), NULL, 0,
				NI_NUMERICHOST) == 0)
			r = allow(w, &n, text);
	return r;
}

int web_listen(struct web *w, const struct web_listen_setup *ls)
{
	int fds[WEB_MAX_LISTENERS];
	size_t n = 0;
	int r;

	if (ls->root) {
		w->root_fd = open(ls->root, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
		if (w->root_fd < 0) {
			r = -errno;
			log_error("http_root %s: %s", ls->root, strerror(-r));  /* (checked at the start) */
			return r;
		}
	}
	if (ls->trust_proxy && !forwarded_address(ls->trust_proxy, &w->proxy)) {
		log_error("http_trust_proxy %s: not an IP address", ls->trust_proxy);
		return -EINVAL;
	}
	r = allowed_hosts(w, ls);
	if (r < 0)
		return r;
	r = server_listen_tcp(ls->addr, "http_listen", ls->text, fds, WEB_MAX_LISTENERS, &n);
	if (r < 0)
		return r;
	{       /* one port for all (server_listen_tcp()) */
		struct sockaddr_storage sa = { 0 };
		socklen_t len = sizeof(sa);
		if (getsockname(fds[0], (struct sockaddr *)&sa, &len) == 0)
			w->port = ntohs(sa.ss_family == AF_INET6
					? ((struct sockaddr_in6 *)&sa)->sin6_port
					: ((struct sockaddr_in *)&sa)->sin_port);
	}
	r = sd_event_add_time(w->event, &w->timer, CLOCK_MONOTONIC, 1, 0, on_timer, w);
	for (size_t i = 0; i < n; i++) {
		if (r >= 0)
			r = listen_on(w, fds[i]);
		else
			close(fds[i]);
	}
	if (r < 0)
		return r;
	rearm(w);
	return 0;
}

unsigned web_port(const struct web *w)
{
	return w ? w->port : 0;
}

size_t web_listeners(const struct web *w)
{
	return w ? w->n_listeners : 0;
}

size_t web_connections(const struct web *w)
{
	return w ? w->n_conns : 0;
}
