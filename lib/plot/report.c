/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The measurement report as a PDF page (cairo's PDF surface). */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nettle/sha2.h>

#include "config.h"
#include "asph/report.h"
#include "plot-layout.h"
#include "util-mem.h"

#if HAVE_CAIRO
#include <cairo-pdf.h>

#define PAGE_W 595.0     /* A4, points */
#define PAGE_H 842.0
#define MARGIN 36.0

DEFINE_TRIVIAL_CLEANUP_FUNC(cairo_t *, cairo_destroy)
DEFINE_TRIVIAL_CLEANUP_FUNC(cairo_surface_t *, cairo_surface_destroy)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_psd *, asph_psd_free)

static void sha256_hex(const void *data, size_t len, char hex[65])
{
	struct sha256_ctx c;
	uint8_t d[SHA256_DIGEST_SIZE];

	sha256_init(&c);
	sha256_update(&c, len, data);
	sha256_digest(&c, sizeof(d), d);
	for (int i = 0; i < SHA256_DIGEST_SIZE; i++)
		snprintf(hex + 2 * i, 3, "%02x", d[i]);
}

static void font(cairo_t *cr, double size, int bold)
{
	cairo_select_font_face(cr, "sans-serif", CAIRO_FONT_SLANT_NORMAL,
			       bold ? CAIRO_FONT_WEIGHT_BOLD : CAIRO_FONT_WEIGHT_NORMAL);
	cairo_set_font_size(cr, size);
	cairo_set_source_rgb(cr, 0, 0, 0);
}

static void text_at(cairo_t *cr, double x, double y, const char *s)
{
	cairo_move_to(cr, x, y);
	cairo_show_text(cr, s);
}

/* A line "label: text" shortened to fit; returns the next baseline. */
static double field_line(cairo_t *cr, double y, const char *label, const char *text)
{
	char buf[160];

	font(cr, 8, 1);
	text_at(cr, MARGIN, y, label);
	font(cr, 8, 0);
	snprintf(buf, sizeof(buf), "%s", text ? text : "-");
	text_at(cr, MARGIN + 78, y, buf);
	return y + 11;
}

static double provenance(cairo_t *cr, double y, const char *label, const char *json)
{
	char hex[65], line[200];

	if (!json)
		return field_line(cr, y, label, "not known");
	sha256_hex(json, strlen(json), hex);
	snprintf(line, sizeof(line), "sha256 %s  %.60s%s", hex, json, strlen(json) > 60 ? "..." : "");
	return field_line(cr, y, label, line);
}

static const char *verdict_text(enum asph_verdict v)
{
	return asph_verdict_name(v);
}

/* "%.*g" of v, or "-" when v is not a number. */
static void num_or_dash(char *buf, size_t size, double v, int digits)
{
	if (isnan(v))
		snprintf(buf, size, "-");
	else
		snprintf(buf, size, "%.*g", digits, v);
}

/* The table: every quantity, its U, and the limit and decision when
 * toleranced. */
