/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "config.h"
#include "asph/plot.h"
#include "colormap.h"
#include "plot-layout.h"
#include "util-mem.h"

#define DEFAULT_WIDTH 900
#define DEFAULT_HEIGHT 760
#define MIN_SIZE 200
#define MAX_SIZE 20000

/* Panel margins, pixels. */
#define TITLE_BAND 44.0
#define LEFT_MARGIN 70.0
#define BOTTOM_MARGIN 56.0
#define BAR_ZONE 118.0
#define GAP 12.0
#define BAR_WIDTH 22.0

void plot_data_extent(const double *xyz, size_t n, const uint32_t *triangles,
		      size_t n_triangles, double ext[4])
{
	ext[0] = ext[2] = INFINITY;
	ext[1] = ext[3] = -INFINITY;
	size_t m = triangles ? 3 * n_triangles : n;
	for (size_t k = 0; k < m; k++) {
		size_t i = triangles ? triangles[k] : k;
		ext[0] = fmin(ext[0], xyz[3 * i]);
		ext[1] = fmax(ext[1], xyz[3 * i]);
		ext[2] = fmin(ext[2], xyz[3 * i + 1]);
		ext[3] = fmax(ext[3], xyz[3 * i + 1]);
	}
	if (m == 0)
		ext[0] = ext[1] = ext[2] = ext[3] = 0;
}

void plot_panel_frame(const struct plot_rect *panel, const double ext[4],
		      struct plot_frame *f)
{
	double dx = ext[1] - ext[0], dy = ext[3] - ext[2];
	double pad = 0.04 * fmax(dx, dy);

	/* A single point or a line still gets a square millimetre or so. */
	if (pad <= 0)
		pad = 0.5;
	dx += 2 * pad;
	dy += 2 * pad;

	f->area.x = panel->x + LEFT_MARGIN;
	f->area.y = panel->y + TITLE_BAND + GAP;
	f->area.w = fmax(panel->w - LEFT_MARGIN - BAR_ZONE - GAP, 10);
	f->area.h = fmax(panel->h - TITLE_BAND - GAP - BOTTOM_MARGIN, 10);
	f->scale = fmin(f->area.w / dx, f->area.h / dy);
	f->box.w = dx * f->scale;
	f->box.h = dy * f->scale;
	f->box.x = f->area.x + 0.5 * (f->area.w - f->box.w);
	f->box.y = f->area.y + 0.5 * (f->area.h - f->box.h);
	f->x0 = ext[0] - pad;
	f->y0 = ext[2] - pad;

	/* The bar follows the map's height unless the map is a thin strip. */
	f->bar.x = f->area.x + f->area.w + GAP + 10;
	f->bar.w = BAR_WIDTH;
	if (f->box.h >= 0.5 * f->area.h) {
		f->bar.y = f->box.y;
		f->bar.h = f->box.h;
	} else {
		f->bar.y = f->area.y;
		f->bar.h = f->area.h;
	}
}

void plot_frame_to_pixel(const struct plot_frame *f, double x, double y,
			 double *u, double *v)
{
	*u = f->box.x + (x - f->x0) * f->scale;
	*v = f->box.y + f->box.h - (y - f->y0) * f->scale;
}

double plot_point_radius(const struct plot_frame *f, const double ext[4],
			 size_t n, double size)
{
	double area = M_PI / 4 * (ext[1] - ext[0]) * (ext[3] - ext[2]);
	double r;

	if (size <= 0)
		size = 1.5;
	if (n < 2 || area <= 0)
		return 4.0;
	/* Covering radius of a hexagonal lattice is 0.62 sqrt(area per
	 * point), of a square one 0.71: the default 0.75 covers both. */
	r = 0.5 * size * sqrt(area / (double)n) * f->scale;
	return fmin(fmax(r, 0.7), 0.05 * fmin(f->box.w, f->box.h));
}

void plot_figure_panel(int width, int height, size_t n_panels, size_t i,
		       struct plot_rect *panel)
{
	panel->w = (double)width / (double)n_panels;
	panel->h = height;
	panel->x = panel->w * (double)i;
	panel->y = 0;
}

#if HAVE_CAIRO
#include <cairo.h>

