/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "job.h"

static const char *const state_names[JOB_N_STATES] = {
	[JOB_QUEUED] = "queued",
	[JOB_RUNNING] = "running",
	[JOB_PAUSED] = "paused",
	[JOB_COMPLETED] = "completed",
	[JOB_FAILED] = "failed",
	[JOB_CANCELLED] = "cancelled",
	[JOB_INTERRUPTED] = "interrupted",
};

const char *job_state_name(enum job_state s)
{
	return (unsigned)s < JOB_N_STATES ? state_names[s] : "unknown";
}

int job_state_from_name(const char *name, enum job_state *out)
{
	for (int i = 0; i < JOB_N_STATES; i++)
		if (!strcmp(state_names[i], name)) {
			*out = (enum job_state)i;
			return 0;
		}
	return -EINVAL;
}

bool job_state_final(enum job_state s)
{
	return s == JOB_COMPLETED || s == JOB_FAILED || s == JOB_CANCELLED;
}

void job_record_clear(struct job_record *j)
{
	free(j->label);
	free(j->instrument);
	free(j->user);
	free(j->spec);
	free(j->reason);
	free(j->result);
	free(j->scan_path);
	free(j->part);
	free(j->lot);
	free(j->serial);
	memset(j, 0, sizeof(*j));
}
