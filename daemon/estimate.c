/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The check and estimate of a job, on a task's thread (estimate.h). */
#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asph/points.h"
#include "fileio.h"

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
	e->measured_fd = e->data_fd = -1;
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

void estimate_set_measured(struct estimate *e, int measured_fd, int data_fd,
			   uint64_t max_bytes)
{
	e->measured_fd = measured_fd;
	e->data_fd = data_fd;
	e->max_measured_bytes = max_bytes;
}

/* The client's data, at most max_measured_bytes: a regular file, whose
 * reading ends (a pipe the client holds open would hold the thread). 0,
 * or a protocol error code with why. */
static int measured_slurp(struct estimate *e, char **data, size_t *len)
{
	struct asph_error err;
	struct stat st;

	if (fstat(e->measured_fd, &st) < 0 || !S_ISREG(st.st_mode)) {
		proto_why_set(&e->why, "\"measured\": the descriptor passed is not a regular "
			      "file");
		return PROTO_INVALID_PARAMS;
	}
	asph_error_clear(&err);
	if ((uint64_t)st.st_size <= e->max_measured_bytes &&
	    fd_read_all(e->measured_fd, e->max_measured_bytes, "measured data", data, len,
			&err) == 0)
		return 0;
	if ((uint64_t)st.st_size > e->max_measured_bytes || err.code == -EFBIG) {
		proto_why_set(&e->why, "\"measured\": the data is larger than "
			      "limits.max_measured_bytes (%" PRIu64 " bytes)", e->max_measured_bytes);
		return PROTO_LIMIT_REACHED;
	}
	proto_why_set(&e->why, "\"measured\": %s", err.message);
	return err.code == -ENOMEM ? PROTO_INTERNAL_ERROR : PROTO_INVALID_PARAMS;
}

/* len bytes into the unnamed file, on disk before the job is queued. */
static int measured_keep(struct estimate *e, const char *data, size_t len)
{
	int r = fd_write_all(e->data_fd, data, len);

	if (r == 0 && fsync(e->data_fd) < 0)
		r = -errno;
	if (r < 0) {
		proto_why_set(&e->why, "\"measured\": cannot keep the data in the state "
			      "directory: %s", strerror(-r));
		return PROTO_INTERNAL_ERROR;
	}
	return 0;
}

/* The measured data read, as the job will read it (its format then
 * fixed in the spec, with the file's name), and kept: the answer to a
 * file that does not parse is the reader's message. */
static int measured_read(struct estimate *e)
{
	json_t *m = json_object_get(e->spec, "measured");
	struct asph_points_read_options o = { 0 };
	struct asph_points_read_info info;
	struct asph_points *pts = NULL;
	const char *units = json_string_value(json_object_get(m, "units"));
	const char *format;
	_cleanup_free_ char *data = NULL;
	struct asph_error err;
	size_t len;
	int code = measured_slurp(e, &data, &len);

	if (code)
		return code;
	asph_points_format_parse(json_string_value(json_object_get(m, "format")), &o.format);
	if (units)
		asph_points_unit_parse(units, &o.unit_mm);
	asph_error_clear(&err);
	if (asph_points_read_memory_as(data, len, "measured data", &o, &pts, &info, &err) < 0) {
		char text[sizeof(e->why.text)];
		asph_error_format(&err, text, sizeof(text));
		proto_why_set(&e->why, "\"measured\": %s", text);
		return err.code == -ENOMEM ? PROTO_INTERNAL_ERROR : PROTO_INVALID_PARAMS;
	}
	e->points = pts->n;
	asph_points_free(pts);
	format = asph_points_format_name(info.format);
	/* the extension the lab's tools know the file by */
	snprintf(e->data_name, sizeof(e->data_name), "measured.%s",
		 info.format == ASPH_POINTS_TEXT ? "txt" :
		 info.format == ASPH_POINTS_METROPRO ? "dat" : format);
	if (json_object_set_new(m, "format", json_string(format)) < 0 ||
	    json_object_set_new(m, "file", json_string(e->data_name)) < 0)
		return PROTO_INTERNAL_ERROR;
	return e->data_fd >= 0 ? measured_keep(e, data, len) : 0;   /* job.estimate: none */
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
	if (!e->code && jobspec_measured(e->spec)) {
		/* no plan, nothing to time: what there is to check is the data */
		if (e->measured_fd >= 0 && !task_cancelled(task))
			e->code = measured_read(e);
		return 0;
	}
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
	if (e->measured_fd >= 0)
		close(e->measured_fd);
	if (e->data_fd >= 0)
		close(e->data_fd);
	free(e);
}
