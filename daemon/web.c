/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The web listener (web.h). libmicrohttpd runs in its "external" mode:
 * no thread of its own; its epoll descriptor is watched by the event loop
 * and MHD_run() is called from there, so every handler below runs on the
 * event loop thread, the only one that may touch the jobs, the sessions
 * and the events. A Server-Sent Events stream with nothing to send is
 * suspended (MHD_suspend_connection) and resumed when an event is queued
 * for it, so that an idle stream costs no turn of the loop.
 */
#include "config.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <unistd.h>

#include <microhttpd.h>
#include <nettle/memops.h>

#include "asph-proto.h"
#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "asph/surface.h"
#include "log.h"
#include "runner.h"
#include "server.h"
#include "util-mem.h"
#include "util-time.h"
#include "web.h"

#define SESSION_COOKIE "asph_session"
/* A session not used for this long ends (the page polls while open). */
#define SESSION_IDLE_NS (12 * 3600 * (int64_t)1000000000)
/* The most points one /points answer carries (the page asks again). */
#define POINTS_MAX 20000
/* The most addresses http_listen listens on. */
#define WEB_MAX_LISTENERS 16
/* libmicrohttpd's own ceiling on connections: the limits are ours
 * (on_accept()), read at each connection; this is the largest
 * limits.max_clients. */
#define MHD_CONNECTIONS_CEILING 65536

/* Only the page's own origin: scripts, styles, images, connections. */
#define CSP "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; " \
	    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; " \
	    "frame-ancestors 'none'"

struct stream;

