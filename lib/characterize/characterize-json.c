/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The characterization as JSON: the summary (asphd's result "summary",
 * asph fit --json) and result.json with its provenance, hashes and files.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include <jansson.h>
#include "util-hash.h"

#include "asph/characterize.h"
#include "characterize-internal.h"
#include "util-fs.h"
#include "util-mem.h"
#include "util-time.h"

/* A JSON text into a value; NULL text is NULL. */
static json_t *loads(const char *text)
{
	return text ? json_loads(text, JSON_DECODE_ANY, NULL) : NULL;
}

static json_t *bands_json(const struct asph_characterization *c)
{
	const struct asph_characterize_result *r = &c->res;

	if (!r->bands_done)
		return json_null();
	return json_pack("{s:f, s:f, s:f, s:f, s:f, s:f, s:f}",
			 "form_mm", c->opts.bands.form_mm, "high_mm", c->opts.bands.high_mm,
			 "grid_spacing_mm", r->grid_spacing_mm, "form_nm", r->bands.form,
			 "mid_nm", r->bands.mid, "high_nm", r->bands.high, "total_nm",
			 r->bands.total);
}

/* The Monte Carlo's keys merged into the summary. */
static int merge_mc(json_t *root, const struct asph_characterize_result *r)
{
	_cleanup_free_ char *text = NULL;
	_cleanup_(json_decrefp) json_t *add = NULL;

	if (asph_mc_result_to_json(&r->mc, r->fit.form.wavelength_nm, &text) < 0 ||
	    !(add = json_loads(text, 0, NULL)))
		return -ENOMEM;
	return json_object_update_recursive(root, add) < 0 ? -ENOMEM : 0;
}

static json_t *summary(const struct asph_characterization *c)
{
	const struct asph_characterize_result *r = &c->res;
	_cleanup_free_ char *text = NULL;
	json_t *root;

	if (asph_fit_result_to_json(&r->fit, asph_characterize_lens_name(c), c->opts.fit.robust,
				    &text) < 0 || !(root = json_loads(text, 0, NULL)))
		return NULL;
	if (r->acquisition_json)
		json_object_set_new(root, "acquisition", loads(r->acquisition_json));
	if (r->mc_done && merge_mc(root, r) < 0) {
		json_decref(root);
		return NULL;
	}
	if (c->opts.outputs & ASPH_CHARACTERIZE_BANDS)
		json_object_set_new(root, "band_rms", bands_json(c));
	return root;
}

int asph_characterize_summary_json(const struct asph_characterization *c, int indent,
				   char **out)
{
	_cleanup_(json_decrefp) json_t *root = NULL;
	size_t flags = indent > 0 ? JSON_INDENT(indent) : JSON_COMPACT;

	*out = NULL;
	if (!c->res.fit_workspace)
		return -EINVAL;
	root = summary(c);
	*out = root ? json_dumps(root, flags | JSON_REAL_PRECISION(17)) : NULL;
	return *out ? 0 : -ENOMEM;
}

/* ------------------------------------------------------------ result.json */

/* The SHA-256 of a file of the folder, read beneath it. */
static int hash_file(int dir_fd, const char *name, char hex[65])
{
	_cleanup_close_ int fd = fs_open_beneath(dir_fd, name, O_RDONLY, 0);
	uint8_t buf[65536];
	struct sha256_ctx h;
	ssize_t n;

	if (fd < 0)
		return fd;
	sha256_init(&h);
	while ((n = read(fd, buf, sizeof(buf))) > 0)
		sha256_update(&h, (size_t)n, buf);
	if (n < 0)
		return -errno;
	sha256_hex_of(&h, hex);
	return 0;
}

/* "hashes": the SHA-256 of every file the result lists but result.json
 * (which cannot hold its own), by file name. */
static json_t *file_hashes(int dir_fd, json_t *files, const char *scan_sha)
{
	json_t *out = json_object(), *v;
	const char *key;
	char hex[65];

	json_object_foreach(files, key, v) {
		const char *name = json_string_value(v);
		if (!name || !strcmp(key, "result"))
			continue;
		if (!strcmp(key, "scan") || !strcmp(key, "measured"))
			json_object_set_new(out, name, json_string(scan_sha));
		else if (hash_file(dir_fd, name, hex) == 0)
			json_object_set_new(out, name, json_string(hex));
	}
	return out;
}

