/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What every handler of the methods uses: the refusal of a call with its
 * detail, the parameters they share, the protocol's answer to an error of
 * jobs.h, who a call is, a file's piece, and an answer that comes later
 * (a computation's, a wrong token's held back). It calls none of the
 * handlers nor rpc.c.
 *
 * Event loop thread.
 */
#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asph-proto.h"
#include "rpc-internal.h"
#include "util-mem.h"

uint64_t rpc_loop_usec(const struct rpc *rpc)
{
	uint64_t now = 0;

	sd_event_now(rpc->event, CLOCK_MONOTONIC, &now);
	return now;
}

/* ------------------------------------------------------------ helpers */

int rpc_fail(struct call *c, int code, const char *fmt, ...)
{
	va_list ap;

	va_start(ap, fmt);
	proto_why_vset(&c->why, fmt, ap);
	va_end(ap);
	return code;
}

/* The protocol's answer to an error of jobs.h. */
int rpc_job_error(struct call *c, int r, const struct asph_error *err)
{
	static const struct {
		int errno_code, code;
	} map[] = {
		{ -ENOENT, PROTO_NO_SUCH_JOB },
		{ -ENODEV, PROTO_NO_SUCH_INSTRUMENT },
		{ -EINVAL, PROTO_INVALID_STATE },
		{ -ENOBUFS, PROTO_LIMIT_REACHED },
		{ -EDQUOT, PROTO_LIMIT_REACHED },
		{ -ENODATA, PROTO_NO_RESULT },
		{ -EPERM, PROTO_INVALID_PATH },
		{ -EBUSY, PROTO_INSTRUMENT_LOCKED },
		{ -ENOMEM, PROTO_INTERNAL_ERROR },
	};
	int code = PROTO_STORAGE_ERROR;

	for (size_t i = 0; i < ARRAY_SIZE(map); i++)
		if (map[i].errno_code == r)
			code = map[i].code;
	/* Who holds the lock and why, for a program to show. */
	if (code == PROTO_INSTRUMENT_LOCKED && err->field[0])
		c->data = json_pack("{s:s, s:o}", "instrument", err->field,
				    "lock", instrument_lock_to_json(jobs_lock_of(c->rpc->jobs,
										  err->field)));
	return rpc_fail(c, code, "%s", err->message[0] ? err->message : strerror(-r));
}

enum access_role rpc_role(const struct call *c)
{
	return access_role_of(c->rpc->access, &c->s->peer, &c->s->grant);
}

bool rpc_is_operator(const struct call *c)
{
	return rpc_role(c) >= ROLE_OPERATOR;
}

/* Who a change is recorded as: the user, or over TCP the token's name. */
struct job_actor rpc_actor(const struct call *c)
{
	const struct rpc_session *s = c->s;

	if (s->peer.tcp && s->grant.valid)
		return (struct job_actor){ .uid = -1, .name = s->grant.credential };
	return (struct job_actor){ .uid = (int64_t)(int)s->peer.uid, .name = s->peer.name };
}

/* params: only the listed members, each checked by the handler. */
int rpc_only(struct call *c, json_t *params, const char *const *names)
{
	return proto_params_only(params, names, &c->why) < 0 ? PROTO_INVALID_PARAMS : 0;
}

int rpc_job_id(struct call *c, json_t *params, int64_t *id)
{
	return proto_param_int(params, "id", true, 1, INT64_MAX, id, &c->why) < 0
		? PROTO_INVALID_PARAMS : 0;
}

/* The job j as the result; clears j. */
int rpc_job_result(struct call *c, struct job_record *j, json_t **result)
{
	*result = jobs_job_to_json(c->rpc->jobs, j);
	job_record_clear(j);
	return *result ? 0 : PROTO_INTERNAL_ERROR;
}

