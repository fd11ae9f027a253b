/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The executor's state and what its parts share: the geometry (kinematics,
 * targets, clearance, the checks before the first move) in
 * executor-geometry.c, streaming in executor-stream.c, drift references and
 * the second pass in executor-drift.c. Internal. */
#ifndef ASPH_EXECUTOR_INTERNAL_H
#define ASPH_EXECUTOR_INTERNAL_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>

#include "asph-engine/executor.h"
#include "asph/motion.h"

#define RECORD_BATCH 4096
/* A sweep lasts at most this long (s), so that pause, abort and progress
 * stay prompt at any speed. */
#define SWEEP_SECONDS 0.25

/* A reading on its way: the probe was triggered (or is about to be) for
 * this measurement. */
struct pending {
	uint64_t index;         /* plan index, or reference number */
	uint32_t kind, attempt; /* enum asph_measurement_kind */
	double cmd[3];          /* the command at the sample instant (machine) */
	uint64_t t_ns;          /* the trigger on the instrument clock; 0 unknown */
	bool timed;             /* cmd is at the sample instant (latency known) */
	double dcmd[3];         /* timed: the command's motion from the trigger to cmd */
};

/* What a reading is paired with: the stage's position and its source. */
struct placed {
	double machine[3];
	uint32_t source;        /* enum asph_position_source */
};

struct asph_scan {
	struct asph_instrument *inst;
	const struct asph_surface *surface;
	const double *xyz;
	size_t n;
	struct asph_scan_options o;
	struct asph_acquisition acq;
	bool tactile, stream, pvt;
	double tip, latency;

	atomic_bool paused, aborted;
	pthread_mutex_t lock;           /* progress, pause condition */
	pthread_cond_t wake;
	struct asph_scan_progress progress;

	/* run state, run thread only */
	uint64_t t0_ns, last_report_ns, rate_t_ns, rate_done, measure_t0_ns;
	double rate;
	uint64_t measure_done0;
	uint64_t clock0;        /* instrument clock when run() began */
	size_t run_from, run_to; /* the last whole run of a timed sweep checked */
	uint64_t scan0;         /* the scan's time then (ns since it began) */
	double theta_prev;
	double pos[3];          /* where the last motion ended, stage axes */
	bool moving;            /* a timed sweep ended in motion */
	double z_safe;          /* travel height over the whole part (machine z) */
	double curvature;       /* bound of the surface's curvature, 1/mm */
	struct asph_scanfile_writer *w;
	struct asph_scanfile_point rec[RECORD_BATCH];
	size_t n_rec;
	uint64_t measured;      /* readings recorded by this run */
	uint64_t commanded;     /* of them paired with a commanded position */
	uint32_t rec_last_flags;        /* of the last measurement recorded */

	/* streaming */
	struct asph_motion_limits lim;
	struct asph_motion_planner *planner;
	double *theta;          /* r-theta-z: the plan's theta, unwrapped */
	double path[3 * RECORD_BATCH];
	struct asph_pvt knots[RECORD_BATCH + 2];
	struct asph_motion_knot mk[RECORD_BATCH + 2];
	struct asph_probe_context ctx[RECORD_BATCH];
	struct asph_reading readings[RECORD_BATCH];
	struct placed placed[RECORD_BATCH];
	struct pending *pend;   /* queue of readings to come */
	size_t pend_head, pend_n, pend_cap;
	struct asph_position_sample *trace;    /* queue of measured positions */
	size_t trace_head, trace_n, trace_cap;
	struct asph_position_sample latch_hist[2];     /* the last two latched */
	size_t n_hist;

	/* drift control */
	uint64_t round;         /* reference rounds in the scan so far */
	uint64_t last_round_ns; /* instrument clock at the last round */
	uint64_t points_since_round;
	struct asph_scanfile_point refs[ASPH_MAX_REFERENCES];

	/* resuming on a simulated stage (clock_align): the measuring starts
	 * again after the file's last round of references, that round
	 * measured again without being recorded, the clock then aligned with
	 * the file's; the plan points below replay_below are in the file and
	 * are measured again without being recorded */
	size_t loop_from;
	uint64_t replay_below;
	bool replay_round;
	uint64_t replay_ref_ns;         /* the file's last reference, scan time */

	/* dropouts: points whose last reading was invalid */
	uint64_t *invalid;
	uint32_t *invalid_attempts;
	size_t n_invalid, cap_invalid;
};

