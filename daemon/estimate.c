/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The check and estimate of a job, on a task's thread (estimate.h). */
#include <errno.h>
#include <stdlib.h>

#include "estimate.h"
#include "jobplan.h"
#include "tolplan.h"
#include "util-mem.h"

int estimate_new(json_t *params, const struct jobspec_limits *limits,
		 const struct asph_instrument_config *ic, bool search, struct estimate **out)
{
	struct estimate *e = calloc(1, sizeof(*e));

	if (!e)
		return -ENOMEM;
	e->limits = *limits;
	e->search = search;
	e->params = json_deep_copy(params);
	if (!e->params || (ic && asph_instrument_config_copy(ic, &e->instrument, NULL) < 0)) {
		estimate_free(e);
		return -ENOMEM;
	}
	*out = e;
	return 0;
}

static bool cancelled(void *task)
{
	return task_cancelled(task);
}

/* The plan for the tolerance: the instrument must declare its
 * uncertainty (refused at submission, not when the job runs); job.estimate
 * searches it (the task's deadline bounds it), *text then the spec with
 * the chosen plan. */
static int for_tolerance(struct estimate *e, const struct task *task, char **text)
{
	const struct asph_instrument_config *ic = &e->instrument->instruments[0];
	const struct tolplan_hooks hooks = { .cancelled = cancelled, .data = (void *)task };
	_cleanup_free_ char *spec = NULL, *chosen = NULL, *choice = NULL;
	struct asph_error err;
	int r;

	asph_error_clear(&err);
	if (tolplan_instrument_ok(ic, &err) < 0) {
		proto_why_set(&e->why, "\"plan.for_tolerance\": %s", err.message);
		return PROTO_INVALID_PLAN;
	}
	if (!e->search)
		return 0;
	spec = json_dumps(e->spec, JSON_COMPACT);
	if (!spec)
		return PROTO_INTERNAL_ERROR;
	r = tolplan_choose(spec, e->limits.max_points, ic, &hooks, &chosen, &choice, &err);
	if (r == -ECANCELED)
		return 0;
	if (r < 0) {
		proto_why_set(&e->why, "\"plan.for_tolerance\": %s", err.message);
		return r == -ENOMEM ? PROTO_INTERNAL_ERROR : PROTO_INVALID_PLAN;
	}
	e->choice = json_loads(choice, 0, NULL);
	if (!e->choice)
		return PROTO_INTERNAL_ERROR;
	e->points = (uint64_t)json_integer_value(json_object_get(json_object_get(e->choice,
									  "plan"), "points"));
	*text = steal_ptr(chosen);
	return 0;
}

int estimate_run(void *data, const struct task *task)
{
	struct estimate *e = data;
	_cleanup_free_ char *text = NULL;
	struct asph_error err;

	e->code = jobspec_from_params(e->params, &e->limits, &e->spec, &e->points, &e->why);
	if (e->code || !e->instrument || task_cancelled(task))
		return 0;
	if (jobspec_for_tolerance(e->spec)) {
		e->code = for_tolerance(e, task, &text);
		if (e->code || !text)
			return 0;
	} else {
		text = json_dumps(e->spec, JSON_COMPACT);
	}
	asph_error_clear(&err);
	/* Drivers that cannot describe themselves without a device give no
	 * time: the job is fine all the same. */
	e->timed = text && job_plan_estimate(text, e->limits.max_points,
					     &e->instrument->instruments[0], &e->seconds,
					     &err) == 0;
	return 0;
}

void estimate_free(void *data)
{
	struct estimate *e = data;

	if (!e)
		return;
	json_decref(e->params);
	json_decref(e->spec);
	json_decref(e->choice);
	asph_config_free(e->instrument);
	free(e);
}
