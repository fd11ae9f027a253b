/* SPDX-License-Identifier: GPL-3.0-or-later */
/* job.submit's parameters into a job specification (pure: any thread). */
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/fit.h"
#include "asph/plan-search.h"
#include "asph/points.h"
#include "asph/prescription.h"
#include "asph/tolerance.h"
#include "jobspec.h"
#include "util-mem.h"
#include "util-suggest.h"

static int spec_lens(json_t *params, json_t *spec, struct asph_prescription *p,
		     struct proto_why *why)
{
	json_t *lens = json_object_get(params, "lens");
	struct asph_error err;
	_cleanup_free_ char *text = NULL;
	_cleanup_free_ char *norm = NULL;
	int r;

	asph_error_clear(&err);
	if (json_is_string(lens)) {
		/* A name only: files are never read on a client's behalf. */
		if (strlen(json_string_value(lens)) != json_string_length(lens)) {
			snprintf(why->text, sizeof(why->text),
				 "\"lens\" contains a NUL character");
			return PROTO_INVALID_PARAMS;
		}
		if (asph_prescription_preset(json_string_value(lens), p) < 0) {
			const char *near = suggest_from_list(json_string_value(lens),
							     asph_prescription_preset_names());
			if (near)
				snprintf(why->text, sizeof(why->text),
					 "\"lens\": no preset named \"%.64s\" (did you mean \"%s\"?)",
					 json_string_value(lens), near);
			else
				snprintf(why->text, sizeof(why->text),
					 "\"lens\": no preset named \"%.64s\" (send the "
					 "prescription as an object)", json_string_value(lens));
			return PROTO_INVALID_LENS;
		}
	} else if (json_is_object(lens)) {
		text = json_dumps(lens, JSON_COMPACT);
		if (!text)
			return PROTO_INTERNAL_ERROR;
		r = asph_prescription_parse(text, strlen(text), "lens", p, &err);
		if (r < 0) {
			snprintf(why->text, sizeof(why->text), "\"lens\"%s%.100s: %.120s",
				 err.field[0] ? "." : "", err.field, err.message);
			return PROTO_INVALID_LENS;
		}
	} else {
		snprintf(why->text, sizeof(why->text),
			 "\"lens\" must be a preset name or a prescription object");
		return PROTO_INVALID_PARAMS;
	}
	if (asph_prescription_check(p, &err) < 0) {
		snprintf(why->text, sizeof(why->text), "\"lens\": %.200s", err.message);
		return PROTO_INVALID_LENS;
	}
	if (asph_prescription_to_json(p, &norm) < 0)
		return PROTO_INTERNAL_ERROR;
	json_object_set_new(spec, "lens", json_pack("{s:s?, s:o}",
		"name", json_is_string(lens) ? json_string_value(lens) : NULL,
		"prescription", json_loads(norm, 0, NULL)));
	return 0;
}

static unsigned nonzero(const double *v, size_t n)
{
	unsigned k = 0;

	for (size_t i = 0; i < n; i++)
		k += v[i] != 0;
	return k;
}

unsigned jobspec_terms(const struct asph_prescription *p)
{
	return 1 + nonzero(p->A, ARRAY_SIZE(p->A)) + nonzero(p->Q, ARRAY_SIZE(p->Q)) +
	       nonzero(p->C, ARRAY_SIZE(p->C)) + nonzero(p->Zernike, ARRAY_SIZE(p->Zernike)) +
	       nonzero(&p->q2d_a[0][0], sizeof(p->q2d_a) / sizeof(double)) +
	       nonzero(&p->q2d_b[0][0], sizeof(p->q2d_b) / sizeof(double));
}

/* Refused when the plan's n points on a surface of p's terms cost more
 * than the limits allow. Not exact: n is the count asked for, which the
 * plan comes near; the plan's own count is held to max_plan_points to the
 * point. */
