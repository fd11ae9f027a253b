/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_PLOT_H
#define ASPH_PLOT_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * PNG plots (cairo). Without cairo at build time every function returns
 * -ENOTSUP with a message saying so.
 *
 * Maps are drawn in the x-y (vertex) plane, seen from +z, with a colour bar
 * labelled with colour_label; lo = hi = 0 picks the range from the data
 * (symmetric about 0 when diverging is set).
 */
struct asph_plot_options {
	const char *title;
	const char *colour_label;  /* e.g. "residual (nm)", "A_i / mean A" */
	double lo, hi;             /* colour range, 0/0 = automatic */
	int diverging;             /* blue-white-red centred on 0 */
	int width, height;         /* pixels, 0 = 900 x 760 */
	double point_size;         /* disc diameter / mean point spacing; 0 =
				    * 1.5: the discs overlap into a continuous
				    * map; 0.4 gives separate dots */
};

/* Points coloured by value (e.g. residual in nm). */
int asph_plot_points_png(const char *path, const double *xyz,
			 const double *value, size_t n,
			 const struct asph_plot_options *opts,
			 struct asph_error *err);

/* The same written to f (flushed, not closed), which the caller opened as
 * it sees fit (e.g. a temporary file renamed into place); name is what
 * messages call it. */
int asph_plot_points_png_stream(FILE *f, const char *name, const double *xyz,
				const double *value, size_t n,
				const struct asph_plot_options *opts,
				struct asph_error *err);

/* Triangles filled by a per-triangle value (e.g. q or A_i / mean A). */
int asph_plot_triangles_png(const char *path, const double *xyz,
			    const uint32_t *triangles, size_t n_triangles,
			    const double *value,
			    const struct asph_plot_options *opts,
			    struct asph_error *err);

/*
 * Several maps side by side in one PNG (e.g. a plan coloured by z next to a
 * heatmap of its triangles). Each panel has its own title, range and colour
 * bar; the panel options' width and height are ignored, the figure is
 * width x height pixels (0 = 900 n x 760).
 */
enum asph_plot_panel_kind {
	ASPH_PLOT_POINTS = 0,      /* xyz, value, n */
	ASPH_PLOT_TRIANGLES,       /* xyz, triangles, n_triangles, value */
};

struct asph_plot_panel {
	enum asph_plot_panel_kind kind;
	const double *xyz;
	size_t n;                  /* points; for triangles 0 = not known (the
				    * indices are then trusted) */
	const uint32_t *triangles;
	size_t n_triangles;        /* (ASPH_PLOT_TRIANGLES) */
	const double *value;       /* one per point or per triangle */
	struct asph_plot_options opts;
};

int asph_plot_panels_png(const char *path, const struct asph_plot_panel *panels,
			 size_t n_panels, int width, int height,
			 struct asph_error *err);
/* The same written to f, as asph_plot_points_png_stream(). */
int asph_plot_panels_png_stream(FILE *f, const char *name,
				const struct asph_plot_panel *panels, size_t n_panels,
				int width, int height, struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