static double verdict_table(cairo_t *cr, double y, const struct asph_report *r)
{
	const struct asph_fit_result *f = r->fit;
	const struct asph_uncertainty_k2 *u = &f->uncertainty_k2;
	struct row {
		const char *name, *key;
		double value, U;
	} rows[] = {
		{ "A, sagitta deviation (nm)", "A_nm", fabs(f->form.A.v), u->A.v },
		{ "B, irregularity (nm)", "B_nm", f->form.B.v, u->B.v },
		{ "C, rot. symmetric irregularity (nm)", "C_nm", f->form.C.v, u->C.v },
		{ "RMSt (nm)", "rms_t_nm", f->form.rms_t.v, u->rms_t.v },
		{ "RMSi (nm)", "rms_i_nm", f->form.rms_i.v, u->rms_i.v },
		{ "RMSa (nm)", "rms_a_nm", f->form.rms_a.v, u->rms_a.v },
		{ "slope RMS (urad)", "slope_rms_urad", f->slope.rms.v, u->slope_rms.v },
		{ "slope max (urad)", "slope_max_urad", f->slope.max.v, u->slope_max.v },
		{ "|R - R nominal| (mm)", "R_deviation_mm", fabs(f->R_deviation_mm), u->R_mm },
	};
	const double col[] = { MARGIN, MARGIN + 190, MARGIN + 270, MARGIN + 350, MARGIN + 430 };
	char buf[64];

	font(cr, 8, 1);
	text_at(cr, col[0], y, "quantity");
	text_at(cr, col[1], y, "value");
	text_at(cr, col[2], y, "U (k = 2)");
	text_at(cr, col[3], y, "limit");
	text_at(cr, col[4], y, "verdict");
	cairo_set_line_width(cr, 0.5);
	cairo_move_to(cr, MARGIN, y + 3);
	cairo_line_to(cr, PAGE_W - MARGIN, y + 3);
	cairo_stroke(cr);
	y += 12;
	for (size_t i = 0; i < sizeof(rows) / sizeof(rows[0]); i++) {
		const struct asph_verdict_item *it = NULL;
		for (size_t k = 0; k < f->verdict.n_items; k++)
			if (!strcmp(f->verdict.items[k].quantity, rows[i].key))
				it = &f->verdict.items[k];
		if (isnan(rows[i].value) && !it)
			continue;
		font(cr, 8, 0);
		text_at(cr, col[0], y, rows[i].name);
		num_or_dash(buf, sizeof(buf), rows[i].value, 4);
		text_at(cr, col[1], y, buf);
		num_or_dash(buf, sizeof(buf), rows[i].U, 3);
		text_at(cr, col[2], y, buf);
		num_or_dash(buf, sizeof(buf), it ? it->limit : NAN, 4);
		text_at(cr, col[3], y, buf);
		if (it) {
			font(cr, 8, 1);
			if (it->verdict == ASPH_VERDICT_FAIL)
				cairo_set_source_rgb(cr, 0.75, 0, 0);
			else if (it->verdict == ASPH_VERDICT_PASS)
				cairo_set_source_rgb(cr, 0, 0.5, 0);
			text_at(cr, col[4], y, verdict_text(it->verdict));
		}
		y += 11;
	}
	return y;
}

/* Axes for a line or bar chart in box (x, y, w, h): ticks from lo to hi. */
struct chart {
	double x, y, w, h;
	double x0, x1, y0, y1;
	int logx, logy;
};

/* v on a logarithmic axis; a log axis has no place for v <= 0, which is
 * pinned to the smallest positive double (far below any axis). */
static double axis_value(int lg, double v)
{
	return lg ? log10(fmax(v, DBL_MIN)) : v;
}

static double chart_u(const struct chart *c, double v)
{
	double t = (axis_value(c->logx, v) - c->x0) / (c->x1 - c->x0);
	return c->x + t * c->w;
}

static double chart_v(const struct chart *c, double v)
{
	double t = (axis_value(c->logy, v) - c->y0) / (c->y1 - c->y0);
	return c->y + c->h - t * c->h;
}

static void chart_frame(cairo_t *cr, const struct chart *c, const char *title,
			const char *xlabel, const char *ylabel)
{
	char buf[32];

	font(cr, 9, 1);
	text_at(cr, c->x, c->y - 6, title);
	cairo_set_line_width(cr, 0.6);
	cairo_rectangle(cr, c->x, c->y, c->w, c->h);
	cairo_stroke(cr);
	font(cr, 6.5, 0);
	for (int axis = 0; axis < 2; axis++) {
		double lo = axis ? c->y0 : c->x0, hi = axis ? c->y1 : c->x1;
		int lg = axis ? c->logy : c->logx;
		double step = lg ? 1 : plot_nice_step(hi - lo, 5);
		/* Ticks counted, not summed: each an exact multiple of step. */
		double first = ceil(lo / step - 1e-9);
		int n_ticks = (int)(floor(hi / step + 1e-9) - first) + 1;
		for (int i = 0; i < n_ticks; i++) {
			double t = (first + i) * step;
			double v = lg ? pow(10, t) : t;
			if (lg)
				snprintf(buf, sizeof(buf), "%.0e", v);
			else
				snprintf(buf, sizeof(buf), "%.4g", fabs(v) < 1e-12 * step ? 0 : v);
			if (axis) {
				double py = chart_v(c, v);
				cairo_move_to(cr, c->x - 3, py);
				cairo_line_to(cr, c->x, py);
				cairo_stroke(cr);
				text_at(cr, c->x - 30, py + 2, buf);
			} else {
				double px = chart_u(c, v);
				cairo_move_to(cr, px, c->y + c->h);
				cairo_line_to(cr, px, c->y + c->h + 3);
				cairo_stroke(cr);
				text_at(cr, px - 6, c->y + c->h + 10, buf);
			}
		}
	}
	font(cr, 7, 0);
	text_at(cr, c->x + c->w / 2 - 20, c->y + c->h + 19, xlabel);
	cairo_save(cr);
	cairo_translate(cr, c->x - 33, c->y + c->h / 2 + 20);
	cairo_rotate(cr, -M_PI / 2);
	text_at(cr, 0, 0, ylabel);
	cairo_restore(cr);
}