struct session {
	struct session *next;
	char id[44];                    /* base64url of 32 random bytes */
	struct rpc_session rpc;
	int64_t last_used_ns;
	struct stream *stream;          /* the event stream, or NULL */
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

/* One request's body as it arrives. */
struct request {
	char *body;
	size_t len;
	bool too_large;
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
};

struct web {
	sd_event *event;
	struct rpc *rpc;
	struct jobs *jobs;
	struct monitor *monitor;
	const struct settings_limits *limits;
	char *state_dir;
	struct listener listeners[WEB_MAX_LISTENERS];
	size_t n_listeners;
	sd_event_source *timer;
	int root_fd;
	unsigned port;
	struct conn *conns;
	size_t n_conns;
	int64_t refused_logged_ns;      /* the last refusal logged (one a second) */
	struct session *sessions;
	size_t n_sessions;
	/* The surface of the job whose points were asked for last: the live
	 * map asks twice a second, and a surface's tables take time to build. */
	int64_t surface_job;
	struct asph_surface *surface;
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

/* ----------------------------------------------------------- sessions */

static void stream_wake(struct stream *st)
{
	if (st->suspended) {
		st->suspended = false;
		MHD_resume_connection(st->conn);
		kick(st->web);
	}
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
	rpc_session_close(w->rpc, &s->rpc);
	free(s);
}

static void expire_sessions(struct web *w)
{
	int64_t now = now_realtime_ns();
	struct session *s, *next;

	for (s = w->sessions; s; s = next) {
		next = s->next;
		if (now - s->last_used_ns > SESSION_IDLE_NS)
			session_free(w, s);
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
	struct session *s, *next;

	for (s = w->sessions; s; s = next) {
		next = s->next;
		if (!rpc_session_valid(w->rpc, &s->rpc)) {
			log_info("web session of %s: its token was changed or removed: ended",
				 s->rpc.peer.name);
			session_free(w, s);
		}
	}
}

/* ------------------------------------------------------------- the RPC */

struct answer {
	char *text;
	size_t len, size;
};

static int answer_write(const char *text, size_t len, void *data)
{
	struct answer *a = data;

	if (a->len + len + 1 > a->size) {
		size_t size = (a->len + len + 1) * 2;
		char *p = realloc(a->text, size);
		if (!p)
			return -1;
		a->text = p;
		a->size = size;
	}
	memcpy(a->text + a->len, text, len);
	a->len += len;
	a->text[a->len] = '\0';
	return 0;
}

/* The answer to one line of s, as the socket gives it (NULL text: none). */
static int call_line(struct web *w, struct session *s, const char *text, size_t len,
		     struct answer *a)
{
	struct rpc_line *line;
	int r;

	r = rpc_line_new(w->rpc, &s->rpc, text, len, &line);
	if (r < 0)
		return r;
	while ((r = rpc_line_step(line, answer_write, a)) > 0)
		;
	rpc_line_free(line);
	return r;
}

static enum MHD_Result route_rpc(struct web *w, struct MHD_Connection *c, struct session *s,
				 const struct request *req)
{
	struct answer a = { 0 };
	enum MHD_Result ret;
	int r;

	r = call_line(w, s, req->body ? req->body : "", req->len, &a);
	if (r < 0) {
		free(a.text);
		return send_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "%s", strerror(-r));
	}
	if (!a.text)    /* notifications only */
		return send_text(c, MHD_HTTP_NO_CONTENT, "application/json", "", 0, NULL);
	ret = send_text(c, MHD_HTTP_OK, "application/json", a.text, a.len, NULL);
	free(a.text);
	return ret;
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

/* The peer of an HTTP connection: its address, "http ADDRESS" in the log
 * (the key stays the address's, as a TCP peer's). */
static void http_peer(struct MHD_Connection *c, struct peer *p)
{
	const union MHD_ConnectionInfo *info =
		MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);

	p->tcp = true;
	server_tcp_peer(info ? info->connect_fd : -1, p);
	memmove(p->name + 1, p->name, sizeof(p->name) - 1);
	p->name[sizeof(p->name) - 1] = '\0';
	memcpy(p->name, "http", 4);
}

static enum MHD_Result route_login(struct web *w, struct MHD_Connection *c,
				   const struct request *req)
{
	_cleanup_(json_decrefp) json_t *body = NULL, *hello = NULL, *answer = NULL;
	_cleanup_free_ char *line = NULL;
	struct answer a = { 0 };
	struct session *s;
	json_t *token, *err;
	char cookie[160];

	token = web_login_token(req->body, req->len, &body);
	if (!token)
		return send_error(c, MHD_HTTP_BAD_REQUEST, "the body must be {\"token\": TOKEN}");
	expire_sessions(w);
	if (w->n_sessions >= w->limits->max_clients)
		return send_error(c, MHD_HTTP_SERVICE_UNAVAILABLE, "too many sessions (limits."
				  "max_clients, %u): log out elsewhere", w->limits->max_clients);
	s = calloc(1, sizeof(*s));
	if (!s || new_session_id(s->id) < 0) {
		free(s);
		return send_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "no memory");
	}
	http_peer(c, &s->rpc.peer);
	s->last_used_ns = now_realtime_ns();
	rpc_session_open(w->rpc, &s->rpc);
	s->next = w->sessions;
	w->sessions = s;
	w->n_sessions++;

