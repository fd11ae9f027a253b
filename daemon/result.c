/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Worker thread: characterization of a recorded scan, and the result files. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <jansson.h>

#include "asph/areal.h"
#include "asph/drift.h"
#include "asph/instrument.h"
#include "asph/plot.h"
#include "asph/points.h"
#include "asph/report.h"
#include "asph/scanfile.h"
#include "asph/x3p.h"
#include "asph-proto.h"
#include "config.h"
#include "dirs.h"
#include "result.h"
#include "runner.h"
#include "sha256.h"
#include "uncertainty.h"
#include "util-fs.h"
#include "util-time.h"
#include "util-mem.h"

#define STR(x) #x
#define XSTR(x) STR(x)
#define PROTOCOL_VERSION XSTR(PROTO_VERSION_MAJOR) "." XSTR(PROTO_VERSION_MINOR)

/* The recorded scan, mapped read-only from the job's folder. */
struct mapped {
	void *data;
	size_t len;
};

static void unmap(struct mapped *m)
{
	if (m->data && m->data != MAP_FAILED)
		munmap(m->data, m->len);
}

static int map_scan(const struct result_source *job, struct mapped *m, struct asph_error *err)
{
	_cleanup_close_ int fd = fs_open_beneath(job->dir_fd, RUNNER_SCAN_FILE, O_RDONLY, 0);
	struct stat st;

	if (fd < 0)
		return asph_error_set(err, fd, "%s/%s: %s", job->dir, RUNNER_SCAN_FILE,
				      fd == -ELOOP ? "a symbolic link: not read" : strerror(-fd));
	if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode) || st.st_size <= 0)
		return asph_error_set(err, -EINVAL, "%s/%s: not a recorded scan", job->dir,
				      RUNNER_SCAN_FILE);
	m->len = (size_t)st.st_size;
	m->data = mmap(NULL, m->len, PROT_READ, MAP_PRIVATE, fd, 0);
	if (m->data == MAP_FAILED) {
		m->data = NULL;
		return asph_error_set(err, -errno, "%s/%s: %s", job->dir, RUNNER_SCAN_FILE,
				      strerror(errno));
	}
	return 0;
}

static int write_text(FILE *f, void *data, struct asph_error *err)
{
	fputs(data, f);
	return 0;
}

struct characterized {
	struct mapped map;
	struct asph_scanfile *scan;
	struct asph_points *points;
	struct asph_fit *fit;
	struct asph_fit_result res;
	char *acquisition;      /* the acquisition's account, JSON */
};

static void characterized_release(struct characterized *c)
{
	asph_fit_free(c->fit);
	asph_points_free(c->points);
	asph_scanfile_free(c->scan);
	free(c->acquisition);
	unmap(&c->map);
}

/* The points as asph export writes them and asph replay fits them: the
 * drift the references measured corrected. */
static int characterize(const struct result_source *job, const struct job_plan *jp,
			struct characterized *c, struct asph_error *err)
{
	_cleanup_free_ char *path = NULL;
	struct asph_drift_summary sum;
	int r = map_scan(job, &c->map, err);

