/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The executor's state and its geometry (kinematics, targets, clearance,
 * the checks before the first move), shared by executor.c and
 * executor-geometry.c. Internal. */
#ifndef ASPH_EXECUTOR_INTERNAL_H
#define ASPH_EXECUTOR_INTERNAL_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>

#include "asph/executor.h"

#define RECORD_BATCH 4096
/* A sweep lasts at most this long (s), so that pause, abort and progress
 * stay prompt at any speed. */
#define SWEEP_SECONDS 0.25

struct asph_scan {
	struct asph_instrument *inst;
	const struct asph_surface *surface;
	const double *xyz;
	size_t n;
	struct asph_scan_options o;
	bool tactile, stream;
	double tip;

	atomic_bool paused, aborted;
	pthread_mutex_t lock;           /* progress, pause condition */
	pthread_cond_t wake;
	struct asph_scan_progress progress;

	/* run state, run thread only */
	uint64_t t0_ns, last_report_ns, rate_t_ns, rate_done, measure_t0_ns;
	double rate;
	uint64_t measure_done0;
	double theta_prev;
	double pos[3];          /* where the last motion ended, stage axes */
	double z_safe;          /* travel height over the whole part (machine z) */
	double curvature;       /* bound of the surface's curvature, 1/mm */
	struct asph_scanfile_writer *w;
	struct asph_scanfile_point rec[RECORD_BATCH];
	size_t n_rec;
	double path[3 * RECORD_BATCH];
	struct asph_probe_context ctx[RECORD_BATCH];
	struct asph_reading readings[RECORD_BATCH];
};

/* Where the stage goes for one plan point. */
struct target {
	double cart[3];         /* probe reference point, cartesian, mm */
	double machine[3];      /* the same in the stage's axes */
	double approach[3];     /* clearance above, stage's axes */
	double normal[3];       /* nominal surface normal at the point */
};

/* A bound of the surface's principal curvatures over its aperture. */
double scan_curvature_bound(const struct asph_surface *s);

/* Cartesian <-> the stage's axes. The rotary axis takes the short way
 * from the previous theta (sc->theta_prev). */
void scan_to_machine(struct asph_scan *sc, const double c[3], double m[3]);
void scan_to_cartesian(const struct asph_scan *sc, const double m[3], double c[3]);

/* Where the stage goes for plan point i (the normal only when asked or
 * for a tactile probe). */
void scan_target(struct asph_scan *sc, size_t i, bool need_normal, struct target *t);

/* The probe's gap to the nominal surface at cartesian c (0 on a measuring
 * position), and whether a straight move keeps it above min_gap (ga, gb:
 * the gaps at the ends when known, else NAN). */
double scan_gap(const struct asph_scan *sc, const double c[3]);
bool scan_path_clear_g(const struct asph_scan *sc, const double *a, double ga,
		       const double *b, double gb, double min_gap);
bool scan_path_clear(const struct asph_scan *sc, const double *a, const double *b,
		     double min_gap);

#endif