static void polyline(cairo_t *cr, const struct chart *c, const double *x, const double *y,
		     size_t n, double r, double g, double b)
{
	int pen = 0;

	cairo_save(cr);
	cairo_rectangle(cr, c->x, c->y, c->w, c->h);
	cairo_clip(cr);
	cairo_set_source_rgb(cr, r, g, b);
	cairo_set_line_width(cr, 0.8);
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
		*lo = isfinite(*lo) ? *lo - 1 : -1;
		*hi = isfinite(*hi) ? *hi + 1 : 1;
	}
}

/* The residual along four diameters (0, 45, 90, 135 degrees). */
static int radial_profile(cairo_t *cr, const struct chart *box, const struct asph_report *r)
{
	double ds = r->radius / 150;
	size_t n = asph_profile_length(r->radius, ds);
	_cleanup_free_ double *s = malloc(n * sizeof(double));
	_cleanup_free_ double *z = malloc(4 * n * sizeof(double));
	static const double colours[4][3] = { { 0.1, 0.3, 0.8 }, { 0.8, 0.2, 0.1 },
					      { 0.1, 0.6, 0.2 }, { 0.5, 0.3, 0.6 } };
	struct chart c = *box;

	if (!s || !z)
		return -ENOMEM;
	for (size_t k = 0; k < n; k++)
		s[k] = -r->radius + (double)k * ds;
	for (int a = 0; a < 4; a++)
		asph_profile_sample(r->scatter, a * M_PI / 4, r->radius, ds, z + (size_t)a * n, NULL);
	c.x0 = -r->radius;
	c.x1 = r->radius;
	range_of(z, 4 * n, &c.y0, &c.y1);
	chart_frame(cr, &c, "Radial profiles (0, 45, 90, 135 deg)", "r (mm)", "residual (nm)");
	for (int a = 0; a < 4; a++)
		polyline(cr, &c, s, z + (size_t)a * n, n, colours[a][0], colours[a][1], colours[a][2]);
	return 0;
}

static void zernike_bars(cairo_t *cr, const struct chart *box, const struct asph_fit_result *f)
{
	struct chart c = *box;
	double lo = 0, hi = 0;

	for (int j = 0; j < f->n_zernike; j++) {
		lo = fmin(lo, f->zernike[j].v);
		hi = fmax(hi, f->zernike[j].v);
	}
	if (!(hi > lo))
		hi = lo + 1;
	c.x0 = 0.5;
	c.x1 = f->n_zernike + 0.5;
	c.y0 = lo;
	c.y1 = hi;
	chart_frame(cr, &c, "Zernike terms (Noll)", "j", "coefficient (nm)");
	cairo_set_source_rgb(cr, 0.2, 0.35, 0.7);
	for (int j = 0; j < f->n_zernike; j++) {
		double u0 = chart_u(&c, j + 0.6), u1 = chart_u(&c, j + 1.4);
		double v0 = chart_v(&c, 0), v1 = chart_v(&c, f->zernike[j].v);
		cairo_rectangle(cr, u0, fmin(v0, v1), u1 - u0, fabs(v1 - v0));
	}
	cairo_fill(cr);
}

