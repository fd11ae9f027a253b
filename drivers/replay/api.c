/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The replay instrument: a recorded scan played back. The stage goes
 * wherever it is told; the probe answers each plan point with the point
 * recorded for it, as an absolute reading, so that measuring the same plan
 * again reproduces the recording bit for bit. */
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "asph-driver/driver.h"
#include "asph/scanfile.h"
#include "std.h"
#include "util-time.h"

enum { OPT_FILE, OPT_TIME_FACTOR, N_OPTIONS };

static const struct asph_option_desc replay_options[N_OPTIONS] = {
	[OPT_FILE] = { "file", ASPH_OPTION_STRING, "", .roles = ASPH_ROLE_PROBE,
		       .help = "the recorded scan to play back (required)" },
	[OPT_TIME_FACTOR] = { "time_factor", ASPH_OPTION_DOUBLE, "0", .ranged = true, .min = 0,
			      .max = 1000, .roles = ASPH_ROLE_PROBE,
			      .help = "replays the recorded timing scaled by this (0: no waiting)" },
};

struct asph_device {
	atomic_bool stop;
	double pos[3];
	bool homed;
	/* probe */
	struct asph_scanfile *scan;
	size_t *by_index;       /* plan index -> its first point + 1, 0 = none */
	size_t *next;           /* point -> the next of its plan index + 1 */
	size_t n_index;
	size_t *ref_first, *ref_next;   /* the same for the references */
	size_t n_ref_index;
	double time_factor;
	uint64_t last_t_ns;
};

static int stage_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = calloc(1, sizeof(*d));

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	atomic_init(&d->stop, false);
	*out = d;
	return 0;
}

static void dev_close(struct asph_device *d)
{
	if (!d)
		return;
	asph_scanfile_free(d->scan);
	free(d->by_index);
	free(d->next);
	free(d->ref_first);
	free(d->ref_next);
	free(d);
}

static int stage_info(struct asph_device *d, struct asph_stage_info *out,
		      struct asph_error *err)
{
	static const char *const names[] = { "x", "y", "z" };

	memset(out, 0, sizeof(*out));
	out->kinematics = ASPH_KINEMATICS_XYZ;
	out->n_axes = 3;
	for (int k = 0; k < 3; k++) {
		snprintf(out->axes[k].name, sizeof(out->axes[k].name), "%s", names[k]);
		snprintf(out->axes[k].unit, sizeof(out->axes[k].unit), "mm");
		out->axes[k].min = -1e6;
		out->axes[k].max = 1e6;
	}
	snprintf(out->model, sizeof(out->model), "replay stage");
	return 0;
}

static int cancelled(struct asph_device *d, struct asph_error *err)
{
	if (atomic_load_explicit(&d->stop, memory_order_relaxed))
		return asph_error_set(err, -ECANCELED, "stopped");
	return 0;
}

static int stage_home(struct asph_device *d, unsigned timeout_ms, struct asph_error *err)
{
	memset(d->pos, 0, sizeof(d->pos));
	d->homed = true;
	return cancelled(d, err);
}

static int stage_move(struct asph_device *d, const double *t, unsigned timeout_ms,
		      struct asph_error *err)
{
	int r = cancelled(d, err);
	if (r == 0)
		memcpy(d->pos, t, sizeof(d->pos));
	return r;
}

static int stage_sweep(struct asph_device *d, const double *pos, size_t n,
		       unsigned timeout_ms, struct asph_error *err)
{
	return n ? stage_move(d, pos + 3 * (n - 1), timeout_ms, err) : 0;
}

static int stage_position(struct asph_device *d, double *pos, unsigned timeout_ms,
			  struct asph_error *err)
{
	memcpy(pos, d->pos, sizeof(d->pos));
	return 0;
}

static int stage_status(struct asph_device *d, struct asph_stage_status *out,
			unsigned timeout_ms, struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->state = d->homed ? ASPH_STAGE_IDLE : ASPH_STAGE_NOT_HOMED;
	out->homed = d->homed;
	memcpy(out->position, d->pos, sizeof(d->pos));
	return 0;
}

static int dev_stop(struct asph_device *d, struct asph_error *err)
{
	atomic_store(&d->stop, true);
	return 0;
}

/* For each index, the records of it in the order measured: the first,
 * and from each the next (+ 1; 0 = none). */
static int chain(const struct asph_scanfile_point *p, size_t n, size_t **first, size_t **next,
		 size_t *n_index)
{
	*n_index = 0;
	for (size_t i = 0; i < n; i++)
		if (p[i].plan_index >= *n_index)
			*n_index = p[i].plan_index + 1;
	*first = calloc(*n_index ? *n_index : 1, sizeof(**first));
	*next = calloc(n ? n : 1, sizeof(**next));
	size_t *last = calloc(*n_index ? *n_index : 1, sizeof(*last));
	if (!*first || !*next || !last) {
		free(last);
		return -ENOMEM;
	}
	for (size_t i = 0; i < n; i++) {
		uint64_t k = p[i].plan_index;
		if (last[k])
			(*next)[last[k] - 1] = i + 1;
		else
			(*first)[k] = i + 1;
		last[k] = i + 1;
	}
	free(last);
	return 0;
}