/* The methods that change one job and answer with it. */
int rpc_change_job(struct call *c, json_t *params, job_change_fn change, json_t **result)
{
	static const char *const names[] = { "id", NULL };
	struct job_actor who = rpc_actor(c);
	struct asph_error err;
	struct job_record j;
	int64_t id;
	int code = rpc_only(c, params, names), r;

	if (code || (code = rpc_job_id(c, params, &id)))
		return code;
	asph_error_clear(&err);
	r = change(c->rpc->jobs, id, &who, &j, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : rpc_job_result(c, &j, result);
}

/* The most bytes one job.file or backup.file answer carries (before
 * base64). */
#define FILE_CHUNK_MAX (1u << 20)

/* The offset and length of a file's piece, as job.file and backup.file
 * take them. */
int rpc_chunk_params(struct call *c, json_t *params, int64_t *offset, int64_t *length)
{
	*offset = 0;
	*length = FILE_CHUNK_MAX;
	if (proto_param_int(params, "offset", false, 0, INT64_MAX, offset, &c->why) == -EINVAL ||
	    proto_param_int(params, "length", false, 1, FILE_CHUNK_MAX, length,
			    &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	return 0;
}

/* The piece of the file fd (named name) from offset, at most length bytes,
 * as job.file and backup.file answer: name, offset, size, data (base64),
 * eof. */
int rpc_file_chunk(struct call *c, int fd, const char *name, int64_t offset, int64_t length,
		   json_t **result)
{
	_cleanup_free_ char *buf = NULL, *data = NULL;
	struct stat st;
	ssize_t n;

	if (fstat(fd, &st) < 0 || !(buf = malloc((size_t)length)))
		return rpc_fail(c, PROTO_STORAGE_ERROR, "%s: %s", name, strerror(errno));
	n = offset < st.st_size ? pread(fd, buf, (size_t)length, (off_t)offset) : 0;
	if (n < 0)
		return rpc_fail(c, PROTO_STORAGE_ERROR, "%s: %s", name, strerror(errno));
	data = proto_base64_encode(buf, (size_t)n);
	if (!data)
		return PROTO_INTERNAL_ERROR;
	*result = json_pack("{s:s, s:I, s:I, s:s, s:b}", "name", name, "offset", (json_int_t)offset,
			    "size", (json_int_t)st.st_size, "data", data,
			    "eof", offset + n >= st.st_size);
	return 0;
}

/* The answer to a request once its method has run: its result, or the
 * error code with c's detail and data. */
static json_t *answer_of(struct call *c, json_t *id, int code, json_t *result)
{
	json_t *data;

	if (!code) {
		json_decref(c->data);
		c->data = NULL;
		return proto_make_result(id, result);
	}
	json_decref(result);
	data = c->data ? c->data : json_object();
	c->data = NULL;
	/* A name cut at 64 bytes may end inside a character. */
	proto_utf8_clean(c->why.text);
	if (c->why.text[0])
		json_object_set_new(data, "detail", json_string(c->why.text));
	return proto_make_error(id, code, NULL, data);
}

/*
 * The answer to a request, or NULL for a notification: its answer is
 * made as a request's would be and only counted in the line's bytes, so
 * that notifications spend limits.max_response_bytes as requests do.
 */
json_t *rpc_make_reply(struct call *c, json_t *id, bool notification, int code,
		       json_t *result)
{
	json_t *reply = answer_of(c, notification ? json_null() : id, code, result);

	if (!notification)
		return reply;
	if (c->line && reply)
		c->line->written += json_dumpb(reply, NULL, 0, JSON_COMPACT);
	json_decref(reply);
	return NULL;
}

/* What the element of l kept while it waited goes (a task still running
 * is cancelled). */
void rpc_wait_end(struct rpc_line *l)
{
	if (l->task)
		tasks_cancel(l->rpc->tasks, l->task);
	l->task = NULL;
	l->delay = sd_event_source_disable_unref(l->delay);
	if (l->pending_free)
		l->pending_free(l->pending);
	l->pending = NULL;
	l->pending_free = NULL;
}

/* The element of l that waited is answered: code and c's detail, or result. */
void rpc_line_answer(struct rpc_line *l, struct call *c, int code, json_t *result)
{
	l->task = NULL;         /* (its task is done: this is its answer) */
	rpc_wait_end(l);
	l->reply = rpc_make_reply(c, l->id, l->notification, code, result);
	l->state = ELEMENT_READY;
	if (l->ready)
		l->ready(l->ready_data);
}

/* The call's element waits for pending (what its method keeps, freed with
 * free_fn when the element ends or the line is freed). */
void rpc_defer(struct call *c, void *pending, void (*free_fn)(void *pending))
{
	c->deferred = true;
	c->line->pending = pending;
	c->line->pending_free = free_fn;
}

/* An answer given only after wait: the call's error, code. */
static int on_delay(sd_event_source *s, uint64_t usec, void *data)
{
	struct rpc_line *l = data;
	struct call c = { .rpc = l->rpc, .s = l->s, .line = l };

	proto_why_set(&c.why, "%s", (const char *)l->pending);
	rpc_line_answer(l, &c, PROTO_PERMISSION_DENIED, NULL);
	return 0;
}

int rpc_defer_answer(struct call *c, int code, uint64_t wait)
{
	struct rpc_line *l = c->line;
	char *why;

	/* Without a transport that waits (rpc_handle_line()), at once. */
	if (!l || !l->ready || code != PROTO_PERMISSION_DENIED || !(why = strdup(c->why.text)))
		return code;
	if (sd_event_add_time_relative(c->rpc->event, &l->delay, CLOCK_MONOTONIC, wait, 0,
				       on_delay, l) < 0) {
		free(why);
		return code;
	}
	rpc_defer(c, why, free);
	return 0;
}
