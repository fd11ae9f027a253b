/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The plan for a job's tolerance, on the thread that asks (tolplan.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph-engine/executor.h"
#include "asph-mc/mc-runner.h"
#include "jobplan.h"
#include "jobspec.h"
#include "tolplan.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_plan_search *, asph_plan_search_free)

struct search {
	const struct tolplan_hooks *hooks;
	struct asph_plan_search *ps;
	size_t shown;           /* the evaluations last told */
};

static bool cancelled(const struct search *s)
{
	return s->hooks && s->hooks->cancelled && s->hooks->cancelled(s->hooks->data);
}

/* Between the Monte Carlo's trials. */
static int on_trials(void *data, size_t done, size_t planned)
{
	return cancelled(data);
}

/* A plan's Monte Carlo, on the threads a job's own uncertainty runs on
 * (result.c), the same bit for bit for any number of them. */
static int run_mc(void *data, struct asph_mc *mc, struct asph_mc_result *out,
		  struct asph_error *err)
{
	struct asph_mc_threads th = { .progress = on_trials, .progress_data = data };

	return asph_mc_run_threads(mc, &th, out, err);
}

/* After each plan characterized. */
static int on_step(void *data, size_t done, size_t budget)
{
	struct search *s = data;
	struct asph_plan_search_status st;

	if (s->hooks && s->hooks->step && s->ps) {
		asph_plan_search_status(s->ps, &st);
		if (isfinite(st.ratio) && st.evaluations > 0 && st.evaluations != s->shown)
			s->hooks->step(s->hooks->data, &st);
		s->shown = st.evaluations;
	}
	return cancelled(s);
}

void tolplan_step_format(const struct asph_plan_search_status *st, char *buf, size_t size)
{
	snprintf(buf, size, "%s, %zu points, %.1f s: U/T %.3f (%s the capability); %zu of at "
		 "most %zu characterizations", asph_plan_method_name(st->method), st->points,
		 st->seconds, st->ratio, st->passed ? "meets" : "does not meet",
		 st->characterizations, st->budget);
}

/* The search's options from the stored plan and the job's tolerance. */
static int search_options(json_t *plan, const struct job_plan *jp, uint64_t max_points,
			  struct asph_plan_search_options *o, struct asph_error *err)
{
	enum asph_plan_method m;
	const char *method = json_string_value(json_object_get(plan, "method"));
	int r;

	if (!jp->fit.tolerance)
		return asph_error_set(err, -EINVAL, "the plan for the tolerance needs the job's "
				      "tolerance: it has none");
	r = asph_plan_search_limits(jp->fit.tolerance, o->limit, err);
	if (r < 0)
		return r;
	o->capability = json_number_value(json_object_get(plan, "capability"));
	if (method) {
		if (asph_plan_method_from_name(method, &m) < 0)
			return asph_error_set(err, -EINVAL, "the stored plan method is damaged");
		o->methods = 1u << m;
	}
	o->max_points = max_points < ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS
		? (size_t)max_points : ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS;
	o->fit = jp->fit;
	o->mc.seed = 1;         /* as the job's own uncertainty */
	return 0;
}

/* No plan meets the capability: why, as the job's failure. */
static int none_found(const struct asph_plan_search_result *r, struct asph_error *err)
{
	const char *q = asph_plan_search_quantity_name(r->failing);

	if (r->n_quantities && isfinite(r->contribution_U[r->dominant]))
		return asph_error_set(err, -EINVAL, "no plan of %zu to %zu points meets U <= %g T%s: "
				      "%s is dominated by the instrument's %s (U %.4g of it alone)",
				      r->min_points, r->max_points, r->capability,
				      r->budget_exhausted ? " within the search's budget" : "", q,
				      asph_plan_search_contribution_name(r->dominant),
				      r->contribution_U[r->dominant]);
	return asph_error_set(err, -EINVAL, "no plan of %zu to %zu points meets U <= %g T%s",
			      r->min_points, r->max_points, r->capability,
			      r->budget_exhausted ? " within the search's budget" : "");
}

/* spec with the chosen plan in place of the request. */
static int chosen_spec(json_t *spec, const struct asph_plan_search_result *r, char **out,
		       struct asph_error *err)
{
	json_t *plan = json_pack("{s:s, s:s, s:f}", "method", asph_plan_method_name(r->method),
				 "density", asph_plan_density_name(r->density.kind),
				 "value", r->density.value);

