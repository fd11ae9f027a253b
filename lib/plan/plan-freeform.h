/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans, internal: the maps of the grid methods on freeform
 * surfaces (docs/sampling-plans.md, "Freeform surfaces"). Each takes the
 * source grid of the aperture at pitch p (plan-aperture.h, the disk grid's
 * pattern: x and y per point, stride 3) and moves it, in place, onto the
 * surface: x, y mapped, z = S(x, y). */
#ifndef ASPH_PLAN_FREEFORM_H
#define ASPH_PLAN_FREEFORM_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/surface.h"

/* LB: T = S^-1 of the discrete harmonic map S of Eq. (6) (P1 elements,
 * lb-fem.c, on the Delaunay mesh of the aperture's grid at half the pitch
 * p of the plan's), inverted piecewise linearly. The grid's points on the
 * aperture's edge (its last plan_outline_count()) are fixed points.
 * -ERANGE when the discrete map folds a triangle. */
int plan_lb_freeform_map(const struct asph_surface *s, double p, double *xyz, size_t n,
			 struct asph_error *err);

/* OT: T = grad phi of the Monge-Ampere equation of asph/ot.h, the
 * aperture's uniform measure carried to the surface's area. -ERANGE when
 * the map cannot be solved to its tolerance. */
int plan_ot_freeform_map(const struct asph_surface *s, double p, double *xyz, size_t n,
			 struct asph_error *err);

#endif