static int check_options(const struct asph_plot_options *o, const char *what,
			 struct asph_error *err)
{
	if (!isfinite(o->lo) || !isfinite(o->hi) ||
	    (!(o->lo == 0 && o->hi == 0) && !(o->lo < o->hi)))
		return asph_error_set(err, -EINVAL,
				      "%s: colour range [%g, %g] is not an increasing pair of finite numbers",
				      what, o->lo, o->hi);
	if (!isfinite(o->point_size) || o->point_size < 0)
		return asph_error_set(err, -EINVAL,
				      "%s: point size %g is not a non-negative number",
				      what, o->point_size);
	return 0;
}

static int check_panel(const struct asph_plot_panel *p, size_t index,
		       struct asph_error *err)
{
	char what[32];
	size_t m;

	snprintf(what, sizeof(what), "panel %zu", index + 1);
	if (!p->xyz)
		return asph_error_set(err, -EINVAL, "%s: no points", what);
	if (p->kind == ASPH_PLOT_POINTS) {
		if (p->n == 0)
			return asph_error_set(err, -EINVAL, "%s: nothing to plot (0 points)", what);
		m = p->n;
	} else if (p->kind == ASPH_PLOT_TRIANGLES) {
		if (p->n_triangles == 0 || !p->triangles)
			return asph_error_set(err, -EINVAL, "%s: nothing to plot (0 triangles)", what);
		for (size_t k = 0; p->n && k < 3 * p->n_triangles; k++)
			if (p->triangles[k] >= p->n)
				return asph_error_set(err, -EINVAL,
						      "%s: triangle %zu uses point %u of %zu",
						      what, k / 3, p->triangles[k], p->n);
		m = p->n_triangles;
	} else {
		return asph_error_set(err, -EINVAL, "%s: unknown kind %d", what, (int)p->kind);
	}
	for (size_t k = 0; k < (p->kind == ASPH_PLOT_POINTS ? m : 3 * m); k++) {
		size_t i = p->kind == ASPH_PLOT_POINTS ? k : p->triangles[k];
		if (!isfinite(p->xyz[3 * i]) || !isfinite(p->xyz[3 * i + 1]))
			return asph_error_set(err, -EINVAL,
					      "%s: point %zu has a non-finite coordinate", what, i);
	}
	return check_options(&p->opts, what, err);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(cairo_t *, cairo_destroy)
DEFINE_TRIVIAL_CLEANUP_FUNC(cairo_surface_t *, cairo_surface_destroy)

struct colour_scale {
	double lo, hi;
	int diverging;
};

static void value_range(const double *v, size_t n,
			const struct asph_plot_options *o,
			struct colour_scale *cs)
{
	double lo = INFINITY, hi = -INFINITY;

	cs->diverging = o->diverging;
	if (!(o->lo == 0 && o->hi == 0)) {
		cs->lo = o->lo;
		cs->hi = o->hi;
		return;
	}
	for (size_t i = 0; v && i < n; i++) {
		if (!isfinite(v[i]))
			continue;
		lo = fmin(lo, v[i]);
		hi = fmax(hi, v[i]);
	}
	if (lo > hi)
		lo = 0, hi = 1;
	if (o->diverging) {
		hi = fmax(fabs(lo), fabs(hi));
		lo = -hi;
	}
	/* One value everywhere: centre it in a range around it. */
	if (hi <= lo) {
		double d = lo != 0 ? 0.5 * fabs(lo) : 1.0;
		lo -= d;
		hi += d;
	}
	cs->lo = lo;
	cs->hi = hi;
}

static void set_value_colour(cairo_t *cr, const struct colour_scale *cs,
			     double value)
{
	uint8_t rgb[3];
	double t = (value - cs->lo) / (cs->hi - cs->lo);

	if (cs->diverging)
		colormap_diverging(t, rgb);
	else
		colormap_sequential(t, rgb);
	cairo_set_source_rgb(cr, rgb[0] / 255.0, rgb[1] / 255.0, rgb[2] / 255.0);
}

double plot_nice_step(double span, int target)
{
	double raw = span / target;
	double p = pow(10, floor(log10(raw)));
	double m = raw / p;

	return p * (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10);
}

static void tick_label(double v, double step, char *buf, size_t size)
{
	int decimals = step >= 1 ? 0 : (int)ceil(-log10(step) - 1e-9);

	if (fabs(v) < 1e-9 * step)
		v = 0;
	if (fabs(v) >= 1e6 || decimals > 9)
		snprintf(buf, size, "%.3g", v);
	else
		snprintf(buf, size, "%.*f", decimals, v);
}

static void show_text_at(cairo_t *cr, const char *text, double x, double y,
			 double align_x, double align_y)
{
	cairo_text_extents_t te;

	cairo_text_extents(cr, text, &te);
	cairo_move_to(cr, x - align_x * te.width - te.x_bearing,
		      y - align_y * te.height - te.y_bearing);
	cairo_show_text(cr, text);
}

static void draw_title(cairo_t *cr, const struct plot_rect *panel,
		       const char *title)
{
	if (!title || !*title)
		return;
	cairo_set_source_rgb(cr, 0, 0, 0);
	cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL,
			       CAIRO_FONT_WEIGHT_BOLD);
	cairo_set_font_size(cr, 17);
	show_text_at(cr, title, panel->x + 0.5 * panel->w,
		     panel->y + 0.5 * TITLE_BAND + 4, 0.5, 0.5);
}

