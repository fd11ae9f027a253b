/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Worker thread: characterization of a recorded scan, and the result files. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <jansson.h>

#include "asph/instrument.h"
#include "asph/plot.h"
#include "asph/points.h"
#include "asph/scanfile.h"
#include "config.h"
#include "result.h"
#include "sha256.h"
#include "util-time.h"
#include "util-mem.h"

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

static int characterize(const struct result_source *job, const struct job_plan *jp,
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
static int write_residuals(const struct result_source *job, struct characterized *c,
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
	if (asprintf(&path, "%s/residuals.csv", job->dir) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_points_write(path, c->points, NULL, err);
	if (r < 0)
		return r;
	json_object_set_new(files, "residuals", json_string("residuals.csv"));
	free(path);
	path = NULL;
	if (asprintf(&path, "%s/residual-map.png", job->dir) < 0)
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

static json_t *provenance(const struct result_source *job, const struct job_plan *jp,
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
		iso8601_utc(st, 0, started, sizeof(started));
	iso8601_utc(now_realtime_ns(), 0, finished, sizeof(finished));
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

/* The fit's summary as asph fit --json prints it; NULL on ENOMEM. */
static json_t *summary_json(const struct asph_fit_result *res, const char *lens,
			    int robust)
{
	_cleanup_free_ char *text = NULL;

	if (asph_fit_result_to_json(res, lens, robust, &text) < 0)
		return NULL;
	return json_loads(text, 0, NULL);
}

int result_build(const struct result_source *job, const struct job_plan *jp,
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
	result = json_pack("{s:I, s:o, s:o, s:o}", "job", (json_int_t)job->job,
			   "summary", summary_json(&c.res, jp->lens_name ? jp->lens_name
							 : jp->prescription.name, jp->fit.robust),
			   "provenance", provenance(job, jp, ic, &c, sha),
			   "files", files);
	text = result ? json_dumps(result, JSON_INDENT(2)) : NULL;
	if (!text) {
		r = asph_error_set(err, -ENOMEM, "out of memory");
		goto out;
	}
	r = write_atomic(job->dir, "result.json", text, err);
	if (r == 0)
		*out = steal_ptr(text);
out:
	characterized_release(&c);
	return r;
}