	/* The same hello as over TCP: its checks, rate limit and log. */
	hello = json_pack("{s:s, s:i, s:s, s:{s:O, s:s}}", "jsonrpc", "2.0", "id", 1, "method",
			  "hello", "params", "token", token, "client", "web");
	line = hello ? json_dumps(hello, JSON_COMPACT) : NULL;
	if (!line || call_line(w, s, line, strlen(line), &a) < 0 || !a.text) {
		free(a.text);
		session_free(w, s);
		return send_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "no memory");
	}
	answer = json_loads(a.text, 0, NULL);
	free(a.text);
	err = json_object_get(answer, "error");
	if (err || !s->rpc.authenticated) {
		json_t *detail = json_object_get(json_object_get(err, "data"), "detail");
		const char *why = json_string_value(detail ? detail : json_object_get(err, "message"));
		session_free(w, s);
		return send_error(c, MHD_HTTP_UNAUTHORIZED, "%s", why ? why : "not authenticated");
	}
	snprintf(cookie, sizeof(cookie), SESSION_COOKIE "=%s; Path=/; HttpOnly; SameSite=Strict",
		 s->id);
	return send_json(c, MHD_HTTP_OK, json_pack("{s:s, s:s}", "role",
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

/* The nominal surface of job id, from its scan's header (the prescription
 * the job measures), or NULL when it does not build. Job ids are never
 * reused, so the one kept stays the job's. */
static const struct asph_surface *job_surface(struct web *w, int64_t id,
					      const struct asph_scanfile_header *h)
{
	struct asph_prescription pr;
	struct asph_surface *s = NULL;
	struct asph_error err;

	if (w->surface_job == id)
		return w->surface;         /* (NULL: said once already) */
	asph_surface_free(w->surface);
	w->surface = NULL;
	w->surface_job = id;
	asph_error_clear(&err);
	if (!h->prescription ||
	    asph_prescription_parse(h->prescription, strlen(h->prescription), "the scan's header",
				    &pr, &err) < 0 ||
	    asph_surface_alloc(&pr, &s, &err) < 0) {
		log_job(LOG_WARNING, id, "the live map has no nominal surface: %s",
			err.message[0] ? err.message : "the scan names no prescription");
		return NULL;
	}
	w->surface = s;
	return s;
}

static json_t *json_number_or_null(double v)
{
	return isfinite(v) ? json_real(v) : json_null();
}

/* One point of the live map: x, y (mm), the probe's reading, and the
 * measured z minus the nominal sag at the measured (x, y), in mm: null for
 * a point that is no measurement, or off the surface (past a conic's root). */
static json_t *live_point(const struct asph_scanfile_point *p, const struct asph_surface *s)
{
	double dz = NAN;

	if (s && !(p->flags & ASPH_SCANFILE_NOT_MEASURED))
		dz = p->z - asph_surface_sag_xy(s, p->x, p->y);
	return json_pack("[o,o,o,o]", json_number_or_null(p->x), json_number_or_null(p->y),
			 json_number_or_null(p->raw), json_number_or_null(dz));
}

/* The points measured so far from the from-th on (the live map), at most
 * POINTS_MAX an answer: the sag is evaluated for those sent only, so one
 * request costs the loop at most POINTS_MAX evaluations. */
static enum MHD_Result route_points(struct web *w, struct MHD_Connection *c, int64_t id)
{
	const char *arg = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "from");
	_cleanup_(json_decrefp) json_t *pts = json_array();
	struct asph_scanfile_reader *rd = NULL;
	const struct asph_scanfile_point *p;
	const struct asph_surface *surface;
	struct asph_error err;
	_cleanup_free_ char *path = NULL;
	int64_t from = 0, index = 0;
	size_t n;
	int r;

	if (arg && strcmp(arg, "0") && !web_parse_count(arg, strlen(arg), &from))
		return send_error(c, MHD_HTTP_BAD_REQUEST, "from must be a count of points");
	asph_error_clear(&err);
	if (asprintf(&path, "%s/jobs/%" PRId64 "/" RUNNER_SCAN_FILE, w->state_dir, id) < 0 || !pts)
		return MHD_NO;
	r = asph_scanfile_reader_open(path, &rd, &err);
	if (r == -ENOENT)
		return send_error(c, MHD_HTTP_NOT_FOUND, "job %" PRId64 " has no scan (yet)", id);
	if (r < 0)
		return send_error(c, MHD_HTTP_CONFLICT, "%s", err.message);
	surface = job_surface(w, id, asph_scanfile_reader_header(rd));
	while (json_array_size(pts) < POINTS_MAX && asph_scanfile_reader_next(rd, &p, &n, &err) > 0)
		for (size_t i = 0; i < n && json_array_size(pts) < POINTS_MAX; i++, index++)
			if (index >= from && json_array_append_new(pts, live_point(&p[i], surface)) < 0) {
				asph_scanfile_reader_free(rd);
				return MHD_NO;
			}
	asph_scanfile_reader_free(rd);
	return send_json(c, MHD_HTTP_OK, json_pack("{s:I, s:O}", "from", (json_int_t)from,
						   "points", pts), NULL);
}

int web_job_route(const char *path, int64_t *id, const char **rest)
{
	const char *slash = strchr(path, '/');

	if (!slash || !web_parse_count(path, (size_t)(slash - path), id) || *id == 0)
		return -ENOENT;
	*rest = slash;
	return 0;
}

static enum MHD_Result route_job(struct web *w, struct MHD_Connection *c, const char *path)
{
	const char *rest;
	int64_t id;

	if (web_job_route(path, &id, &rest) < 0)
		return send_error(c, MHD_HTTP_NOT_FOUND, "no such job");
	if (!strcmp(rest, "/points"))
		return route_points(w, c, id);
	if (!strncmp(rest, "/files/", 7))
		return route_file(w, c, id, rest + 7);
	return send_error(c, MHD_HTTP_NOT_FOUND, "no such route");
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

/* GET /metrics: the Prometheus text format, to a viewer's token sent as
 * "Authorization: Bearer TOKEN" (what Prometheus sends with its scrape
 * configuration's authorization). The token is checked as a hello's is,
 * under its rate limit, and no session is made. */
static enum MHD_Result route_metrics(struct web *w, struct MHD_Connection *c)
{
	const char *auth = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Authorization");
	struct rpc_session s = { 0 };
	struct proto_why why = { 0 };
	_cleanup_free_ char *text = NULL;
	char token[520];
	size_t len = 0;
	bool sent;

	sent = web_bearer_token(auth, token, sizeof(token));
	if (!sent)
		return send_unauthorized(c, false, "send a viewer token as \"Authorization: Bearer "
					 "TOKEN\"");
	http_peer(c, &s.peer);
	if (rpc_check_token(w->rpc, &s, token, "/metrics", &why)) {
		explicit_bzero(token, sizeof(token));
		return send_unauthorized(c, true, why.text);
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

/* ------------------------------------------------------------ requests */

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

static enum MHD_Result route_post(struct web *w, struct MHD_Connection *c, const char *url,
				  const struct request *req)
{
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
		return route_login(w, c, req);
	s = find_session(w, c);
	if (!s)
		return send_error(c, MHD_HTTP_UNAUTHORIZED, "log in first");
	if (!strcmp(url, "/api/rpc"))
		return route_rpc(w, c, s, req);
	return route_logout(w, c, s);
}

static enum MHD_Result route_get(struct web *w, struct MHD_Connection *c, const char *url)
{
	struct session *s;

	if (!strcmp(url, "/healthz"))
		return route_healthz(w, c);
	if (!strcmp(url, "/metrics"))
		return route_metrics(w, c);
	if (strncmp(url, "/api/", 5))
		return route_static(w, c, url);
	s = find_session(w, c);
	if (!s)
		return send_error(c, MHD_HTTP_UNAUTHORIZED, "log in first");
	if (!strcmp(url, "/api/events"))
		return route_events(w, c, s);
	if (!strncmp(url, "/api/jobs/", 10))
		return route_job(w, c, url + 10);
	return send_error(c, MHD_HTTP_NOT_FOUND, "no such route: %s", url);
}

static bool post_route(const char *url)
{
	return !strcmp(url, "/api/login") || !strcmp(url, "/api/logout") ||
	       !strcmp(url, "/api/rpc");
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *c, const char *url,
				  const char *method, const char *version,
				  const char *upload, size_t *upload_size, void **con_cls)
{
	struct web *w = cls;
	struct request *req = *con_cls;
	bool get = !strcmp(method, "GET") || !strcmp(method, "HEAD");

	if (!req) {
		req = calloc(1, sizeof(*req));
		if (!req)
			return MHD_NO;
		*con_cls = req;
		return MHD_YES;
	}
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
	if (post_route(url)) {
		if (strcmp(method, "POST"))
			return send_error(c, MHD_HTTP_METHOD_NOT_ALLOWED, "%s takes POST", url);
		return route_post(w, c, url, req);
	}
	if (!get)
		return send_error(c, MHD_HTTP_METHOD_NOT_ALLOWED, "%s takes GET", url);
	return route_get(w, c, url);
}

static void on_completed(void *cls, struct MHD_Connection *c, void **con_cls,
			 enum MHD_RequestTerminationCode why)
{
	struct request *req = *con_cls;

	if (req) {
		free(req->body);
		free(req);
		*con_cls = NULL;
	}
}

static void on_mhd_log(void *cls, const char *fmt, va_list ap)
{
	char text[512];

	vsnprintf(text, sizeof(text), fmt, ap);
	text[strcspn(text, "\n")] = '\0';
	log_debug("http: %s", text);
}

/* -------------------------------------------------------------- setup */

int web_new(const struct web_setup *setup, struct web **out)
{
	struct web *w = calloc(1, sizeof(*w));

	if (!w)
		return -ENOMEM;
	w->event = setup->event;
	w->rpc = setup->rpc;
	w->jobs = setup->jobs;
	w->monitor = setup->monitor;
	w->limits = setup->limits;
	w->root_fd = -1;
	w->state_dir = strdup(setup->state_dir);
	if (!w->state_dir) {
		free(w);
		return -ENOMEM;
	}
	*out = w;
	return 0;
}

void web_free(struct web *w)
{
	if (!w)
		return;
	while (w->sessions)
		session_free(w, w->sessions);
	sd_event_source_disable_unref(w->timer);
	for (size_t i = 0; i < w->n_listeners; i++) {
		sd_event_source_disable_unref(w->listeners[i].io);
		MHD_stop_daemon(w->listeners[i].mhd);   /* (closes its socket) */
	}
	if (w->root_fd >= 0)
		close(w->root_fd);
	asph_surface_free(w->surface);
	free(w->state_dir);
	free(w);
}

/* --------------------------------------------------------- connections */

static size_t conns_of(const struct web *w, const char *key)
{
	size_t n = 0;

	for (const struct conn *c = w->conns; c; c = c->next)
		n += !strcmp(c->key, key);
	return n;
}

/*
 * Whether a connection from addr may be taken: the limits as they are now
 * (a reload may have changed them), limits.max_clients connections in all
 * and limits.max_clients_per_user from one address. One over is closed
 * at once, before anything is read from it.
 */
static enum MHD_Result on_accept(void *cls, const struct sockaddr *addr, socklen_t len)
{
	struct web *w = cls;
	const struct settings_limits *l = w->limits;
	struct peer p = { 0 };
	char why[128] = "";
	int64_t now;

	server_addr_peer(addr, &p);
	if (w->n_conns >= l->max_clients)
		snprintf(why, sizeof(why), "%zu connections, limits.max_clients", w->n_conns);
	else if (conns_of(w, p.key) >= l->max_clients_per_user)
		snprintf(why, sizeof(why), "%s has %u connections, limits.max_clients_per_user",
			 p.key, l->max_clients_per_user);
	if (!why[0])
		return MHD_YES;
	now = now_realtime_ns();
	if (now - w->refused_logged_ns >= 1000000000) {
		w->refused_logged_ns = now;
		log_notice("http: connection refused: %s", why);
	}
	return MHD_NO;
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
	if (info && info->client_addr)
		server_addr_peer(info->client_addr, &p);
	else
		snprintf(p.key, sizeof(p.key), "tcp ?");
	snprintf(conn->key, sizeof(conn->key), "%s", p.key);
	conn->next = w->conns;
	if (w->conns)
		w->conns->prev = conn;
	w->conns = conn;
	w->n_conns++;
	*socket_context = conn;
}

/* -------------------------------------------------------------- setup */

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

int web_listen(struct web *w, const struct addrinfo *addr, const char *text, const char *root)
{
	int fds[WEB_MAX_LISTENERS];
	size_t n = 0;
	int r;

	if (root) {
		w->root_fd = open(root, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
		if (w->root_fd < 0) {
			r = -errno;
			log_error("http_root %s: %s", root, strerror(-r));   /* (checked at the start) */
			return r;
		}
	}
	r = server_listen_tcp(addr, "http_listen", text, fds, WEB_MAX_LISTENERS, &n);
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