/* A 1-pixel black outline on the pixel grid, and the tick label font. */
static void outline(cairo_t *cr, const struct plot_rect *r)
{
	cairo_set_source_rgb(cr, 0, 0, 0);
	cairo_set_line_width(cr, 1);
	cairo_rectangle(cr, r->x + 0.5, r->y + 0.5, r->w - 1, r->h - 1);
	cairo_stroke(cr);
	cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL,
			       CAIRO_FONT_WEIGHT_NORMAL);
	cairo_set_font_size(cr, 12);
}

/* A 5-pixel tick from (u, v) in direction (du, dv), snapped to the grid. */
static void tick(cairo_t *cr, double u, double v, int du, int dv)
{
	if (du == 0)
		u = floor(u) + 0.5;
	else
		v = floor(v) + 0.5;
	cairo_move_to(cr, u, v);
	cairo_line_to(cr, u + 5 * du, v + 5 * dv);
	cairo_stroke(cr);
}

/* Multiples of step in [lo, hi], counted so that rounding drops none. */
static long first_tick(double lo, double step)
{
	return (long)ceil(lo / step - 1e-9);
}

static int tick_in_range(long k, double hi, double step)
{
	return (double)k * step <= hi + 1e-9 * step;
}

static void rotated_label(cairo_t *cr, const char *text, double x, double y)
{
	cairo_save(cr);
	cairo_translate(cr, x, y);
	cairo_rotate(cr, -M_PI / 2);
	show_text_at(cr, text, 0, 0, 0.5, 0.5);
	cairo_restore(cr);
}

static void draw_axes(cairo_t *cr, const struct plot_frame *f)
{
	const struct plot_rect *b = &f->box;
	double x1 = f->x0 + b->w / f->scale, y1 = f->y0 + b->h / f->scale;
	double step = plot_nice_step(fmax(x1 - f->x0, y1 - f->y0), 6);
	char label[32];
	double u, v;

	outline(cr, b);
	for (long k = first_tick(f->x0, step); tick_in_range(k, x1, step); k++) {
		plot_frame_to_pixel(f, (double)k * step, f->y0, &u, &v);
		tick(cr, u, v, 0, 1);
		tick_label((double)k * step, step, label, sizeof(label));
		show_text_at(cr, label, u, v + 8, 0.5, 0);
	}
	for (long k = first_tick(f->y0, step); tick_in_range(k, y1, step); k++) {
		plot_frame_to_pixel(f, f->x0, (double)k * step, &u, &v);
		tick(cr, u, v, -1, 0);
		tick_label((double)k * step, step, label, sizeof(label));
		show_text_at(cr, label, u - 8, v, 1, 0.5);
	}
	cairo_set_font_size(cr, 13);
	show_text_at(cr, "x (mm)", b->x + 0.5 * b->w, b->y + b->h + 30, 0.5, 0);
	rotated_label(cr, "y (mm)", b->x - 52, b->y + 0.5 * b->h);
}

