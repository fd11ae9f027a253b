/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A plan's parameters as JSON: one writer for every recorded scan and job
 * result, one reader for both shapes scan headers have held. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/plan.h"
#include "util-mem.h"

int asph_plan_to_json(const struct asph_plan *p, char **out)
{
	_cleanup_(json_decrefp) json_t *j =
		json_pack("{s:s, s:s, s:f, s:f, s:I}",
			  "method", asph_plan_method_name(p->method),
			  "density", asph_plan_density_name(p->density.kind),
			  "value", p->density.value,
			  "spacing_mm", p->spacing_mm,
			  "points", (json_int_t)p->n);

	if (j && p->method == ASPH_PLAN_PROFILES &&
	    json_object_set_new(j, "profiles", json_integer(p->profiles)) < 0)
		return -ENOMEM;
	*out = j ? json_dumps(j, JSON_COMPACT | JSON_REAL_PRECISION(17)) : NULL;
	return *out ? 0 : -ENOMEM;
}

/* "density": "h", "value": v, or (as asph scan wrote it) "density":
 * {"kind": "h", "value": v}. */
static int density_of(json_t *root, const char *source, struct asph_plan_density *out,
		      struct asph_error *err)
{
	json_t *d = json_object_get(root, "density"), *v = json_object_get(root, "value");
	const char *kind_field = "plan.density", *value_field = "plan.value";

	if (json_is_object(d)) {
		v = json_object_get(d, "value");
		d = json_object_get(d, "kind");
		kind_field = "plan.density.kind";
		value_field = "plan.density.value";
	}
	if (asph_plan_density_from_name(json_string_value(d), &out->kind) < 0) {
		char known[64];
		asph_plan_density_names(known, sizeof(known));
		return asph_error_set_at(err, -EINVAL, source, 0, 0, kind_field,
					 "the density is not one of %s", known);
	}
	if (!json_is_number(v) || !(json_number_value(v) > 0) ||
	    !isfinite(json_number_value(v)))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, value_field,
					 "the density is not a positive number");
	out->value = json_number_value(v);
	return 0;
}

int asph_plan_info_from_json(const char *text, size_t len, const char *source,
			     struct asph_plan_info *out, struct asph_error *err)
{
	json_error_t jerr;
	_cleanup_(json_decrefp) json_t *root = json_loadb(text, len, 0, &jerr);
	json_t *v;

	if (!json_is_object(root))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "plan", "%s",
					 root ? "a plan is a JSON object" : jerr.text);
	memset(out, 0, sizeof(*out));
	if (asph_plan_method_from_name(json_string_value(json_object_get(root, "method")),
				       &out->method) < 0) {
		char known[256];
		asph_plan_method_names(known, sizeof(known));
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "plan.method",
					 "not a plan method (%s)", known);
	}
	int r = density_of(root, source, &out->density, err);
	if (r < 0)
		return r;
	v = json_object_get(root, "profiles");
	if (out->method == ASPH_PLAN_PROFILES)
		out->profiles = v ? (unsigned)json_integer_value(v) : 1;
	if ((v && out->method != ASPH_PLAN_PROFILES) ||
	    (v && (!json_is_integer(v) || json_integer_value(v) < 1 ||
		   json_integer_value(v) > ASPH_PLAN_MAX_PROFILES)))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "plan.profiles",
					 "profiles is a whole number 1..%d of the profiles method",
					 ASPH_PLAN_MAX_PROFILES);
	v = json_object_get(root, "spacing_mm");
	out->spacing_mm = json_is_number(v) ? json_number_value(v) : NAN;
	v = json_object_get(root, "points");
	if (v && (!json_is_integer(v) || json_integer_value(v) < 0))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "plan.points",
					 "the point count is not a whole number");
	out->points = v ? (uint64_t)json_integer_value(v) : 0;
	return 0;
}
