/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_EXECUTOR_H
#define ASPH_EXECUTOR_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph-driver/instrument.h"
#include "asph/plan.h"
#include "asph/scanfile.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The scan executor: measures the points of a plan with an open instrument
 * and records each through a scan file writer. The safety rules, the
 * approach and the tip compensation are in docs/scanning.md. In short:
 * every target is checked against the travel limits and the probe before
 * the first move; each point is approached from a clearance above it
 * along the probe axis; a tactile probe's tip centre is aimed at the
 * point's normal offset and the reading compensated along the nominal
 * normal; a driver fault stops motion, keeps every point measured and ends
 * the file with the reason.
 *
 * run() is called on one thread; pause(), resume(), abort() and
 * get_progress() from any thread, while the scan and its instrument exist.
 * abort() calls the drivers' stop(), which latches: the instrument is
 * reopened for the next scan.
 *
 * Every point records the position the stage measured (latched on the
 * probe's trigger, read back after settling, interpolated in time) with
 * the probe's latency compensated; a point paired with a commanded position
 * is flagged so. The instrument's acquisition settings (asph-driver/instrument.h)
 * decide the settling, the drift references and the retries of dropouts.
 */

enum asph_scan_state {
	ASPH_SCAN_READY = 0,
	ASPH_SCAN_CHECKING,
	ASPH_SCAN_HOMING,
	ASPH_SCAN_MEASURING,
	ASPH_SCAN_PAUSED,
	ASPH_SCAN_COMPLETED,
	ASPH_SCAN_ABORTED,
	ASPH_SCAN_FAILED,
};

/* "ready", "checking", ..., "failed" */
const char *asph_scan_state_name(enum asph_scan_state s);

struct asph_scan_progress {
	enum asph_scan_state state;
	uint64_t done;          /* plan points finished (incl. before start) */
	uint64_t total;         /* plan points */
	uint64_t measured;      /* readings taken by this run */
	double elapsed_s;       /* since run() started, pauses included */
	double instrument_s;    /* the same on the instrument's clock (a
				   simulated instrument's simulated time) */
	double rate;            /* points per second over the last interval */
	double eta_s;           /* remaining at the mean rate; < 0 unknown */
};

typedef void (*asph_scan_progress_fn)(const struct asph_scan_progress *p,
				      void *data);

enum asph_scan_flags {
	/* Use the probe's stream with the stage's sweep when both exist. */
	ASPH_SCAN_STREAM = 1u << 0,
	/* Record an out-of-range reading and go on instead of failing. */
	ASPH_SCAN_SKIP_OUT_OF_RANGE = 1u << 1,
	/* Do not home the stage before the first move. */
	ASPH_SCAN_NO_HOME = 1u << 2,
	/* On abort, close the file without an end block (resumable). */
	ASPH_SCAN_ABORT_RESUMABLE = 1u << 3,
	/* Pair every reading with the commanded position (each point is
	 * flagged commanded-position): to see what measured positions save. */
	ASPH_SCAN_COMMANDED = 1u << 4,
};

struct asph_scan_options {
	unsigned flags;                 /* enum asph_scan_flags */
	uint64_t start_index;           /* first plan point to measure */
	double clearance;               /* mm above each point; 0 = 0.5 */
	unsigned move_timeout_ms;       /* 0 = 60000 */
	unsigned read_timeout_ms;       /* 0 = the probe's read_timeout option
					 * when it sets one (docs/drivers.md),
					 * else 2000 */
	unsigned home_timeout_ms;       /* 0 = 120000 */
	size_t stream_batch;            /* points per sweep; 0 = 4096 */
	asph_scan_progress_fn progress; /* may be NULL */
	void *progress_data;
	uint64_t progress_interval_ns;  /* 0 = 100 ms */
	/* A resumed scan as asph_scan_reopen() recovered it (or NULL): its
	 * reference rounds and the points still invalid go on from there. */
	const struct asph_scanfile *recovered;
};

struct asph_scan;

/*
 * A scan of the n plan points xyz (3 n, mm, on the nominal surface s, the
 * part's frame = the machine's cartesian frame) with inst. opts may be NULL.
 * s, xyz and inst must outlive the scan.
 */
int asph_scan_new(struct asph_instrument *inst, const struct asph_surface *s,
		  const double *xyz, size_t n,
		  const struct asph_scan_options *opts, struct asph_scan **out,
		  struct asph_error *err);
void asph_scan_free(struct asph_scan *sc);

/*
 * The checks run() makes before anything moves: every target (and its
 * approach point) inside the travel limits, every expected reading inside
 * the probe's range, no surface steeper than the probe reads. -ERANGE with
 * err naming the first offending plan point.
 */
int asph_scan_check(struct asph_scan *sc, struct asph_error *err);

/*
 * Runs the scan, recording through w, and ends the file: completed, or
 * aborted / failed with the reason (w is finished and freed in every case;
 * with ASPH_SCAN_ABORT_RESUMABLE an aborted scan's file is closed without
 * an end block). Returns 0 when completed, -ECANCELED when aborted, else
 * the fault's negative errno with err saying which point and why. A plan
 * refused by asph_scan_check() ends the file as failed with nothing
 * measured.
 */
int asph_scan_run(struct asph_scan *sc, struct asph_scanfile_writer *w,
		  struct asph_error *err);

/*
 * Reopens the interrupted scan at path to go on measuring plan: the
 * executor measures in plan order, so *start_index (for
 * asph_scan_options.start_index) follows the last plan index recorded.
 * The scan must have been recorded with this plan (method, density and
 * point count, as its header says in either shape
 * asph_plan_info_from_json() reads), else -EINVAL and the file is left as
 * it was: points of two plans never share a file. opts and the other
 * refusals are asph_scanfile_writer_resume()'s. recovered (may be NULL)
 * receives the scan as read, for asph_scan_options.recovered.
 */
int asph_scan_reopen(const char *path, const struct asph_plan *plan,
		     const struct asph_scanfile_writer_options *opts,
		     struct asph_scanfile_writer **w, uint64_t *start_index,
		     struct asph_scanfile **recovered, struct asph_error *err);
/* The same with path relative to the directory dirfd, never opened
 * through a symbolic link (asph_scanfile_writer_resume_at()). */
int asph_scan_reopen_at(int dirfd, const char *path, const struct asph_plan *plan,
			const struct asph_scanfile_writer_options *opts,
			struct asph_scanfile_writer **w, uint64_t *start_index,
			struct asph_scanfile **recovered, struct asph_error *err);

/*
 * The predicted measuring time in s of the n plan points xyz on surface s
 * with instrument c and options so (may be NULL), before anything is
 * opened (asph_instrument_describe()): streamed, the feed-rate planner's
 * time along the path; point by point, the moves, the settling dwell and
 * the readings; and the drift references' rounds. Homing and a stage's
 * ringing are not included. -ENOTSUP when a driver cannot describe itself.
 */
int asph_scan_estimate(const struct asph_instrument_config *c, const struct asph_surface *s,
		       const double *xyz, size_t n, const struct asph_scan_options *so,
		       double *seconds, struct asph_error *err);

/*
 * The measuring time of a plan on an instrument as the plan search
 * (asph/plan-search.h) asks for it: an asph_plan_time_fn whose data is a
 * struct asph_scan_timing. The instrument carries the lens (the mock's
 * part).
 */
struct asph_scan_timing {
	const struct asph_instrument_config *instrument;
	const struct asph_surface *surface;
	struct asph_scan_options options;       /* ASPH_SCAN_STREAM where the
						   program measures streamed */
};
int asph_scan_plan_time(void *timing, const struct asph_plan *plan, double *seconds,
			struct asph_error *err);

/*
 * Re-simulation for a Monte Carlo evaluation: the points instrument c (a
 * simulated one: the mock and its physical model, time_factor=0) measures
 * for the n plan points xyz of surface s, streamed where it can, as
 * characterization takes them from a recorded scan (the drift references'
 * correction applied, drift receives its size; may be NULL), in *out
 * (asph_points_free()). The recording is a temporary file in dir, removed
 * before the call returns. Each draw of the model's contributions is a
 * configuration: its options (seed, noise, misalignment, form, the bench's
 * errors) decide the readings, and the same configuration gives the same
 * points to the bit. 0 or -errno.
 */
struct asph_drift_summary;
int asph_scan_simulate(const struct asph_instrument_config *c, const struct asph_surface *s,
		       const double *xyz, size_t n, const char *dir, struct asph_points **out,
		       struct asph_drift_summary *drift, struct asph_error *err);

/* Any thread. Pause takes effect before the next point; abort stops the
 * stage and the probe at once. */
void asph_scan_pause(struct asph_scan *sc);
void asph_scan_resume(struct asph_scan *sc);
void asph_scan_abort(struct asph_scan *sc);

/* Any thread: a consistent snapshot. */
void asph_scan_get_progress(struct asph_scan *sc,
			    struct asph_scan_progress *out);

#ifdef __cplusplus
}
#endif

#endif
