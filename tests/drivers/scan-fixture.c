/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include <cmocka.h>

#include "asph/prescription.h"
#include "scan-fixture.h"

void scan_fixture_init(struct scan_fixture *f, double n_points, const char *name)
{
	struct asph_prescription p;
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, n_points };
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };

	*f = (struct scan_fixture){ 0 };
	assert_int_equal(asph_registry_new(&f->reg, NULL), 0);
	assert_int_equal(asph_prescription_preset("strong", &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &f->s, NULL), 0);
	assert_int_equal(asph_plan_compute_opts(f->s, ASPH_PLAN_FERMAT, d, &po, &f->plan, NULL), 0);
	snprintf(f->dir, sizeof(f->dir), "/tmp/asph-test-%s-XXXXXX", name);
	assert_non_null(mkdtemp(f->dir));
}

void scan_fixture_fini(struct scan_fixture *f)
{
	char path[128];

	for (int i = 0; i < f->n_files; i++) {
		snprintf(path, sizeof(path), "%s/scan%d.asph", f->dir, i);
		unlink(path);
	}
	rmdir(f->dir);
	asph_plan_free(f->plan);
	asph_surface_free(f->s);
	asph_registry_free(f->reg);
}

const char *new_path(struct scan_fixture *f, char *buf, size_t size)
{
	snprintf(buf, size, "%s/scan%d.asph", f->dir, f->n_files++);
	return buf;
}

struct asph_scanfile *read_scan(const char *path)
{
	struct asph_scanfile *s;
	struct asph_error err;

	if (asph_scanfile_read(path, &s, &err) < 0)
		fail_msg("%s: %s", path, err.message);
	return s;
}

int fixture_scan(struct scan_fixture *f, const struct asph_instrument_config *ic,
		 const double *xyz, size_t n, const char *path, struct asph_error *err,
		 bool open_may_fail)
{
	struct asph_scanfile_header_info info = { "{\"name\":\"strong\"}", "{\"method\":\"fermat\"}",
						  "{\"name\":\"bench\"}", NULL };
	struct asph_scanfile_writer *w;
	struct asph_instrument *inst;
	struct asph_scan *sc;

	int r = asph_instrument_open(ic, 2000, &inst, err);
	if (r < 0 && open_may_fail)
		return r;
	if (r < 0)
		fail_msg("open: %s", err->message);
	assert_int_equal(asph_scan_new(inst, f->s, xyz, n, NULL, &sc, NULL), 0);
	assert_int_equal(asph_scanfile_writer_create(path, &info, NULL, &w, NULL), 0);
	r = asph_scan_run(sc, w, err);
	asph_scan_free(sc);
	asph_instrument_close(inst);
	return r;
}

void fixture_fit_rigid(const struct scan_fixture *f, const char *path, size_t n,
		       struct asph_fit_result *res)
{
	struct asph_scanfile *s = read_scan(path);
	struct asph_points *pts;
	struct asph_fit *w;
	struct asph_error err;
	struct asph_fit_options fo = { .dof = ASPH_FIT_DOF_RIGID };

	assert_int_equal(s->report.outcome, ASPH_SCANFILE_COMPLETED);
	assert_int_equal(s->n, n);
	assert_int_equal(asph_scanfile_to_points(s, 0, &pts, NULL), 0);
	assert_int_equal(asph_fit_alloc(f->s, pts->n, &fo, &w, NULL), 0);
	if (asph_fit_run(w, pts->xyz, pts->n, res, &err) < 0)
		fail_msg("fit: %s", err.message);
	asph_fit_free(w);
	asph_points_free(pts);
	asph_scanfile_free(s);
}