static int build_index(struct asph_device *d, struct asph_error *err)
{
	if (chain(d->scan->points, d->scan->n, &d->by_index, &d->next, &d->n_index) < 0 ||
	    chain(d->scan->references, d->scan->n_references, &d->ref_first, &d->ref_next,
		  &d->n_ref_index) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}

/* The attempt-th record of index (the last when there are fewer). */
static const struct asph_scanfile_point *nth(const struct asph_scanfile_point *p,
					     const size_t *first, const size_t *next, size_t n_index,
					     uint64_t index, uint32_t attempt, bool exact)
{
	size_t k = index < n_index ? first[index] : 0;

	for (uint32_t a = 0; k && a < attempt; a++) {
		if (!next[k - 1])
			return exact ? NULL : &p[k - 1];
		k = next[k - 1];
	}
	return k ? &p[k - 1] : NULL;
}

static int probe_open(const struct asph_driver *drv, const struct asph_option_value *o,
		      unsigned timeout_ms, struct asph_device **out, struct asph_error *err)
{
	struct asph_device *d = NULL;
	int r;

	if (!o[OPT_FILE].s || !*o[OPT_FILE].s)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "file",
					 "option 'file' is required: the scan to play back");
	r = stage_open(drv, o, timeout_ms, &d, err);
	if (r < 0)
		return r;
	d->time_factor = o[OPT_TIME_FACTOR].d;
	r = asph_scanfile_read(o[OPT_FILE].s, &d->scan, err);
	if (r == 0)
		r = build_index(d, err);
	if (r < 0) {
		dev_close(d);
		return r;
	}
	*out = d;
	return 0;
}

static int probe_info(struct asph_device *d, struct asph_probe_info *out,
		      struct asph_error *err)
{
	memset(out, 0, sizeof(*out));
	out->type = ASPH_PROBE_OPTICAL;
	out->range_min = -1e6;
	out->range_max = 1e6;
	out->can_stream = true;
	snprintf(out->model, sizeof(out->model), "replay probe");
	return 0;
}

static void pace(struct asph_device *d, uint64_t t_ns)
{
	if (d->time_factor > 0 && t_ns > d->last_t_ns) {
		sleep_ns((uint64_t)(d->time_factor * (double)(t_ns - d->last_t_ns)));
	}
	d->last_t_ns = t_ns;
}

static int probe_read(struct asph_device *d, const struct asph_probe_context *ctx,
		      struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	int r = cancelled(d, err);
	if (r < 0)
		return r;
	const struct asph_scanfile_point *p;
	if (ctx->kind == ASPH_MEASURE_REFERENCE) {
		p = nth(d->scan->references, d->ref_first, d->ref_next, d->n_ref_index,
			ctx->plan_index, ctx->attempt, true);
		if (!p)
			return asph_error_set(err, -ENODATA,
					      "the recording has no round %u of drift reference %llu "
					      "(record again with the drift_interval it had, or off)",
					      ctx->attempt, (unsigned long long)ctx->plan_index);
	} else {
		/* a point measured again: its record of that attempt */
		p = nth(d->scan->points, d->by_index, d->next, d->n_index, ctx->plan_index,
			ctx->attempt, false);
		if (!p)
			return asph_error_set(err, -ENODATA,
					      "the recording has no point for plan point %llu (was it recorded with this plan?)",
					      (unsigned long long)ctx->plan_index);
	}
	pace(d, p->t_ns);
	memset(out, 0, sizeof(*out));
	out->flags = ASPH_READING_ABSOLUTE;
	if (p->flags & ASPH_SCANFILE_POINT_TIP_COMPENSATED)
		out->flags |= ASPH_READING_TIP_COMPENSATED;
	if (p->flags & ASPH_SCANFILE_POINT_OUT_OF_RANGE)
		out->flags |= ASPH_READING_OUT_OF_RANGE;
	if (p->flags & ASPH_SCANFILE_POINT_LOW_SIGNAL)
		out->flags |= ASPH_READING_LOW_SIGNAL;
	if (p->flags & ASPH_SCANFILE_POINT_INVALID)
		out->flags |= ASPH_READING_INVALID;
	if (p->flags & ASPH_SCANFILE_POINT_COMMANDED)
		out->flags |= ASPH_READING_COMMANDED;
	/* where the recording says the stage was, and how it knew */
	out->position_source = p->position_source;
	if (p->position_source != ASPH_POSITION_NONE)
		memcpy(out->position, p->stage, sizeof(out->position));
	out->xyz[0] = p->x;
	out->xyz[1] = p->y;
	out->xyz[2] = p->z;
	out->raw = p->raw;
	out->value = p->z - ctx->xyz[2];
	return 0;
}

/* The recording's readings belong to their plan points, moving or not.
 * (The record's time is its own: the replay does not stamp readings.) */
static int probe_stream(struct asph_device *d, const struct asph_probe_context *ctx,
			size_t n, struct asph_reading *out, size_t *n_done,
			unsigned timeout_ms, struct asph_error *err)
{
	return std_stream_by_read(d, probe_read, ctx, n, out, n_done, timeout_ms, err);
}

static const struct asph_stage_ops replay_stage = {
	.open = stage_open,
	.close = dev_close,
	.info = stage_info,
	.home = stage_home,
	.move_to = stage_move,
	.sweep = stage_sweep,
	.position = stage_position,
	.status = stage_status,
	.stop = dev_stop,
};

static const struct asph_probe_ops replay_probe = {
	.open = probe_open,
	.close = dev_close,
	.info = probe_info,
	.read = probe_read,
	.stream = probe_stream,
	.stop = dev_stop,
};

const struct asph_driver replay_driver = {
	.abi_version = ASPH_DRIVER_ABI_VERSION,
	.name = "replay",
	.description = "plays a recorded scan back as an instrument",
	.version = "1.0",
	.roles = ASPH_ROLE_STAGE | ASPH_ROLE_PROBE,
	.options = replay_options,
	.n_options = N_OPTIONS,
	.stage = &replay_stage,
	.probe = &replay_probe,
};
