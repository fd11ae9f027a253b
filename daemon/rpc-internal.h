/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What the files of the JSON-RPC methods share. Calls go one way:
 *
 *   rpc.c (the sessions, the method table and its dispatch, the lines)
 *     → rpc-daemon.c (hello and the token check, version, daemon.*, events.*)
 *       rpc-jobs.c (job.*, queue.*)
 *       rpc-instruments.c (instrument.*, driver.list)
 *       rpc-admin.c (token.*, backup.*)
 *     → rpc-call.c (what every handler uses: its parameters, its errors,
 *       an answer that comes later)
 *
 * The handlers (rpc_method_*) are named only in rpc.c's table, the one
 * list of the methods' names. Each returns 0 with a result, or a protocol
 * error code with a detail in call->why.
 *
 * Event loop thread.
 */
#ifndef ASPHD_RPC_INTERNAL_H
#define ASPHD_RPC_INTERNAL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <jansson.h>
#include <systemd/sd-event.h>

#include "asph-proto.h"
#include "jobs.h"
#include "ratelimit.h"
#include "rpc.h"

/* Wrong tokens a peer (an address) may send at once, and of one claimed
 * prefix from anywhere, then one per interval: past that, the answer to a
 * wrong token waits until the interval is up. A right token is never held
 * back, so that one guesser behind a shared address (a proxy, a NAT)
 * cannot lock its users out; a guesser's pace is one guess per interval on
 * each of its connections, which max_clients_per_user bounds. */
#define HELLO_FAILURES_BURST 5
#define HELLO_FAILURE_INTERVAL_USEC (2 * 1000000ull)

struct rpc {
	sd_event *event;
	uint64_t started_usec;
	struct jobs *jobs;
	const struct instruments *instruments;
	struct events *events;
	const struct access *access;
	struct tokens *tokens;
	struct tasks *tasks;
	struct backups *backups;
	struct monitor *monitor;
	const struct settings_limits *limits;
	size_t n_sessions;
	uint64_t requests;
	struct ratelimit *hello_failures;       /* per peer key */
	struct ratelimit *prefix_failures;      /* per claimed token prefix */
	struct ratelimit *refusals_logged;      /* per peer key */
};

/* How the element of a line answered now goes on. */
enum element {
	ELEMENT_NEXT,           /* none started: the next one is taken */
	ELEMENT_WAITING,        /* a task computes its answer */
	ELEMENT_READY,          /* its answer is in reply */
	ELEMENT_LISTING,        /* its answer is a listing, made a step at a time */
};

/* A listing's answer: the response up to the array, the jobs a step at a
 * time, then the closing "]}}". */
struct listing {
	struct jobs_cursor *cursor;
	char *head;
	bool head_out;
	size_t items;
};

struct rpc_line {
	struct rpc *rpc;
	struct rpc_session *s;
	json_t *msg;            /* the request, the batch, or an error answer */
	bool batch;
	bool parsed;            /* msg is a request or batch to answer */
	size_t next;            /* the batch element answered next */
	size_t written;         /* bytes of answer so far, notifications' too */
	bool opened;            /* a batch's "[" is out */
	void (*ready)(void *data);
	void *ready_data;
	/* The element being answered over several steps. */
	enum element state;
	json_t *id;             /* its id */
	bool notification;      /* its answer is counted, not sent */
	json_t *reply;          /* ELEMENT_READY */
	struct task *task;      /* ELEMENT_WAITING: a computation */
	sd_event_source *delay; /* ELEMENT_WAITING: an answer held back */
	void *pending;          /* ELEMENT_WAITING: the method's, freed with it */
	void (*pending_free)(void *pending);
	struct listing *listing;
};

struct call {
	struct rpc *rpc;
	struct rpc_session *s;
	struct rpc_line *line;  /* the line it is part of */
	struct proto_why why;
	json_t *data;           /* more members of an error's data, or NULL */
	/* The answer comes later: a task computes it (deferred), or it is
	 * the result given and a list of jobs made a step at a time. */
	bool deferred;
	struct listing *listing;
};

typedef int (*method_fn)(struct call *c, json_t *params, json_t **result);

/* ------------------------------------------------ handlers (rpc.c's table) */

