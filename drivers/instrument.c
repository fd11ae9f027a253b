/* SPDX-License-Identifier: GPL-3.0-or-later */
/* An instrument: the stage and probe devices of a configuration, open,
 * and the calls that take readings from drivers of every ABI minor
 * version. */
#include <errno.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "asph-driver/instrument.h"
#include "util-time.h"

/*
 * The structures a probe of ABI 1.0 reads and writes: struct
 * asph_probe_context and struct asph_reading as they were, before 1.1
 * appended members. Arrays of them have this stride.
 */
struct context_1_0 {
	uint64_t plan_index;
	double machine[ASPH_DRIVER_MAX_AXES];
	double xyz[3];
};

struct reading_1_0 {
	double value;
	double raw;
	double xyz[3];
	uint64_t t_ns;
	uint32_t flags;
};

_Static_assert(sizeof(struct context_1_0) == offsetof(struct asph_probe_context, kind),
	       "1.1 appends to the 1.0 probe context");
_Static_assert(offsetof(struct reading_1_0, flags) == offsetof(struct asph_reading, flags),
	       "1.1 appends to the 1.0 reading");

/* The flags a probe of ABI 1.0 may set. */
#define READING_FLAGS_1_0 (ASPH_READING_OUT_OF_RANGE | ASPH_READING_LOW_SIGNAL | \
			   ASPH_READING_ABSOLUTE | ASPH_READING_TIP_COMPENSATED)

unsigned asph_driver_abi_minor(const struct asph_driver *d)
{
	return ASPH_DRIVER_ABI_MINOR_OF(d->abi_version);
}

void asph_instrument_close(struct asph_instrument *inst)
{
	if (!inst)
		return;
	if (inst->probe)
		inst->probe_driver->probe->close(inst->probe);
	if (inst->stage)
		inst->stage_driver->stage->close(inst->stage);
	free(inst->scratch);
	free(inst);
}

/* The operations as this program may call them: a driver's table of an
 * older minor version ends before the members appended since. */
static void callable_ops(struct asph_instrument *in)
{
	const struct asph_driver *s = in->stage_driver, *p = in->probe_driver;

	memset(&in->stage_ops, 0, sizeof(in->stage_ops));
	memset(&in->probe_ops, 0, sizeof(in->probe_ops));
	unsigned sm = asph_driver_abi_minor(s);
	memcpy(&in->stage_ops, s->stage,
	       sm >= 3   ? sizeof(in->stage_ops)
	       : sm == 2 ? offsetof(struct asph_stage_ops, motion_time)
	       : sm == 1 ? offsetof(struct asph_stage_ops, clock_align)
			 : offsetof(struct asph_stage_ops, sweep_pvt));
	memcpy(&in->probe_ops, p->probe,
	       asph_driver_abi_minor(p) >= 1 ? sizeof(in->probe_ops)
					     : offsetof(struct asph_probe_ops, attach));
}

static int open_devices(struct asph_instrument *in, unsigned timeout_ms,
			struct asph_error *err)
{
	const struct asph_instrument_config *c = in->config;
	int r = c->stage_driver->stage->open(c->stage_driver,
					     asph_options_values(c->stage_options),
					     timeout_ms, &in->stage, err);
	if (r < 0)
		return r;
	r = c->probe_driver->probe->open(c->probe_driver,
					 asph_options_values(c->probe_options),
					 timeout_ms, &in->probe, err);
	if (r < 0)
		return r;
	/* a driver of an older minor version leaves the newer members as
	 * they are: 0 */
	memset(&in->stage_info, 0, sizeof(in->stage_info));
	r = c->stage_driver->stage->info(in->stage, &in->stage_info, err);
	if (r < 0)
		return r;
	if (in->stage_info.n_axes != 3)
		return asph_error_set(err, -EPROTO, "stage '%s' reports %u axes; 3 are needed",
				      c->stage_driver->name, in->stage_info.n_axes);
	memset(&in->probe_info, 0, sizeof(in->probe_info));
	r = c->probe_driver->probe->info(in->probe, &in->probe_info, err);
	if (r < 0)
		return r;
	if (in->probe_ops.attach) {
		r = in->probe_ops.attach(in->probe, c->stage_driver, in->stage);
		if (r < 0)
			return asph_error_set(err, r, "probe '%s' cannot be mounted on stage '%s'",
					      c->probe_driver->name, c->stage_driver->name);
		in->attached = r > 0;
	}
	in->shared_timebase = in->attached || !in->stage_ops.clock;
	return 0;
}

int asph_instrument_open(const struct asph_instrument_config *c,
			 unsigned timeout_ms, struct asph_instrument **out,
			 struct asph_error *err)
{
	struct asph_instrument *in = calloc(1, sizeof(*in));

	if (!in)
		return asph_error_set(err, -ENOMEM, "out of memory");
	in->config = c;
	in->stage_driver = c->stage_driver;
	in->probe_driver = c->probe_driver;
	callable_ops(in);
	int r = open_devices(in, timeout_ms, err);
	if (r < 0) {
		asph_instrument_close(in);
		return r;
	}
	*out = in;
	return 0;
}

