/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The fixture of the driver tests that measure a whole plan through the
 * executor (test-executor.c, test-modbus-scan.c): the driver registry, the
 * strong preset's surface, a Fermat plan without mesh and a temporary
 * directory for the scan files a test writes. Failures are cmocka's.
 */
#ifndef ASPH_TEST_SCAN_FIXTURE_H
#define ASPH_TEST_SCAN_FIXTURE_H

#include <stdbool.h>
#include <stddef.h>

#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph/plan.h"

struct scan_fixture {
	struct asph_registry *reg;
	struct asph_surface *s;
	struct asph_plan *plan;
	char dir[64];
	int n_files;            /* scan files named so far */
};

/* A plan of n_points; the files go to /tmp/asph-test-NAME-XXXXXX. */
void scan_fixture_init(struct scan_fixture *f, double n_points, const char *name);

/* Removes the scan files and the directory, frees the rest. */
void scan_fixture_fini(struct scan_fixture *f);

/* The path of the next scan file, in buf. */
const char *new_path(struct scan_fixture *f, char *buf, size_t size);

/* The scan file at path, read whole (the test fails when it cannot be). */
struct asph_scanfile *read_scan(const char *path);

/*
 * Measures the n points xyz of f's surface with instrument ic into path,
 * the executor's defaults. -errno of the scan; an instrument that does
 * not open fails the test unless open_may_fail (then its code).
 */
int fixture_scan(struct scan_fixture *f, const struct asph_instrument_config *ic,
		 const double *xyz, size_t n, const char *path, struct asph_error *err,
		 bool open_may_fail);

/* The rigid-body fit to f's surface of the completed scan at path, which
 * must hold n points. */
void fixture_fit_rigid(const struct scan_fixture *f, const char *path, size_t n,
		       struct asph_fit_result *res);

#endif