int rpc_method_hello(struct call *c, json_t *params, json_t **result);
int rpc_method_version(struct call *c, json_t *params, json_t **result);
int rpc_method_daemon_status(struct call *c, json_t *params, json_t **result);
int rpc_method_daemon_health(struct call *c, json_t *params, json_t **result);
int rpc_method_events_subscribe(struct call *c, json_t *params, json_t **result);
int rpc_method_events_unsubscribe(struct call *c, json_t *params, json_t **result);
int rpc_method_job_submit(struct call *c, json_t *params, json_t **result);
int rpc_method_job_estimate(struct call *c, json_t *params, json_t **result);
int rpc_method_job_get(struct call *c, json_t *params, json_t **result);
int rpc_method_job_list(struct call *c, json_t *params, json_t **result);
int rpc_method_job_cancel(struct call *c, json_t *params, json_t **result);
int rpc_method_job_pause(struct call *c, json_t *params, json_t **result);
int rpc_method_job_resume(struct call *c, json_t *params, json_t **result);
int rpc_method_job_requeue(struct call *c, json_t *params, json_t **result);
int rpc_method_job_result(struct call *c, json_t *params, json_t **result);
int rpc_method_job_file(struct call *c, json_t *params, json_t **result);
int rpc_method_queue_get(struct call *c, json_t *params, json_t **result);
int rpc_method_queue_move(struct call *c, json_t *params, json_t **result);
int rpc_method_queue_start(struct call *c, json_t *params, json_t **result);
int rpc_method_queue_stop(struct call *c, json_t *params, json_t **result);
int rpc_method_instrument_list(struct call *c, json_t *params, json_t **result);
int rpc_method_instrument_status(struct call *c, json_t *params, json_t **result);
int rpc_method_driver_list(struct call *c, json_t *params, json_t **result);
int rpc_method_instrument_lock(struct call *c, json_t *params, json_t **result);
int rpc_method_instrument_unlock(struct call *c, json_t *params, json_t **result);
int rpc_method_backup_start(struct call *c, json_t *params, json_t **result);
int rpc_method_backup_get(struct call *c, json_t *params, json_t **result);
int rpc_method_backup_file(struct call *c, json_t *params, json_t **result);
int rpc_method_token_create(struct call *c, json_t *params, json_t **result);
int rpc_method_token_list(struct call *c, json_t *params, json_t **result);
int rpc_method_token_revoke(struct call *c, json_t *params, json_t **result);

/* ------------------------------------------------------ rpc-call.c */

uint64_t rpc_loop_usec(const struct rpc *rpc);

/* The call fails with code, the detail formatted into c->why; returns code. */
int rpc_fail(struct call *c, int code, const char *fmt, ...)
	__attribute__((format(printf, 3, 4)));
/* The protocol's answer to an error of jobs.h. */
int rpc_job_error(struct call *c, int r, const struct asph_error *err);
enum access_role rpc_role(const struct call *c);
bool rpc_is_operator(const struct call *c);
/* Takes the descriptor index of those s holds (rpc.h): it, or -ENOENT. */
int rpc_session_take_fd(struct rpc_session *s, unsigned index);
/* Who a change is recorded as: the user, or over TCP the token's name. */
struct job_actor rpc_actor(const struct call *c);
/* params: only the listed members, each checked by the handler. */
int rpc_only(struct call *c, json_t *params, const char *const *names);
int rpc_job_id(struct call *c, json_t *params, int64_t *id);
/* The job j as the result; clears j. */
int rpc_job_result(struct call *c, struct job_record *j, json_t **result);

/* The methods that change one job and answer with it. */
typedef int (*job_change_fn)(struct jobs *jobs, int64_t id, const struct job_actor *who,
			     struct job_record *out, struct asph_error *err);

int rpc_change_job(struct call *c, json_t *params, job_change_fn change, json_t **result);

/* A file's piece (job.file, backup.file): its offset and length from
 * params, then the piece of fd as the result. */
int rpc_chunk_params(struct call *c, json_t *params, int64_t *offset, int64_t *length);
int rpc_file_chunk(struct call *c, int fd, const char *name, int64_t offset, int64_t length,
		   json_t **result);

/* The answer to a request, or NULL for a notification (counted in the
 * line's bytes). */
json_t *rpc_make_reply(struct call *c, json_t *id, bool notification, int code,
		       json_t *result);

/* An answer that comes later: the call's element waits for pending (what
 * its method keeps, freed with free_fn when the element ends or the line
 * is freed); rpc_line_answer() gives it. */
void rpc_defer(struct call *c, void *pending, void (*free_fn)(void *pending));
/* An error answer (a wrong token's) held back for wait microseconds. */
int rpc_defer_answer(struct call *c, int code, uint64_t wait);
void rpc_line_answer(struct rpc_line *l, struct call *c, int code, json_t *result);
/* What the element of l kept while it waited goes (a task still running
 * is cancelled). */
void rpc_wait_end(struct rpc_line *l);

#endif