/* The fit's options as a job carries them (proto's "fit"). */
static json_t *fit_options(const struct asph_characterization *c)
{
	const struct asph_fit_options *o = &c->opts.fit;
	unsigned dof = o->dof ? o->dof : ASPH_FIT_DOF_RIGID;
	char names[64] = "";

	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (dof & ASPH_FIT_DOF_BIT(d)) {
			if (names[0])
				strncat(names, ",", sizeof(names) - strlen(names) - 1);
			strncat(names, asph_fit_dof_name((enum asph_fit_dof)d),
				sizeof(names) - strlen(names) - 1);
		}
	return json_pack("{s:s, s:s, s:b, s:i}", "dof", names,
			 "residual", asph_fit_residual_name(o->residual), "robust", o->robust,
			 "zernike", o->n_zernike ? o->n_zernike : ASPH_FIT_DEFAULT_ZERNIKE);
}

static json_t *scan_json(const struct asph_characterization *c,
			 const struct asph_characterize_folder *f, const char *sha)
{
	if (!c->from_scan)
		return json_pack("{s:s, s:s, s:I}", "file", f->scan_file, "sha256", sha,
				 "points", (json_int_t)c->res.fit.n_points);
	return json_pack("{s:s, s:s, s:I, s:i, s:s}", "file", f->scan_file, "sha256", sha,
			 "points", (json_int_t)c->res.scan_points, "resumes",
			 (int)c->res.scan_resumes, "created", c->created ? c->created : "");
}

static json_t *provenance(const struct asph_characterization *c,
			  const struct asph_characterize_folder *f, const char *sha)
{
	_cleanup_(json_decrefp) json_t *meta = loads(characterize_metadata(c));
	json_int_t st = json_integer_value(json_object_get(meta, "started_ns"));
	char started[32] = "", finished[32];
	json_t *p;

	if (st > 0)
		iso8601_utc(st, 0, started, sizeof(started));
	iso8601_utc(f->finished_ns ? f->finished_ns : now_realtime_ns(), 0, finished,
		    sizeof(finished));
	p = json_pack("{s:s?, s:o, s:o?, s:o, s:o?, s:o?, s:o, s:O?, s:O?, s:O?,"
		      " s:s?, s:s, s:o}",
		"lens_name", c->opts.run.lens_name,
		"prescription", loads(c->prescription_json),
		"plan", loads(characterize_plan(c)),    /* none for measured points */
		"fit_options", f->fit_options_json ? loads(f->fit_options_json) : fit_options(c),
		"tolerance", loads(f->tolerance_json),
		"instrument", loads(characterize_instrument(c)),
		"software", loads(f->software_json),
		"submitted_by", json_object_get(meta, "submitted_by"),
		"label", json_object_get(meta, "label"),
		"submitted", json_object_get(meta, "submitted"),
		"started", started[0] ? started : NULL,
		"finished", finished,
		c->from_scan ? "scan" : "measured", scan_json(c, f, sha));
	if (p)
		json_object_set_new(p, "acquisition", loads(c->res.acquisition_json));
	return p;
}

int characterize_result_json(const struct asph_characterization *c,
			     const struct asph_characterize_folder *f, int dir_fd,
			     json_t *files, char **out, struct asph_error *err)
{
	const char *sha = c->data_sha256;
	int64_t job = characterize_job(c);
	json_t *result;
	result = json_pack("{s:o, s:o, s:o, s:o, s:O}",
			   "job", job > 0 ? json_integer(job) : json_null(),
			   "summary", summary(c),
			   "provenance", provenance(c, f, sha),
			   "hashes", file_hashes(dir_fd, files, sha),
			   "files", files);
	if (result && characterize_plan_choice(c))
		json_object_set_new(result, "plan_for_tolerance", loads(characterize_plan_choice(c)));
	*out = result ? json_dumps(result, JSON_INDENT(2)) : NULL;
	json_decref(result);
	return *out ? 0 : asph_error_set(err, -ENOMEM, "out of memory");
}
