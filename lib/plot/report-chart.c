/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The report's figures (cairo). */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "config.h"
#include "report-chart.h"

#if HAVE_CAIRO
#include "plot-layout.h"
#include "report-text.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_psd *, asph_psd_free)

#define TITLE_SIZE 8.5
#define LABEL_SIZE 7.5
#define TICK_SIZE REPORT_MIN_TEXT
#define TICK_LENGTH 3.0
/* The map panel of the PNG figures is laid out in pixels with 12 px tick
 * labels: drawn at this scale they are 7.2 pt. */
#define MAP_SCALE 0.6

/* Lines of text wrapped to width in the current font, shown from the top
 * y down; returns the height they took. */
static double text_block(cairo_t *cr, double x, double y, double width, double size,
			 const char *text)
{
	struct report_lines lines = { 0 };
	_cleanup_free_ char *clean = report_text_clean(text);
	double lead = 1.25 * size;

	if (!clean || report_text_wrap(cr, clean, width, &lines) < 0) {
		report_lines_release(&lines);
		return 0;
	}
	for (size_t i = 0; i < lines.n; i++) {
		_cleanup_free_ char *s = strndup(lines.v[i].s, lines.v[i].len);
		if (!s)
			break;
		cairo_move_to(cr, x, y + (double)i * lead + size);
		cairo_show_text(cr, s);
	}
	double h = (double)lines.n * lead;
	report_lines_release(&lines);
	return h;
}

/* text with its left (align 0), centre (0.5) or right end (1) at x. */
static void text_at(cairo_t *cr, double x, double baseline, double align, const char *text)
{
	cairo_move_to(cr, x - align * report_text_width(cr, text, strlen(text)), baseline);
	cairo_show_text(cr, text);
}

/* ---------------------------------------------------------------- axes */

/* The plot box of a chart and its axes (log10 of the range on a log axis). */
struct chart {
	struct report_rect box;
	double x0, x1, y0, y1;
	int logx, logy;
};

/* Tick values of one axis: multiples of a 1-2-5 step, or the decades. */
struct ticks {
	int n;
	double v[32];
	double step;
};

static void axis_ticks(double lo, double hi, int lg, struct ticks *t)
{
	t->step = lg ? 1 : plot_nice_step(hi - lo, 5);
	/* counted, not summed: each an exact multiple of the step */
	double first = ceil(lo / t->step - 1e-9);
	int n = (int)(floor(hi / t->step + 1e-9) - first) + 1;

	t->n = 0;
	for (int i = 0; i < n && t->n < (int)(sizeof(t->v) / sizeof(t->v[0])); i++)
		t->v[t->n++] = (first + i) * t->step;
}

/* "10⁻³" for decade k. */
static void decade_label(int k, char *buf, size_t size)
{
	static const char *const sup[] = { "⁰", "¹", "²", "³", "⁴", "⁵", "⁶", "⁷", "⁸", "⁹" };
	char digits[16];
	size_t n = (size_t)snprintf(buf, size, "10%s", k < 0 ? "⁻" : "");

	snprintf(digits, sizeof(digits), "%d", abs(k));
	for (const char *d = digits; *d && n < size; d++)
		n += (size_t)snprintf(buf + n, size - n, "%s", sup[*d - '0']);
}

static void tick_label(double v, const struct ticks *t, int lg, char *buf, size_t size)
{
	int decimals = t->step >= 1 ? 0 : (int)ceil(-log10(t->step) - 1e-9);

	if (lg) {
		decade_label((int)lrint(v), buf, size);
		return;
	}
	if (fabs(v) < 1e-9 * t->step)
		v = 0;
	if (decimals > 9 || fabs(v) >= 1e7)
		snprintf(buf, size, "%.3g", v);
	else
		snprintf(buf, size, "%.*f", decimals, v);
}

static double chart_u(const struct chart *c, double v)
{
	double a = c->logx ? log10(fmax(v, DBL_MIN)) : v;

	return c->box.x + (a - c->x0) / (c->x1 - c->x0) * c->box.w;
}

