/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The writers of a characterization: residual points (CSV, PLY, X3P), the
 * map (PNG), the grid (X3P), the PSD, correction tables, the report (PDF)
 * and a job's result folder. Each takes the one result.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/characterize.h"
#include "asph/plot.h"
#include "asph/report.h"
#include "asph/x3p.h"
#include "characterize-internal.h"
#include "util-fs.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

/* The fit must have run (the result's workspace is set once it has). */
static int not_yet(const struct asph_characterization *c, struct asph_error *err)
{
	return c->res.fit_workspace ? 0
				    : asph_error_set(err, -EINVAL, "nothing characterized to write");
}

/* The map's error: why there is no grid. */
static int no_map(const struct asph_characterization *c, struct asph_error *err)
{
	if (c->res.map_error.code) {
		*err = c->res.map_error;
		return c->res.map_error.code;
	}
	return asph_error_set(err, -EINVAL, "the residual map was not computed");
}

static int in_set(uint8_t status, enum asph_characterize_points_set set)
{
	switch (set) {
	case ASPH_CHARACTERIZE_FITTED_POINTS:
		return status == ASPH_FIT_POINT_USED || status == ASPH_FIT_POINT_OUTLIER;
	case ASPH_CHARACTERIZE_USED_POINTS:
		return status == ASPH_FIT_POINT_USED;
	default:
		return 1;
	}
}

int asph_characterize_residual_points(const struct asph_characterization *c,
				      enum asph_characterize_points_set set,
				      struct asph_points **out, struct asph_error *err)
{
	const struct asph_points *pts = c->points;
	const uint8_t *st;
	const double *res;
	struct asph_points *p;
	size_t m = 0;
	int r = not_yet(c, err);

	if (r < 0)
		return r;
	st = asph_fit_point_status(c->fit);
	res = asph_fit_residuals(c->fit);
	for (size_t i = 0; i < pts->n; i++)
		m += in_set(st[i], set);
	p = asph_points_alloc(m);
	if (!p || asph_points_add_value(p, "residual_nm") < 0) {
		asph_points_free(p);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	m = 0;
	for (size_t i = 0; i < pts->n; i++) {
		if (!in_set(st[i], set))
			continue;
		memcpy(p->xyz + 3 * m, pts->xyz + 3 * i, 3 * sizeof(double));
		p->value[m++] = asph_nm_from_mm(res[i]).v;
	}
	*out = p;
	return 0;
}

void characterize_x3p_comment(const struct asph_characterization *c, char *buf, size_t size)
{
	int64_t job = characterize_job(c);
	int n = snprintf(buf, size, "%s residual of %s after the best fit (z in m)",
			 asph_fit_residual_name(c->res.fit.residual),
			 asph_characterize_lens_name(c));

	if (job > 0 && n >= 0 && (size_t)n < size)
		snprintf(buf + n, size - (size_t)n, ", job %lld", (long long)job);
}

/* Record2 of the X3P files: who wrote them, when the part was measured,
 * on what. */
static struct asph_x3p_info x3p_info(const struct asph_characterization *c, const char *comment)
{
	return (struct asph_x3p_info){
		.creator = c->opts.run.program, .comment = comment,
		.date_ns = characterize_measured_ns(c),
		.instrument_json = characterize_instrument(c),
	};
}

/* The list layout of x, y and the residual as z (mm: the writer's unit). */
static int write_residuals_x3p(const struct asph_characterization *c, const char *path,
			       const struct asph_points *p, struct asph_error *err)
{
	_cleanup_free_ double *xyz = malloc(3 * p->n * sizeof(double) + 1);
	char comment[256];
	struct asph_x3p_info info;

	if (!xyz)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(xyz, 3 * p->n * sizeof(double));
	for (size_t i = 0; i < p->n; i++) {
		xyz[3 * i] = p->xyz[3 * i];
		xyz[3 * i + 1] = p->xyz[3 * i + 1];
		xyz[3 * i + 2] = p->value[i] * 1e-6;
	}
	snprintf(comment, sizeof(comment), "x, y of the points of %s and their %s residual after "
		 "the best fit as z (m)", asph_characterize_lens_name(c),
		 asph_fit_residual_name(c->res.fit.residual));
	info = x3p_info(c, comment);
	return asph_x3p_write_points(path, xyz, p->n, &info, err);
}

static int is_x3p(const char *path)
{
	const char *dot = strrchr(path, '.');

	return dot && !strcasecmp(dot, ".x3p");
}

int asph_characterize_write_residuals(const struct asph_characterization *c, const char *path,
				      enum asph_characterize_points_set set,
				      struct asph_error *err)
{
	_cleanup_(asph_points_freep) struct asph_points *p = NULL;
	int r = asph_characterize_residual_points(c, set, &p, err);

