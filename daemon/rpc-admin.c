/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The admin's methods: the copies of the job store (backup.*) and the
 * named API tokens (token.*).
 *
 * Event loop thread.
 */
#include <errno.h>
#include <string.h>

#include "asph-proto.h"
#include "rpc-internal.h"
#include "util-mem.h"
#include "util-time.h"

/* ------------------------------------------------------------ backups */

static json_t *backup_json(const struct backup_info *b)
{
	char started[ISO8601_SIZE], finished[ISO8601_SIZE];

	iso8601_utc(b->started_ns, 0, started, sizeof(started));
	iso8601_utc(b->finished_ns, 0, finished, sizeof(finished));
	return json_pack("{s:s, s:s, s:I, s:I, s:o, s:s?, s:s?, s:s, s:s?}",
		"name", b->name, "state", backup_state_name(b->state),
		"pages_done", (json_int_t)b->pages_done, "pages_total", (json_int_t)b->pages_total,
		"size", b->state == BACKUP_DONE ? json_integer(b->size) : json_null(),
		"sha256", b->sha256, "error", b->error, "started", started,
		"finished", b->finished_ns ? finished : NULL);
}

/* This session's copy, or 107 saying there is none. */
static int session_backup(struct call *c, struct backup_info *info)
{
	if (backups_get(c->rpc->backups, c->s, info) < 0)
		return rpc_fail(c, PROTO_NO_RESULT, "this connection has made no copy of the job "
				"store: backup.start makes one");
	return 0;
}

int rpc_method_backup_start(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct backup_info info;
	struct asph_error err;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	asph_error_clear(&err);
	r = backups_start(c->rpc->backups, c->s, c->s->peer.name, &err);
	if (r == -EBUSY || r == -EDQUOT)
		return rpc_fail(c, PROTO_LIMIT_REACHED, "%s", err.message);
	if (r < 0)
		return rpc_fail(c, r == -ENOMEM ? PROTO_INTERNAL_ERROR : PROTO_STORAGE_ERROR, "%s",
				err.message[0] ? err.message : strerror(-r));
	if ((code = session_backup(c, &info)))
		return code;
	*result = backup_json(&info);
	return 0;
}

int rpc_method_backup_get(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	struct backup_info info;
	int code = rpc_only(c, params, names);

	if (code || (code = session_backup(c, &info)))
		return code;
	*result = backup_json(&info);
	return 0;
}

int rpc_method_backup_file(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "offset", "length", NULL };
	struct backup_info info;
	int64_t offset, length;
	int fd = -1, code = rpc_only(c, params, names);

	if (code || (code = rpc_chunk_params(c, params, &offset, &length)) ||
	    (code = session_backup(c, &info)))
		return code;
	switch (backups_fd(c->rpc->backups, c->s, &fd)) {
	case 0:
		return rpc_file_chunk(c, fd, info.name, offset, length, result);
	case -EAGAIN:
		return rpc_fail(c, PROTO_NO_RESULT, "the copy %s is not finished: %" PRId64 " of %"
				PRId64 " pages copied (backup.get tells when it is done)",
				info.name, info.pages_done, info.pages_total);
	default:
		return rpc_fail(c, PROTO_STORAGE_ERROR, "the copy %s failed: %s", info.name,
				info.error ? info.error : "?");
	}
}

/* ------------------------------------------------------------ tokens */

static int token_error(struct call *c, int r, const struct asph_error *err)
{
	int code = r == -EINVAL || r == -EEXIST ? PROTO_INVALID_PARAMS
		 : r == -ENOENT || r == -EALREADY ? PROTO_INVALID_STATE : PROTO_STORAGE_ERROR;

	return rpc_fail(c, code, "%s", err->message);
}

int rpc_method_token_create(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", "role", "expires", NULL };
	struct job_actor who = rpc_actor(c);
	char secret[TOKENS_SECRET_SIZE];
	const char *name, *role_name, *expires = NULL;
	enum access_role r_role;
	struct asph_error err;
	int64_t expires_ns = 0;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, TOKENS_NAME_MAX + 1, &name, &c->why) < 0 ||
	    proto_param_string(params, "role", true, 16, &role_name, &c->why) < 0 ||
	    proto_param_string(params, "expires", false, 32, &expires, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (access_role_from_name(role_name, &r_role) < 0)
		return rpc_fail(c, PROTO_INVALID_PARAMS,
				"\"role\" must be viewer, operator or admin");
	if (expires && iso8601_parse_utc(expires, &expires_ns) < 0)
		return rpc_fail(c, PROTO_INVALID_PARAMS, "\"expires\" must be a UTC time such as "
				"\"2027-01-31T12:00:00Z\" or a day such as \"2027-01-31\"");
	asph_error_clear(&err);
	r = tokens_create(c->rpc->tokens, name, r_role, expires_ns, who.name, secret, &err);
	if (r < 0)
		return token_error(c, r, &err);
	*result = json_pack("{s:s, s:s, s:s?, s:s}", "name", name, "role", role_name,
			    "expires", expires, "token", secret);
	explicit_bzero(secret, sizeof(secret));
	return 0;
}

int rpc_method_token_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = rpc_only(c, params, names);

	if (code)
		return code;
	*result = tokens_to_json(c->rpc->tokens);
	return 0;
}

int rpc_method_token_revoke(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", NULL };
	struct asph_error err;
	const char *name;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, TOKENS_NAME_MAX + 1, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	asph_error_clear(&err);
	r = tokens_revoke(c->rpc->tokens, name, &err);
	if (r < 0)
		return token_error(c, r, &err);
	*result = json_pack("{s:s, s:s}", "name", name, "state", "revoked");
	return 0;
}