	if (!plan || json_object_set_new(spec, "plan", plan) < 0 ||
	    !(*out = json_dumps(spec, JSON_COMPACT)))
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}

int tolplan_instrument_ok(const struct asph_instrument_config *ic, struct asph_error *err)
{
	if (!ic->has_uncertainty || asph_uncertainty_model_is_empty(&ic->uncertainty))
		return asph_error_set(err, -EINVAL, "the instrument '%s' declares no uncertainty "
				      "contributions (an \"uncertainty\" section of its "
				      "configuration, docs/drivers.md)", ic->name);
	return 0;
}

/* The instrument's copy carrying the lens, with its contributions. */
static int instrument(const struct asph_instrument_config *ic, const struct job_plan *jp,
		      struct asph_config **own, struct asph_error *err)
{
	int r = tolplan_instrument_ok(ic, err);

	if (r == 0)
		r = asph_instrument_config_copy(ic, own, err);
	if (r == 0)
		r = asph_instrument_config_set_lens(&(*own)->instruments[0], jp->prescription_json,
						    err);
	return r;
}

static int choose(json_t *spec, const struct job_plan *jp, uint64_t max_points,
		  const struct asph_instrument_config *ic, const struct tolplan_hooks *hooks,
		  char **spec_out, char **choice, struct asph_error *err)
{
	_cleanup_(asph_config_freep) struct asph_config *own = NULL;
	_cleanup_(asph_plan_search_freep) struct asph_plan_search *ps = NULL;
	struct asph_plan_search_options o = { 0 };
	struct search s = { .hooks = hooks };
	const struct asph_plan_search_result *res;
	int r = search_options(json_object_get(spec, "plan"), jp, max_points, &o, err);

	if (r == 0)
		r = instrument(ic, jp, &own, err);
	if (r < 0)
		return r;
	struct asph_scan_timing timing = { .instrument = &own->instruments[0],
					   .surface = jp->surface,
					   .options = { .flags = ASPH_SCAN_STREAM } };
	o.model = own->instruments[0].uncertainty;
	o.run_mc = run_mc;
	o.run_mc_data = &s;
	o.plan_time = asph_scan_plan_time;
	o.plan_time_data = &timing;
	o.progress = (struct asph_progress){ .fn = on_step, .data = &s };
	r = asph_plan_search_alloc(jp->surface, &o, &ps, err);
	if (r < 0)
		return r;
	s.ps = ps;
	r = asph_plan_search_run(ps, err);
	if (r < 0)
		return r;
	res = asph_plan_search_result(ps);
	if (!res->found)
		return none_found(res, err);
	if (asph_plan_search_result_to_json(res, choice) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	return chosen_spec(spec, res, spec_out, err);
}

int tolplan_choose(const char *spec_text, uint64_t max_points, const struct asph_instrument_config *ic,
		   const struct tolplan_hooks *hooks, char **spec_out, char **choice,
		   struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(spec_text, 0, NULL);
	struct job_plan jp;
	int r;

	*spec_out = *choice = NULL;
	r = job_plan_build_part(spec_text, &jp, err);
	if (r == 0 && !spec)
		r = asph_error_set(err, -EINVAL, "the stored job specification is damaged");
	if (r == 0)
		r = choose(spec, &jp, max_points, ic, hooks, spec_out, choice, err);
	job_plan_release(&jp);
	if (r < 0) {
		free(*choice);
		*choice = NULL;
	}
	return r;
}

void tolplan_choice_format(const char *choice, char *buf, size_t size)
{
	_cleanup_(json_decrefp) json_t *o = json_loads(choice, 0, NULL);
	json_t *plan = json_object_get(o, "plan"), *q, *worst = NULL;
	size_t i;

	json_array_foreach(json_object_get(o, "quantities"), i, q)
		if (!worst || json_number_value(json_object_get(q, "ratio")) >
			      json_number_value(json_object_get(worst, "ratio")))
			worst = q;
	snprintf(buf, size, "%s, %lld points, %.1f s predicted, the largest U/T %.3f (%s)",
		 json_string_value(json_object_get(plan, "method")),
		 (long long)json_integer_value(json_object_get(plan, "points")),
		 json_number_value(json_object_get(o, "estimate_s")),
		 json_number_value(json_object_get(worst, "ratio")),
		 json_string_value(json_object_get(worst, "quantity")));
}

bool tolplan_wanted(const char *spec_text)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(spec_text, 0, NULL);

	return jobspec_for_tolerance(spec);
}
