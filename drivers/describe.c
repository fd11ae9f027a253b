/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The registry described as JSON: the one builder of asph drivers --json
 * and the daemon's driver.list. Every member is present; what a driver
 * table leaves out is null, and roles are always named. */
#include <errno.h>
#include <stdio.h>

#include <jansson.h>

#include "asph-driver/instrument.h"
#include "util-mem.h"

/* Every role named: an option (or driver) of roles 0 serves both. */
static json_t *roles_json(unsigned roles)
{
	json_t *a = json_array();

	if (!roles || (roles & ASPH_ROLE_STAGE))
		json_array_append_new(a, json_string("stage"));
	if (!roles || (roles & ASPH_ROLE_PROBE))
		json_array_append_new(a, json_string("probe"));
	return a;
}

/* A text member that may be absent in the table: null then. */
static json_t *text_or_null(const char *s)
{
	return s ? json_string(s) : json_null();
}

static json_t *option_json(const struct asph_option_desc *o)
{
	json_t *j = json_object();

	json_object_set_new(j, "name", json_string(o->name));
	json_object_set_new(j, "type", json_string(asph_option_type_name(o->type)));
	json_object_set_new(j, "default", text_or_null(o->default_value));
	json_object_set_new(j, "unit", text_or_null(o->unit));
	if (o->ranged) {
		json_object_set_new(j, "min", json_real(o->min));
		json_object_set_new(j, "max", json_real(o->max));
	}
	if (o->choices) {
		json_t *c = json_array();
		for (size_t i = 0; o->choices[i]; i++)
			json_array_append_new(c, json_string(o->choices[i]));
		json_object_set_new(j, "choices", c);
	}
	json_object_set_new(j, "roles", roles_json(o->roles));
	json_object_set_new(j, "help", text_or_null(o->help));
	return j;
}

const char *asph_driver_abi_text(uint32_t version, char *buf, size_t size)
{
	snprintf(buf, size, "%u.%u", ASPH_DRIVER_ABI_MAJOR_OF(version),
		 ASPH_DRIVER_ABI_MINOR_OF(version));
	return buf;
}

static json_t *profile_json(const struct asph_driver_profile *p)
{
	json_t *j = json_object();

	json_object_set_new(j, "name", json_string(p->name));
	json_object_set_new(j, "roles", p->roles ? roles_json(p->roles) : json_array());
	json_object_set_new(j, "description", json_string(p->description));
	json_object_set_new(j, "reference", json_string(p->reference));
	json_object_set_new(j, "path", json_string(p->path));
	json_object_set_new(j, "error", p->error[0] ? json_string(p->error) : json_null());
	return j;
}

/* The profiles the driver's "profile" option can name, as found now. */
static int profiles_json(const struct asph_registry *reg, size_t i, json_t **out,
			 struct asph_error *err)
{
	_cleanup_free_ struct asph_driver_profile *v = NULL;
	size_t n = 0;
	int r = asph_registry_profiles(reg, i, &v, &n, err);

	if (r < 0)
		return r;
	*out = json_array();
	for (size_t k = 0; k < n; k++)
		json_array_append_new(*out, profile_json(&v[k]));
	return 0;
}

int asph_registry_to_json(const struct asph_registry *reg, bool pretty, char **out,
			  struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *root = json_object();
	json_t *list = json_array();

	json_object_set_new(root, "driver_abi", json_integer(ASPH_DRIVER_ABI_MAJOR));
	json_object_set_new(root, "driver_abi_minor", json_integer(ASPH_DRIVER_ABI_MINOR));
	json_object_set_new(root, "drivers", list);     /* (root owns it: nothing leaks on an error) */
	for (size_t i = 0; i < asph_registry_count(reg); i++) {
		const struct asph_driver *d = asph_registry_get(reg, i);
		char abi[24];
		json_t *j = json_object(), *opts = json_array();
		json_object_set_new(j, "name", json_string(d->name));
		json_object_set_new(j, "description", text_or_null(d->description));
		json_object_set_new(j, "version", text_or_null(d->version));
		json_object_set_new(j, "origin", json_string(asph_registry_origin(reg, i)));
		json_object_set_new(j, "abi", json_string(asph_driver_abi_text(d->abi_version, abi, sizeof(abi))));
		json_object_set_new(j, "roles", roles_json(d->roles));
		for (size_t k = 0; k < d->n_options; k++)
			json_array_append_new(opts, option_json(&d->options[k]));
		json_object_set_new(j, "options", opts);
		json_array_append_new(list, j);
		json_t *profiles = NULL;
		int r = profiles_json(reg, i, &profiles, err);
		if (r < 0)
			return r;
		json_object_set_new(j, "profiles", profiles);
	}
	*out = json_dumps(root, (pretty ? JSON_INDENT(2) : JSON_COMPACT) | JSON_PRESERVE_ORDER |
				JSON_REAL_PRECISION(17));
	return *out ? 0 : -ENOMEM;
}