static void psd_chart(cairo_t *cr, const struct chart *box, const struct asph_report *r)
{
	_cleanup_(asph_psd_freep) struct asph_psd *own = NULL;
	const struct asph_psd *p = r->psd;
	struct chart c = *box;
	double lo = INFINITY, hi = -INFINITY;
	char title[64];

	if (!p && asph_psd_residual(r->scatter, r->radius, &own, NULL) < 0) {
		chart_frame(cr, &c, "PSD: not enough data", "", "");
		return;
	}
	p = p ? p : own;
	_cleanup_free_ double *f = malloc(p->n * sizeof(double));
	if (!f)
		return;
	for (size_t k = 0; k < p->n; k++) {
		f[k] = (double)k * p->df;
		if (k > 0 && p->psd[k] > 0) {
			lo = fmin(lo, p->psd[k]);
			hi = fmax(hi, p->psd[k]);
		}
	}
	c.logx = c.logy = 1;
	c.x0 = floor(log10(p->df));
	c.x1 = ceil(log10((double)(p->n - 1) * p->df));
	c.y0 = isfinite(lo) ? floor(log10(lo)) : 0;
	c.y1 = isfinite(hi) ? ceil(log10(hi)) : 1;
	if (c.y1 - c.y0 > 12)
		c.y0 = c.y1 - 12;
	snprintf(title, sizeof(title), "PSD, mean of %zu diameters (Hann)", p->n_profiles);
	chart_frame(cr, &c, title, "f (1/mm)", "PSD (nm^2 mm)");
	polyline(cr, &c, f + 1, p->psd + 1, p->n - 1, 0.1, 0.1, 0.1);
}

static void residual_map(cairo_t *cr, double x, double y, double w, double h,
			 const struct asph_report *r)
{
	struct asph_plot_panel p = {
		.kind = ASPH_PLOT_POINTS, .n = r->n, .value = r->residual_nm,
		.opts = { .title = "Residual", .colour_label = "nm", .diverging = 1 },
	};
	_cleanup_free_ double *xyz = malloc(3 * r->n * sizeof(double) + 1);
	struct plot_rect panel = { 0, 0, 900, 760 };

	if (!xyz)
		return;
	for (size_t k = 0; k < r->n; k++) {
		xyz[3 * k] = r->xy[2 * k];
		xyz[3 * k + 1] = r->xy[2 * k + 1];
		xyz[3 * k + 2] = 0;
	}
	p.xyz = xyz;
	cairo_save(cr);
	cairo_translate(cr, x, y);
	cairo_scale(cr, w / 900, h / 760);
	plot_draw_panel(cr, &p, &panel);
	cairo_restore(cr);
}

static double header_block(cairo_t *cr, const struct asph_report *r)
{
	const struct asph_fit_result *f = r->fit;
	char line[200], hex[65];
	double y = MARGIN + 14;

	font(cr, 15, 1);
	snprintf(line, sizeof(line), "Form measurement report: %s", r->lens_name ? r->lens_name : "-");
	text_at(cr, MARGIN, y, line);
	y += 20;
	snprintf(line, sizeof(line), "part %s   lot %s   serial %s", r->part ? r->part : "-",
		 r->lot ? r->lot : "-", r->serial ? r->serial : "-");
	y = field_line(cr, y, "Part", line);
	y = provenance(cr, y, "Lens", r->lens_json);
	y = provenance(cr, y, "Plan", r->plan_json);
	y = provenance(cr, y, "Instrument", r->instrument_json);
	if (r->data) {
		sha256_hex(r->data, r->data_len, hex);
		snprintf(line, sizeof(line), "sha256 %s  %s", hex, r->data_name ? r->data_name : "");
		y = field_line(cr, y, "Data", line);
	}
	y = field_line(cr, y, "Software", r->software);
	snprintf(line, sizeof(line), "%zu points, %zu used, %zu outside, %zu outliers; %s residual; %s",
		 f->n_points, f->n_used, f->n_outside_aperture, f->n_outliers,
		 asph_fit_residual_name(f->residual), f->converged ? "converged" : "NOT converged");
	y = field_line(cr, y, "Fit", line);
	snprintf(line, sizeof(line), "RMS %.3f nm, PV %.3f nm, PVr %.3f nm; lambda %g nm; slope length %g mm",
		 f->rms.v, f->pv.v, f->pvr.v, f->form.wavelength_nm, f->slope.length_mm);
	y = field_line(cr, y, "Residual", line);
	snprintf(line, sizeof(line), "%s  (uncertainty: %s)",
		 r->tolerance ? (r->tolerance->callout[0] ? r->tolerance->callout : "see the table")
			      : "none given",
		 asph_uncertainty_method_name(f->uncertainty_k2.method));
	y = field_line(cr, y, "Tolerance", line);
	if (f->verdict.present) {
		y += 6;
		font(cr, 13, 1);
		if (f->verdict.overall == ASPH_VERDICT_FAIL)
			cairo_set_source_rgb(cr, 0.75, 0, 0);
		else if (f->verdict.overall == ASPH_VERDICT_PASS)
			cairo_set_source_rgb(cr, 0, 0.5, 0);
		else
			cairo_set_source_rgb(cr, 0.6, 0.45, 0);
		snprintf(line, sizeof(line), "Verdict (ISO 14253-1): %s",
			 verdict_text(f->verdict.overall));
		text_at(cr, MARGIN, y, line);
		y += 8;
	}
	return y + 10;
}

