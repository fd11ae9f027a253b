/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The configured instruments, each with its worker, and the drivers. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "asph/instrument.h"
#include "asphd.h"
#include "jsonpos.h"
#include "log.h"
#include "util-mem.h"

static void warn_plugin(const struct asph_error *err, void *data)
{
	char buf[1024];

	log_warning("driver plugin: %s", asph_error_format(err, buf, sizeof(buf)));
}

int instruments_load(const struct settings *cfg, struct asph_registry **reg_out,
		     struct asph_config **out, struct asph_error *err)
{
	struct asph_registry *reg = NULL;
	int r;

	r = asph_registry_new(&reg, err);
	if (r < 0)
		return r;
	asph_registry_load_default_dirs(reg, warn_plugin, NULL, NULL);
	if (!cfg->instruments_json) {
		r = asph_instrument_spec_parse(reg, "mock", out, err);
	} else {
		r = asph_config_parse(reg, cfg->instruments_json, strlen(cfg->instruments_json),
				      cfg->source, out, err);
		/* Their positions refer to the text we gave them; point into
		 * the file instead. */
		if (r < 0 && err && err->field[0] && cfg->text) {
			int line = 0, column = 0;
			if (json_locate_dotted(cfg->text, cfg->text_len, err->field,
					       &line, &column) == 0)
				asph_error_locate(err, cfg->source, line, column, NULL);
		}
	}
	if (r < 0) {
		asph_registry_free(reg);
		return r;
	}
	*reg_out = reg;
	return 0;
}

static void report(const struct runner_report *rep, void *data)
{
	jobs_runner_report(data, rep);
}

int instruments_setup(struct daemon *d, struct asph_error *err)
{
	struct asph_config *cfg = d->instrument_config;
	int r;

	d->instruments = calloc(cfg->n, sizeof(*d->instruments));
	if (!d->instruments)
		return asph_error_set(err, -ENOMEM, "out of memory");
	d->n_instruments = cfg->n;
	for (size_t i = 0; i < cfg->n; i++) {
		struct instrument *in = &d->instruments[i];
		_cleanup_free_ char *desc = NULL;

		in->d = d;
		in->name = strdup(cfg->instruments[i].name);
		if (!in->name)
			return asph_error_set(err, -ENOMEM, "out of memory");
		r = asph_instrument_config_to_json(&cfg->instruments[i], &desc);
		if (r < 0)
			return asph_error_set(err, r, "instrument %s: cannot describe it",
					      in->name);
		in->description = json_loads(desc, 0, NULL);
		r = runner_new(&cfg->instruments[i], d->event, report, in, &in->runner);
		if (r < 0)
			return asph_error_set(err, r, "instrument %s: cannot start its worker: %s",
					      in->name, strerror(-r));
	}
	return 0;
}

void instruments_free(struct daemon *d)
{
	for (size_t i = 0; i < d->n_instruments; i++) {
		struct instrument *in = &d->instruments[i];
		runner_free(in->runner);
		json_decref(in->description);
		free(in->name);
		free(in->fault);
	}
	free(d->instruments);
	d->instruments = NULL;
	d->n_instruments = 0;
}

struct instrument *instrument_find(struct daemon *d, const char *name)
{
	for (size_t i = 0; i < d->n_instruments; i++)
		if (!strcmp(d->instruments[i].name, name))
			return &d->instruments[i];
	return NULL;
}

struct instrument *instrument_of_job(struct daemon *d, int64_t id)
{
	for (size_t i = 0; i < d->n_instruments; i++)
		if (d->instruments[i].job == id)
			return &d->instruments[i];
	return NULL;
}

const char *instrument_state(const struct instrument *in)
{
	if (in->job)
		return in->paused ? "paused" : "measuring";
	return in->fault ? "fault" : "idle";
}

json_t *instrument_to_json(struct instrument *in)
{
	json_t *o = json_pack("{s:s, s:s, s:O?}", "name", in->name,
			      "state", instrument_state(in),
			      "configuration", in->description);

	if (!o)
		return NULL;
	json_object_set_new(o, "job", in->job ? json_integer(in->job) : json_null());
	json_object_set_new(o, "fault", in->fault ? json_string(in->fault) : json_null());
	if (in->job)
		json_object_set_new(o, "progress",
				    json_pack("{s:I, s:I, s:f, s:f}", "done", (json_int_t)in->done,
					      "total", (json_int_t)in->total, "rate", in->rate,
					      "eta_s", in->eta_s));
	return o;
}

static json_t *option_to_json(const struct asph_option_desc *o)
{
	json_t *j = json_pack("{s:s, s:s, s:s?, s:s?, s:s?}", "name", o->name,
			      "type", asph_option_type_name(o->type),
			      "default", o->default_value, "unit", o->unit, "help", o->help);

	if (!j)
		return NULL;
	if (o->ranged) {
		json_object_set_new(j, "min", json_real(o->min));
		json_object_set_new(j, "max", json_real(o->max));
	}
	if (o->choices) {
		json_t *c = json_array();
		for (size_t k = 0; o->choices[k]; k++)
			json_array_append_new(c, json_string(o->choices[k]));
		json_object_set_new(j, "choices", c);
	}
	if (o->roles) {
		json_t *roles = json_array();
		if (o->roles & ASPH_ROLE_STAGE)
			json_array_append_new(roles, json_string("stage"));
		if (o->roles & ASPH_ROLE_PROBE)
			json_array_append_new(roles, json_string("probe"));
		json_object_set_new(j, "roles", roles);
	}
	return j;
}

json_t *drivers_to_json(struct daemon *d)
{
	json_t *list = json_array();

	for (size_t i = 0; list && i < asph_registry_count(d->registry); i++) {
		const struct asph_driver *drv = asph_registry_get(d->registry, i);
		json_t *roles = json_array(), *opts = json_array();
		if (drv->roles & ASPH_ROLE_STAGE)
			json_array_append_new(roles, json_string("stage"));
		if (drv->roles & ASPH_ROLE_PROBE)
			json_array_append_new(roles, json_string("probe"));
		for (size_t k = 0; k < drv->n_options; k++)
			json_array_append_new(opts, option_to_json(&drv->options[k]));
		json_array_append_new(list, json_pack("{s:s, s:s?, s:s?, s:s, s:o, s:o}",
			"name", drv->name, "description", drv->description,
			"version", drv->version, "origin", asph_registry_origin(d->registry, i),
			"roles", roles, "options", opts));
	}
	return list;
}
