/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What a recovered scan says of the run that goes on with it (resume.c):
 * where the measuring starts, the rounds of references so far, the points
 * still invalid; and on a simulated stage, how the interrupted scan's
 * motion and time are taken up again. Internal.
 */
#ifndef ASPH_ENGINE_RESUME_H
#define ASPH_ENGINE_RESUME_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

struct asph_scan;

/* What resume.c finds at the start of a run; only it writes it, the rest
 * reads it. On a simulated stage (clock_align), the measuring starts again
 * after the file's last round of references, that round measured again
 * without being recorded, the clock then aligned with the file's; the plan
 * points below replay_below are in the file and are measured again without
 * being recorded. */
struct scan_resume {
	size_t loop_from;               /* the first plan point measured */
	uint64_t replay_below;
	bool replay;                    /* the interrupted scan's motion taken up */
	bool replay_round;              /* ... from the file's last round */
	uint64_t replay_ref_ns;         /* the file's last reference, scan time */
	uint64_t rounds;                /* the file's rounds of references */
};

/* From the scan options' recovered file (none: a new scan from
 * start_index); the points still invalid go to the dropouts. */
int scan_resume_state(struct asph_scan *sc, struct asph_error *err);

#endif