/* Draws the page on surface (a PDF surface of name) and finishes it. */
static int draw_report(cairo_surface_t *surface, const char *name, const struct asph_report *r,
		       struct asph_error *err)
{
	_cleanup_(cairo_destroyp) cairo_t *cr = cairo_create(surface);
	double y, cw = (PAGE_W - 2 * MARGIN - 60) / 2, ch = 150;
	cairo_status_t st;

	if (cairo_status(cr) != CAIRO_STATUS_SUCCESS)
		return asph_error_set(err, -EIO, "cannot create %s: %s", name,
				      cairo_status_to_string(cairo_status(cr)));
	cairo_pdf_surface_set_metadata(surface, CAIRO_PDF_METADATA_TITLE, "Form measurement report");
	cairo_pdf_surface_set_metadata(surface, CAIRO_PDF_METADATA_CREATOR, "asphd");
	y = header_block(cr, r);
	y = verdict_table(cr, y, r) + 8;
	residual_map(cr, MARGIN, y, 260, 220, r);
	struct chart prof = { MARGIN + 310, y + 20, cw + 10, ch };
	if (radial_profile(cr, &prof, r) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	y += 250;
	struct chart z = { MARGIN + 40, y, cw, ch }, psd = { MARGIN + 80 + cw, y, cw, ch };
	if (r->fit->n_zernike > 0)
		zernike_bars(cr, &z, r->fit);
	psd_chart(cr, &psd, r);
	cairo_show_page(cr);
	cairo_destroy(steal_ptr(cr));
	cairo_surface_finish(surface);
	st = cairo_surface_status(surface);
	if (st != CAIRO_STATUS_SUCCESS)
		return asph_error_set(err, -EIO, "cannot write %s: %s", name, cairo_status_to_string(st));
	return 0;
}

static int check_report(const struct asph_report *r, struct asph_error *err)
{
	if (!r->fit || !r->scatter || !r->xy || !r->residual_nm || r->n == 0 || !(r->radius > 0))
		return asph_error_set(err, -EINVAL, "a report needs a fit and its residual map");
	return 0;
}

int asph_report_write_pdf(const char *path, const struct asph_report *r,
			  struct asph_error *err)
{
	_cleanup_(cairo_surface_destroyp) cairo_surface_t *surface = NULL;
	int rc = check_report(r, err);

	if (rc < 0)
		return rc;
	surface = cairo_pdf_surface_create(path, PAGE_W, PAGE_H);
	return draw_report(surface, path, r, err);
}

int asph_report_write_pdf_stream(FILE *f, const char *name, const struct asph_report *r,
				 struct asph_error *err)
{
	_cleanup_(cairo_surface_destroyp) cairo_surface_t *surface = NULL;
	int rc = check_report(r, err);

	if (rc < 0)
		return rc;
	surface = cairo_pdf_surface_create_for_stream(plot_write_to_file, f, PAGE_W, PAGE_H);
	rc = draw_report(surface, name, r, err);
	if (rc == 0 && fflush(f) != 0)
		return asph_error_set(err, -errno, "cannot write %s: %s", name, strerror(errno));
	return rc;
}

#else /* !HAVE_CAIRO */

int asph_report_write_pdf(const char *path, const struct asph_report *r,
			  struct asph_error *err)
{
	return asph_error_set(err, -ENOTSUP,
			      "the PDF report needs cairo, and this libasph was built without it");
}

int asph_report_write_pdf_stream(FILE *f, const char *name, const struct asph_report *r,
				 struct asph_error *err)
{
	return asph_report_write_pdf(name, r, err);
}

#endif