static void draw_colour_bar(cairo_t *cr, const struct plot_frame *f,
			    const struct colour_scale *cs, const char *label)
{
	const struct plot_rect *r = &f->bar;
	double step = plot_nice_step(cs->hi - cs->lo, 6);
	double widest = 0;
	char text[32];
	cairo_text_extents_t te;

	/* One row of pixels per colour: exact colours, no gradient blending. */
	for (int i = 0; i < (int)ceil(r->h); i++) {
		double t = 1 - (i + 0.5) / r->h;
		set_value_colour(cr, cs, cs->lo + t * (cs->hi - cs->lo));
		cairo_rectangle(cr, r->x, r->y + i, r->w, 1);
		cairo_fill(cr);
	}
	outline(cr, r);
	for (long k = first_tick(cs->lo, step); tick_in_range(k, cs->hi, step); k++) {
		double v = (double)k * step;
		double y = r->y + r->h * (1 - (v - cs->lo) / (cs->hi - cs->lo));
		tick(cr, r->x + r->w, y, 1, 0);
		tick_label(v, step, text, sizeof(text));
		cairo_text_extents(cr, text, &te);
		widest = fmax(widest, te.width);
		show_text_at(cr, text, r->x + r->w + 8, y, 0, 0.5);
	}
	if (!label || !*label)
		return;
	cairo_set_font_size(cr, 13);
	rotated_label(cr, label, r->x + r->w + 8 + widest + 18, r->y + 0.5 * r->h);
}

static void draw_points(cairo_t *cr, const struct asph_plot_panel *p,
			const struct plot_frame *f,
			const struct colour_scale *cs, double radius)
{
	double u, v;

	if (!p->value)
		cairo_set_source_rgb(cr, 0.2, 0.2, 0.25);
	for (size_t i = 0; i < p->n; i++) {
		plot_frame_to_pixel(f, p->xyz[3 * i], p->xyz[3 * i + 1], &u, &v);
		cairo_new_sub_path(cr);
		cairo_arc(cr, u, v, radius, 0, 2 * M_PI);
		if (p->value) {
			set_value_colour(cr, cs, p->value[i]);
			cairo_fill(cr);
		}
	}
	if (!p->value)
		cairo_fill(cr);
}

/* Resolution of the discs on a vector surface. */
#define POINTS_DPI 300.0
#define POINTS_MAX_PIXELS 4096

/* The discs on a vector surface (the PDF report): drawn into an image of
 * the frame's box at POINTS_DPI and that image painted. A vector surface
 * records every disc until its page ends (about 900 bytes each, 4.5 GB for
 * five million points) and its file would hold them all; the image's size
 * does not depend on the number of points. */
static int draw_points_raster(cairo_t *cr, const struct asph_plot_panel *p,
			      const struct plot_frame *f,
			      const struct colour_scale *cs, double radius)
{
	double w = f->box.w, h = f->box.h;
	cairo_surface_t *img;
	cairo_t *icr;
	double s;
	int r;

	cairo_user_to_device_distance(cr, &w, &h);
	s = fmin(fmax(fabs(w), fabs(h)) * POINTS_DPI / 72, POINTS_MAX_PIXELS) /
	    fmax(f->box.w, f->box.h);
	img = cairo_image_surface_create(CAIRO_FORMAT_ARGB32, (int)ceil(f->box.w * s),
					 (int)ceil(f->box.h * s));
	icr = cairo_create(img);	/* on an error, an inert context */
	cairo_scale(icr, s, s);
	cairo_translate(icr, -f->box.x, -f->box.y);
	draw_points(icr, p, f, cs, radius);
	r = cairo_status(icr) == CAIRO_STATUS_SUCCESS ? 0 : -ENOMEM;
	cairo_destroy(icr);
	if (r == 0) {
		cairo_save(cr);
		cairo_translate(cr, f->box.x, f->box.y);
		cairo_scale(cr, 1 / s, 1 / s);
		cairo_set_source_surface(cr, img, 0, 0);
		cairo_paint(cr);
		cairo_restore(cr);
	}
	cairo_surface_destroy(img);
	return r;
}

static void draw_triangles(cairo_t *cr, const struct asph_plot_panel *p,
			   const struct plot_frame *f,
			   const struct colour_scale *cs)
{
	double u, v;

	/* The thin stroke in the fill colour closes the hairline seams that
	 * antialiasing leaves between neighbouring triangles. */
	cairo_set_line_width(cr, 0.6);
	cairo_set_line_join(cr, CAIRO_LINE_JOIN_BEVEL);
	for (size_t t = 0; t < p->n_triangles; t++) {
		for (int k = 0; k < 3; k++) {
			const double *q = p->xyz + 3 * (size_t)p->triangles[3 * t + k];
			plot_frame_to_pixel(f, q[0], q[1], &u, &v);
			if (k == 0)
				cairo_move_to(cr, u, v);
			else
				cairo_line_to(cr, u, v);
		}
		cairo_close_path(cr);
		if (p->value)
			set_value_colour(cr, cs, p->value[t]);
		else
			cairo_set_source_rgb(cr, 0.6, 0.6, 0.65);
		cairo_fill_preserve(cr);
		cairo_stroke(cr);
	}
}

