/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Worker thread: characterization of a recorded scan, and the result files. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <jansson.h>

#include "asph/instrument.h"
#include "asph/plot.h"
#include "asph/points.h"
#include "asph/scanfile.h"
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
};

static void characterized_release(struct characterized *c)
{
	asph_fit_free(c->fit);
	asph_points_free(c->points);
	asph_scanfile_free(c->scan);
	unmap(&c->map);
}

static int characterize(const struct result_source *job, const struct job_plan *jp,
			struct characterized *c, struct asph_error *err)
{
	_cleanup_free_ char *path = NULL;
	int r = map_scan(job, &c->map, err);

	if (r < 0)
		return r;
	if (asprintf(&path, "%s/%s", job->dir, RUNNER_SCAN_FILE) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_scanfile_read_memory(c->map.data, c->map.len, path, &c->scan, err);
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
		"software", "asphd", ASPH_VERSION, "libasph", ASPH_VERSION, "protocol", PROTOCOL_VERSION,
		"submitted_by", json_object_get(meta, "submitted_by"),
		"label", json_object_get(meta, "label"),
		"submitted", json_object_get(meta, "submitted"),
		"started", started[0] ? started : NULL,
		"finished", finished,
		"scan", "file", RUNNER_SCAN_FILE, "sha256", sha,
		"points", (json_int_t)c->scan->n, "resumes", (int)c->scan->report.n_resumes,
		"created", c->scan->header.created ? c->scan->header.created : "");
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
	_cleanup_(json_decrefp) json_t *mc = NULL;
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
	r = write_residuals(job, &c, files, err);
	if (r < 0) {
		json_decref(files);
		goto out;
	}
	summary = summary_json(&c.res, jp->lens_name ? jp->lens_name : jp->prescription.name,
			       jp->fit.robust);
	if (summary && mc)
		json_object_update_recursive(summary, mc);
	result = json_pack("{s:I, s:o, s:o, s:o, s:o}", "job", (json_int_t)job->job,
			   "summary", summary,
			   "provenance", provenance(job, jp, ic, &c, sha),
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