	if (r < 0)
		return r;
	if (is_x3p(path))
		return write_residuals_x3p(c, path, p, err);
	return asph_points_write(path, p, NULL, err);
}

static struct asph_plot_options map_options(const char *title)
{
	return (struct asph_plot_options){
		.title = title, .colour_label = "residual (nm)", .diverging = 1,
	};
}

int asph_characterize_write_map(const struct asph_characterization *c, const char *path,
				const char *title, enum asph_characterize_points_set set,
				struct asph_error *err)
{
	_cleanup_(asph_points_freep) struct asph_points *p = NULL;
	struct asph_plot_options po = map_options(title);
	int r = asph_characterize_residual_points(c, set, &p, err);

	if (r < 0)
		return r;
	return asph_plot_points_png(path, p->xyz, p->value, p->n, &po, err);
}

int asph_characterize_write_x3p(const struct asph_characterization *c, const char *path,
				struct asph_error *err)
{
	char comment[256];
	struct asph_x3p_info info;

	if (!c->grid)
		return no_map(c, err);
	characterize_x3p_comment(c, comment, sizeof(comment));
	info = x3p_info(c, comment);
	return asph_x3p_write_grid(path, c->grid, &info, err);
}

/* The frequencies past 0 (the mean is removed before the transform),
 * with the digits to give each double back. */
static int psd_stream(FILE *f, void *data, struct asph_error *err)
{
	const struct asph_psd *p = data;

	fputs("f_per_mm,psd_nm2_mm\n", f);
	for (size_t k = 1; k < p->n; k++)
		fprintf(f, "%.17g,%.17g\n", (double)k * p->df, p->psd[k]);
	if (fflush(f) != 0 || ferror(f))
		return asph_error_set(err, -EIO, "psd.csv: cannot write");
	return 0;
}

int asph_characterize_write_psd(const struct asph_characterization *c, const char *path,
				struct asph_error *err)
{
	_cleanup_fclose_ FILE *f = NULL;
	int r;

	if (!c->psd)
		return c->grid ? asph_error_set(err, -EDOM, "too few samples for a spectrum")
			       : no_map(c, err);
	f = fopen(path, "we");
	if (!f)
		return asph_error_set_at(err, -errno, path, 0, 0, NULL, "cannot create: %s",
					 strerror(errno));
	r = psd_stream(f, c->psd, err);
	if (fclose(steal_ptr(f)) != 0 && r == 0)
		r = asph_error_set_at(err, -errno, path, 0, 0, NULL, "write error: %s",
				      strerror(errno));
	return r;
}

int asph_characterize_write_correction(const struct asph_characterization *c,
				       const char *path,
				       const struct asph_correction_options *opts,
				       struct asph_error *err)
{
	if (!c->scatter)
		return no_map(c, err);
	return asph_correction_write(path, c->surface, asph_characterize_lens_name(c), c->scatter,
				     c->res.fit.residual == ASPH_FIT_RESIDUAL_NORMAL, opts, err);
}

static const char *meta_string(const json_t *meta, const char *object, const char *key)
{
	if (object)
		meta = json_object_get(meta, object);
	return json_string_value(json_object_get(meta, key));
}

static const char *first(const char *a, const char *b)
{
	return a ? a : b;
}

/* The report of the result: what, who and when the run's, else the job's
 * (meta, the metadata parsed, holds the texts). */
static struct asph_report report_of(const struct asph_characterization *c, const json_t *meta)
{
	const struct asph_characterize_run *run = &c->opts.run;