static int plan_cost(const struct asph_prescription *p, double n, bool exact,
		     const struct jobspec_limits *lim, struct proto_why *why)
{
	unsigned terms = jobspec_terms(p);

	if (n > (exact ? 1.0 : 2.0) * (double)lim->max_points) {
		snprintf(why->text, sizeof(why->text),
			 "the plan %s %.0f points, more than the limit of %" PRIu64
			 " (limits.max_plan_points)", exact ? "has" : "asks for", n, lim->max_points);
		return PROTO_LIMIT_REACHED;
	}
	if (n * terms > (double)lim->max_point_terms) {
		snprintf(why->text, sizeof(why->text),
			 "the plan's %.0f points on a surface of %u terms make %.0f point-terms, "
			 "more than the limit of %" PRIu64 " (limits.max_plan_point_terms)",
			 n, terms, n * terms, lim->max_point_terms);
		return PROTO_LIMIT_REACHED;
	}
	return 0;
}

/* How many points the plan of this lens would have. */
static int plan_size(const struct asph_prescription *p, enum asph_plan_method m,
		     struct asph_plan_density density, const struct asph_plan_options *po,
		     size_t *n, struct asph_error *err)
{
	struct asph_surface *s = NULL;
	double spacing;
	int r = asph_surface_alloc(p, &s, err);

	if (r < 0)
		return r;
	r = asph_plan_resolve_opts(s, m, density, po, &spacing, n, err);
	asph_surface_free(s);
	return r;
}

/* The plan for the job's tolerance (tolplan.h): {"for_tolerance": true,
 * "capability" (default 0.25), "method" (default: every method the
 * search tries)}. The search runs when the job runs; the tolerance is
 * checked with the fit's (spec_tolerance()). */
