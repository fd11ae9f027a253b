/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Drift control (drift.c): when a round of the instrument's reference
 * points is due, and the round itself, recorded in blocks of its own;
 * after each, a simulated stage's clock aligned so that a resumed scan
 * takes up the interrupted one's time. Internal.
 */
#ifndef ASPH_ENGINE_DRIFT_H
#define ASPH_ENGINE_DRIFT_H

#include <stdbool.h>
#include <stdint.h>

#include "asph-driver/instrument.h"
#include "asph/error.h"
#include "asph/scanfile.h"

struct asph_scan;

/* What drift.c keeps of a scan; only it writes it. */
struct scan_drift {
	uint64_t round;                 /* rounds in the scan so far, the file's too */
	uint64_t run_rounds;            /* rounds measured by this run */
	uint64_t last_round_ns;         /* instrument clock at the last round; 0: none */
	uint64_t readings_at_round;     /* the run's plan readings then */
	struct asph_scanfile_point refs[ASPH_MAX_REFERENCES];
};

/* The start of a run: its rounds are numbered after the recovered
 * file's. */
void scan_drift_begin(struct asph_scan *sc);
/* A round of references is due: the first of the run, then every
 * drift_interval (points or instrument time). */
bool scan_round_due(const struct asph_scan *sc);
/* One round of references. The first of a resumed run that takes up the
 * interrupted one's motion is the file's last round measured again: not
 * recorded, the clock set to the file's time after it. */
int scan_reference_round(struct asph_scan *sc, struct asph_error *err);

#endif
