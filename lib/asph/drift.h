/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_DRIFT_H
#define ASPH_DRIFT_H

#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/points.h"
#include "asph/scanfile.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Drift correction (docs/characterization.md, "Drift"): the model fitted to
 * a scan's drift references and applied to its points; and what a scan's
 * acquisition says about its points (where their positions came from).
 *
 * The model. A scan measures its reference points in rounds (the k-th
 * measurement of every reference is round k). Round k's drift d_k = (dx,
 * dy, dz) is what moved the part against the probe since round 0: each
 * valid reference r gives delta_r = e_rk - e_r0, e the height of the
 * measured point above the nominal surface there, and delta_r = dz -
 * grad S(r) . (dx, dy). With references whose gradients span the plane
 * (their design matrix of rank 3) all three are fitted by least squares,
 * else dz alone (the vertex, whose slope is 0, sees no lateral drift).
 * d(t) is linear between the rounds' times (the mean of their references'
 * sample instants), constant before the first and after the last. A point
 * measured at t is corrected to p - d(t). The recorded points stay as
 * they are; only the points handed to characterization are corrected.
 */

struct asph_drift;

/*
 * Fits the model to s's references (s->references), on the nominal
 * surface of s's lens. A scan without references (or with one round) gets
 * a model that corrects nothing. -ENOMEM.
 */
int asph_drift_fit(const struct asph_scanfile *s, const struct asph_surface *surface,
		   struct asph_drift **out, struct asph_error *err);
void asph_drift_free(struct asph_drift *d);

/* d(t), mm, t in ns since the scan began. */
void asph_drift_at(const struct asph_drift *d, uint64_t t_ns, double out[3]);

struct asph_drift_summary {
	size_t n_references;    /* reference points in the scan */
	size_t n_rounds;        /* rounds that entered the model */
	unsigned components;    /* 0: none, 1: z, 3: x, y and z */
	double span_s;          /* from the first round to the last */
	/* of the corrections applied to the points: */
	size_t n_corrected;
	double max_mm;          /* the largest length */
	double rms_mm;          /* the RMS length */
	double max_z_mm;        /* the largest |dz| */
};

/*
 * The points characterization sees: asph_scanfile_to_points()'s (the same
 * selection), each corrected by d (NULL: as recorded). sum (may be NULL)
 * receives the model and the size of the corrections applied.
 */
int asph_drift_points(const struct asph_drift *d, const struct asph_scanfile *s,
		      uint32_t exclude_flags, struct asph_points **out,
		      struct asph_drift_summary *sum, struct asph_error *err);

/*
 * The acquisition's account of s as a JSON object (malloc'd text): its
 * points by position source ("positions"), the points paired with a
 * commanded position ("commanded_points", and a warning in "warnings"
 * when there are any), the invalid ones ("invalid_points", "retried_points"),
 * and the drift model with the size of its correction ("drift"; corrected:
 * whether it was applied). Keys in docs/characterization.md.
 */
int asph_drift_report_json(const struct asph_scanfile *s, const struct asph_drift_summary *sum,
			   int corrected, char **out);

/*
 * The points of the scan at scan_path for characterization, as `asph
 * export` writes them and `asph replay` fits them: read, the lens from its
 * header, the drift model fitted and applied (raw: not applied). s_out,
 * sum, report may be NULL.
 */
int asph_drift_scan_points(const char *scan_path, uint32_t exclude_flags, int raw,
			   struct asph_scanfile **s_out, struct asph_points **out,
			   struct asph_drift_summary *sum, struct asph_error *err);
/* The same for a scan already read; name locates errors. */
int asph_drift_scanfile_points(const struct asph_scanfile *s, const char *name,
			       uint32_t exclude_flags, int raw, struct asph_points **out,
			       struct asph_drift_summary *sum, struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
