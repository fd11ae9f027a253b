/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Re-simulation: the points a simulated instrument (the mock, with its
 * physical model) measures for a plan, characterized as a recorded scan is
 * (the drift references' correction applied). A Monte Carlo evaluation of
 * the measurement uncertainty draws the instrument model's contributions
 * (its options: noise and seed, misalignment, bench errors), simulates,
 * fits, and repeats.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "asph/drift.h"
#include "asph-engine/executor.h"
#include "asph/prescription.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

/* Measures the plan into the file at path: 0 or -errno. */
static int record(const struct asph_instrument_config *c, const struct asph_surface *s,
		  const double *xyz, size_t n, const char *path, struct asph_error *err)
{
	_cleanup_free_ char *lens = NULL, *inst_json = NULL;
	struct asph_scanfile_writer_options wo = { .flags = ASPH_SCANFILE_OVERWRITE };
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	struct asph_scanfile_writer *w;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	int r;

	if (asph_prescription_to_json(asph_surface_prescription(s), &lens) < 0 ||
	    asph_instrument_config_to_json(c, &inst_json) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	struct asph_scanfile_header_info info = { lens, "{\"method\":\"simulated\"}", inst_json,
						  NULL };
	r = asph_instrument_open(c, 1000, &inst, err);
	if (r < 0)
		return r;
	r = asph_scan_new(inst, s, xyz, n, &so, &sc, err);
	if (r == 0) {
		r = asph_scanfile_writer_create(path, &info, &wo, &w, err);
		if (r == 0)
			r = asph_scan_run(sc, w, err);
		asph_scan_free(sc);
	}
	asph_instrument_close(inst);
	return r;
}

int asph_scan_simulate(const struct asph_instrument_config *c, const struct asph_surface *s,
		       const double *xyz, size_t n, const char *dir, struct asph_points **out,
		       struct asph_drift_summary *drift, struct asph_error *err)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *rec = NULL;
	char path[4096];
	int fd, r;

	if (snprintf(path, sizeof(path), "%s/asph-simulate-XXXXXX", dir) >= (int)sizeof(path))
		return asph_error_set(err, -ENAMETOOLONG, "%s: directory name too long", dir);
	fd = mkstemp(path);
	if (fd < 0)
		return asph_error_set(err, -errno, "%s: %s", dir, strerror(errno));
	close(fd);
	r = record(c, s, xyz, n, path, err);
	if (r == 0)
		r = asph_scanfile_read(path, &rec, err);
	if (r == 0)
		r = asph_drift_scanfile_points(rec, path, 0, 0, out, drift, err);
	unlink(path);
	return r;
}