static double chart_v(const struct chart *c, double v)
{
	double a = c->logy ? log10(fmax(v, DBL_MIN)) : v;

	return c->box.y + c->box.h - (a - c->y0) / (c->y1 - c->y0) * c->box.h;
}

/*
 * Places the plot box of c inside area: the title wrapped over the top,
 * the widest y tick label and the rotated y label on the left, the x tick
 * labels and the x label below, `below` more points under those (a
 * legend, a note). The axis ranges of c must be set.
 */
static void chart_place(cairo_t *cr, struct chart *c, const struct report_rect *area,
			const char *title, double below)
{
	struct report_lines lines = { 0 };
	_cleanup_free_ char *clean = report_text_clean(title);
	struct ticks t;
	char buf[48];
	double widest = 0, top;

	report_font(cr, REPORT_SANS_BOLD, TITLE_SIZE);
	if (!clean || report_text_wrap(cr, clean, area->w, &lines) < 0)
		lines.n = 1;
	top = (double)lines.n * 1.25 * TITLE_SIZE + 4;
	report_lines_release(&lines);
	report_font(cr, REPORT_SANS, TICK_SIZE);
	axis_ticks(c->y0, c->y1, c->logy, &t);
	for (int i = 0; i < t.n; i++) {
		tick_label(t.v[i], &t, c->logy, buf, sizeof(buf));
		widest = fmax(widest, report_text_width(cr, buf, strlen(buf)));
	}
	/* room on the right for half of the last x tick label */
	c->box.x = area->x + LABEL_SIZE + 4 + widest + TICK_LENGTH + 2;
	c->box.w = area->x + area->w - 12 - c->box.x;
	c->box.y = area->y + top;
	c->box.h = area->h - top - (TICK_LENGTH + 2 + TICK_SIZE + 4 + LABEL_SIZE + 2) - below;
}

static void chart_axis(cairo_t *cr, const struct chart *c, int vertical)
{
	struct ticks t;
	char buf[48];

	axis_ticks(vertical ? c->y0 : c->x0, vertical ? c->y1 : c->x1,
		   vertical ? c->logy : c->logx, &t);
	for (int i = 0; i < t.n; i++) {
		int lg = vertical ? c->logy : c->logx;
		double v = lg ? pow(10, t.v[i]) : t.v[i];
		tick_label(t.v[i], &t, lg, buf, sizeof(buf));
		if (vertical) {
			double py = chart_v(c, v);
			cairo_move_to(cr, c->box.x - TICK_LENGTH, py);
			cairo_line_to(cr, c->box.x, py);
			cairo_stroke(cr);
			text_at(cr, c->box.x - TICK_LENGTH - 2, py + 0.35 * TICK_SIZE, 1, buf);
		} else {
			double px = chart_u(c, v);
			cairo_move_to(cr, px, c->box.y + c->box.h);
			cairo_line_to(cr, px, c->box.y + c->box.h + TICK_LENGTH);
			cairo_stroke(cr);
			text_at(cr, px, c->box.y + c->box.h + TICK_LENGTH + 1 + TICK_SIZE, 0.5, buf);
		}
	}
}

static void chart_frame(cairo_t *cr, const struct chart *c, const struct report_rect *area,
			const char *title, const char *xlabel, const char *ylabel)
{
	const struct report_rect *b = &c->box;

	report_font(cr, REPORT_SANS_BOLD, TITLE_SIZE);
	text_block(cr, area->x, area->y, area->w, TITLE_SIZE, title);
	cairo_set_line_width(cr, 0.6);
	cairo_rectangle(cr, b->x, b->y, b->w, b->h);
	cairo_stroke(cr);
	report_font(cr, REPORT_SANS, TICK_SIZE);
	cairo_set_line_width(cr, 0.5);
	chart_axis(cr, c, 0);
	chart_axis(cr, c, 1);
	report_font(cr, REPORT_SANS, LABEL_SIZE);
	text_at(cr, b->x + b->w / 2, b->y + b->h + TICK_LENGTH + 2 + TICK_SIZE + 3 + LABEL_SIZE,
		0.5, xlabel);
	cairo_save(cr);
	cairo_translate(cr, area->x + LABEL_SIZE, b->y + b->h / 2);
	cairo_rotate(cr, -M_PI / 2);
	text_at(cr, 0, 0, 0.5, ylabel);
	cairo_restore(cr);
}

