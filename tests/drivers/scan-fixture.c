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