int plot_draw_panel(cairo_t *cr, const struct asph_plot_panel *p,
		    const struct plot_rect *panel)
{
	struct plot_frame f;
	struct colour_scale cs;
	double ext[4];
	int r = 0;
	size_t n_values = p->kind == ASPH_PLOT_POINTS ? p->n : p->n_triangles;

	plot_data_extent(p->xyz, p->n, p->kind == ASPH_PLOT_TRIANGLES ? p->triangles : NULL,
			 p->n_triangles, ext);
	plot_panel_frame(panel, ext, &f);
	value_range(p->value, n_values, &p->opts, &cs);

	draw_title(cr, panel, p->opts.title);
	cairo_save(cr);
	cairo_rectangle(cr, f.box.x, f.box.y, f.box.w, f.box.h);
	cairo_clip(cr);
	if (p->kind == ASPH_PLOT_POINTS &&
	    cairo_surface_get_type(cairo_get_target(cr)) != CAIRO_SURFACE_TYPE_IMAGE)
		r = draw_points_raster(cr, p, &f, &cs,
				       plot_point_radius(&f, ext, p->n, p->opts.point_size));
	else if (p->kind == ASPH_PLOT_POINTS)
		draw_points(cr, p, &f, &cs,
			    plot_point_radius(&f, ext, p->n, p->opts.point_size));
	else
		draw_triangles(cr, p, &f, &cs);
	cairo_restore(cr);
	draw_axes(cr, &f);
	if (p->value)
		draw_colour_bar(cr, &f, &cs, p->opts.colour_label);
	return r;
}

cairo_status_t plot_write_to_file(void *closure, const unsigned char *data,
				  unsigned int length)
{
	return fwrite(data, 1, length, closure) == length ? CAIRO_STATUS_SUCCESS
							  : CAIRO_STATUS_WRITE_ERROR;
}

/* The figure's panels and size (0: the default), checked before anything
 * is written. */
static int check_figure(const struct asph_plot_panel *panels, size_t n_panels, int *width,
			int *height, struct asph_error *err)
{
	if (!panels || n_panels == 0 || n_panels > 16)
		return asph_error_set(err, -EINVAL, "a plot needs a path and 1 to 16 panels");
	if (*width == 0)
		*width = DEFAULT_WIDTH * (int)n_panels;
	if (*height == 0)
		*height = DEFAULT_HEIGHT;
	if (*width < MIN_SIZE || *height < MIN_SIZE || *width > MAX_SIZE || *height > MAX_SIZE)
		return asph_error_set(err, -EINVAL, "image size %d x %d is outside %d..%d pixels",
				      *width, *height, MIN_SIZE, MAX_SIZE);
	for (size_t i = 0; i < n_panels; i++) {
		int r = check_panel(&panels[i], i, err);
		if (r < 0)
			return r;
	}
	return 0;
}

/* The PNG to f, flushed; name is for messages. */
static int write_png(cairo_surface_t *surface, FILE *f, const char *name,
		     struct asph_error *err)
{
	cairo_status_t st;

	errno = 0;
	st = cairo_surface_write_to_png_stream(surface, plot_write_to_file, f);
	if (st == CAIRO_STATUS_SUCCESS && fflush(f) != 0)
		st = CAIRO_STATUS_WRITE_ERROR;
	if (st != CAIRO_STATUS_SUCCESS)
		return asph_error_set(err, -EIO, "cannot write %s: %s", name,
				      st == CAIRO_STATUS_WRITE_ERROR && errno
					      ? strerror(errno)
					      : cairo_status_to_string(st));
	return 0;
}

