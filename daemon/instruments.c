/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Event loop thread: the configured instruments and the drivers. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "asph-driver/instrument.h"
#include "instruments.h"
#include "util-time.h"
#include "log.h"
#include "util-mem.h"

struct instruments {
	struct asph_registry *registry;
	struct asph_config *config;
	struct instrument *v;
	size_t n;
};

static void warn_plugin(const struct asph_error *err, void *data)
{
	char buf[1024];

	log_warning("driver plugin: %s", asph_error_format(err, buf, sizeof(buf)));
}

static int parse(const struct settings *s, struct instruments *ins, struct asph_error *err)
{
	int r;

	r = asph_registry_new(&ins->registry, err);
	if (r < 0)
		return r;
	asph_registry_load_default_dirs(ins->registry, warn_plugin, NULL, NULL);
	if (!s->instruments_json)
		return asph_instrument_spec_parse(ins->registry, "mock", &ins->config, err);
	r = asph_config_parse(ins->registry, s->instruments_json, strlen(s->instruments_json),
			      s->source, &ins->config, err);
	/* Their positions refer to the text we gave them; point into the
	 * file instead. */
	if (r < 0 && err && err->field[0])
		settings_locate(s, err->field, err);
	return r;
}

static int describe(struct instruments *ins, struct asph_error *err)
{
	ins->v = calloc(ins->config->n, sizeof(*ins->v));
	if (!ins->v)
		return asph_error_set(err, -ENOMEM, "out of memory");
	ins->n = ins->config->n;
	for (size_t i = 0; i < ins->n; i++) {
		struct instrument *in = &ins->v[i];
		_cleanup_free_ char *desc = NULL;
		int r;

		in->config = &ins->config->instruments[i];
		in->name = strdup(in->config->name);
		if (!in->name)
			return asph_error_set(err, -ENOMEM, "out of memory");
		r = asph_instrument_config_to_json(in->config, &desc);
		if (r < 0)
			return asph_error_set(err, r, "instrument %s: cannot describe it", in->name);
		in->description = json_loads(desc, 0, NULL);
	}
	return 0;
}

int instruments_load(const struct settings *s, struct instruments **out, struct asph_error *err)
{
	struct instruments *ins = calloc(1, sizeof(*ins));
	int r;

	if (!ins)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = parse(s, ins, err);
	if (r == 0)
		r = describe(ins, err);
	if (r < 0) {
		instruments_free(ins);
		return r;
	}
	*out = ins;
	return 0;
}

void instruments_free(struct instruments *ins)
{
	if (!ins)
		return;
	for (size_t i = 0; i < ins->n; i++) {
		json_decref(ins->v[i].description);
		free(ins->v[i].name);
	}
	free(ins->v);
	asph_config_free(ins->config);
	asph_registry_free(ins->registry);
	free(ins);
}

size_t instruments_count(const struct instruments *ins)
{
	return ins->n;
}

const struct instrument *instruments_get(const struct instruments *ins, size_t i)
{
	return i < ins->n ? &ins->v[i] : NULL;
}

int instruments_find(const struct instruments *ins, const char *name)
{
	for (size_t i = 0; i < ins->n; i++)
		if (!strcmp(ins->v[i].name, name))
			return (int)i;
	return -ENOENT;
}

const char *instrument_state_name(const struct instrument_activity *a)
{
	if (a->job)
		return a->paused ? "paused" : "measuring";
	return a->fault ? "fault" : "idle";
}

json_t *instrument_to_json(const struct instrument *in, const struct instrument_activity *a)
{
	json_t *o = json_pack("{s:s, s:s, s:O?}", "name", in->name,
			      "state", instrument_state_name(a),
			      "configuration", in->description);

	if (!o)
		return NULL;
	json_object_set_new(o, "job", a->job ? json_integer(a->job) : json_null());
	json_object_set_new(o, "fault", a->fault ? json_string(a->fault) : json_null());
	json_object_set_new(o, "lock", instrument_lock_to_json(a->lock));
	if (a->job)
		json_object_set_new(o, "progress", activity_progress_to_json(a));
	return o;
}

const char *activity_phase(const struct instrument_activity *a)
{
	if (a->planning)
		return "planning";
	if (!a->characterizing)
		return "measuring";
	return a->trials_planned > 0 ? "uncertainty" : "characterizing";
}

json_t *activity_progress_to_json(const struct instrument_activity *a)
{
	const char *phase = activity_phase(a);
	json_t *trials = a->characterizing && a->trials_planned > 0
		? json_pack("{s:I, s:I, s:f}", "done", (json_int_t)a->trials_done,
			    "planned", (json_int_t)a->trials_planned, "rate", a->trials_rate)
		: json_null();

	return json_pack("{s:I, s:I, s:f, s:f, s:s, s:o}", "done", (json_int_t)a->done,
			 "total", (json_int_t)a->total, "rate", a->rate, "eta_s", a->eta_s,
			 "phase", phase, "trials", trials);
}

json_t *instrument_lock_to_json(const struct instrument_lock *l)
{
	char since[ISO8601_SIZE];

	if (!l)
		return json_null();
	iso8601_utc(l->since_ns, 0, since, sizeof(since));
	return json_pack("{s:s, s:I, s:s, s:s, s:b}", "holder", l->holder,
			 "uid", (json_int_t)l->holder_uid, "reason", l->reason, "since", since,
			 "pause", l->pause);
}

/* The registry as asph drivers --json describes it (drivers/describe.c). */
json_t *drivers_to_json(const struct instruments *ins)
{
	_cleanup_free_ char *text = NULL;
	struct asph_error err;
	char buf[640];

	asph_error_clear(&err);
	if (asph_registry_to_json(ins->registry, false, &text, &err) < 0) {
		log_error("driver.list: %s", asph_error_format(&err, buf, sizeof(buf)));
		return NULL;
	}
	return json_loads(text, 0, NULL);
}
