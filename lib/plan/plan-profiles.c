/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The profiles plan: what a tactile profilometer measures of an asphere,
 * N straight traces through the apex at equal angles (docs/sampling-plans.md,
 * "profiles").
 */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "asph/fit.h"
#include "asph/plan.h"
#include "plan-patterns.h"
#include "plan-profiles.h"

_Static_assert(ASPH_PLAN_MAX_PROFILES <= ASPH_FIT_MAX_PROFILES,
	       "the fit tells apart every profile a plan makes");

/* Largest plan: as plan.c's (triangle indices are 32-bit). */
#define MAX_POINTS ((size_t)UINT32_MAX - 1)

/* Points on lines: neighbours a pitch apart; no area to share out. The
 * count and the points need the number of profiles (below), not a
 * pattern's. */
const struct plan_pattern plan_profile_lines = {
	.lattice = { NAN, 1.0 },
};

/* Points on one diameter of radius a at pitch (at most) p, its ends on the
 * rim; SIZE_MAX when absurdly many. */
static size_t per_profile(double a, double p)
{
	double steps = ceil(2 * a / p - 1e-9);

	return steps < (double)MAX_POINTS ? (size_t)steps + 1 : SIZE_MAX;
}

/* The x-y pitch along a diameter whose mean spacing on the surface is e:
 * the meridian's arc length over a diameter is 2 s(a). */
static double pitch_of_spacing(const struct asph_surface *s, double a, double e)
{
	return e * a / asph_surface_arc_length(s, a);
}

int plan_profiles_resolve(const struct asph_surface *s, struct asph_plan_density d,
			  unsigned profiles, double *e, double *p, size_t *n,
			  struct asph_error *err)
{
	double a = asph_surface_aperture_radius(s), stretch = asph_surface_arc_length(s, a) / a;
	size_t m;

	if (profiles < 1 || profiles > ASPH_PLAN_MAX_PROFILES)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "profiles",
					 "%u profiles: the profiles plan takes 1 to %d", profiles,
					 ASPH_PLAN_MAX_PROFILES);
	switch (d.kind) {
	case ASPH_DENSITY_H:
	case ASPH_DENSITY_SPACING:
		*e = d.kind == ASPH_DENSITY_H ? d.value * a : d.value;
		*p = pitch_of_spacing(s, a, *e);
		m = per_profile(a, *p);
		break;
	case ASPH_DENSITY_POINTS:
		/* points in all: each profile the nearest whole share, two at
		 * least (its ends) */
		m = (size_t)fmax(2, fmin(round(d.value / profiles), (double)MAX_POINTS));
		*p = 2 * a / (double)(m - 1);
		*e = *p * stretch;
		break;
	default:
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "density",
					 "unknown density kind %d", d.kind);
	}
	if (!(*e <= a))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, asph_plan_density_name(d.kind),
					 "%g is too coarse: it gives a spacing of %.6g mm, more than "
					 "the aperture radius %.6g mm (h > 1)", d.value, *e, a);
	if (m == SIZE_MAX || (double)m * profiles > (double)MAX_POINTS)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, asph_plan_density_name(d.kind),
					 "%g gives more than %zu points, the most a plan can hold",
					 d.value, MAX_POINTS);
	*n = m * profiles;
	return 0;
}

int plan_profiles_fill(double a, double p, unsigned profiles, double *xyr)
{
	size_t m = per_profile(a, p), k = 0;
	double step = 2 * a / (double)(m - 1);

	for (unsigned j = 0; j < profiles; j++) {
		double phi = M_PI * j / profiles, c = cos(phi), sn = sin(phi);
		for (size_t i = 0; i < m; i++, k++) {
			/* back and forth: odd profiles from +a to -a; the ends
			 * exactly on the rim */
			size_t at = j % 2 ? m - 1 - i : i;
			double t = at == m - 1 ? a : -a + step * (double)at;
			xyr[3 * k] = t * c + 0.0;      /* no -0 */
			xyr[3 * k + 1] = t * sn + 0.0;
			xyr[3 * k + 2] = fabs(t);
		}
	}
	return 0;
}
