/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The primitives of a run (run.c), below the loops that use them: the
 * progress and the controls of other threads (pause, abort), the stage's
 * moves and settling, one measurement point by point, the records and the
 * scan file, the dropouts to measure again. Internal.
 */
#ifndef ASPH_ENGINE_RUN_H
#define ASPH_ENGINE_RUN_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "asph-engine/executor.h"
#include "geometry.h"

#define RECORD_BATCH 4096

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

/* Plan points whose last reading was invalid, with its attempt. */
struct scan_dropouts {
	uint64_t *index;
	uint32_t *attempt;
	size_t n, cap;
};

/* What run.c keeps of a scan; only it writes it. */
struct scan_run {
	atomic_bool paused, aborted;
	pthread_mutex_t lock;           /* progress, pause condition */
	pthread_cond_t wake;
	struct asph_scan_progress progress;

	/* the run thread's */
	uint64_t t0_ns, last_report_ns, rate_t_ns, rate_done, measure_t0_ns;
	double rate;
	uint64_t measure_done0;
	uint64_t clock0;        /* instrument clock when run() began */
	uint64_t scan0;         /* the scan's time then (ns since it began) */
	double pos[3];          /* where the last motion ended, stage axes */
	/* plan points below it are in the file already: measured again (a
	 * resumed scan taking up the interrupted one's motion), not recorded */
	uint64_t record_from;
	struct asph_scanfile_writer *w;
	struct asph_scanfile_point rec[RECORD_BATCH];
	size_t n_rec;
	uint64_t measured;      /* readings recorded by this run */
	uint64_t readings;      /* plan readings taken, recorded or measured again */
	uint32_t last_flags;    /* of the last measurement recorded */
	struct scan_dropouts dropouts;
};

/* asph_scan_new() and asph_scan_free(). */
void scan_run_init(struct asph_scan *sc);
void scan_run_fini(struct asph_scan *sc);

/* The start of run(): w is the file; the scan's time is the instrument's
 * from now on for a new scan, else goes on from the time the file has
 * lived. */
void scan_run_begin(struct asph_scan *sc, struct asph_scanfile_writer *w);
/* What the recovered scan says of the run: record from plan point
 * record_from on, and whether the scan's time is the instrument's, as
 * when the interrupted scan began. */
void scan_run_resumed(struct asph_scan *sc, uint64_t record_from, bool instrument_time);
/* The measuring starts at plan point i (the rate and the time left). */
void scan_measure_begin(struct asph_scan *sc, size_t i);

/* Progress: reported at most every progress interval unless force. */
void scan_publish(struct asph_scan *sc, enum asph_scan_state state, uint64_t done, bool force);
/* -ECANCELED once asph_scan_abort() was called. */
int scan_aborted(struct asph_scan *sc, struct asph_error *err);
/* Whether another thread asked for a pause or the abort. */
bool scan_stop_asked(struct asph_scan *sc);
/* Waits while paused, keeping the file's flush policy. */
int scan_wait_paused(struct asph_scan *sc, uint64_t done, struct asph_error *err);

/* "plan point i: who: the driver's reason" (r passes through). */
int scan_prefixed(int r, const char *who, size_t i, struct asph_error *err);
/* The base timeout plus twice what the operation should take (s). */
unsigned scan_timeout(unsigned base_ms, double expected_s);
/* The stage's position read back into pos (before the first move). */
int scan_read_position(struct asph_scan *sc, size_t i, struct asph_error *err);
/* Where a sweep left the stage. */
void scan_moved_to(struct asph_scan *sc, const double m[3]);
int scan_stage_move(struct asph_scan *sc, const double *m, size_t i, struct asph_error *err);
int scan_move_clear(struct asph_scan *sc, const double *m, double min_gap, size_t i,
		    struct asph_error *err);
/* Waits until the read-back position is inside the settling window of
 * target for the settling time; the last read-back in out. */
int scan_settle(struct asph_scan *sc, const double target[3], size_t i, double out[3],
		struct asph_error *err);

/* The scan's time (ns since it began) of an instant on the instrument's
 * clock. */
uint64_t scan_time(const struct asph_scan *sc, uint64_t instrument_ns);
/* Records the reading of a measurement placed at machine position pl;
 * its point goes to *keep instead when keep is given (a drift
 * reference). */
int scan_record(struct asph_scan *sc, const struct pending *m, const struct placed *pl,
		const double normal[3], const struct asph_reading *rd, uint32_t extra_flags,
		struct asph_scanfile_point *keep, struct asph_error *err);
int scan_flush(struct asph_scan *sc, struct asph_error *err);
/* A round of drift references into the file. */
int scan_append_references(struct asph_scan *sc, const struct asph_scanfile_point *refs,
			   size_t n, struct asph_error *err);
/* An out-of-range reading fails the scan unless told to go on. */
int scan_check_reading(struct asph_scan *sc, size_t i, const struct asph_reading *rd,
		       struct asph_error *err);
/* One measurement point by point: approach, settle, read, retract; the
 * point recorded, or into *keep (scan_record()). */
int scan_measure_at(struct asph_scan *sc, const struct target *t, const struct pending *m,
		    uint32_t extra_flags, struct asph_scanfile_point *keep, bool *recorded,
		    struct asph_error *err);

/* A plan point whose last reading (attempt) was invalid; and the list
 * emptied once they have been measured again. */
int scan_dropout_add(struct asph_scan *sc, uint64_t index, uint32_t attempt);
void scan_dropouts_clear(struct asph_scan *sc);

/* The end of the file: flushed, then finished with state and reason (or
 * closed without an end block when resumable), the progress's last
 * report. 0 or the writer's error in err. */
int scan_run_end(struct asph_scan *sc, enum asph_scan_state state, const char *reason,
		 bool resumable, struct asph_error *err);

#endif
