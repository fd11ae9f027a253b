/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The mock instrument's "wire": a simulated part on the machine and the
 * pacing of motion and readings. The part is the nominal lens (any surface
 * type, freeforms included) with a form
 * error e(u, v) = sum_j c_j Z_j (nm, along the nominal normal, as
 * asph_fit_synthesize() makes it) lying with a pose (lib/asph/fit.h's
 * convention), so that fitting what the mock measures returns the pose and
 * the form error. Internal.
 */
#ifndef ASPH_MOCK_PROTOCOL_H
#define ASPH_MOCK_PROTOCOL_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/fit.h"
#include "asph/surface.h"
#include "asph/zernike.h"

struct mock_part;

struct mock_part_params {
	const char *lens;               /* preset, prescription file or the
					 * prescription as JSON text ("{...}");
					 * "" is strong */
	struct asph_pose pose;
	const char *form;               /* "j:nm;j:nm;..." or "" */
	double noise_nm;                /* along the probe axis */
	unsigned long seed;
	double tip_radius;              /* mm; 0 = optical */
};

int mock_part_new(const struct mock_part_params *pp, struct mock_part **out,
		  struct asph_error *err);
void mock_part_free(struct mock_part *p);

/*
 * Where the probe axis through (x, y) meets the part: the z of the surface
 * (optical) or of the tip ball's centre when it touches the part (tactile),
 * plus the noise of plan point index (a function of the seed and the index
 * only). -EDOM when the axis misses the part.
 */
int mock_part_probe_z(struct mock_part *p, double x, double y, uint64_t index,
		      double *z);

/* The angle of the part's surface to the probe axis at (x, y), rad. */
double mock_part_slope(const struct mock_part *p, double x, double y);

/* Parses "4:30;9:-12.5" into coef[0 .. *n-1] (Noll order, nm). */
int mock_parse_form(const char *text, double *coef, int *n,
		    struct asph_error *err);

/*
 * Waits seconds (scaled already), at most timeout_ms, watching stop.
 * -ECANCELED when stop was raised, -ETIMEDOUT when the wait is longer
 * than the timeout (after waiting the timeout).
 */
int mock_wait(atomic_bool *stop, double seconds, unsigned timeout_ms);

#endif
