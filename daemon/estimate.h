/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * A job's parameters checked (jobspec.h) and, where wanted, its measuring
 * time predicted (jobplan.h): the work of job.submit and job.estimate,
 * done by a task (tasks.h) since a freeform surface, a plan and its
 * feed-rate profile take seconds to compute. The loop makes it from the
 * request (its own copies of everything), a worker thread runs it, the
 * loop reads what it found. Each function says which thread runs it.
 */
#ifndef ASPHD_ESTIMATE_H
#define ASPHD_ESTIMATE_H

#include <stdbool.h>
#include <stdint.h>

#include <jansson.h>

#include "asph-proto.h"
#include "asph-driver/instrument.h"
#include "jobspec.h"
#include "tasks.h"

struct estimate {
	/* what to do */
	json_t *params;                 /* a copy of the request's */
	struct jobspec_limits limits;
	struct asph_config *instrument; /* a copy, or NULL: no time wanted */
	bool search;                    /* choose a plan for the tolerance */
	/* A job of measured data ("measured"): the client's descriptor it is
	 * read from (at most max_measured_bytes), and the unnamed file of the
	 * state directory it is copied into (jobs.h, data_fd); both owned,
	 * -1 otherwise. */
	int measured_fd, data_fd;
	uint64_t max_measured_bytes;
	/* what was found */
	int code;                       /* 0, or the protocol's error code */
	struct proto_why why;
	json_t *spec;                   /* the job's specification */
	uint64_t points;                /* the plan's, or the measured data's */
	char data_name[32];             /* the measured data's file in the job's folder */
	bool timed;                     /* the instrument can predict: seconds */
	double seconds;
	/* job.estimate of a plan for the tolerance (tolplan.h): the plan
	 * chosen and why; NULL otherwise (job.submit searches when the
	 * job runs). */
	json_t *choice;
};

/* Loop: the work for params (copied), with the time on instrument ic
 * (copied; NULL: none wanted). 0 or -ENOMEM. */
int estimate_new(json_t *params, const struct jobspec_limits *limits,
		 const struct asph_instrument_config *ic, bool search, struct estimate **out);
/* Loop: e reads its measured data from measured_fd into data_fd, each
 * taken (closed with e). */
void estimate_set_measured(struct estimate *e, int measured_fd, int data_fd,
			   uint64_t max_bytes);
/* A task's run(): worker thread. Always 0 (what it found is in e). */
int estimate_run(void *e, const struct task *task);
/* A task's free(): loop. */
void estimate_free(void *e);

#endif
