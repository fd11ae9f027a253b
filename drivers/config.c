/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Instrument configurations: sigrok-cli style specs and JSON files. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <jansson.h>

#include "asph-driver/instrument.h"
#include "jsonpos.h"
#include "options-internal.h"
#include "fileio.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)

void asph_config_free(struct asph_config *c)
{
	if (!c)
		return;
	for (size_t i = 0; i < c->n; i++) {
		asph_options_free(c->instruments[i].stage_options);
		asph_options_free(c->instruments[i].probe_options);
	}
	free(c->instruments);
	free(c);
}

static int config_alloc(size_t n, struct asph_config **out, struct asph_error *err)
{
	struct asph_config *c = calloc(1, sizeof(*c));

	if (c)
		c->instruments = calloc(n ? n : 1, sizeof(*c->instruments));
	if (!c || !c->instruments) {
		free(c);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	c->n = n;
	for (size_t i = 0; i < n; i++)
		asph_acquisition_defaults(&c->instruments[i].acquisition);
	*out = c;
	return 0;
}

static int role_options(const struct asph_driver *drv, unsigned role,
			const struct asph_driver **slot, struct asph_options **opts,
			struct asph_error *err)
{
	if (!(drv->roles & role))
		return asph_error_set(err, -EINVAL, "driver '%s' cannot be a %s", drv->name,
				      role == ASPH_ROLE_STAGE ? "stage" : "probe");
	*slot = drv;
	return asph_options_new(drv, opts, err);
}

/* ------------------------------------------------------------- spec */

static int spec_option(struct asph_instrument_config *ic, char *kv,
		       struct asph_error *err)
{
	char *eq = strchr(kv, '=');

	if (!eq || eq == kv)
		return asph_error_set(err, -EINVAL, "'%s' is not key=value", kv);
	*eq = '\0';
	int r = asph_acquisition_set(&ic->acquisition, kv, eq + 1, err);
	if (r != -ENOENT)
		return r;
	r = asph_options_set(ic->stage_options, kv, eq + 1, err);
	if (r == 0)
		r = asph_options_set(ic->probe_options, kv, eq + 1, err);
	return r;
}

int asph_instrument_spec_parse(const struct asph_registry *reg,
			       const char *spec, struct asph_config **out,
			       struct asph_error *err)
{
	_cleanup_(asph_config_freep) struct asph_config *c = NULL;
	_cleanup_free_ char *copy = strdup(spec);
	int r;

	if (!copy)
		return asph_error_set(err, -ENOMEM, "out of memory");
	char *opts = strchr(copy, ':');
	if (opts)
		*opts++ = '\0';
	const struct asph_driver *drv = asph_registry_find(reg, copy);
	if (!drv) {
		char hint[96];
		return asph_error_set(err, -ENOENT,
				      "no driver '%s'%s (and no such configuration file); see asph drivers",
				      copy, driver_hint(reg, copy, hint, sizeof(hint)));
	}
	r = config_alloc(1, &c, err);
	if (r < 0)
		return r;
	struct asph_instrument_config *ic = &c->instruments[0];
	snprintf(ic->name, sizeof(ic->name), "%s", drv->name);
	r = role_options(drv, ASPH_ROLE_STAGE, &ic->stage_driver, &ic->stage_options, err);
	if (r == 0)
		r = role_options(drv, ASPH_ROLE_PROBE, &ic->probe_driver, &ic->probe_options, err);
	char *save = NULL;
	for (char *kv = opts ? strtok_r(opts, ",", &save) : NULL; r == 0 && kv;
	     kv = strtok_r(NULL, ",", &save))
		r = spec_option(ic, kv, err);
	if (r < 0) {
		asph_error_locate(err, spec, 0, 0, NULL);
		return r;
	}
	*out = steal_ptr(c);
	return 0;
}

/* ------------------------------------------------------------- JSON */

static int value_text(const struct asph_option_desc *d, json_t *v, char *buf,
		      size_t size, const char **text)
{
	*text = buf;
	switch (d->type) {
	case ASPH_OPTION_BOOL:
		if (!json_is_boolean(v))
			return -EINVAL;
		snprintf(buf, size, "%s", json_is_true(v) ? "true" : "false");
		return 0;
	case ASPH_OPTION_INT:
		if (!json_is_integer(v))
			return -EINVAL;
		snprintf(buf, size, "%lld", (long long)json_integer_value(v));
		return 0;
	case ASPH_OPTION_DOUBLE:
		if (!json_is_number(v))
			return -EINVAL;
		snprintf(buf, size, "%.17g", json_number_value(v));
		return 0;
	case ASPH_OPTION_STRING:
	case ASPH_OPTION_ENUM:
		if (!json_is_string(v))
			return -EINVAL;
		*text = json_string_value(v);
		return 0;
	}
	return -EINVAL;
}

static const char *json_type_word(enum asph_option_type t)
{
	switch (t) {
	case ASPH_OPTION_BOOL: return "true or false";
	case ASPH_OPTION_INT: return "an integer";
	case ASPH_OPTION_DOUBLE: return "a number";
	default: return "a string";
	}
}

static int json_options(const struct json_source *src, json_t *obj,
			struct asph_options *opts, const char *path,
			struct asph_error *err)
{
	const struct asph_driver *drv = asph_options_driver(opts);
	const char *key;
	json_t *v;
	char dotted[256], buf[64], hint[96];

	if (!json_is_object(obj))
		return json_error_set_at(err, -EINVAL, src, path, "options must be an object");
	json_object_foreach(obj, key, v) {
		int i = asph_option_index(drv, key);
		const char *text;
		int r;

		if (snprintf(dotted, sizeof(dotted), "%s.%s", path, key) >= (int)sizeof(dotted))
			dotted[0] = '\0';
		if (i < 0)
			return json_error_set_at(err, -ENOENT, src, dotted,
						 "driver '%s' has no option '%s'%s (see asph drivers)",
						 drv->name, key,
						 option_hint(drv, key, hint, sizeof(hint)));
		if (value_text(&drv->options[i], v, buf, sizeof(buf), &text) < 0)
			return json_error_set_at(err, -EINVAL, src, dotted,
						 "option '%s' expects %s", key,
						 json_type_word(drv->options[i].type));
		r = asph_options_set(opts, key, text, err);
		if (r < 0)
			return json_error_locate(err, r, src, dotted);
	}
	return 0;
}

static int json_role(const struct json_source *src, const struct asph_registry *reg,
		     json_t *obj, unsigned role, const char *path,
		     const struct asph_driver **drv_out,
		     struct asph_options **opts, struct asph_error *err)
{
	char dotted[256];
	const char *key;
	json_t *v;

	if (!obj) {
		/* point at the instrument that lacks it */
		char parent[256];
		int line = 0, column = 0;
		snprintf(parent, sizeof(parent), "%s", path);
		*strrchr(parent, '.') = '\0';
		json_locate_dotted(src->text, src->len, parent, &line, &column);
		return asph_error_set_at(err, -EINVAL, src->name, line, column, path,
					 "missing: an object with \"driver\"");
	}
	if (!json_is_object(obj))
		return json_error_set_at(err, -EINVAL, src, path, "not an object with \"driver\"");
	json_object_foreach(obj, key, v) {
		if (strcmp(key, "driver") && strcmp(key, "options")) {
			snprintf(dotted, sizeof(dotted), "%s.%s", path, key);
			return json_error_set_at(err, -EINVAL, src, dotted,
						 "unknown member '%s' (driver, options)", key);
		}
	}
	snprintf(dotted, sizeof(dotted), "%s.driver", path);
	const char *name = json_string_value(json_object_get(obj, "driver"));
	if (!name)
		return json_error_set_at(err, -EINVAL, src,
					 json_object_get(obj, "driver") ? dotted : path,
					 "\"driver\" must be a driver name");
	const struct asph_driver *drv = asph_registry_find(reg, name);
	if (!drv) {
		char hint[96];
		return json_error_set_at(err, -ENOENT, src, dotted, "no driver '%s'%s (see asph drivers)",
					 name, driver_hint(reg, name, hint, sizeof(hint)));
	}
	int r = role_options(drv, role, drv_out, opts, err);
	if (r < 0)
		return json_error_locate(err, r, src, dotted);
	json_t *o = json_object_get(obj, "options");
	snprintf(dotted, sizeof(dotted), "%s.options", path);
	return o ? json_options(src, o, *opts, dotted, err) : 0;
}

/* The acquisition settings of an instrument: each as its text. */
static int json_acquisition(const struct json_source *src, json_t *obj, const char *path,
			    struct asph_acquisition *a, struct asph_error *err)
{
	char dotted[256], buf[64];
	const char *key;
	json_t *v;

	if (!json_is_object(obj))
		return json_error_set_at(err, -EINVAL, src, path, "acquisition must be an object");
	json_object_foreach(obj, key, v) {
		_cleanup_free_ char *list = NULL;
		const char *text = buf;
		snprintf(dotted, sizeof(dotted), "%s.%s", path, key);
		if (json_is_number(v)) {
			snprintf(buf, sizeof(buf), "%.17g", json_number_value(v));
			if (!strcmp(key, "drift_interval"))
				strcat(buf, "s");
		} else if (json_is_string(v)) {
			text = json_string_value(v);
		} else if (json_is_array(v) && !strcmp(key, "drift_references")) {
			/* [[x, y], ...] as X:Y;X:Y */
			size_t i;
			json_t *xy;
			list = calloc(json_array_size(v) * 64 + 1, 1);
			if (!list)
				return asph_error_set(err, -ENOMEM, "out of memory");
			json_array_foreach(v, i, xy) {
				if (!json_is_array(xy) || json_array_size(xy) != 2 ||
				    !json_is_number(json_array_get(xy, 0)) ||
				    !json_is_number(json_array_get(xy, 1)))
					return json_error_set_at(err, -EINVAL, src, dotted,
								 "drift_references: each an [x, y] pair of numbers (mm)");
				snprintf(list + strlen(list), 64, "%s%.17g:%.17g", i ? ";" : "",
					 json_number_value(json_array_get(xy, 0)),
					 json_number_value(json_array_get(xy, 1)));
			}
			text = list;
		} else {
			return json_error_set_at(err, -EINVAL, src, dotted,
						 "'%s' expects a number or a string", key);
		}
		int r = asph_acquisition_set(a, key, text, err);
		if (r == -ENOENT)
			return json_error_set_at(err, -EINVAL, src, dotted,
						 "unknown member '%s' (settle_window, settle_dwell, "
						 "drift_interval, drift_references, retries)", key);
		if (r < 0)
			return json_error_locate(err, r, src, dotted);
	}
	return 0;
}

/* "uncertainty": { "probe_noise_nm": 5, ... }, every member a number >= 0
 * named as asph_uncertainty_model_fields() lists them. */
static int json_uncertainty(const struct json_source *src, json_t *obj, const char *path,
			    struct asph_instrument_config *ic, struct asph_error *err)
{
	char dotted[256];
	const char *key;
	json_t *v;
	int r;

	if (!json_is_object(obj))
		return json_error_set_at(err, -EINVAL, src, path,
					 "uncertainty must be an object of contributions");
	asph_uncertainty_model_init(&ic->uncertainty);
	json_object_foreach(obj, key, v) {
		snprintf(dotted, sizeof(dotted), "%s.%s", path, key);
		if (!json_is_number(v))
			return json_error_set_at(err, -EINVAL, src, dotted,
						 "'%s' must be a number", key);
		r = asph_uncertainty_model_set(&ic->uncertainty, key, json_number_value(v), err);
		if (r < 0)
			return json_error_locate(err, r, src, dotted);
	}
	struct asph_error why;
	asph_error_clear(&why);
	r = asph_uncertainty_model_check(&ic->uncertainty, &why);
	if (r < 0) {
		/* at the member at fault when it is written, else the section */
		if (!json_object_get(obj, why.field) ||
		    snprintf(dotted, sizeof(dotted), "%s.%s", path, why.field) >= (int)sizeof(dotted))
			snprintf(dotted, sizeof(dotted), "%s", path);
		return json_error_set_at(err, r, src, dotted, "%s", why.message);
	}
	ic->has_uncertainty = 1;
	return 0;
}

static int json_instrument(const struct json_source *src,
			   const struct asph_registry *reg, json_t *obj,
			   size_t idx, struct asph_instrument_config *ic,
			   struct asph_error *err)
{
	char path[64], dotted[192];
	const char *key;
	json_t *v;

	snprintf(path, sizeof(path), "instruments.[%zu]", idx);
	if (!json_is_object(obj))
		return json_error_set_at(err, -EINVAL, src, path,
					 "an instrument must be an object");
	json_object_foreach(obj, key, v) {
		if (strcmp(key, "name") && strcmp(key, "stage") && strcmp(key, "probe") &&
		    strcmp(key, "acquisition") && strcmp(key, "uncertainty")) {
			snprintf(dotted, sizeof(dotted), "%s.%s", path, key);
			return json_error_set_at(err, -EINVAL, src, dotted,
						 "unknown member '%s' (name, stage, probe, acquisition, "
						 "uncertainty)",
						 key);
		}
	}
	json_t *name = json_object_get(obj, "name");
	snprintf(dotted, sizeof(dotted), "%s.name", path);
	if (name && (!json_is_string(name) || !json_string_length(name) ||
		     json_string_length(name) >= sizeof(ic->name))) {
		return json_error_set_at(err, -EINVAL, src, dotted,
					 "name must be a string of 1 to %zu bytes",
					 sizeof(ic->name) - 1);
	}
	if (name)
		snprintf(ic->name, sizeof(ic->name), "%s", json_string_value(name));
	else
		snprintf(ic->name, sizeof(ic->name), "instrument%zu", idx + 1);
	snprintf(dotted, sizeof(dotted), "%s.stage", path);
	int r = json_role(src, reg, json_object_get(obj, "stage"), ASPH_ROLE_STAGE,
			  dotted, &ic->stage_driver, &ic->stage_options, err);
	if (r < 0)
		return r;
	snprintf(dotted, sizeof(dotted), "%s.probe", path);
	r = json_role(src, reg, json_object_get(obj, "probe"), ASPH_ROLE_PROBE,
		      dotted, &ic->probe_driver, &ic->probe_options, err);
	json_t *acq = json_object_get(obj, "acquisition");
	snprintf(dotted, sizeof(dotted), "%s.acquisition", path);
	if (r == 0 && acq)
		r = json_acquisition(src, acq, dotted, &ic->acquisition, err);
	json_t *u = json_object_get(obj, "uncertainty");
	snprintf(dotted, sizeof(dotted), "%s.uncertainty", path);
	if (r == 0 && u)
		r = json_uncertainty(src, u, dotted, ic, err);
	return r;
}

static int check_names(const struct json_source *src, const struct asph_config *c,
		       struct asph_error *err)
{
	char path[64];

	for (size_t i = 0; i < c->n; i++)
		for (size_t j = 0; j < i; j++)
			if (!strcmp(c->instruments[i].name, c->instruments[j].name)) {
				snprintf(path, sizeof(path), "instruments.[%zu].name", i);
				return json_error_set_at(err, -EINVAL, src, path,
							 "instrument name '%s' used twice",
							 c->instruments[i].name);
			}
	return 0;
}

int asph_config_parse(const struct asph_registry *reg, const char *text,
		      size_t len, const char *source, struct asph_config **out,
		      struct asph_error *err)
{
	struct json_source src = { text, len, source };
	_cleanup_(asph_config_freep) struct asph_config *c = NULL;
	json_error_t jerr;
	const char *key;
	json_t *v;

	_cleanup_(json_decrefp) json_t *root = json_loadb(text, len, JSON_REJECT_DUPLICATES, &jerr);
	if (!root)
		return asph_error_set_at(err, -EINVAL, source, jerr.line, jerr.column, NULL, "%s",
					 jerr.text);
	if (!json_is_object(root))
		return asph_error_set_at(err, -EINVAL, source, 1, 1, NULL,
					 "the configuration must be a JSON object");
	json_object_foreach(root, key, v) {
		if (strcmp(key, "instruments"))
			return json_error_set_at(err, -EINVAL, &src, key,
						 "unknown member '%s' (instruments)", key);
	}
	json_t *list = json_object_get(root, "instruments");
	if (!json_is_array(list) || json_array_size(list) == 0) {
		asph_error_set(err, -EINVAL, "\"instruments\" must be a non-empty array");
		if (list)
			return json_error_locate(err, -EINVAL, &src, "instruments");
		asph_error_locate(err, source, 1, 1, "instruments");
		return -EINVAL;
	}
	int r = config_alloc(json_array_size(list), &c, err);
	for (size_t i = 0; r == 0 && i < c->n; i++)
		r = json_instrument(&src, reg, json_array_get(list, i), i,
				    &c->instruments[i], err);
	if (r == 0)
		r = check_names(&src, c, err);
	if (r < 0)
		return r;
	*out = steal_ptr(c);
	return 0;
}

int asph_config_load(const struct asph_registry *reg, const char *path,
		     struct asph_config **out, struct asph_error *err)
{
	_cleanup_free_ char *text = NULL;
	size_t len = 0;
	int r = file_read_all(path, 16u << 20, &text, &len, err);
	if (r < 0)
		return r;
	return asph_config_parse(reg, text, len, path, out, err);
}

int asph_config_resolve(const struct asph_registry *reg, const char *arg,
			struct asph_config **out, size_t *index,
			struct asph_error *err)
{
	_cleanup_free_ char *path = strdup(arg);
	struct stat st;

	if (!path)
		return asph_error_set(err, -ENOMEM, "out of memory");
	*index = 0;
	char *hash = strrchr(path, '#');
	if (stat(path, &st) != 0 && hash) {
		*hash = '\0';
		if (stat(path, &st) != 0)
			*hash = '#', hash = NULL;
	} else {
		hash = NULL;
	}
	if (stat(path, &st) != 0)
		return asph_instrument_spec_parse(reg, arg, out, err);
	int r = asph_config_load(reg, path, out, err);
	if (r < 0 || !hash)
		return r;
	for (size_t i = 0; i < (*out)->n; i++)
		if (!strcmp((*out)->instruments[i].name, hash + 1))
			return *index = i, 0;
	asph_config_free(*out);
	*out = NULL;
	return asph_error_set_at(err, -ENOENT, path, 0, 0, NULL,
				 "no instrument '%s' in the configuration", hash + 1);
}

int asph_instrument_config_copy(const struct asph_instrument_config *c,
				struct asph_config **out, struct asph_error *err)
{
	_cleanup_(asph_config_freep) struct asph_config *copy = NULL;
	int r = config_alloc(1, &copy, err);

	if (r < 0)
		return r;
	struct asph_instrument_config *ic = &copy->instruments[0];
	*ic = (struct asph_instrument_config){ .stage_driver = c->stage_driver,
					       .probe_driver = c->probe_driver,
					       .acquisition = c->acquisition };
	memcpy(ic->name, c->name, sizeof(ic->name));
	ic->has_uncertainty = c->has_uncertainty;
	ic->uncertainty = c->uncertainty;
	r = asph_options_copy(c->stage_options, &ic->stage_options, err);
	if (r == 0)
		r = asph_options_copy(c->probe_options, &ic->probe_options, err);
	if (r < 0)
		return r;
	*out = steal_ptr(copy);
	return 0;
}

static int lens_option(struct asph_options *o, const char *json, struct asph_error *err)
{
	int i = asph_option_index(asph_options_driver(o), "lens");

	if (i < 0 || asph_options_driver(o)->options[i].type != ASPH_OPTION_STRING)
		return 0;
	return asph_options_set_default(o, "lens", json, err);
}

int asph_instrument_config_set_lens(struct asph_instrument_config *c,
				    const char *prescription_json,
				    struct asph_error *err)
{
	int r = lens_option(c->stage_options, prescription_json, err);

	if (r >= 0)
		r = lens_option(c->probe_options, prescription_json, err);
	return r < 0 ? r : 0;
}

static json_t *role_json(const struct asph_driver *drv, const struct asph_options *o,
		 unsigned role)
{
	json_t *obj = json_object(), *opts = json_object();
	const struct asph_option_value *v = asph_options_values(o);
	char abi[24];

	json_object_set_new(obj, "driver", json_string(drv->name));
	json_object_set_new(obj, "version", json_string(drv->version ? drv->version : ""));
	json_object_set_new(obj, "abi", json_string(asph_driver_abi_text(drv->abi_version, abi, sizeof(abi))));
	for (size_t i = 0; i < drv->n_options; i++) {
		json_t *j = NULL;
		if (drv->options[i].roles && !(drv->options[i].roles & role))
			continue;
		switch (v[i].type) {
		case ASPH_OPTION_BOOL: j = json_boolean(v[i].b); break;
		case ASPH_OPTION_INT: j = json_integer(v[i].i); break;
		case ASPH_OPTION_DOUBLE: j = json_real(v[i].d); break;
		default: j = json_string(v[i].s ? v[i].s : ""); break;
		}
		json_object_set_new(opts, drv->options[i].name, j);
	}
	json_object_set_new(obj, "options", opts);
	return obj;
}

static json_t *acquisition_json(const struct asph_acquisition *a)
{
	json_t *refs = json_array();
	char interval[48] = "off";

	for (size_t i = 0; i < a->n_references; i++)
		json_array_append_new(refs, json_pack("[f, f]", a->references[i][0],
						      a->references[i][1]));
	if (a->drift_interval_s > 0)
		snprintf(interval, sizeof(interval), "%.17gs", a->drift_interval_s);
	else if (a->drift_interval_points > 0)
		snprintf(interval, sizeof(interval), "%llupoints",
			 (unsigned long long)a->drift_interval_points);
	return json_pack("{s:f, s:f, s:s, s:o, s:i}", "settle_window_um", a->settle_window * 1e3,
			 "settle_dwell_s", a->settle_dwell, "drift_interval", interval,
			 "drift_references", refs, "retries", (int)a->retries);
}

int asph_instrument_config_to_json(const struct asph_instrument_config *c,
				   char **out)
{
	_cleanup_(json_decrefp) json_t *root = json_object();

	json_object_set_new(root, "name", json_string(c->name));
	json_object_set_new(root, "driver_abi", json_integer(ASPH_DRIVER_ABI_MAJOR));
	json_object_set_new(root, "driver_abi_minor", json_integer(ASPH_DRIVER_ABI_MINOR));
	json_object_set_new(root, "stage", role_json(c->stage_driver, c->stage_options, ASPH_ROLE_STAGE));
	json_object_set_new(root, "probe", role_json(c->probe_driver, c->probe_options, ASPH_ROLE_PROBE));
	/* the settling in effect: the stage's advice where the instrument
	 * sets none */
	struct asph_acquisition acq = c->acquisition;
	struct asph_stage_info si;
	struct asph_probe_info pi;
	if (asph_instrument_describe(c, &si, &pi, NULL) == 0)
		asph_acquisition_advised(&acq, &si);
	json_object_set_new(root, "acquisition", acquisition_json(&acq));
	if (c->has_uncertainty) {
		_cleanup_free_ char *u = NULL;
		if (asph_uncertainty_model_to_json(&c->uncertainty, &u) < 0)
			return -ENOMEM;
		json_object_set_new(root, "uncertainty", json_loads(u, 0, NULL));
	}
	*out = json_dumps(root, JSON_COMPACT | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
	return *out ? 0 : -ENOMEM;
}