/* The top of what lies below the x label: legends and notes. */
static double chart_below(const struct chart *c)
{
	return c->box.y + c->box.h + TICK_LENGTH + 2 + TICK_SIZE + 4 + LABEL_SIZE + 6;
}

static void polyline(cairo_t *cr, const struct chart *c, const double *x, const double *y,
		     size_t n, const double rgb[3])
{
	int pen = 0;

	cairo_save(cr);
	cairo_rectangle(cr, c->box.x, c->box.y, c->box.w, c->box.h);
	cairo_clip(cr);
	cairo_set_source_rgb(cr, rgb[0], rgb[1], rgb[2]);
	cairo_set_line_width(cr, 0.9);
	for (size_t k = 0; k < n; k++) {
		if (isnan(y[k]) || (c->logy && !(y[k] > 0)) || (c->logx && !(x[k] > 0))) {
			pen = 0;
			continue;
		}
		if (pen)
			cairo_line_to(cr, chart_u(c, x[k]), chart_v(c, y[k]));
		else
			cairo_move_to(cr, chart_u(c, x[k]), chart_v(c, y[k]));
		pen = 1;
	}
	cairo_stroke(cr);
	cairo_restore(cr);
}

/* The range of the values that are numbers, widened when it is empty. */
static void range_of(const double *v, size_t n, double *lo, double *hi)
{
	*lo = INFINITY;
	*hi = -INFINITY;
	for (size_t k = 0; k < n; k++)
		if (!isnan(v[k])) {
			*lo = fmin(*lo, v[k]);
			*hi = fmax(*hi, v[k]);
		}
	if (!(*lo < *hi)) {
		double d = isfinite(*lo) && *lo != 0 ? 0.5 * fabs(*lo) : 1;
		*lo = isfinite(*lo) ? *lo - d : -1;
		*hi = isfinite(*hi) ? *hi + d : 1;
	}
}

/* The note under a figure of numerical noise. */
static void noise_note(char *buf, size_t size, double pv_nm, double noise_nm)
{
	snprintf(buf, size,
		 "Numerical noise: PV %.2g nm, below %.2g nm (the resolution of a fit in double "
		 "precision); the scale is fixed at ±%.2g nm, not stretched.",
		 pv_nm, noise_nm, noise_nm);
}

static double pv_of(const double *v, size_t n)
{
	double lo, hi;

	range_of(v, n, &lo, &hi);
	return hi - lo;
}

/* ------------------------------------------------------------- figures */

