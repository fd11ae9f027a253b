/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The plan search's result as JSON. */
#include <errno.h>
#include <math.h>

#include <jansson.h>

#include "asph/plan-search.h"
#include "util-mem.h"

/* A limited quantity's name: the verdict's item name where the tolerance
 * limits it, else the Monte Carlo's key. */
const char *asph_plan_search_quantity_name(enum asph_mc_quantity q)
{
	switch ((int)q) {
	case ASPH_MC_SLOPE_RMS: return "slope_rms_urad";
	case ASPH_MC_SLOPE_MAX: return "slope_max_urad";
	case ASPH_FIT_R: return "R_deviation_mm";
	default: return asph_mc_quantity_key(q);
	}
}

static json_t *num(double v)
{
	return isfinite(v) ? json_real(v) : json_null();
}

static json_t *quantity_name(enum asph_mc_quantity q)
{
	const char *name = (unsigned)q < ASPH_MC_N_QUANTITIES ? asph_plan_search_quantity_name(q)
							      : NULL;
	return name ? json_string(name) : json_null();
}

static json_t *plan_object(const struct asph_plan_search_result *r)
{
	if (!r->found)
		return json_null();
	return json_pack("{s:s, s:s, s:f, s:I, s:o, s:o}",
			 "method", asph_plan_method_name(r->method),
			 "density", asph_plan_density_name(r->density.kind),
			 "value", r->density.value, "points", (json_int_t)r->points,
			 "spacing_mm", num(r->spacing_mm), "h", num(r->h));
}

static json_t *quantities_array(const struct asph_plan_search_result *r)
{
	json_t *a = json_array();

	for (size_t i = 0; a && i < r->n_quantities; i++) {
		const struct asph_plan_search_quantity *q = &r->quantity[i];
		json_array_append_new(a, json_pack("{s:o, s:f, s:o, s:o, s:o}",
			"quantity", quantity_name(q->q), "limit", q->limit, "U", num(q->U),
			"ratio", num(q->ratio), "U_run", num(q->U_run)));
	}
	return a;
}

static json_t *methods_array(const struct asph_plan_search_result *r)
{
	json_t *a = json_array();

	for (int m = 0; a && m < ASPH_PLAN_N_METHODS; m++) {
		const struct asph_plan_search_method *x = &r->methods[m];
		if (x->outcome == ASPH_PLAN_SEARCH_NOT_TRIED && x->evaluations == 0)
			continue;
		json_array_append_new(a, json_pack(
			"{s:s, s:s, s:o, s:o, s:o, s:o, s:o, s:o, s:I, s:I, s:s?}",
			"method", asph_plan_method_name(x->method),
			"outcome", asph_plan_search_outcome_name(x->outcome),
			"points", x->points ? json_integer((json_int_t)x->points) : json_null(),
			"h", num(x->h), "estimate_s", num(x->seconds), "ratio", num(x->ratio),
			"worst", isfinite(x->ratio) ? quantity_name(x->worst) : json_null(),
			"needed_s", num(x->needed_seconds),
			"evaluations", (json_int_t)x->evaluations,
			"characterizations", (json_int_t)x->characterizations,
			"message", x->outcome == ASPH_PLAN_SEARCH_FAILED ? x->message : NULL));
	}
	return a;
}

static json_t *impossible_object(const struct asph_plan_search_result *r)
{
	json_t *c;

	if (r->found || r->n_quantities == 0)
		return json_null();
	c = json_object();
	for (int k = 0; c && k < ASPH_PLAN_SEARCH_N_CONTRIBUTIONS; k++)
		json_object_set_new(c, asph_plan_search_contribution_key(k),
				    num(r->contribution_U[k]));
	return json_pack("{s:o, s:s?, s:o}", "quantity", quantity_name(r->failing),
			 "dominant", isfinite(r->contribution_U[r->dominant])
				     ? asph_plan_search_contribution_key(r->dominant) : NULL,
			 "contributions", c);
}

static json_t *part_array(const struct asph_plan_search_result *r)
{
	json_t *a = json_array();

	for (size_t i = 0; a && i < r->n_terms; i++)
		json_array_append_new(a, json_pack("{s:i, s:f}", "j", r->terms[i].j,
						   "nm", r->terms[i].nm));
	return a;
}

int asph_plan_search_result_to_json(const struct asph_plan_search_result *r, char **out)
{
	_cleanup_(json_decrefp) json_t *root = json_pack(
		"{s:b, s:f, s:o, s:o, s:o, s:o, s:o, s:o, s:I, s:I, s:b, s:[I, I]}",
		"found", r->found, "capability", r->capability, "plan", plan_object(r),
		"estimate_s", r->found ? num(r->seconds) : json_null(),
		"quantities", quantities_array(r), "methods", methods_array(r),
		"impossible", impossible_object(r), "part", part_array(r),
		"evaluations", (json_int_t)r->evaluations,
		"characterizations", (json_int_t)r->characterizations,
		"budget_exhausted", r->budget_exhausted,
		"points_range", (json_int_t)r->min_points, (json_int_t)r->max_points);

	*out = root ? json_dumps(root, JSON_COMPACT | JSON_PRESERVE_ORDER |
				 JSON_REAL_PRECISION(17)) : NULL;
	return *out ? 0 : -ENOMEM;
}