	return (struct asph_report){
		.part = first(run->part, meta_string(meta, NULL, "part")),
		.lot = first(run->lot, meta_string(meta, NULL, "lot")),
		.serial = first(run->serial, meta_string(meta, NULL, "serial")),
		.operator_name = first(first(run->operator_name,
					     meta_string(meta, "submitted_by", "name")),
				       run->default_operator),
		.measured_ns = characterize_measured_ns(c),
		.measured_end_ns = characterize_measured_end_ns(c),
		.job = characterize_job(c), .label = meta_string(meta, NULL, "label"),
		.lens_name = asph_characterize_lens_name(c),
		.lens_json = c->prescription_json, .plan_json = characterize_plan(c),
		.instrument_json = characterize_instrument(c),
		.data_name = run->data_name, .data = run->data, .data_len = run->data_len,
		.data_sha256 = run->data ? c->data_sha256 : NULL,
		.software = run->program, .fit = &c->res.fit, .tolerance = c->opts.fit.tolerance,
		.xy = c->res.map_xy, .residual_nm = c->res.map_nm, .n = c->res.n_map,
		.scatter = c->scatter, .radius = asph_surface_aperture_radius(c->surface),
		.psd = c->psd,
	};
}

static json_t *metadata(const struct asph_characterization *c)
{
	const char *text = characterize_metadata(c);

	return text ? json_loads(text, 0, NULL) : NULL;
}

int asph_characterize_write_report(const struct asph_characterization *c, const char *path,
				   struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *meta = NULL;
	struct asph_report r;

	if (!c->scatter)
		return no_map(c, err);
	meta = metadata(c);
	r = report_of(c, meta);
	return asph_report_write_pdf(path, &r, err);
}

/* ------------------------------------------------------------ the folder */

struct folder {
	const struct asph_characterization *c;
	const struct asph_characterize_folder *f;
	int dir_fd;
	json_t *files;
	struct asph_points *all;        /* every point with its residual */
};

static int csv_stream(FILE *f, void *data, struct asph_error *err)
{
	return asph_points_write_stream(f, "residuals.csv", data, NULL, err);
}

static int map_stream(FILE *f, void *data, struct asph_error *err)
{
	const struct asph_points *p = data;
	struct asph_plot_options po = map_options("Form error");

	return asph_plot_points_png_stream(f, "residual-map.png", p->xyz, p->value, p->n, &po,
					   err);
}

static int x3p_stream(FILE *f, void *data, struct asph_error *err)
{
	const struct asph_characterization *c = data;
	char comment[256];
	struct asph_x3p_info info;

	characterize_x3p_comment(c, comment, sizeof(comment));
	info = x3p_info(c, comment);
	return asph_x3p_write_grid_stream(f, "residual.x3p", c->grid, &info, err);
}

static int report_stream(FILE *f, void *data, struct asph_error *err)
{
	_cleanup_(json_decrefp) json_t *meta = metadata(data);
	struct asph_report r = report_of(data, meta);

	return asph_report_write_pdf_stream(f, "report.pdf", &r, err);
}

static int text_stream(FILE *f, void *data, struct asph_error *err)
{
	fputs(data, f);
	return 0;
}

/* name written by fn into the folder and listed under key. */
static int folder_file(struct folder *d, const char *key, const char *name, fs_write_fn fn,
		       void *data, struct asph_error *err)
{
	int r = fs_write_file_at(d->dir_fd, name, (mode_t)d->f->mode, fn, data, err);

	if (r == 0)
		json_object_set_new(d->files, key, json_string(name));
	return r;
}

/* residuals.csv; residual-map.png, a picture of the same numbers: without
 * cairo, none. */
static int folder_residuals(struct folder *d, struct asph_error *err)
{
	struct asph_error perr;
	int r = asph_characterize_residual_points(d->c, ASPH_CHARACTERIZE_ALL_POINTS, &d->all,
						  err);

	if (r == 0)
		r = folder_file(d, "residuals", "residuals.csv", csv_stream, d->all, err);
	if (r < 0)
		return r;
	asph_error_clear(&perr);
	folder_file(d, "map", "residual-map.png", map_stream, d->all, &perr);
	/* its last reader: not held beside the report's own copies */
	asph_points_free(d->all);
	d->all = NULL;
	return 0;
}

/* residual.x3p, psd.csv and report.pdf: none for a scan too sparse for a
 * map; no report without cairo. Only a failure to write fails. */
static int folder_exports(struct folder *d, struct asph_error *err)
{
	const struct asph_characterization *c = d->c;
	struct asph_error perr;
	int r;

	if (!c->grid)
		return 0;
	r = folder_file(d, "x3p", "residual.x3p", x3p_stream, (void *)c, err);
	if (r == 0 && c->psd)
		r = folder_file(d, "psd", "psd.csv", psd_stream, c->psd, err);
	if (r < 0)
		return r;
	asph_error_clear(&perr);
	r = folder_file(d, "report", "report.pdf", report_stream, (void *)c, &perr);
	if (r == -ENOTSUP || r == -EDOM || r == -EINVAL)
		return 0;
	if (r < 0)
		*err = perr;
	return r;
}

int asph_characterize_write_folder(const struct asph_characterization *c, int dir_fd,
				   const struct asph_characterize_folder *f,
				   char **result_json, struct asph_error *err)
{
	struct folder d = { .c = c, .f = f, .dir_fd = dir_fd };
	_cleanup_free_ char *text = NULL;
	int r = not_yet(c, err);

	if (r == 0 && (!f->scan_file || !c->opts.run.data))
		r = asph_error_set(err, -EINVAL, "a result folder needs its measured data");
	if (r < 0)
		return r;
	/* a recorded scan's, or measured points read from a file's */
	d.files = json_pack("{s:s, s:s}", c->from_scan ? "scan" : "measured", f->scan_file,
			    "result", "result.json");
	if (!d.files)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = folder_residuals(&d, err);
	if (r == 0)
		r = folder_exports(&d, err);
	if (r == 0)
		r = characterize_result_json(c, f, dir_fd, d.files, &text, err);
	if (r == 0)
		r = fs_write_file_at(dir_fd, "result.json", (mode_t)f->mode, text_stream, text,
				     err);
	json_decref(d.files);
	asph_points_free(d.all);
	if (r == 0 && result_json)
		*result_json = steal_ptr(text);
	return r;
}
