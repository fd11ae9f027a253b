/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The methods of the instruments: instrument.list, instrument.status,
 * instrument.lock, instrument.unlock, driver.list.
 *
 * Event loop thread.
 */
#include <errno.h>

#include "asph-proto.h"
#include "rpc-internal.h"

/* ------------------------------------------------------- instruments */

static json_t *instrument_json(const struct rpc *rpc, size_t i)
{
	return instrument_to_json(instruments_get(rpc->instruments, i),
				  jobs_activity(rpc->jobs, i));
}

int rpc_method_instrument_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	json_t *list;
	int code = rpc_only(c, params, names);

	if (code)
		return code;
	list = json_array();
	for (size_t i = 0; list && i < instruments_count(c->rpc->instruments); i++)
		json_array_append_new(list, instrument_json(c->rpc, i));
	*result = json_pack("{s:o}", "instruments", list);
	return 0;
}

int rpc_method_instrument_status(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", NULL };
	const char *name;
	int i, code = rpc_only(c, params, names);

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0)
		return PROTO_INVALID_PARAMS;
	i = instruments_find(c->rpc->instruments, name);
	if (i < 0)
		return rpc_fail(c, PROTO_NO_SUCH_INSTRUMENT, "no instrument \"%s\"", name);
	*result = instrument_json(c->rpc, (size_t)i);
	return 0;
}

int rpc_method_driver_list(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { NULL };
	int code = rpc_only(c, params, names);

	if (code)
		return code;
	*result = drivers_to_json(c->rpc->instruments);
	return 0;
}

static int lock_result(struct call *c, const char *name, json_t **result)
{
	int i = instruments_find(c->rpc->instruments, name);

	*result = i < 0 ? NULL : instrument_json(c->rpc, (size_t)i);
	return 0;
}

int rpc_method_instrument_lock(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", "reason", "pause", NULL };
	struct job_actor who = rpc_actor(c);
	const char *name, *reason;
	struct asph_error err;
	bool pause = false;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0 ||
	    proto_param_string(params, "reason", true, c->rpc->limits->max_label_bytes, &reason,
			       &c->why) < 0 ||
	    proto_param_bool(params, "pause", false, &pause, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (!reason[0])
		return rpc_fail(c, PROTO_INVALID_PARAMS, "\"reason\" must say why the instrument "
				"is locked");
	asph_error_clear(&err);
	r = jobs_lock(c->rpc->jobs, name, reason, pause, &who, &err);
	return r < 0 ? rpc_job_error(c, r, &err) : lock_result(c, name, result);
}

int rpc_method_instrument_unlock(struct call *c, json_t *params, json_t **result)
{
	static const char *const names[] = { "name", "force", NULL };
	struct job_actor who = rpc_actor(c);
	struct asph_error err;
	const char *name;
	bool force = false;
	int code = rpc_only(c, params, names), r;

	if (code)
		return code;
	if (proto_param_string(params, "name", true, 63, &name, &c->why) < 0 ||
	    proto_param_bool(params, "force", false, &force, &c->why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (force && rpc_role(c) < ROLE_ADMIN)
		return rpc_fail(c, PROTO_PERMISSION_DENIED, "only an admin may end another's lock "
				"(force)");
	asph_error_clear(&err);
	r = jobs_unlock(c->rpc->jobs, name, force, &who, &err);
	if (r == -EINVAL)
		return rpc_fail(c, PROTO_INVALID_STATE, "%s", err.message);
	return r < 0 ? rpc_job_error(c, r, &err) : lock_result(c, name, result);
}
