/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: the profiles plan (plan-profiles.c). */
#ifndef ASPH_PLAN_PROFILES_H
#define ASPH_PLAN_PROFILES_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/plan.h"
#include "asph/surface.h"

/* The profiles method's pattern: only its lattice (one pitch between
 * neighbours on a line); plan_profiles_resolve() and plan_profiles_fill()
 * count and lay the points. */
extern const struct plan_pattern plan_profile_lines;

/*
 * The density of a profiles plan of that many profiles: the surface
 * spacing e (mean along a trace on the surface), the x-y pitch p and the
 * points n. --h and --spacing give e (h a, or the spacing); --points the
 * points in all, each profile an equal share. -EINVAL for a profile count
 * outside 1..ASPH_PLAN_MAX_PROFILES, a spacing above the aperture radius,
 * more points than a plan holds.
 */
int plan_profiles_resolve(const struct asph_surface *s, struct asph_plan_density d,
			  unsigned profiles, double *e, double *p, size_t *n,
			  struct asph_error *err);

/*
 * The profiles through the apex at azimuths j 180 / profiles deg, each a
 * diameter of radius a in ceil(2 a / p) + 1 points at equal x-y steps,
 * ends on the rim, scanned back and forth; x, y and the radius per point
 * (plan-patterns.h's layout). xyr holds the resolved n points.
 */
int plan_profiles_fill(double a, double p, unsigned profiles, double *xyr);

#endif
