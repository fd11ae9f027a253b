/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The JSON-RPC methods of proto/README.md, for one session (a connection)
 * at a time: a line in, the response out. Each method maps its parameters
 * in, calls the module that owns what it asks about (jobs.h,
 * instruments.h, events.h, access.h) and maps the outcome, or the error,
 * out. Each method needs a role (tokens.h: viewer, operator, admin; the
 * table in rpc.c, documented in proto/README.md) and is refused before it
 * runs to a peer without it. The sessions are counted here (the "clients" of
 * daemon.status), and the lines handled (its "requests").
 *
 * A transport (server.c) fills a session's peer, opens it, hands over its
 * lines and closes it once; nothing here calls the transport. A session's
 * end also ends what it owns: its subscription, its copy of the job store
 * (backup.h).
 *
 * Event loop thread.
 */
#ifndef ASPHD_RPC_H
#define ASPHD_RPC_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>
#include <systemd/sd-event.h>

#include "access.h"
#include "asph-proto.h"
#include "backup.h"
#include "events.h"
#include "instruments.h"
#include "jobs.h"
#include "monitor.h"
#include "settings.h"
#include "tasks.h"

/* The descriptors a unix peer may have passed and no request has taken
 * yet; more are closed as they come. */
#define RPC_SESSION_MAX_FDS 4

struct rpc_session {
	struct peer peer;               /* the transport fills it */
	/* What the peer passed with SCM_RIGHTS, oldest first, until a request
	 * takes it (job.submit's "measured"); closed with the session. */
	int fds[RPC_SESSION_MAX_FDS];
	unsigned n_fds;
	bool authenticated;             /* unix peers at once; TCP after hello */
	struct access_grant grant;      /* rpc-daemon.c's: what a TCP peer proved */
	/* rpc's: whose share of subscriptions and computations it takes:
	 * the peer's key, or once a named token is proved "token NAME" (a
	 * user's, from whichever address and listener). */
	char owner[RATELIMIT_KEY_MAX];
	struct event_subscription events;
	bool open;                      /* rpc.c's */
};

struct rpc_setup {
	sd_event *event;                        /* the clock of the uptime */
	uint64_t started_usec;                  /* CLOCK_MONOTONIC: the daemon's start */
	struct jobs *jobs;
	const struct instruments *instruments;
	struct events *events;
	const struct access *access;
	struct tokens *tokens;                  /* the named API tokens */
	/* Where plans are checked and estimated (job.submit, job.estimate);
	 * NULL: at once, in the call (tests, the fuzz target). */
	struct tasks *tasks;
	struct backups *backups;                /* copies of the job store */
	struct monitor *monitor;                /* the health (daemon.health) */
	const struct settings_limits *limits;   /* read at each use: may change */
};

struct rpc;

int rpc_new(const struct rpc_setup *setup, struct rpc **out);
void rpc_free(struct rpc *rpc);
/* The methods' table, in its order (asphd --list-methods): the name of
 * method i and, in *need, the role it needs; NULL past the last. */
const char *rpc_method(size_t i, enum access_role *need);
/* Who may do what, after a reload. */
void rpc_set_access(struct rpc *rpc, const struct access *access);

/* A session starts (counted) and ends (its subscription with it);
 * closing a closed session changes nothing. */
void rpc_session_open(struct rpc *rpc, struct rpc_session *s);
void rpc_session_close(struct rpc *rpc, struct rpc_session *s);
size_t rpc_sessions(const struct rpc *rpc);
/* A descriptor s's peer passed (taken): kept for a request, or closed
 * when RPC_SESSION_MAX_FDS wait already (false). */
bool rpc_session_add_fd(struct rpc_session *s, int fd);
/* Closes every descriptor s holds (the transport's end of a session, also
 * one never opened). */
void rpc_session_close_fds(struct rpc_session *s);
/* Whether a peer operates as it connects (root, the operator group; a TCP
 * peer not before hello): it may take the connections reserved for them. */
bool rpc_peer_operator(const struct rpc *rpc, const struct peer *p);
/*
 * A token presented by s's peer (where: "hello", "/metrics", for the
 * log): s->grant filled, 0; or PROTO_PERMISSION_DENIED with why (wrong,
 * expired, revoked). A wrong one is counted against the peer's key and the
 * prefix it claimed, and *wait_usec says how long the answer should wait
 * (0: none): past a burst of 5, until the next try is earned, so that a
 * guesser goes no faster while a right token is never held back. A
 * success is not logged here.
 */
int rpc_check_token(struct rpc *rpc, struct rpc_session *s, const char *token,
		    const char *where, struct proto_why *why, uint64_t *wait_usec);
/* Whether s still stands after a reload: false for a TCP session whose
 * token was changed or removed, which the transport then ends. */
bool rpc_session_valid(const struct rpc *rpc, const struct rpc_session *s);

/*
 * What a line's answer is written through: len bytes of text, in order (a
 * response, or a piece of a batch's array); an answer ends with "\n".
 * Returns 0, or -1 when the transport cannot take it (the connection is
 * gone), which abandons the line.
 */
typedef int (*rpc_write_fn)(const char *text, size_t len, void *data);

/*
 * One line being answered: a request, a notification or a batch. A batch
 * is answered a step at a time (rpc_line_step()), so that the transport
 * can serve other connections between two steps and send each answer as
 * it comes instead of building the whole array in memory. A step is one
 * request, or a slice of a long answer (a listing of jobs, about a
 * millisecond of them), or nothing while a computation runs on a task's
 * thread (the line then waits: its ready function is called when it can
 * go on).
 * A notification is carried out as a request is, and its answer, which
 * is not sent, counts as if it were. Once a line's answers have passed
 * limits.max_response_bytes, each further request of it is answered -32004
 * (a notification dropped) without being carried out.
 */
struct rpc_line;

/* What rpc_line_step() returns besides errors. */
enum {
	RPC_LINE_DONE = 0,      /* answered in full */
	RPC_LINE_MORE = 1,      /* step again */
	RPC_LINE_WAITING = 2,   /* a computation runs: step again once ready() is called */
};

/* Takes a line (without its "\n"; it is parsed here and not kept) of s,
 * which must outlive the line. 0 or -ENOMEM. */
int rpc_line_new(struct rpc *rpc, struct rpc_session *s, const char *text, size_t len,
		 struct rpc_line **out);
/* Who is told (ready(data), on the loop) when a waiting line can go on. */
void rpc_line_on_ready(struct rpc_line *l, void (*ready)(void *data), void *data);
/* Answers the next step of l through write: RPC_LINE_MORE, RPC_LINE_DONE,
 * RPC_LINE_WAITING, -ECONNRESET when write refused, -ENOMEM. */
int rpc_line_step(struct rpc_line *l, rpc_write_fn write, void *data);
/* Whether part of l's answer line is out and the rest is not: nothing
 * else may be written to the connection until it is. */
bool rpc_line_open(const struct rpc_line *l);
/* Frees l; a computation it waits for is cancelled. */
void rpc_line_free(struct rpc_line *l);

/* The whole answer to one line at once (every step), as JSON, or NULL when
 * nothing is due: what the transport would send, for tests and the fuzz
 * target (whose rpc has no tasks: nothing waits). */
json_t *rpc_handle_line(struct rpc *rpc, struct rpc_session *s, const char *line, size_t len);

#endif