/* Where the stage goes for one plan point. */
struct target {
	double cart[3];         /* probe reference point, cartesian, mm */
	double machine[3];      /* the same in the stage's axes */
	double approach[3];     /* clearance above, stage's axes */
	double normal[3];       /* nominal surface normal at the point */
};

/* ------------------------------------------------------------- geometry */

/* A bound of the surface's principal curvatures over its aperture. */
double scan_curvature_bound(const struct asph_surface *s);

/* Cartesian <-> the stage's axes. The rotary axis takes the short way
 * from the previous theta (sc->theta_prev). */
void scan_to_machine(struct asph_scan *sc, const double c[3], double m[3]);
void scan_to_cartesian(const struct asph_scan *sc, const double m[3], double c[3]);

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

/* ------------------------------------------------------- in executor.c */

/* "plan point i: who: the driver's reason" (r passes through). */
int scan_prefixed(int r, const char *who, size_t i, struct asph_error *err);
/* The base timeout plus twice what the operation should take (s). */
unsigned scan_timeout(unsigned base_ms, double expected_s);
int scan_stage_move(struct asph_scan *sc, const double *m, size_t i, struct asph_error *err);
/* The moves from from to m keeping min_gap: straight, else up to the
 * travel height, over, down; the waypoints into way, how many. */
size_t scan_clear_path(const struct asph_scan *sc, const double from[3], const double *m,
		       double min_gap, double way[3][3]);
int scan_move_clear(struct asph_scan *sc, const double *m, double min_gap, size_t i,
		    struct asph_error *err);
/* Waits until the read-back position is inside the settling window of
 * target for the settling time; the last read-back in out. */
int scan_settle(struct asph_scan *sc, const double target[3], size_t i, double out[3],
		struct asph_error *err);
/* The scan's time (ns since it began) of an instant on the instrument's
 * clock. */
uint64_t scan_time(const struct asph_scan *sc, uint64_t instrument_ns);
/* Records the reading of a measurement placed at machine position pl; its
 * point goes to the references of the round instead when kind says so. */
int scan_record(struct asph_scan *sc, const struct pending *m, const struct placed *pl,
		const double normal[3], const struct asph_reading *rd, uint32_t extra_flags,
		struct asph_error *err);
int scan_flush(struct asph_scan *sc, struct asph_error *err);
/* An out-of-range reading fails the scan unless told to go on. */
int scan_check_reading(struct asph_scan *sc, size_t i, const struct asph_reading *rd,
		       struct asph_error *err);
/* One measurement point by point: approach, settle, read, retract. */
int scan_measure_at(struct asph_scan *sc, const struct target *t, const struct pending *m,
		    uint32_t extra_flags, bool *recorded, struct asph_error *err);
int scan_aborted(struct asph_scan *sc, struct asph_error *err);
void scan_publish(struct asph_scan *sc, enum asph_scan_state state, uint64_t done, bool force);

/* -------------------------------------------------- executor-stream.c */

/* The stage's and probe's limits for the planner: what they declare, a
 * speed they leave unknown as good as none (the executor's and the
 * estimate's). */
void scan_motion_limits(const struct asph_stage_info *si, const struct asph_probe_info *pi,
			struct asph_motion_limits *lim);
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
int scan_stream_init(struct asph_scan *sc, struct asph_error *err);
void scan_stream_fini(struct asph_scan *sc);
/* Measures from plan point i on while the sweeps can go on; *done gets
 * the plan points it finished. */
int scan_stream(struct asph_scan *sc, size_t i, size_t *done, struct asph_error *err);

/* --------------------------------------------------- executor-drift.c */

/* A round of references when drift control says one is due (or when
 * force, at the start and the end). */
bool scan_round_due(const struct asph_scan *sc);
int scan_reference_round(struct asph_scan *sc, struct asph_error *err);
/* Notes a plan point's reading as invalid or valid again. */
int scan_note_reading(struct asph_scan *sc, uint64_t index, uint32_t attempt, bool invalid);
/* The invalid points measured again, each up to the retries. */
int scan_second_pass(struct asph_scan *sc, struct asph_error *err);
/* What the recovered scan says: reference rounds done, invalid points;
 * on a simulated stage, where the measuring starts again. */
int scan_resume_state(struct asph_scan *sc, struct asph_error *err);
/* A simulated stage's clock set to the next whole millisecond of the
 * scan's time (of the file's time when a round is measured again), after
 * a round of references. */
int scan_align_clock(struct asph_scan *sc, struct asph_error *err);

#endif
