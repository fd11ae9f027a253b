/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The scan's geometry (geometry.c): the stage's kinematics, where it goes
 * for a point, the clearance of its moves over the part, the checks made
 * before the first move; and the axes' limits as the planner takes them,
 * with the cut of untimed sweeps, which the estimate shares. Below every
 * other part of the engine. Internal.
 */
#ifndef ASPH_ENGINE_GEOMETRY_H
#define ASPH_ENGINE_GEOMETRY_H

#include <stdbool.h>
#include <stddef.h>

#include "asph-driver/instrument.h"
#include "asph/error.h"
#include "asph/motion.h"
#include "asph/surface.h"

struct asph_scan;

/* What geometry.c keeps of a scan; only it writes it. */
struct scan_geometry {
	double curvature;       /* bound of the surface's curvature, 1/mm */
	double z_safe;          /* travel height over the whole part (machine z) */
	double theta_prev;      /* the rotary axis's angle the short way goes from */
};

/* Where the stage goes for one plan point. */
struct target {
	double cart[3];         /* probe reference point, cartesian, mm */
	double machine[3];      /* the same in the stage's axes */
	double approach[3];     /* clearance above, stage's axes */
	double normal[3];       /* nominal surface normal at the point */
};

/* The bound of the surface's principal curvatures over its aperture, for
 * the clearance of straight moves. */
void scan_geometry_init(struct asph_scan *sc);

/* Cartesian <-> the stage's axes. The rotary axis takes the short way
 * from the previous theta, which scan_turn_from() sets to where the stage
 * is. */
void scan_to_machine(struct asph_scan *sc, const double c[3], double m[3]);
void scan_to_cartesian(const struct asph_scan *sc, const double m[3], double c[3]);
void scan_turn_from(struct asph_scan *sc, double theta);

/* Where the stage goes for plan point i (the normal only when asked or
 * for a tactile probe). */
void scan_target(struct asph_scan *sc, size_t i, bool need_normal, struct target *t);
/* The same for a point p on the nominal surface. */
void scan_target_at(struct asph_scan *sc, const double p[3], bool need_normal, struct target *t);

/* The probe's gap to the nominal surface at cartesian c (0 on a measuring
 * position), and whether a straight move keeps it above min_gap (ga, gb:
 * the gaps at the ends when known, else NAN). */
double scan_gap(const struct asph_scan *sc, const double c[3]);
bool scan_path_clear_g(const struct asph_scan *sc, const double *a, double ga,
		       const double *b, double gb, double min_gap);
bool scan_path_clear(const struct asph_scan *sc, const double *a, const double *b,
		     double min_gap);
/* The moves from from to m keeping min_gap: straight, else up to the
 * travel height, over, down; the waypoints into way, how many. */
size_t scan_clear_path(const struct asph_scan *sc, const double from[3], const double *m,
		       double min_gap, double way[3][3]);

/* The checks of asph_scan_check() from plan point first on; sets the
 * travel height. */
int scan_check(struct asph_scan *sc, size_t first, struct asph_error *err);

/* The stage's and probe's limits for the planner: what they declare, a
 * speed they leave unknown as good as none (the executor's and the
 * estimate's). */
void scan_motion_limits(const struct asph_stage_info *si, const struct asph_probe_info *pi,
			struct asph_motion_limits *lim);

/* A sweep lasts at most this long (s), so that pause, abort and progress
 * stay prompt at any speed. */
#define SWEEP_SECONDS 0.25

/* How an untimed sweep is cut (the executor's and the estimate's): plan
 * points join it while the motion so far (each step at the axes' speeds)
 * and the readings so far last under SWEEP_SECONDS. */
struct sweep_cut {
	double motion, reading;
	size_t n;
};
static inline bool sweep_cut_open(const struct sweep_cut *c)
{
	return c->n == 0 || (c->motion < SWEEP_SECONDS && c->reading < SWEEP_SECONDS);
}
/* The step from from to to (stage axes) and one reading at rate (1/s). */
void sweep_cut_add(struct sweep_cut *c, const double from[3], const double to[3],
		   const struct asph_motion_limits *lim, double rate);

#endif