uint64_t asph_instrument_clock(struct asph_instrument *inst)
{
	uint64_t t;

	if (inst->stage_ops.clock && inst->stage_ops.clock(inst->stage, &t) == 0)
		return t;
	return now_monotonic_ns();
}

/* --------------------------------------------------- readings of 1.0 */

static void context_to_1_0(const struct asph_probe_context *c, struct context_1_0 *o)
{
	o->plan_index = c->plan_index;
	memcpy(o->machine, c->machine, sizeof(o->machine));
	memcpy(o->xyz, c->xyz, sizeof(o->xyz));
}

static void reading_from_1_0(const struct reading_1_0 *r, struct asph_reading *o)
{
	memset(o, 0, sizeof(*o));
	o->value = r->value;
	o->raw = r->raw;
	memcpy(o->xyz, r->xyz, sizeof(o->xyz));
	o->t_ns = r->t_ns;
	o->flags = r->flags & READING_FLAGS_1_0;
}

static bool probe_1_0(const struct asph_instrument *inst)
{
	return asph_driver_abi_minor(inst->probe_driver) == 0;
}

int asph_instrument_read(struct asph_instrument *inst, const struct asph_probe_context *ctx,
			 struct asph_reading *out, unsigned timeout_ms, struct asph_error *err)
{
	const struct asph_probe_ops *ops = inst->probe_driver->probe;

	if (!probe_1_0(inst)) {
		memset(out, 0, sizeof(*out));
		return ops->read(inst->probe, ctx, out, timeout_ms, err);
	}
	struct context_1_0 c;
	struct reading_1_0 r;
	memset(&r, 0, sizeof(r));
	context_to_1_0(ctx, &c);
	int ret = ops->read(inst->probe, (const struct asph_probe_context *)(const void *)&c,
			    (struct asph_reading *)(void *)&r, timeout_ms, err);
	if (ret == 0)
		reading_from_1_0(&r, out);
	return ret;
}

/* Room for n contexts and n readings of 1.0, kept for the next call. */
static int scratch(struct asph_instrument *inst, size_t n)
{
	if (inst->scratch_n >= n)
		return 0;
	void *p = realloc(inst->scratch, n * (sizeof(struct context_1_0) + sizeof(struct reading_1_0)));
	if (!p)
		return -ENOMEM;
	inst->scratch = p;
	inst->scratch_n = n;
	return 0;
}

int asph_instrument_stream(struct asph_instrument *inst, const struct asph_probe_context *ctx,
			   size_t n, struct asph_reading *out, size_t *n_done,
			   unsigned timeout_ms, struct asph_error *err)
{
	const struct asph_probe_ops *ops = inst->probe_driver->probe;

	*n_done = 0;
	if (!ops->stream)
		return asph_error_set(err, -ENOTSUP, "probe '%s' does not stream",
				      inst->probe_driver->name);
	if (!probe_1_0(inst)) {
		memset(out, 0, n * sizeof(*out));
		return ops->stream(inst->probe, ctx, n, out, n_done, timeout_ms, err);
	}
	if (scratch(inst, n) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	struct context_1_0 *c = inst->scratch;
	struct reading_1_0 *r = (struct reading_1_0 *)(void *)(c + inst->scratch_n);
	for (size_t i = 0; i < n; i++)
		context_to_1_0(&ctx[i], &c[i]);
	memset(r, 0, n * sizeof(*r));
	int ret = ops->stream(inst->probe, (const struct asph_probe_context *)(const void *)c, n,
			      (struct asph_reading *)(void *)r, n_done, timeout_ms, err);
	if (*n_done > n)
		*n_done = n;
	for (size_t i = 0; i < *n_done; i++)
		reading_from_1_0(&r[i], &out[i]);
	return ret;
}

/* --------------------------------------------------------- describe */

int asph_instrument_describe(const struct asph_instrument_config *c,
			     struct asph_stage_info *stage, struct asph_probe_info *probe,
			     struct asph_error *err)
{
	const struct asph_driver *s = c->stage_driver, *p = c->probe_driver;
	int r;

	memset(stage, 0, sizeof(*stage));
	memset(probe, 0, sizeof(*probe));
	if (asph_driver_abi_minor(s) < 1 || !s->stage->describe)
		return asph_error_set(err, -ENOTSUP,
				      "stage '%s' cannot describe its motion without being opened",
				      s->name);
	if (asph_driver_abi_minor(p) < 1 || !p->probe->describe)
		return asph_error_set(err, -ENOTSUP,
				      "probe '%s' cannot describe itself without being opened", p->name);
	r = s->stage->describe(s, asph_options_values(c->stage_options), stage, err);
	if (r == 0)
		r = p->probe->describe(p, asph_options_values(c->probe_options), probe, err);
	return r;
}
