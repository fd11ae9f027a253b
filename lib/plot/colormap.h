/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The one colour map of the project (PLY colours, PNG maps). Internal. */
#ifndef ASPH_COLORMAP_H
#define ASPH_COLORMAP_H

#include <stdint.h>

/* t in [0, 1] (clamped; NaN gives grey) to RGB: a diverging blue-white-red
 * map, so that zero residual is white when the range is symmetric. */
void colormap_diverging(double t, uint8_t rgb[3]);

/* t in [0, 1] to RGB: a sequential map (viridis-like) for positive
 * quantities such as q or A_i/mean(A). */
void colormap_sequential(double t, uint8_t rgb[3]);

#endif