int asph_plot_panels_png_stream(FILE *f, const char *name,
				const struct asph_plot_panel *panels, size_t n_panels,
				int width, int height, struct asph_error *err)
{
	_cleanup_(cairo_surface_destroyp) cairo_surface_t *surface = NULL;
	_cleanup_(cairo_destroyp) cairo_t *cr = NULL;
	struct plot_rect panel;
	int r = check_figure(panels, n_panels, &width, &height, err);

	if (r < 0)
		return r;
	if (!f)
		return asph_error_set(err, -EINVAL, "a plot needs a file");
	surface = cairo_image_surface_create(CAIRO_FORMAT_RGB24, width, height);
	cr = cairo_create(surface);
	if (cairo_status(cr) != CAIRO_STATUS_SUCCESS)
		return asph_error_set(err, -ENOMEM, "cannot create a %d x %d image: %s", width,
				      height, cairo_status_to_string(cairo_status(cr)));
	cairo_set_source_rgb(cr, 1, 1, 1);
	cairo_paint(cr);
	for (size_t i = 0; i < n_panels; i++) {
		plot_figure_panel(width, height, n_panels, i, &panel);
		r = plot_draw_panel(cr, &panels[i], &panel);
		if (r < 0)
			return asph_error_set(err, r, "out of memory");
	}
	cairo_surface_flush(surface);
	return write_png(surface, f, name ? name : "the plot", err);
}

int asph_plot_panels_png(const char *path, const struct asph_plot_panel *panels,
			 size_t n_panels, int width, int height,
			 struct asph_error *err)
{
	FILE *f;
	int r = check_figure(panels, n_panels, &width, &height, err);

	if (r < 0)
		return r;
	if (!path)
		return asph_error_set(err, -EINVAL, "a plot needs a path and 1 to 16 panels");
	f = fopen(path, "wbe");
	if (!f)
		return asph_error_set(err, -errno, "cannot create %s: %s", path,
				      strerror(errno));
	r = asph_plot_panels_png_stream(f, path, panels, n_panels, width, height, err);
	if (fclose(f) != 0 && r == 0)
		r = asph_error_set(err, -errno, "cannot write %s: %s", path, strerror(errno));
	if (r < 0)
		unlink(path);
	return r;
}

#else /* !HAVE_CAIRO */

int asph_plot_panels_png(const char *path, const struct asph_plot_panel *panels,
			 size_t n_panels, int width, int height,
			 struct asph_error *err)
{
	return asph_error_set(err, -ENOTSUP,
			      "PNG plots need cairo, and this libasph was built without it");
}

int asph_plot_panels_png_stream(FILE *f, const char *name,
				const struct asph_plot_panel *panels, size_t n_panels,
				int width, int height, struct asph_error *err)
{
	return asph_error_set(err, -ENOTSUP,
			      "PNG plots need cairo, and this libasph was built without it");
}

#endif

static int single_panel(const char *path, const struct asph_plot_panel *p,
			struct asph_error *err)
{
	return asph_plot_panels_png(path, p, 1, p->opts.width, p->opts.height, err);
}

static struct asph_plot_panel points_panel(const double *xyz, const double *value, size_t n,
					   const struct asph_plot_options *opts)
{
	struct asph_plot_panel p = {
		.kind = ASPH_PLOT_POINTS, .xyz = xyz, .n = n, .value = value,
	};

	if (opts)
		p.opts = *opts;
	return p;
}

int asph_plot_points_png(const char *path, const double *xyz,
			 const double *value, size_t n,
			 const struct asph_plot_options *opts,
			 struct asph_error *err)
{
	struct asph_plot_panel p = points_panel(xyz, value, n, opts);

	return single_panel(path, &p, err);
}

int asph_plot_points_png_stream(FILE *f, const char *name, const double *xyz,
				const double *value, size_t n,
				const struct asph_plot_options *opts,
				struct asph_error *err)
{
	struct asph_plot_panel p = points_panel(xyz, value, n, opts);

	return asph_plot_panels_png_stream(f, name, &p, 1, p.opts.width, p.opts.height, err);
}

int asph_plot_triangles_png(const char *path, const double *xyz,
			    const uint32_t *triangles, size_t n_triangles,
			    const double *value,
			    const struct asph_plot_options *opts,
			    struct asph_error *err)
{
	struct asph_plot_panel p = {
		.kind = ASPH_PLOT_TRIANGLES, .xyz = xyz, .triangles = triangles,
		.n_triangles = n_triangles, .value = value,
	};

	if (opts)
		p.opts = *opts;
	return single_panel(path, &p, err);
}