static int spec_plan_for_tolerance(json_t *plan, json_t *spec, struct proto_why *why)
{
	static const char *const names[] = { "for_tolerance", "capability", "method", NULL };
	double capability = ASPH_PLAN_SEARCH_DEFAULT_CAPABILITY;
	const char *method = NULL;
	enum asph_plan_method m;
	int r;

	if (proto_params_only(plan, names, why) < 0)
		return PROTO_INVALID_PARAMS;
	if (!json_is_true(json_object_get(plan, "for_tolerance"))) {
		snprintf(why->text, sizeof(why->text), "\"plan.for_tolerance\" must be true "
			 "(or left out, with \"method\" and a density)");
		return PROTO_INVALID_PARAMS;
	}
	r = proto_param_number(plan, "capability", false, -1e300, 1e300, &capability, why);
	if (r == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (!(capability > 0 && capability <= 1)) {
		snprintf(why->text, sizeof(why->text), "\"plan.capability\": %g is outside (0, 1]: "
			 "it is the largest U (k = 2) the plan may reach, as a fraction of each "
			 "quantity's tolerance T", capability);
		return PROTO_INVALID_PARAMS;
	}
	if (proto_param_string(plan, "method", false, 32, &method, why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (method && asph_plan_method_from_name(method, &m) < 0) {
		snprintf(why->text, sizeof(why->text), "\"plan.method\": unknown method \"%s\"",
			 method);
		return PROTO_INVALID_PLAN;
	}
	json_object_set_new(spec, "plan", json_pack("{s:b, s:f}", "for_tolerance", 1,
						    "capability", capability));
	if (method)
		json_object_set_new(json_object_get(spec, "plan"), "method", json_string(method));
	return 0;
}

static int spec_plan(json_t *params, json_t *spec, const struct asph_prescription *p,
		     const struct jobspec_limits *lim, uint64_t *points, struct proto_why *why)
{
	static const char *const names[] = { "method", "h", "spacing", "points", "profiles", NULL };
	struct asph_plan_density density = { 0 };
	struct asph_plan_options po = { 0 };
	int64_t profiles = 0;
	enum asph_plan_method m;
	struct asph_error err;
	json_t *plan;
	const char *method;
	int n_density = 0, r;
	size_t n;

	if (proto_param_object(params, "plan", true, &plan, why) < 0)
		return PROTO_INVALID_PARAMS;
	if (json_object_get(plan, "for_tolerance")) {
		*points = 0;    /* chosen when the job runs */
		return spec_plan_for_tolerance(plan, spec, why);
	}
	if (proto_params_only(plan, names, why) < 0 ||
	    proto_param_string(plan, "method", true, 32, &method, why) < 0)
		return PROTO_INVALID_PARAMS;
	if (asph_plan_method_from_name(method, &m) < 0) {
		const char *near = asph_plan_method_suggest(method);
		snprintf(why->text, sizeof(why->text), "\"plan.method\": unknown method \"%s\"%s%s%s",
			 method, near ? " (did you mean \"" : "", near ? near : "", near ? "\"?)" : "");
		return PROTO_INVALID_PLAN;
	}
	for (int k = 0; k < 3; k++) {
		double v;
		r = proto_param_number(plan, asph_plan_density_name((enum asph_plan_density_kind)k),
				       false, 1e-9, 1e12, &v, why);
		if (r == -EINVAL)
			return PROTO_INVALID_PARAMS;
		if (r == 0) {
			density.kind = (enum asph_plan_density_kind)k;
			density.value = v;
			n_density++;
		}
	}
	if (n_density != 1) {
		snprintf(why->text, sizeof(why->text),
			 "\"plan\" needs exactly one of \"h\", \"spacing\", \"points\"");
		return PROTO_INVALID_PARAMS;
	}
	if (proto_param_int(plan, "profiles", false, 1, ASPH_PLAN_MAX_PROFILES, &profiles,
			    why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (profiles && m != ASPH_PLAN_PROFILES) {
		snprintf(why->text, sizeof(why->text),
			 "\"plan.profiles\" is for the method \"profiles\", not \"%s\"", method);
		return PROTO_INVALID_PARAMS;
	}
	if (m == ASPH_PLAN_PROFILES)
		po.profiles = profiles ? (unsigned)profiles : 1;
	/* Asked for by its number of points: refused before the surface is
	 * built (which takes time for a freeform of many terms). */
	if (density.kind == ASPH_DENSITY_POINTS &&
	    (r = plan_cost(p, density.value, false, lim, why)))
		return r;
	asph_error_clear(&err);
	r = plan_size(p, m, density, &po, &n, &err);
	if (r < 0) {
		snprintf(why->text, sizeof(why->text), "\"plan\": %.200s", err.message);
		return PROTO_INVALID_PLAN;
	}
	if ((r = plan_cost(p, (double)n, true, lim, why)))
		return r;
	*points = n;
	json_object_set_new(spec, "plan", json_pack("{s:s, s:s, s:f}", "method", method,
		"density", asph_plan_density_name(density.kind), "value", density.value));
	if (po.profiles)
		json_object_set_new(json_object_get(spec, "plan"), "profiles",
				    json_integer(po.profiles));
	return 0;
}

/* A plan of one profile: the fit has its DOF (in the trace's frame). */
static bool one_profile(const json_t *spec)
{
	const json_t *plan = json_object_get(spec, "plan");
	const char *method = json_string_value(json_object_get(plan, "method"));

	/* (a plan for the tolerance may name no method) */
	return method && !strcmp(method, asph_plan_method_name(ASPH_PLAN_PROFILES)) &&
	       json_integer_value(json_object_get(plan, "profiles")) == 1;
}

static int spec_fit(json_t *params, json_t *spec, struct proto_why *why)
{
	static const char *const names[] = { "dof", "residual", "robust", "zernike", NULL };
	json_t *fit = NULL;
	const char *dof = one_profile(spec) ? "tx,tz,ry" : "tx,ty,tz,rx,ry", *residual = "normal";
	bool robust = false;
	int64_t zernike = ASPH_FIT_DEFAULT_ZERNIKE;
	enum asph_fit_residual_kind kind;
	struct asph_error err;
	unsigned mask;

	if (proto_param_object(params, "fit", false, &fit, why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (fit && (proto_params_only(fit, names, why) < 0 ||
		    proto_param_string(fit, "dof", false, 64, &dof, why) == -EINVAL ||
		    proto_param_string(fit, "residual", false, 16, &residual, why) == -EINVAL ||
		    proto_param_bool(fit, "robust", false, &robust, why) == -EINVAL ||
		    proto_param_int(fit, "zernike", false, 1, ASPH_FIT_MAX_ZERNIKE, &zernike,
				    why) == -EINVAL))
		return PROTO_INVALID_PARAMS;
	if (asph_fit_dof_parse(dof, &mask, &err) < 0) {
		snprintf(why->text, sizeof(why->text), "\"fit.dof\": %.200s", err.message);
		return PROTO_INVALID_PARAMS;
	}
	if (one_profile(spec) && (mask & ~ASPH_FIT_DOF_PROFILE)) {
		snprintf(why->text, sizeof(why->text),
			 "\"fit.dof\": a plan of one profile tells apart tx (the decentre along "
			 "the trace), tz, ry (the tilt about the axis across it), R and k, in the "
			 "trace's frame, not \"%.40s\"", dof);
		return PROTO_INVALID_PARAMS;
	}
	if (asph_fit_residual_from_name(residual, &kind) < 0) {
		snprintf(why->text, sizeof(why->text),
			 "\"fit.residual\" must be \"normal\" or \"sag\"");
		return PROTO_INVALID_PARAMS;
	}
	json_object_set_new(spec, "fit", json_pack("{s:s, s:s, s:b, s:I}", "dof", dof,
		"residual", residual, "robust", robust, "zernike", (json_int_t)zernike));
	return 0;
}

/*
 * Where a tolerance is wrong: its member, and for a call-out the column in
 * the call-out as a JSON string ("3/2(0.5" -> column 9: missing ')'), as
 * asph fit --tolerance counts it.
 */
static int tolerance_why(json_t *tol, const struct asph_error *err, struct proto_why *why)
{
	json_t *co = json_is_string(tol) ? tol : json_object_get(tol, "iso10110_5");
	bool in_callout = json_is_string(tol) || !strcmp(err->field, "iso10110_5");
	_cleanup_free_ char *text = NULL;
	struct asph_tolerance t;
	struct asph_error cerr;

	asph_error_clear(&cerr);
	if (in_callout && json_is_string(co) && (text = json_dumps(co, JSON_ENCODE_ANY)) &&
	    asph_tolerance_parse_json(text, strlen(text), "tolerance", &t, &cerr) < 0 &&
	    cerr.column > 0) {
		snprintf(why->text, sizeof(why->text), "\"tolerance%s\": column %d: %.150s",
			 json_is_string(tol) ? "" : ".iso10110_5", cerr.column, cerr.message);
		return PROTO_INVALID_PARAMS;
	}
	snprintf(why->text, sizeof(why->text), "\"tolerance%s%.60s\": %.150s",
		 err->field[0] ? "." : "", err->field, err->message);
	return PROTO_INVALID_PARAMS;
}

/*
 * The tolerance (docs/characterization.md): kept as the client wrote it,
 * checked here so that a job that cannot be decided is refused at once.
 * An R_mm limit needs R among the fitted degrees of freedom.
 */
static int spec_tolerance(json_t *params, json_t *spec, struct proto_why *why)
{
	json_t *tol = json_object_get(params, "tolerance");
	struct asph_tolerance t;
	struct asph_error err;
	_cleanup_free_ char *text = NULL;
	unsigned mask = 0;

	if (!tol || json_is_null(tol))
		return 0;
	if (!json_is_object(tol) && !json_is_string(tol)) {
		snprintf(why->text, sizeof(why->text),
			 "\"tolerance\" must be an object or an ISO 10110-5 call-out string");
		return PROTO_INVALID_PARAMS;
	}
	text = json_dumps(tol, JSON_ENCODE_ANY | JSON_COMPACT);
	if (!text)
		return PROTO_INTERNAL_ERROR;
	asph_error_clear(&err);
	if (asph_tolerance_parse_json(text, strlen(text), "tolerance", &t, &err) < 0)
		return tolerance_why(tol, &err, why);
	asph_fit_dof_parse(json_string_value(json_object_get(json_object_get(spec, "fit"), "dof")),
			   &mask, &err);
	if (!isnan(t.R_mm) && !(mask & ASPH_FIT_DOF_BIT(ASPH_FIT_R))) {
		snprintf(why->text, sizeof(why->text),
			 "\"tolerance.R_mm\" needs R among the degrees of freedom (\"fit.dof\")");
		return PROTO_INVALID_PARAMS;
	}
	json_object_set(spec, "tolerance", tol);
	return 0;
}

/* "measured" in place of "plan": the descriptor's index (the transport
 * holds it), the format and the unit of unitless text columns, checked
 * here (into spec, unless NULL); the data itself is read by the caller
 * (estimate.c). */
static int spec_measured(json_t *params, json_t *spec, struct proto_why *why)
{
	static const char *const names[] = { "fd", "format", "units", NULL };
	const char *format = NULL, *units = NULL;
	enum asph_points_format f;
	json_t *m;
	int64_t fd;
	double mm;

	if (json_object_get(params, "plan")) {
		snprintf(why->text, sizeof(why->text), "\"measured\" is the job's data: a job with "
			 "it has no \"plan\"");
		return PROTO_INVALID_PARAMS;
	}
	if (proto_param_object(params, "measured", true, &m, why) < 0 ||
	    proto_params_only(m, names, why) < 0 ||
	    proto_param_int(m, "fd", true, 0, JOBSPEC_MAX_FD, &fd, why) < 0 ||
	    proto_param_string(m, "format", false, 32, &format, why) == -EINVAL ||
	    proto_param_string(m, "units", false, 16, &units, why) == -EINVAL)
		return PROTO_INVALID_PARAMS;
	if (format && asph_points_format_parse(format, &f) < 0) {
		char list[128];
		asph_points_format_names(list, sizeof(list));
		snprintf(why->text, sizeof(why->text), "\"measured.format\": unknown format "
			 "\"%s\" (%s)", format, list);
		return PROTO_INVALID_PARAMS;
	}
	if (units && asph_points_unit_parse(units, &mm) < 0) {
		char list[128];
		asph_points_unit_names(list, sizeof(list));
		snprintf(why->text, sizeof(why->text), "\"measured.units\": unknown unit \"%s\" "
			 "(%s)", units, list);
		return PROTO_INVALID_PARAMS;
	}
	if (!spec)
		return 0;
	return json_object_set_new(spec, "measured", json_pack("{s:s, s:s?}", "format",
				   format ? format : "auto", "units", units)) < 0
		? PROTO_INTERNAL_ERROR : 0;
}

int jobspec_check_measured(json_t *params, struct proto_why *why)
{
	return spec_measured(params, NULL, why);
}

bool jobspec_measured(const json_t *spec)
{
	return json_object_get(spec, "measured") != NULL;
}

int jobspec_from_params(json_t *params, const struct jobspec_limits *lim, json_t **out,
			uint64_t *points, struct proto_why *why)
{
	struct asph_prescription p;
	json_t *spec = json_object();
	int code;

	if (!spec)
		return PROTO_INTERNAL_ERROR;
	code = spec_lens(params, spec, &p, why);
	if (!code && json_object_get(params, "measured")) {
		*points = 0;    /* counted as the data is read */
		code = spec_measured(params, spec, why);
	} else if (!code) {
		code = spec_plan(params, spec, &p, lim, points, why);
	}
	if (!code)
		code = spec_fit(params, spec, why);
	if (!code)
		code = spec_tolerance(params, spec, why);
	if (!code && jobspec_for_tolerance(spec) && !json_object_get(spec, "tolerance")) {
		snprintf(why->text, sizeof(why->text), "\"plan.for_tolerance\" chooses the plan "
			 "from the job's tolerance: \"tolerance\" is missing");
		code = PROTO_INVALID_PARAMS;
	}
	if (code) {
		json_decref(spec);
		return code;
	}
	*out = spec;
	return 0;
}

bool jobspec_for_tolerance(const json_t *spec)
{
	return json_is_true(json_object_get(json_object_get(spec, "plan"), "for_tolerance"));
}