	if (r < 0)
		return r;
	if (asprintf(&path, "%s/%s", job->dir, RUNNER_SCAN_FILE) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_scanfile_read_memory(c->map.data, c->map.len, path, &c->scan, err);
	if (r < 0)
		return r;
	r = asph_drift_scanfile_points(c->scan, path, 0, 0, &c->points, &sum, err);
	if (r < 0)
		return r;
	if (asph_drift_report_json(c->scan, &sum, 1, &c->acquisition) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_fit_alloc(jp->surface, c->points->n, &jp->fit, &c->fit, err);
	if (r < 0)
		return r;
	return asph_fit_run(c->fit, c->points->xyz, c->points->n, &c->res, err);
}

static int write_csv(FILE *f, void *data, struct asph_error *err)
{
	return asph_points_write_stream(f, "residuals.csv", data, NULL, err);
}

static int write_map(FILE *f, void *data, struct asph_error *err)
{
	const struct asph_points *p = data;
	struct asph_plot_options po = {
		.title = "Form error", .colour_label = "residual (nm)", .diverging = 1,
	};

	return asph_plot_points_png_stream(f, "residual-map.png", p->xyz, p->value, p->n, &po,
					   err);
}

/* residuals.csv (x, y, z, residual_nm) and residual-map.png. */
static int write_residuals(const struct result_source *job, struct characterized *c,
			   json_t *files, struct asph_error *err)
{
	const double *res = asph_fit_residuals(c->fit);
	struct asph_error perr;
	int r;

	r = asph_points_add_value(c->points, "residual_nm");
	if (r < 0)
		return asph_error_set(err, r, "out of memory");
	for (size_t i = 0; i < c->points->n; i++)
		c->points->value[i] = res[i] * 1e6;
	r = fs_write_file_at(job->dir_fd, "residuals.csv", DIRS_FILE_MODE, write_csv, c->points,
			     err);
	if (r < 0)
		return r;
	json_object_set_new(files, "residuals", json_string("residuals.csv"));
	/* The map is a picture of the same numbers: without cairo, none. */
	asph_error_clear(&perr);
	if (fs_write_file_at(job->dir_fd, "residual-map.png", DIRS_FILE_MODE, write_map,
			     c->points, &perr) == 0)
		json_object_set_new(files, "map", json_string("residual-map.png"));
	return 0;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scatter *, asph_scatter_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_grid *, asph_grid_free)

/* The residual grid of the X3P file: the points' own spacing, but no finer
 * than a thousandth of the aperture's diameter (8 MB of data at most). */
#define X3P_MIN_NODES_ACROSS 1000.0

struct export_source {
	const struct result_source *job;
	const struct job_plan *jp;
	const struct characterized *c;
	const char *instrument_json, *instrument_name;
	const struct asph_scatter *scatter;
	const struct asph_grid *grid;
	const struct asph_psd *psd;     /* NULL: too few samples for one */
	const double *xy, *residual_nm;
	size_t n;
};

static int write_x3p(FILE *f, void *data, struct asph_error *err)
{
	const struct export_source *e = data;
	char comment[256];
	struct asph_x3p_info info = { .creator = "asphd " ASPH_VERSION, .comment = comment };

	snprintf(comment, sizeof(comment), "%s residual of %s after the best fit (z in m), job %lld",
		 asph_fit_residual_name(e->c->res.residual), e->jp->prescription.name,
		 (long long)e->job->job);
	return asph_x3p_write_grid_stream(f, "residual.x3p", e->grid, &info, err);
}

static const char *meta_string(const json_t *meta, const char *key)
{
	return json_string_value(json_object_get(meta, key));
}

/* The report: what, when and by whom from the job's metadata and its
 * recorded scan. */
static int write_report(FILE *f, void *data, struct asph_error *err)
{
	const struct export_source *e = data;
	_cleanup_(json_decrefp) json_t *meta = json_loads(e->job->metadata, 0, NULL);
	const struct asph_report r = {
		.part = meta_string(meta, "part"), .lot = meta_string(meta, "lot"),
		.serial = meta_string(meta, "serial"), .label = meta_string(meta, "label"),
		.operator_name = meta_string(json_object_get(meta, "submitted_by"), "name"),
		.measured_ns = e->c->scan->header.created_ns,
		.measured_end_ns = e->c->scan->report.ended_ns, .job = e->job->job,
		.instrument_name = e->instrument_name,
		.lens_name = e->jp->lens_name ? e->jp->lens_name : e->jp->prescription.name,
		.lens_json = e->jp->prescription_json, .plan_json = e->jp->plan_json,
		.instrument_json = e->instrument_json, .data_name = RUNNER_SCAN_FILE,
		.data = e->c->map.data, .data_len = e->c->map.len,
		.software = "asphd " ASPH_VERSION, .fit = &e->c->res,
		.tolerance = e->jp->fit.tolerance,
		.xy = e->xy, .residual_nm = e->residual_nm, .n = e->n,
		.scatter = e->scatter, .radius = asph_surface_aperture_radius(e->jp->surface),
		.psd = e->psd,
	};

	return asph_report_write_pdf_stream(f, "report.pdf", &r, err);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_psd *, asph_psd_free)

/* psd.csv: the frequencies past 0 (the mean is removed before the
 * transform), with the digits to give each double back. */
static int write_psd(FILE *f, void *data, struct asph_error *err)
{
	const struct asph_psd *p = data;

	fputs("f_per_mm,psd_nm2_mm\n", f);
	for (size_t k = 1; k < p->n; k++)
		fprintf(f, "%.17g,%.17g\n", (double)k * p->df, p->psd[k]);
	if (ferror(f))
		return asph_error_set(err, -EIO, "psd.csv: cannot write");
	return 0;
}

/* The PSD of the residual (asph_psd_residual()), for psd.csv and the
 * report alike: *out NULL when the map has too few samples for one. */
static int residual_psd(const struct asph_scatter *sc, double radius, struct asph_psd **out,
			struct asph_error *err)
{
	struct asph_error perr;
	int r;

	*out = NULL;
	asph_error_clear(&perr);
	r = asph_psd_residual(sc, radius, out, &perr);
	if (r == -EDOM || r == -EINVAL)
		return 0;
	if (r < 0)
		*err = perr;
	return r;
}

/* psd.csv: the spectrum the report draws; none without one. */
static int write_psd_file(const struct result_source *job, const struct asph_psd *p,
			  json_t *files, struct asph_error *err)
{
	int r;

	if (!p)
		return 0;
	r = fs_write_file_at(job->dir_fd, "psd.csv", DIRS_FILE_MODE, write_psd, (void *)p, err);
	if (r < 0)
		return r;
	json_object_set_new(files, "psd", json_string("psd.csv"));
	return 0;
}

/*
 * residual.x3p (the residual map resampled on a grid, ISO 25178-72 matrix
 * layout), psd.csv and report.pdf (without cairo, none). A scan too sparse for a
 * map of the part has neither; only a failure to write fails the result.
 */
static int write_exports(const struct result_source *job, const struct job_plan *jp,
			 const struct asph_instrument_config *ic, const char *instrument_json,
			 const struct characterized *c, json_t *files, struct asph_error *err)
{
	_cleanup_(asph_scatter_freep) struct asph_scatter *sc = NULL;
	_cleanup_(asph_grid_freep) struct asph_grid *g = NULL;
	_cleanup_(asph_psd_freep) struct asph_psd *psd = NULL;
	_cleanup_free_ double *xy = malloc(2 * c->res.n_used * sizeof(double) + 1);
	_cleanup_free_ double *v = malloc(c->res.n_used * sizeof(double) + 1);
	double radius = asph_surface_aperture_radius(jp->surface);
	struct export_source e = { .job = job, .jp = jp, .c = c, .instrument_json = instrument_json,
				   .instrument_name = ic->name, .xy = xy, .residual_nm = v };
	struct asph_error perr;
	int r;

	if (!xy || !v)
		return asph_error_set(err, -ENOMEM, "out of memory");
	e.n = asph_fit_residual_map(c->fit, xy, v);
	asph_error_clear(&perr);
	r = asph_fit_residual_scatter(c->fit, &sc, &perr);
	if (r == 0)
		r = asph_grid_resample(sc, radius, fmax(asph_scatter_median_edge(sc),
							2 * radius / X3P_MIN_NODES_ACROSS), &g, &perr);
	/* Too few points, or all on a line, for a map of the part: the
	 * result stands without the map's exports. */
	if (r == -EDOM || r == -EINVAL)
		return 0;
	if (r < 0) {
		*err = perr;
		return r;
	}
	e.scatter = sc;
	e.grid = g;
	r = fs_write_file_at(job->dir_fd, "residual.x3p", DIRS_FILE_MODE, write_x3p, &e, err);
	if (r < 0)
		return r;
	json_object_set_new(files, "x3p", json_string("residual.x3p"));
	r = residual_psd(sc, radius, &psd, err);
	if (r == 0)
		r = write_psd_file(job, psd, files, err);
	if (r < 0)
		return r;
	e.psd = psd;
	asph_error_clear(&perr);
	r = fs_write_file_at(job->dir_fd, "report.pdf", DIRS_FILE_MODE, write_report, &e, &perr);
	/* Without cairo, or a map too sparse to draw: no report. */
	if (r == -ENOTSUP || r == -EDOM || r == -EINVAL)
		return 0;
	if (r < 0) {
		*err = perr;
		return r;
	}
	json_object_set_new(files, "report", json_string("report.pdf"));
	return 0;
}

static json_t *provenance(const struct result_source *job, const struct job_plan *jp,
			  const char *inst, const struct characterized *c, const char *sha)
{
	_cleanup_(json_decrefp) json_t *meta = json_loads(job->metadata, 0, NULL);
	char started[32] = "", finished[32];
	json_t *p;

	json_int_t st = json_integer_value(json_object_get(meta, "started_ns"));
	if (st > 0)
		iso8601_utc(st, 0, started, sizeof(started));
	iso8601_utc(now_realtime_ns(), 0, finished, sizeof(finished));
	p = json_pack("{s:s?, s:o, s:o, s:o, s:o?, s:o?, s:{s:s, s:s, s:s}, s:O?, s:O?, s:O?,"
		      " s:s?, s:s, s:{s:s, s:s, s:I, s:i, s:s}}",
		"lens_name", jp->lens_name,
		"prescription", json_loads(jp->prescription_json, 0, NULL),
		"plan", json_loads(jp->plan_json, 0, NULL),
		"fit_options", json_loads(jp->fit_json, 0, NULL),
		"tolerance", jp->tolerance_json
			? json_loads(jp->tolerance_json, JSON_DECODE_ANY, NULL) : NULL,
		"instrument", inst ? json_loads(inst, 0, NULL) : NULL,
		"software", "asphd", ASPH_VERSION, "libasph", ASPH_VERSION, "protocol", PROTOCOL_VERSION,
		"submitted_by", json_object_get(meta, "submitted_by"),
		"label", json_object_get(meta, "label"),
		"submitted", json_object_get(meta, "submitted"),
		"started", started[0] ? started : NULL,
		"finished", finished,
		"scan", "file", RUNNER_SCAN_FILE, "sha256", sha,
		"points", (json_int_t)c->scan->n, "resumes", (int)c->scan->report.n_resumes,
		"created", c->scan->header.created ? c->scan->header.created : "");
	if (p)
		json_object_set_new(p, "acquisition", json_loads(c->acquisition, 0, NULL));
	return p;
}

/* The SHA-256 of a file of the job's folder, read beneath it. */
static int hash_file(int dir_fd, const char *name, char hex[65])
{
	_cleanup_close_ int fd = fs_open_beneath(dir_fd, name, O_RDONLY, 0);
	static const char digits[] = "0123456789abcdef";
	uint8_t buf[65536], digest[32];
	struct sha256 h;
	ssize_t n;

	if (fd < 0)
		return fd;
	sha256_init(&h);
	while ((n = read(fd, buf, sizeof(buf))) > 0)
		sha256_update(&h, buf, (size_t)n);
	if (n < 0)
		return -errno;
	sha256_final(&h, digest);
	for (int i = 0; i < 32; i++) {
		hex[2 * i] = digits[digest[i] >> 4];
		hex[2 * i + 1] = digits[digest[i] & 15];
	}
	hex[64] = '\0';
	return 0;
}

/* "hashes": the SHA-256 of every file the result lists but result.json
 * (which cannot hold its own), by file name; the provenance of a result
 * that leaves the PC (MQTT, the central database). */
static json_t *file_hashes(const struct result_source *job, json_t *files, const char *scan_sha)
{
	json_t *out = json_object(), *v;
	const char *key;
	char hex[65];

	json_object_foreach(files, key, v) {
		const char *name = json_string_value(v);
		if (!name || !strcmp(key, "result"))
			continue;
		if (!strcmp(key, "scan"))
			json_object_set_new(out, name, json_string(scan_sha));
		else if (hash_file(job->dir_fd, name, hex) == 0)
			json_object_set_new(out, name, json_string(hex));
	}
	return out;
}

/* The fit's summary as asph replay --json prints it; NULL on ENOMEM. */
static json_t *summary_json(const struct asph_fit_result *res, const char *lens,
			    int robust, const char *acquisition)
{
	_cleanup_free_ char *text = NULL;

	if (asph_fit_result_to_json(res, lens, robust, &text) < 0)
		return NULL;
	json_t *s = json_loads(text, 0, NULL);
	if (s)
		json_object_set_new(s, "acquisition", json_loads(acquisition, 0, NULL));
	return s;
}

int result_build(const struct result_source *job, const struct job_plan *jp,
		 const struct asph_instrument_config *ic, char **out,
		 struct asph_error *err)
{
	struct characterized c = { 0 };
	_cleanup_(json_decrefp) json_t *result = NULL;
	_cleanup_(json_decrefp) json_t *mc = NULL;
	_cleanup_free_ char *inst = NULL;
	json_t *files, *summary;
	char sha[65];
	_cleanup_free_ char *text = NULL;
	int r;

	r = characterize(job, jp, &c, err);
	if (r == 0)
		r = result_uncertainty(job, jp, ic, c.points, &c.res, &mc, err);
	if (r < 0)
		goto out;
	if (job->cancelled && job->cancelled(job->cancelled_data)) {
		r = -ECANCELED;
		goto out;
	}
	sha256_hex(c.map.data, c.map.len, sha);
	files = json_pack("{s:s, s:s}", "scan", RUNNER_SCAN_FILE, "result", "result.json");
	asph_instrument_config_to_json(ic, &inst);
	r = write_residuals(job, &c, files, err);
	if (r == 0)
		r = write_exports(job, jp, ic, inst, &c, files, err);
	if (r < 0) {
		json_decref(files);
		goto out;
	}
	summary = summary_json(&c.res, jp->lens_name ? jp->lens_name : jp->prescription.name,
			       jp->fit.robust, c.acquisition);
	if (summary && mc)
		json_object_update_recursive(summary, mc);
	result = json_pack("{s:I, s:o, s:o, s:o, s:o}", "job", (json_int_t)job->job,
			   "summary", summary,
			   "provenance", provenance(job, jp, inst, &c, sha),
			   "hashes", file_hashes(job, files, sha),
			   "files", files);
	text = result ? json_dumps(result, JSON_INDENT(2)) : NULL;
	if (!text) {
		r = asph_error_set(err, -ENOMEM, "out of memory");
		goto out;
	}
	r = fs_write_file_at(job->dir_fd, "result.json", DIRS_FILE_MODE, write_text, text, err);
	if (r == 0)
		*out = steal_ptr(text);
out:
	characterized_release(&c);
	return r;
}
