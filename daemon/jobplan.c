/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Worker thread: a stored job specification made ready to measure. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph-engine/executor.h"
#include "jobplan.h"
#include "util-mem.h"

/* The job's tolerance, checked when it was submitted. */
static int plan_tolerance(json_t *tol, struct job_plan *jp, struct asph_error *err)
{
	_cleanup_free_ char *text = NULL;

	if (!tol)
		return 0;
	text = json_dumps(tol, JSON_ENCODE_ANY | JSON_COMPACT);
	if (!text)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if (asph_tolerance_parse_json(text, strlen(text), "the stored tolerance", &jp->tolerance,
				      err) < 0)
		return err->code;
	jp->fit.tolerance = &jp->tolerance;
	jp->tolerance_json = steal_ptr(text);
	return 0;
}

/* Everything of spec but its plan (or its measured data): the lens, its
 * surface, the fit. */
static int build_part(json_t *spec, struct job_plan *jp, struct asph_error *err)
{
	json_t *lens = json_object_get(spec, "lens"), *fit = json_object_get(spec, "fit");
	_cleanup_free_ char *text = NULL;
	int r;

	if (!lens || (!json_object_get(spec, "plan") && !json_object_get(spec, "measured")) ||
	    !fit)
		return asph_error_set(err, -EINVAL, "the stored job specification is damaged");
	text = json_dumps(json_object_get(lens, "prescription"), JSON_COMPACT);
	if (!text)
		return asph_error_set(err, -EINVAL, "the stored prescription is damaged");
	r = asph_prescription_parse(text, strlen(text), "job", &jp->prescription, err);
	if (r < 0)
		return r;
	if (json_is_string(json_object_get(lens, "name")))
		jp->lens_name = strdup(json_string_value(json_object_get(lens, "name")));
	r = asph_surface_alloc(&jp->prescription, &jp->surface, err);
	if (r < 0)
		return r;
	if (asph_prescription_to_json(&jp->prescription, &jp->prescription_json) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	jp->fit_json = json_dumps(fit, JSON_COMPACT);
	r = asph_fit_dof_parse(json_string_value(json_object_get(fit, "dof")), &jp->fit.dof, err);
	if (r < 0)
		return r;
	r = asph_fit_residual_from_name(json_string_value(json_object_get(fit, "residual")),
					&jp->fit.residual);
	if (r < 0)
		return asph_error_set(err, r, "the stored fit options are damaged");
	jp->fit.robust = json_is_true(json_object_get(fit, "robust"));
	jp->fit.n_zernike = (int)json_integer_value(json_object_get(fit, "zernike"));
	return plan_tolerance(json_object_get(spec, "tolerance"), jp, err);
}

int job_plan_build_part(const char *spec_text, struct job_plan *jp, struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(spec_text, 0, NULL);

	memset(jp, 0, sizeof(*jp));
	return build_part(spec, jp, err);
}

int job_plan_build(const char *spec_text, uint64_t max_points, struct job_plan *jp,
		   struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(spec_text, 0, NULL);
	json_t *plan = json_object_get(spec, "plan");
	struct asph_plan_density density = { 0 };
	struct asph_plan_options po = { .max_points = max_points, .flags = ASPH_PLAN_NO_MESH };
	enum asph_plan_method m;
	int r;

	memset(jp, 0, sizeof(*jp));
	r = build_part(spec, jp, err);
	if (r < 0)
		return r;
	if (asph_plan_method_from_name(json_string_value(json_object_get(plan, "method")), &m) < 0)
		return asph_error_set(err, -EINVAL, "the stored plan method is damaged");
	if (asph_plan_density_from_name(json_string_value(json_object_get(plan, "density")),
					&density.kind) < 0)
		return asph_error_set(err, -EINVAL, "the stored plan density is damaged");
	density.value = json_number_value(json_object_get(plan, "value"));
	po.profiles = (unsigned)json_integer_value(json_object_get(plan, "profiles"));
	r = asph_plan_compute_opts(jp->surface, m, density, &po, &jp->plan, err);
	if (r < 0)
		return r;
	if (asph_plan_to_json(jp->plan, &jp->plan_json) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	return 0;
}

void job_plan_release(struct job_plan *jp)
{
	asph_plan_free(jp->plan);
	asph_surface_free(jp->surface);
	free(jp->prescription_json);
	free(jp->plan_json);
	free(jp->fit_json);
	free(jp->tolerance_json);
	free(jp->lens_name);
	memset(jp, 0, sizeof(*jp));
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)

int job_plan_estimate(const char *spec, uint64_t max_points,
		      const struct asph_instrument_config *c, double *seconds,
		      struct asph_error *err)
{
	_cleanup_(asph_config_freep) struct asph_config *own = NULL;
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	struct job_plan jp;
	int r = job_plan_build(spec, max_points, &jp, err);

	if (r == 0)
		r = asph_instrument_config_copy(c, &own, err);
	if (r == 0)
		r = asph_instrument_config_set_lens(&own->instruments[0], jp.prescription_json, err);
	if (r == 0)
		r = asph_scan_estimate(&own->instruments[0], jp.surface, jp.plan->xyz, jp.plan->n,
				       &so, seconds, err);
	job_plan_release(&jp);
	return r;
}