int report_map(cairo_t *cr, const struct report_rect *area, const struct asph_report *r,
	       double noise_nm)
{
	struct asph_plot_panel p = {
		.kind = ASPH_PLOT_POINTS, .n = r->n, .value = r->residual_nm,
		.opts = { .colour_label = "residual (nm)", .diverging = 1 },
	};
	_cleanup_free_ double *xyz = malloc(3 * r->n * sizeof(double) + 1);
	double note_h = noise_nm > 0 ? 3 * 1.25 * TICK_SIZE : 0;
	char note[256];

	if (!xyz)
		return -ENOMEM;
	mem_advise_huge(xyz, 3 * r->n * sizeof(double));
	for (size_t k = 0; k < r->n; k++) {
		xyz[3 * k] = r->xy[2 * k];
		xyz[3 * k + 1] = r->xy[2 * k + 1];
		xyz[3 * k + 2] = 0;
	}
	p.xyz = xyz;
	if (noise_nm > 0) {
		p.opts.lo = -noise_nm;
		p.opts.hi = noise_nm;
		noise_note(note, sizeof(note), pv_of(r->residual_nm, r->n), noise_nm);
		report_font(cr, REPORT_SANS, TICK_SIZE);
		text_block(cr, area->x, area->y + area->h - note_h, area->w, TICK_SIZE, note);
	}
	report_font(cr, REPORT_SANS_BOLD, TITLE_SIZE);
	text_block(cr, area->x, area->y, area->w, TITLE_SIZE, "Residual map (seen from +z)");
	struct plot_rect panel = { 0, 0, area->w / MAP_SCALE, (area->h - note_h) / MAP_SCALE };
	cairo_save(cr);
	cairo_translate(cr, area->x, area->y);
	cairo_scale(cr, MAP_SCALE, MAP_SCALE);
	int drawn = plot_draw_panel(cr, &p, &panel);
	cairo_restore(cr);
	return drawn;
}

int report_profiles(cairo_t *cr, const struct report_rect *area, const struct asph_report *r,
		    double noise_nm)
{
	static const double colours[4][3] = { { 0.12, 0.35, 0.75 }, { 0.80, 0.25, 0.10 },
					      { 0.10, 0.55, 0.25 }, { 0.55, 0.30, 0.65 } };
	static const char *const names[4] = { "0°", "45°", "90°", "135°" };
	double ds = r->radius / 150;
	size_t n = asph_profile_length(r->radius, ds);
	_cleanup_free_ double *s = malloc(n * sizeof(double));
	_cleanup_free_ double *z = malloc(4 * n * sizeof(double));
	struct chart c = { .x0 = -r->radius, .x1 = r->radius };
	double legend = 2 * 1.3 * TICK_SIZE + 2, below = legend + (noise_nm > 0 ? 3 * 1.25 * TICK_SIZE : 0);
	char note[256];

	if (!s || !z)
		return -ENOMEM;
	for (size_t k = 0; k < n; k++)
		s[k] = -r->radius + (double)k * ds;
	for (int a = 0; a < 4; a++)
		asph_profile_sample(r->scatter, a * M_PI / 4, r->radius, ds, z + (size_t)a * n, NULL);
	if (noise_nm > 0) {
		c.y0 = -noise_nm;
		c.y1 = noise_nm;
	} else {
		range_of(z, 4 * n, &c.y0, &c.y1);
	}
	chart_place(cr, &c, area, "Radial profiles of the residual", below);
	chart_frame(cr, &c, area, "Radial profiles of the residual",
		    "position along the diameter (mm)", "residual (nm)");
	for (int a = 0; a < 4; a++)
		polyline(cr, &c, s, z + (size_t)a * n, n, colours[a]);
	/* the legend: a short line in each colour and the diameter's
	 * azimuth, on as many rows as the width needs */
	double y = chart_below(&c), x = c.box.x;
	report_font(cr, REPORT_SANS, TICK_SIZE);
	text_at(cr, x, y + TICK_SIZE, 0, "azimuth:");
	x += report_text_width(cr, "azimuth:", strlen("azimuth:")) + 6;
	for (int a = 0; a < 4; a++) {
		double w = 17 + report_text_width(cr, names[a], strlen(names[a]));
		if (x + w > area->x + area->w) {
			x = c.box.x;
			y += 1.3 * TICK_SIZE;
		}
		cairo_set_source_rgb(cr, colours[a][0], colours[a][1], colours[a][2]);
		cairo_set_line_width(cr, 1.5);
		cairo_move_to(cr, x, y + 0.65 * TICK_SIZE);
		cairo_line_to(cr, x + 14, y + 0.65 * TICK_SIZE);
		cairo_stroke(cr);
		report_font(cr, REPORT_SANS, TICK_SIZE);
		text_at(cr, x + 17, y + TICK_SIZE, 0, names[a]);
		x += w + 10;
	}
	if (noise_nm > 0) {
		noise_note(note, sizeof(note), pv_of(r->residual_nm, r->n), noise_nm);
		text_block(cr, area->x, chart_below(&c) + legend, area->w, TICK_SIZE, note);
	}
	return 0;
}

