/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Going on with a recovered scan: its rounds of references so far, the
 * points whose last reading was invalid (measured again at the end, up to
 * the instrument's retries), and on a simulated stage where the measuring
 * starts again so that the interrupted scan's motion and time are taken up
 * exactly. resume.h.
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "scan.h"

/*
 * A simulated stage goes on with the interrupted scan's time: the
 * measuring starts again after the file's last round of references (or
 * from the first plan point without one), that round measured again to
 * put the stage where it was and then the clock set to the file's time.
 * From there the motion, the clock and so every reading are those of the
 * uninterrupted scan; the plan points the file has are measured again but
 * not recorded.
 */
static void replay_from_round(struct asph_scan *sc, const struct asph_scanfile *s, size_t per)
{
	uint64_t t_round = 0;   /* none: nothing comes before it */
	size_t from = 0;

	if (asph_acquisition_drift(&sc->acq) && s->n_references >= per) {
		t_round = s->references[s->n_references - per].t_ns;
		sc->resume.replay_ref_ns = s->references[s->n_references - 1].t_ns;
		sc->resume.replay_round = true;
	}
	for (size_t k = 0; k < s->n; k++) {
		const struct asph_scanfile_point *p = &s->points[k];
		if (!(p->flags & ASPH_SCANFILE_POINT_RETRIED) && p->t_ns < t_round &&
		    p->plan_index + 1 > from)
			from = (size_t)p->plan_index + 1;
	}
	sc->resume.loop_from = from < sc->o.start_index ? from : sc->o.start_index;
	sc->resume.replay_below = sc->o.start_index;
	/* the scan's time is the instrument's, as when it began */
	sc->resume.replay = true;
}

int scan_resume_state(struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_scanfile *s = sc->o.recovered;
	size_t per = sc->acq.n_references ? sc->acq.n_references : 1;
	bool any = false;

	memset(&sc->resume, 0, sizeof(sc->resume));
	sc->resume.loop_from = sc->o.start_index;
	if (!s)
		return 0;
	/* the reference rounds so far: the next one is numbered after them */
	sc->resume.rounds = (s->n_references + per - 1) / per;
	if (sc->o.start_index > 0 && sc->inst->stage_ops.clock_align)
		replay_from_round(sc, s, per);
	for (size_t k = 0; k < s->n && !any; k++)
		any = s->points[k].flags & ASPH_SCANFILE_POINT_INVALID;
	if (!any)
		return 0;
	/* the points whose last measurement was invalid, with its attempt */
	uint16_t *count = calloc(sc->n ? sc->n : 1, sizeof(*count));
	uint8_t *last_invalid = calloc(sc->n ? sc->n : 1, 1);
	if (!count || !last_invalid) {
		free(count);
		free(last_invalid);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	for (size_t k = 0; k < s->n; k++) {
		uint64_t i = s->points[k].plan_index;
		if (i >= sc->n)
			continue;
		if (count[i] < UINT16_MAX)
			count[i]++;
		last_invalid[i] = (s->points[k].flags & ASPH_SCANFILE_POINT_INVALID) != 0;
	}
	int r = 0;
	for (size_t i = 0; i < sc->n && r == 0; i++)
		if (count[i] && last_invalid[i])
			r = scan_dropout_add(sc, i, (uint32_t)count[i] - 1);
	free(count);
	free(last_invalid);
	return r < 0 ? asph_error_set(err, r, "out of memory") : 0;
}
