/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The check and estimate of a job, on a task's thread (estimate.h). */
#include <errno.h>
#include <stdlib.h>

#include "estimate.h"
#include "jobplan.h"
#include "util-mem.h"

int estimate_new(json_t *params, const struct jobspec_limits *limits,
		 const struct asph_instrument_config *ic, struct estimate **out)
{
	struct estimate *e = calloc(1, sizeof(*e));

	if (!e)
		return -ENOMEM;
	e->limits = *limits;
	e->params = json_deep_copy(params);
	if (!e->params || (ic && asph_instrument_config_copy(ic, &e->instrument, NULL) < 0)) {
		estimate_free(e);
		return -ENOMEM;
	}
	*out = e;
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
	text = json_dumps(e->spec, JSON_COMPACT);
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
	asph_config_free(e->instrument);
	free(e);
}
