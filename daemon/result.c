/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph/instrument.h"
#include "asph/plot.h"
#include "asph/points.h"
#include "asph/scanfile.h"
#include "config.h"
#include "fit-json.h"
#include "result.h"
#include "runner.h"
#include "sha256.h"
#include "time-util.h"
#include "util-mem.h"

/* ------------------------------------------------------------ the spec */

static const char *const density_names[] = { "h", "spacing", "points" };

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
			snprintf(why->text, sizeof(why->text),
				 "\"lens\": no preset named \"%.64s\" (send the prescription "
				 "as an object)", json_string_value(lens));
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

/* How many points the plan of this lens would have. */
static int plan_size(const struct asph_prescription *p, enum asph_plan_method m,
		     struct asph_plan_density density, size_t *n, struct asph_error *err)
{
	struct asph_surface *s = NULL;
	double spacing;
	int r = asph_surface_alloc(p, &s, err);

	if (r < 0)
		return r;
	r = asph_plan_resolve(s, m, density, &spacing, n, err);
	asph_surface_free(s);
	return r;
}

static int spec_plan(json_t *params, json_t *spec, const struct asph_prescription *p,
		     uint64_t max_points, uint64_t *points, struct proto_why *why)
{
	static const char *const names[] = { "method", "h", "spacing", "points", NULL };
	struct asph_plan_density density = { 0 };
	enum asph_plan_method m;
	struct asph_error err;
	json_t *plan;
	const char *method;
	int n_density = 0, r;
	size_t n;

	if (proto_param_object(params, "plan", true, &plan, why) < 0)
		return PROTO_INVALID_PARAMS;
	if (proto_params_only(plan, names, why) < 0 ||
	    proto_param_string(plan, "method", true, 32, &method, why) < 0)
		return PROTO_INVALID_PARAMS;
	if (asph_plan_method_from_name(method, &m) < 0) {
		snprintf(why->text, sizeof(why->text), "\"plan.method\": unknown method \"%s\"",
			 method);
		return PROTO_INVALID_PLAN;
	}
	for (int k = 0; k < 3; k++) {
		double v;
		r = proto_param_number(plan, density_names[k], false, 1e-9, 1e12, &v, why);
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
	asph_error_clear(&err);
	r = plan_size(p, m, density, &n, &err);
	if (r < 0) {
		snprintf(why->text, sizeof(why->text), "\"plan\": %.200s", err.message);
		return PROTO_INVALID_PLAN;
	}
	if (n > max_points) {
		snprintf(why->text, sizeof(why->text),
			 "the plan has %zu points, more than the limit of %" PRIu64, n, max_points);
		return PROTO_LIMIT_REACHED;
	}
	*points = n;
	json_object_set_new(spec, "plan", json_pack("{s:s, s:s, s:f}", "method", method,
		"density", density_names[density.kind], "value", density.value));
	return 0;
}

static int spec_fit(json_t *params, json_t *spec, struct proto_why *why)
{
	static const char *const names[] = { "dof", "residual", "robust", "zernike", NULL };
	json_t *fit = NULL;
	const char *dof = "tx,ty,tz,rx,ry", *residual = "normal";
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
	if (asph_fit_residual_from_name(residual, &kind) < 0) {
		snprintf(why->text, sizeof(why->text),
			 "\"fit.residual\" must be \"normal\" or \"sag\"");
		return PROTO_INVALID_PARAMS;
	}
	json_object_set_new(spec, "fit", json_pack("{s:s, s:s, s:b, s:I}", "dof", dof,
		"residual", residual, "robust", robust, "zernike", (json_int_t)zernike));
	return 0;
}

int spec_from_params(json_t *params, uint64_t max_points, json_t **out,
		     uint64_t *points, struct proto_why *why)
{
	struct asph_prescription p;
	json_t *spec = json_object();
	int code;

	if (!spec)
		return PROTO_INTERNAL_ERROR;
	code = spec_lens(params, spec, &p, why);
	if (!code)
		code = spec_plan(params, spec, &p, max_points, points, why);
	if (!code)
		code = spec_fit(params, spec, why);
	if (code) {
		json_decref(spec);
		return code;
	}
	*out = spec;
	return 0;
}

/* ---------------------------------------------------------- job plan */

int job_plan_build(const char *spec_text, uint64_t max_points, struct job_plan *jp,
		   struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *spec = json_loads(spec_text, 0, NULL);
	json_t *lens, *plan, *fit;
	struct asph_plan_density density = { 0 };
	struct asph_plan_options po = { .max_points = max_points, .flags = ASPH_PLAN_NO_MESH };
	enum asph_plan_method m;
	_cleanup_free_ char *text = NULL;
	const char *dname;
	int r;

	memset(jp, 0, sizeof(*jp));
	lens = json_object_get(spec, "lens");
	plan = json_object_get(spec, "plan");
	fit = json_object_get(spec, "fit");
	if (!lens || !plan || !fit)
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
	if (asph_plan_method_from_name(json_string_value(json_object_get(plan, "method")), &m) < 0)
		return asph_error_set(err, -EINVAL, "the stored plan method is damaged");
	dname = json_string_value(json_object_get(plan, "density"));
	for (int k = 0; k < 3; k++)
		if (dname && !strcmp(dname, density_names[k]))
			density.kind = (enum asph_plan_density_kind)k;
	density.value = json_number_value(json_object_get(plan, "value"));
	r = asph_plan_compute_opts(jp->surface, m, density, &po, &jp->plan, err);
	if (r < 0)
		return r;
	json_t *pj = json_pack("{s:s, s:s, s:f, s:f, s:I}", "method", asph_plan_method_name(m),
			       "density", density_names[density.kind], "value", density.value,
			       "spacing_mm", jp->plan->spacing_mm,
			       "points", (json_int_t)jp->plan->n);
	jp->plan_json = json_dumps(pj, JSON_COMPACT);
	json_decref(pj);
	r = asph_prescription_to_json(&jp->prescription, &jp->prescription_json);
	if (r < 0 || !jp->plan_json)
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
	return 0;
}

void job_plan_release(struct job_plan *jp)
{
	asph_plan_free(jp->plan);
	asph_surface_free(jp->surface);
	free(jp->prescription_json);
	free(jp->plan_json);
	free(jp->fit_json);
	free(jp->lens_name);
	memset(jp, 0, sizeof(*jp));
}

/* ------------------------------------------------------------ result */

/* Writes text to dir/name through a temporary file, synced. */
static int write_atomic(const char *dir, const char *name, const char *text,
			struct asph_error *err)
{
	_cleanup_free_ char *tmp = NULL, *path = NULL;
	_cleanup_close_ int fd = -1;
	size_t len = strlen(text), off = 0;

	if (asprintf(&tmp, "%s/.%s.tmp", dir, name) < 0 ||
	    asprintf(&path, "%s/%s", dir, name) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC | O_NOFOLLOW, 0644);
	if (fd < 0)
		return asph_error_set(err, -errno, "%s: %s", tmp, strerror(errno));
	while (off < len) {
		ssize_t n = write(fd, text + off, len - off);
		if (n < 0) {
			if (errno == EINTR)
				continue;
			return asph_error_set(err, -errno, "%s: %s", tmp, strerror(errno));
		}
		off += (size_t)n;
	}
	if (fsync(fd) < 0 || rename(tmp, path) < 0)
		return asph_error_set(err, -errno, "%s: %s", path, strerror(errno));
	return 0;
}

struct characterized {
	struct asph_scanfile *scan;
	struct asph_points *points;
	struct asph_fit *fit;
	struct asph_fit_result res;
};

static void characterized_release(struct characterized *c)
{
	asph_fit_free(c->fit);
	asph_points_free(c->points);
	asph_scanfile_free(c->scan);
}

static int characterize(const struct runner_job *job, const struct job_plan *jp,
			struct characterized *c, struct asph_error *err)
{
	int r = asph_scanfile_read(job->scan_path, &c->scan, err);

	if (r < 0)
		return r;
	r = asph_scanfile_to_points(c->scan, 0, &c->points, err);
	if (r < 0)
		return r;
	r = asph_fit_alloc(jp->surface, c->points->n, &jp->fit, &c->fit, err);
	if (r < 0)
		return r;
	return asph_fit_run(c->fit, c->points->xyz, c->points->n, &c->res, err);
}

/* residuals.csv (x, y, z, residual_nm) and residual-map.png. */
static int write_residuals(const struct runner_job *job, struct characterized *c,
			   json_t *files, struct asph_error *err)
{
	const double *res = asph_fit_residuals(c->fit);
	_cleanup_free_ char *path = NULL;
	int r;

	r = asph_points_add_value(c->points, "residual_nm");
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	for (size_t i = 0; i < c->points->n; i++)
		c->points->value[i] = res[i] * 1e6;
	if (asprintf(&path, "%s/residuals.csv", job->result_dir) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_points_write(path, c->points, NULL, err);
	if (r < 0)
		return r;
	json_object_set_new(files, "residuals", json_string("residuals.csv"));
	free(path);
	path = NULL;
	if (asprintf(&path, "%s/residual-map.png", job->result_dir) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	struct asph_plot_options po = {
		.title = "Form error", .colour_label = "residual (nm)", .diverging = 1,
	};
	struct asph_error perr;
	if (asph_plot_points_png(path, c->points->xyz, c->points->value, c->points->n,
				 &po, &perr) == 0)
		json_object_set_new(files, "map", json_string("residual-map.png"));
	return 0;
}

static json_t *provenance(const struct runner_job *job, const struct job_plan *jp,
			  const struct asph_instrument_config *ic,
			  const struct characterized *c, const char *sha)
{
	_cleanup_(json_decrefp) json_t *meta = json_loads(job->metadata, 0, NULL);
	_cleanup_free_ char *inst = NULL;
	char started[32] = "", finished[32];
	json_t *p;

	asph_instrument_config_to_json(ic, &inst);
	json_int_t st = json_integer_value(json_object_get(meta, "started_ns"));
	if (st > 0)
		iso8601_utc(st, started, sizeof(started));
	iso8601_utc(realtime_now_ns(), finished, sizeof(finished));
	p = json_pack("{s:s?, s:o, s:o, s:o, s:o?, s:{s:s, s:s, s:s}, s:O?, s:O?, s:O?,"
		      " s:s?, s:s, s:{s:s, s:s, s:I, s:i, s:s}}",
		"lens_name", jp->lens_name,
		"prescription", json_loads(jp->prescription_json, 0, NULL),
		"plan", json_loads(jp->plan_json, 0, NULL),
		"fit_options", json_loads(jp->fit_json, 0, NULL),
		"instrument", inst ? json_loads(inst, 0, NULL) : NULL,
		"software", "asphd", ASPH_VERSION, "libasph", ASPH_VERSION, "protocol", "1.0",
		"submitted_by", json_object_get(meta, "submitted_by"),
		"label", json_object_get(meta, "label"),
		"submitted", json_object_get(meta, "submitted"),
		"started", started[0] ? started : NULL,
		"finished", finished,
		"scan", "file", "scan.asphscan", "sha256", sha,
		"points", (json_int_t)c->scan->n, "resumes", (int)c->scan->report.n_resumes,
		"created", c->scan->header.created ? c->scan->header.created : "");
	return p;
}

int result_build(const struct runner_job *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err)
{
	struct characterized c = { 0 };
	_cleanup_(json_decrefp) json_t *result = NULL;
	json_t *files;
	char sha[65];
	_cleanup_free_ char *text = NULL;
	int r;

	r = characterize(job, jp, &c, err);
	if (r < 0)
		goto out;
	r = sha256_file(job->scan_path, sha);
	if (r < 0) {
		asph_error_set(err, r, "cannot hash the scan: %s", strerror(-r));
		goto out;
	}
	files = json_pack("{s:s, s:s}", "scan", "scan.asphscan", "result", "result.json");
	r = write_residuals(job, &c, files, err);
	if (r < 0) {
		json_decref(files);
		goto out;
	}
	result = json_pack("{s:I, s:o, s:o, s:o}", "job", (json_int_t)job->id,
			   "summary", fit_result_json(&c.res, jp->lens_name ? jp->lens_name
							 : jp->prescription.name, jp->fit.robust),
			   "provenance", provenance(job, jp, ic, &c, sha),
			   "files", files);
	text = result ? json_dumps(result, JSON_INDENT(2)) : NULL;
	if (!text) {
		r = asph_error_set(err, -ENOMEM, "out of memory");
		goto out;
	}
	r = write_atomic(job->result_dir, "result.json", text, err);
	if (r == 0)
		*out = steal_ptr(text);
out:
	characterized_release(&c);
	return r;
}