void report_zernike(cairo_t *cr, const struct report_rect *area, const struct asph_fit_result *f)
{
	struct chart c = { .x0 = 0.5, .x1 = f->n_zernike + 0.5 };
	double lo = 0, hi = 0;

	for (int j = 0; j < f->n_zernike; j++) {
		lo = fmin(lo, f->zernike[j].v);
		hi = fmax(hi, f->zernike[j].v);
	}
	if (!(hi > lo))
		hi = lo + 1;
	c.y0 = lo;
	c.y1 = hi;
	chart_place(cr, &c, area, "Zernike terms of the residual (Noll)", 0);
	chart_frame(cr, &c, area, "Zernike terms of the residual (Noll)", "Noll index j",
		    "coefficient (nm)");
	cairo_set_source_rgb(cr, 0.2, 0.35, 0.7);
	for (int j = 0; j < f->n_zernike; j++) {
		double u0 = chart_u(&c, j + 0.65), u1 = chart_u(&c, j + 1.35);
		double v0 = chart_v(&c, 0), v1 = chart_v(&c, f->zernike[j].v);
		cairo_rectangle(cr, u0, fmin(v0, v1), u1 - u0, fabs(v1 - v0));
	}
	cairo_fill(cr);
	cairo_set_source_rgb(cr, 0, 0, 0);
	cairo_set_line_width(cr, 0.4);
	cairo_move_to(cr, c.box.x, chart_v(&c, 0));
	cairo_line_to(cr, c.box.x + c.box.w, chart_v(&c, 0));
	cairo_stroke(cr);
}

int report_psd(cairo_t *cr, const struct report_rect *area, const struct asph_report *r)
{
	_cleanup_(asph_psd_freep) struct asph_psd *own = NULL;
	const struct asph_psd *p = r->psd;
	struct chart c = { .logx = 1, .logy = 1 };
	double lo = INFINITY, hi = -INFINITY;
	char title[96];

	if (!p && asph_psd_residual(r->scatter, r->radius, &own, NULL) < 0) {
		report_font(cr, REPORT_SANS_BOLD, TITLE_SIZE);
		text_block(cr, area->x, area->y, area->w, TITLE_SIZE,
			   "PSD of the residual: too few measured samples along the diameters");
		return 0;
	}
	p = p ? p : own;
	_cleanup_free_ double *f = malloc(p->n * sizeof(double));
	if (!f)
		return -ENOMEM;
	for (size_t k = 0; k < p->n; k++) {
		f[k] = (double)k * p->df;
		if (k > 0 && p->psd[k] > 0) {
			lo = fmin(lo, p->psd[k]);
			hi = fmax(hi, p->psd[k]);
		}
	}
	c.x0 = floor(log10(p->df));
	c.x1 = ceil(log10((double)(p->n - 1) * p->df));
	c.y0 = isfinite(lo) ? floor(log10(lo)) : 0;
	c.y1 = isfinite(hi) ? ceil(log10(hi)) : 1;
	if (c.y1 - c.y0 > 12)
		c.y0 = c.y1 - 12;
	if (!(c.x1 > c.x0))
		c.x1 = c.x0 + 1;
	if (!(c.y1 > c.y0))
		c.y1 = c.y0 + 1;
	snprintf(title, sizeof(title), "Residual PSD, mean of %zu diameters (Hann)",
		 p->n_profiles);
	chart_place(cr, &c, area, title, 0);
	chart_frame(cr, &c, area, title, "spatial frequency (mm⁻¹)", "PSD (nm²·mm)");
	polyline(cr, &c, f + 1, p->psd + 1, p->n - 1, (const double[3]){ 0.1, 0.1, 0.1 });
	return 0;
}

#endif
