/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Geometry of a plot panel: where data (mm) lands in the image. Internal;
 * shared by lib/plot.c and its test so that pixels can be checked at the
 * place a given point is drawn. */
#ifndef ASPH_PLOT_LAYOUT_H
#define ASPH_PLOT_LAYOUT_H

#include <stddef.h>
#include <stdint.h>

/* A device rectangle, pixels, y down. */
struct plot_rect {
	double x, y, w, h;
};

struct plot_frame {
	struct plot_rect area;   /* space for the map inside the panel */
	struct plot_rect box;    /* the data extent, equal aspect, centred */
	struct plot_rect bar;    /* the colour bar */
	double x0, y0;           /* data coordinates of box's lower left */
	double scale;            /* pixels per mm, both axes */
};

/* Data extent [xmin, xmax, ymin, ymax] of the points (all n of them, or
 * those the triangles use when triangles != NULL). */
void plot_data_extent(const double *xyz, size_t n, const uint32_t *triangles,
		      size_t n_triangles, double ext[4]);

/* Lays out a panel occupying `panel` with data extent ext, padded by a
 * few percent so that discs at the rim stay inside the frame. */
void plot_panel_frame(const struct plot_rect *panel, const double ext[4],
		      struct plot_frame *f);

/* Data (mm) to pixel coordinates (u right, v down). */
void plot_frame_to_pixel(const struct plot_frame *f, double x, double y,
			 double *u, double *v);

/* Disc radius in pixels for n points covering ext (its area taken as the
 * inscribed ellipse, as for a round part) drawn with diameter `size` times
 * the mean spacing; size 0 means 1.5, which covers a hexagonal or square
 * sampling without gaps. */
double plot_point_radius(const struct plot_frame *f, const double ext[4],
			 size_t n, double size);

/* The panel rectangles of an n-panel figure of width x height. */
void plot_figure_panel(int width, int height, size_t n_panels, size_t i,
		       struct plot_rect *panel);

#include "config.h"
#include "asph/plot.h"

/* A tick step of 1, 2 or 5 times a power of ten giving about target ticks
 * over span. */
double plot_nice_step(double span, int target);

#if HAVE_CAIRO
#include <cairo.h>

/* Draws one map panel into panel (device units) of any cairo surface: the
 * PNG figures and the PDF report share it. The panel must be valid. On a
 * vector surface the points are painted as an image at 300 dpi. 0, or
 * -ENOMEM when that image cannot be made. */
int plot_draw_panel(cairo_t *cr, const struct asph_plot_panel *p,
		    const struct plot_rect *panel);

/* A cairo write function appending to the FILE * closure. */
cairo_status_t plot_write_to_file(void *closure, const unsigned char *data,
				  unsigned int length);
#endif

#endif
