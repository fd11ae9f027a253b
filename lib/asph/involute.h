/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_INVOLUTE_H
#define ASPH_INVOLUTE_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * The circle involute embedded in the surface (the paper's section 4), as
 * ordered points: the end of a string unwound, along surface geodesics,
 * from the parallel of radius r0 = spacing / (2 pi) around the vertex.
 *
 * Consecutive turns are spacing apart, measured along the geodesic that is
 * normal to both; consecutive points are spacing apart in arc length along
 * the curve (3-D arc length of the curve on the surface; the chord between
 * neighbours is slightly shorter where the curve bends). The first point is
 * the start of the unwinding, (r0, 0, Z(r0)); the points then run outward
 * in spiral order (counter-clockwise seen from +z) to the last one with
 * r <= a. Every step sweeps the same surface area, spacing^2, so the count
 * is n = floor((A(a) - A(r0)) / spacing^2) + 1 with A = asph_surface_area.
 * In the plane the points are exactly those of the paper's Eq. (5) at arc
 * lengths 0, 2 pi r0, 4 pi r0, ...
 *
 * docs/circle-involute.md has the derivation (Clairaut's relation).
 *
 * spacing_mm: finite, > 0, and r0 < a. max_points: 0 for no limit, else
 * -E2BIG when n would exceed it. *xyz (3 n doubles, malloc'd) is the
 * caller's to free.
 */
int asph_involute_points(const struct asph_surface *s, double spacing_mm,
			 size_t max_points, double **xyz, size_t *n,
			 struct asph_error *err);

/*
 * The circle involute on any surface, rotationally symmetric or freeform,
 * by geodesics integrated on the smooth surface (docs/circle-involute.md,
 * "On any surface"): the string is unwound from the circle about the
 * aperture's centre (asph_surface_aperture_disk()) whose 3-D length on the
 * surface is the spacing; consecutive turns are spacing apart along the
 * geodesics normal to them, and consecutive points spacing apart in 3-D arc
 * length. The points run outward in spiral order (counter-clockwise seen
 * from +z) from the start of the unwinding, on the circle at angle 0, to
 * the first turn that lies wholly outside the aperture's disk; those in
 * the aperture are kept (asph_surface_contains()), with z = S(x, y). On a
 * surface of revolution with a centred circular aperture they are
 * asph_involute_points()' (to 1e-6 of the spacing, seen 1e-10).
 *
 * spacing_mm: finite, > 0, and spacing / (2 pi) less than the aperture
 * disk's radius. -ERANGE where a turn would leave the domain of the
 * surface, or where the turns vary too fast around the centre to be
 * resolved (768 panels of 12 geodesics); -E2BIG past max_points (0: no
 * limit). *xyz (3 n doubles,
 * malloc'd) is the caller's to free.
 */
int asph_involute_points_geodesic(const struct asph_surface *s, double spacing_mm,
				  size_t max_points, double **xyz, size_t *n,
				  struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
