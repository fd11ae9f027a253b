/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The measurement report as A4 PDF pages (cairo's PDF surface). The pages
 * are laid out twice with the same code: a first pass measures (nothing is
 * shown) and counts the pages, the second draws them with "page i of n".
 * Every text goes through report_text_wrap() inside its column, and a
 * block that does not fit on the page starts the next one.
 */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>
#include "util-hash.h"

#include "config.h"
#include "asph/report.h"
#include "plot-layout.h"
#include "quantity.h"
#include "util-mem.h"
#include "util-time.h"

#if HAVE_CAIRO
#include <cairo-pdf.h>

#include "report-chart.h"
#include "report-text.h"

#define PAGE_W 595.276          /* A4, points */
#define PAGE_H 841.890
#define MARGIN 42.52            /* 15 mm */
#define CONTENT_W (PAGE_W - 2 * MARGIN)
#define FOOTER_H 18.0           /* kept free above the bottom margin */
#define BOTTOM (PAGE_H - MARGIN - FOOTER_H)
#define BODY 8.0
#define SMALL REPORT_MIN_TEXT
#define LEAD 1.3                /* line spacing / font size */
#define LABEL_W 86.0            /* the label column of the fields */
#define FIGURE_H 300.0          /* the map and the profiles */
#define CHART_H 200.0           /* the Zernike terms and the PSD */

DEFINE_TRIVIAL_CLEANUP_FUNC(cairo_t *, cairo_destroy)
DEFINE_TRIVIAL_CLEANUP_FUNC(cairo_surface_t *, cairo_surface_destroy)

struct style {
	enum report_face face;
	double size;
	double grey;            /* 0 black */
};

static const struct style body = { REPORT_SANS, BODY, 0 };
static const struct style bold = { REPORT_SANS_BOLD, BODY, 0 };
static const struct style hash_style = { REPORT_MONO, SMALL, 0.3 };
static const struct style note_style = { REPORT_SANS, SMALL, 0.25 };
static const struct style heading = { REPORT_SANS_BOLD, 11, 0 };

/* A description (lens, plan, instrument): its text as given, hashed. */
struct description {
	const char *title;      /* "Lens prescription", ... */
	const char *text;       /* NULL: not known */
	char *clean;
	char sha256[65];
	char *summary;          /* name and type; NULL on ENOMEM */
};

enum { DESC_LENS, DESC_PLAN, DESC_INSTRUMENT, N_DESC };

struct doc {
	cairo_t *cr;
	const struct asph_report *r;
	int drawing;            /* 0: the measuring pass */
	int page, n_pages;
	double y;               /* the top of the free space on the page */
	const char *continued;  /* the section a new page continues */
	int appendix_page;      /* where the descriptions in full begin */
	double noise_nm;        /* > 0: the residual is numerical noise */
	int error;              /* -ENOMEM when a text could not be laid out */
	char measured[160], reported[64];
	char *identity;         /* lens, part, lot, serial: the running footer */
	char *part, *lot, *serial, *operator_name, *lens_name, *label, *software, *data_name,
		*instrument_name;
	struct description desc[N_DESC];
};

/* ---------------------------------------------------------------- text */

static void set_style(struct doc *d, const struct style *s)
{
	report_font(d->cr, s->face, s->size);
	cairo_set_source_rgb(d->cr, s->grey, s->grey, s->grey);
}

static void show(struct doc *d, double x, double baseline, const char *s, size_t len)
{
	_cleanup_free_ char *t = NULL;

	if (!d->drawing || len == 0)
		return;
	t = strndup(s, len);
	if (!t) {
		d->error = -ENOMEM;
		return;
	}
	cairo_move_to(d->cr, x, baseline);
	cairo_show_text(d->cr, t);
}

static void start_page(struct doc *d);

static void new_page(struct doc *d)
{
	if (d->drawing)
		cairo_show_page(d->cr);
	d->page++;
	start_page(d);
}

/* Starts a new page unless h more points fit on this one (or the page is
 * still empty: a block taller than a page is then split by lines). */
static void need(struct doc *d, double h)
{
	if (d->y + h > BOTTOM && d->y > MARGIN + 40)
		new_page(d);
}

/* text wrapped to width at x, line by line across pages. Returns the
 * number of lines (0 on ENOMEM, which d->error keeps). */
static size_t paragraph(struct doc *d, double x, double width, const struct style *s,
			const char *text)
{
	struct report_lines l = { 0 };
	double lead = LEAD * s->size;

	set_style(d, s);
	if (report_text_wrap(d->cr, text, width, &l) < 0) {
		d->error = -ENOMEM;
		l.n = 0;
	}
	for (size_t i = 0; i < l.n; i++) {
		need(d, lead);
		set_style(d, s);
		show(d, x, d->y + s->size, l.v[i].s, l.v[i].len);
		d->y += lead;
	}
	size_t n = l.n;
	report_lines_release(&l);
	return n;
}

/* text (clean) wrapped into a cell of width, left or right aligned, from
 * the top y; returns its lines. */
static size_t cell(struct doc *d, double x, double y, double width, int right,
		   const struct style *s, const char *text, int draw)
{
	struct report_lines l = { 0 };

	set_style(d, s);
	if (report_text_wrap(d->cr, text, width, &l) < 0) {
		d->error = -ENOMEM;
		l.n = 0;
	}
	for (size_t i = 0; draw && i < l.n; i++) {
		double w = right ? report_text_width(d->cr, l.v[i].s, l.v[i].len) : 0;
		show(d, right ? x + width - w : x, y + (double)i * LEAD * s->size + s->size,
		     l.v[i].s, l.v[i].len);
	}
	size_t n = l.n;
	report_lines_release(&l);
	return n;
}

/* A text made safe for cairo, "" for NULL; NULL on ENOMEM. */
static char *clean_text(const char *text)
{
	return report_text_clean(text ? text : "");
}

/* "label  value" with the value wrapped in its column, kept on one page
 * unless it is taller than a page. A hash, when given, follows on a line
 * of its own in the mono face. */
static void field(struct doc *d, const char *label, const char *value, const char *sha256)
{
	_cleanup_free_ char *v = clean_text(value);
	char hash[80] = "";
	size_t nl, nv, nh = 0;

	if (!v) {
		d->error = -ENOMEM;
		return;
	}
	if (sha256)
		snprintf(hash, sizeof(hash), "SHA-256 %s", sha256);
	nl = cell(d, MARGIN, d->y, LABEL_W - 6, 0, &bold, label, 0);
	nv = cell(d, MARGIN + LABEL_W, d->y, CONTENT_W - LABEL_W, 0, &body, v, 0);
	if (sha256)
		nh = cell(d, MARGIN + LABEL_W, d->y, CONTENT_W - LABEL_W, 0, &hash_style, hash, 0);
	double hl = (double)nl * LEAD * BODY;
	double hv = (double)nv * LEAD * BODY + (double)nh * LEAD * SMALL;
	if (fmax(hl, hv) < BOTTOM - MARGIN - 60) {
		need(d, fmax(hl, hv));
		cell(d, MARGIN, d->y, LABEL_W - 6, 0, &bold, label, 1);
		cell(d, MARGIN + LABEL_W, d->y, CONTENT_W - LABEL_W, 0, &body, v, 1);
		if (sha256)
			cell(d, MARGIN + LABEL_W, d->y + (double)nv * LEAD * BODY,
			     CONTENT_W - LABEL_W, 0, &hash_style, hash, 1);
		d->y += fmax(hl, hv);
		return;
	}
	/* taller than a page: the label, then the value line by line */
	cell(d, MARGIN, d->y, LABEL_W - 6, 0, &bold, label, 1);
	paragraph(d, MARGIN + LABEL_W, CONTENT_W - LABEL_W, &body, v);
	if (sha256)
		paragraph(d, MARGIN + LABEL_W, CONTENT_W - LABEL_W, &hash_style, hash);
}

static void rule(struct doc *d, double gap)
{
	d->y += gap / 2;
	if (d->drawing) {
		cairo_set_source_rgb(d->cr, 0.55, 0.55, 0.55);
		cairo_set_line_width(d->cr, 0.5);
		cairo_move_to(d->cr, MARGIN, d->y);
		cairo_line_to(d->cr, PAGE_W - MARGIN, d->y);
		cairo_stroke(d->cr);
	}
	d->y += gap / 2;
}

/* text, or its first line wrapped to width with "…" after it: for the
 * running footer only, everything it names being in full on page 1. NULL
 * on ENOMEM. */
static char *shortened(cairo_t *cr, const char *text, double width)
{
	struct report_lines l = { 0 };
	char *out = NULL;

	if (report_text_width(cr, text, strlen(text)) <= width)
		return strdup(text);
	if (report_text_wrap(cr, text, width - report_text_width(cr, "…", strlen("…")), &l) == 0 &&
	    asprintf(&out, "%.*s…", (int)l.v[0].len, l.v[0].s) < 0)
		out = NULL;
	report_lines_release(&l);
	return out;
}

static void start_page(struct doc *d)
{
	char right[48];

	d->y = MARGIN;
	if (d->drawing) {
		set_style(d, &note_style);
		snprintf(right, sizeof(right), "page %d of %d", d->page, d->n_pages);
		double rw = report_text_width(d->cr, right, strlen(right));
		_cleanup_free_ char *left = shortened(d->cr, d->identity, CONTENT_W - rw - 20);
		double base = PAGE_H - MARGIN - 0.3 * SMALL;
		if (left)
			show(d, MARGIN, base, left, strlen(left));
		show(d, PAGE_W - MARGIN - rw, base, right, strlen(right));
		cairo_set_line_width(d->cr, 0.5);
		cairo_move_to(d->cr, MARGIN, base - SMALL - 3);
		cairo_line_to(d->cr, PAGE_W - MARGIN, base - SMALL - 3);
		cairo_stroke(d->cr);
	}
	if (d->page > 1 && d->continued) {
		char h[96];
		snprintf(h, sizeof(h), "%s (continued)", d->continued);
		paragraph(d, MARGIN, CONTENT_W, &bold, h);
		d->y += 4;
	}
}

/* ----------------------------------------------------------- summaries */

static const char *member_string(const json_t *o, const char *key)
{
	return json_string_value(json_object_get(o, key));
}

/* "stage mock 2.0": the driver of one role of an instrument. */
static char *driver_of(const json_t *inst, const char *role)
{
	const json_t *r = json_object_get(inst, role);
	const char *drv = member_string(r, "driver"), *ver = member_string(r, "version");
	char *s;

	if (asprintf(&s, "%s %s%s%s", role, drv ? drv : "?", ver ? " " : "", ver ? ver : "") < 0)
		return NULL;
	return s;
}

/* The name and type of a description: the lens's type, the plan's method
 * and points, the instrument's drivers. NULL on ENOMEM. */
static char *summarise(const char *text, int which, const char *name)
{
	_cleanup_(json_decrefp) json_t *j = json_loads(text, 0, NULL);
	_cleanup_free_ char *stage = NULL, *probe = NULL;
	const char *s;
	char *out = NULL;
	int r;

	if (!j) {
		r = asprintf(&out, "%s (not JSON)", name ? name : "");
	} else if (which == DESC_LENS) {
		s = member_string(j, "type");
		r = asprintf(&out, "%s (%s)", name ? name : "", s ? s : "type not given");
	} else if (which == DESC_PLAN) {
		json_int_t points = json_integer_value(json_object_get(j, "points"));
		s = member_string(j, "method");
		r = points > 0 ? asprintf(&out, "method %s, %lld points", s ? s : "not given",
					  (long long)points)
			       : asprintf(&out, "method %s", s ? s : "not given");
	} else {
		stage = driver_of(j, "stage");
		probe = driver_of(j, "probe");
		s = name ? name : member_string(j, "name");
		r = asprintf(&out, "%s: %s, %s", s ? s : "-", stage ? stage : "",
			     probe ? probe : "");
	}
	return r < 0 ? NULL : out;
}

/* ISO 8601 in the local time zone with its offset; "not known" for 0. */
static void when(int64_t ns, char *buf, size_t size)
{
	if (ns == 0)
		snprintf(buf, size, "not known");
	else
		iso8601_local(ns, buf, size);
}

static void measured_text(const struct asph_report *r, char *buf, size_t size)
{
	char a[ISO8601_SIZE], b[ISO8601_SIZE];

	if (r->measured_ns == 0) {
		snprintf(buf, size, "not known");
		return;
	}
	when(r->measured_ns, a, sizeof(a));
	if (r->measured_end_ns < r->measured_ns) {
		snprintf(buf, size, "%s", a);
		return;
	}
	when(r->measured_end_ns, b, sizeof(b));
	double s = (double)(r->measured_end_ns - r->measured_ns) / 1e9;
	if (s < 120)
		snprintf(buf, size, "%s to %s (%.0f s)", a, b, s);
	else
		snprintf(buf, size, "%s to %s (%.0f min)", a, b, s / 60);
}

/* ------------------------------------------------------------- page 1 */

static void title_block(struct doc *d)
{
	_cleanup_free_ char *lens = NULL;

	paragraph(d, MARGIN, CONTENT_W, &(struct style){ REPORT_SANS_BOLD, 17, 0 },
		  "Form measurement report");
	d->y += 2;
	if (asprintf(&lens, "Optical asphere, lens %s", d->lens_name) < 0)
		lens = NULL;
	paragraph(d, MARGIN, CONTENT_W, &(struct style){ REPORT_SANS, 11, 0.15 },
		  lens ? lens : "Optical asphere");
	rule(d, 8);
}

/* Part, lot and serial side by side, each wrapped in its third; one under
 * the other when that row would be taller than a page. */
static void identity_row(struct doc *d)
{
	const char *labels[3] = { "Part", "Lot", "Serial" };
	const char *values[3] = { d->part, d->lot, d->serial };
	double w = CONTENT_W / 3, lw = 34;
	size_t most = 1;

	for (int draw = 0; draw < 2; draw++) {
		if (draw && (double)most * LEAD * 9 > BOTTOM - MARGIN - 60) {
			for (int i = 0; i < 3; i++)
				field(d, labels[i], values[i][0] ? values[i] : "not given", NULL);
			return;
		}
		for (int i = 0; i < 3; i++) {
			double x = MARGIN + i * w;
			const char *v = values[i][0] ? values[i] : "not given";
			/* on the baseline of the larger value */
			cell(d, x, d->y + 9 - BODY, lw, 0, &bold, labels[i], draw);
			size_t n = cell(d, x + lw, d->y, w - lw - 8, 0,
					&(struct style){ REPORT_SANS_BOLD, 9, 0 }, v, draw);
			most = n > most ? n : most;
		}
		if (!draw && (double)most * LEAD * 9 <= BOTTOM - MARGIN - 60)
			need(d, (double)most * LEAD * 9);
	}
	d->y += (double)most * LEAD * 9 + 2;
}

static void identification(struct doc *d)
{
	const struct asph_report *r = d->r;
	_cleanup_free_ char *job = NULL, *rep = NULL;

	identity_row(d);
	field(d, "Measured", d->measured, NULL);
	field(d, "Operator", d->operator_name[0] ? d->operator_name : "not given", NULL);
	field(d, "Instrument",
	      d->desc[DESC_INSTRUMENT].text ? d->desc[DESC_INSTRUMENT].summary
	      : d->instrument_name[0]       ? d->instrument_name
					    : "not known",
	      d->desc[DESC_INSTRUMENT].text ? d->desc[DESC_INSTRUMENT].sha256 : NULL);
	if (r->job > 0) {
		if (asprintf(&job, "%lld%s%s", (long long)r->job, d->label[0] ? ", label: " : "",
			     d->label) < 0)
			job = NULL;
		field(d, "Job", job ? job : "", NULL);
	}
	if (asprintf(&rep, "%s by %s", d->reported, d->software[0] ? d->software : "-") < 0)
		rep = NULL;
	field(d, "Report issued", rep ? rep : d->reported, NULL);
	rule(d, 8);
}

static void fit_line(const struct asph_fit_result *f, char *buf, size_t size)
{
	snprintf(buf, size,
		 "%zu points, %zu used, %zu outside the aperture, %zu outliers; %s residual; "
		 "%s after %d iterations",
		 f->n_points, f->n_used, f->n_outside_aperture, f->n_outliers,
		 asph_fit_residual_name(f->residual), f->converged ? "converged" : "NOT converged",
		 f->iterations);
}

/* v as the quantity at path prints (quantity.h); flags: enum
 * quantity_format_flags. */
static const char *figure(char *buf, size_t size, const char *path, double v, unsigned flags)
{
	return quantity_format(quantity_by_path(path), v, flags, buf, size);
}

static void tolerance_line(const struct asph_report *r, char *buf, size_t size)
{
	const struct asph_tolerance *t = r->tolerance;

	if (!t) {
		snprintf(buf, size, "none given: no verdict");
		return;
	}
	char lambda[32];

	snprintf(buf, size, "%s%s; fringes of λ = %s nm; decision rule ISO 14253-1",
		 t->callout[0] ? "ISO 10110-5 " : "limits in the table",
		 t->callout[0] ? t->callout : "",
		 figure(lambda, sizeof(lambda), "form.wavelength_nm", r->fit->form.wavelength_nm, 0));
}

static void measurement(struct doc *d)
{
	const struct asph_report *r = d->r;
	_cleanup_free_ char *data = NULL;
	char line[512];

	for (int i = 0; i < N_DESC; i++) {
		if (i == DESC_INSTRUMENT)
			continue;
		field(d, i == DESC_LENS ? "Lens" : "Plan",
		      d->desc[i].text ? d->desc[i].summary : "not known",
		      d->desc[i].text ? d->desc[i].sha256 : NULL);
	}
	if (r->data) {
		char hex[65];
		if (r->data_sha256)
			snprintf(hex, sizeof(hex), "%s", r->data_sha256);
		else
			sha256_hex(r->data, r->data_len, hex);
		if (asprintf(&data, "%s (%zu bytes)", d->data_name, r->data_len) < 0)
			data = NULL;
		field(d, "Data", data ? data : d->data_name, hex);
	}
	fit_line(r->fit, line, sizeof(line));
	field(d, "Fit", line, NULL);
	tolerance_line(r, line, sizeof(line));
	field(d, "Tolerance", line, NULL);
	if (d->desc[DESC_LENS].text || d->desc[DESC_PLAN].text || d->desc[DESC_INSTRUMENT].text) {
		/* the measuring pass has no page number yet: 0 stands in */
		snprintf(line, sizeof(line),
			 "The lens, plan and instrument descriptions are given in full from page %d.",
			 d->appendix_page);
		paragraph(d, MARGIN + LABEL_W, CONTENT_W - LABEL_W, &note_style, line);
	}
	d->y += 6;
}

static void verdict_colour(cairo_t *cr, enum asph_verdict v)
{
	if (v == ASPH_VERDICT_FAIL)
		cairo_set_source_rgb(cr, 0.75, 0.05, 0.05);
	else if (v == ASPH_VERDICT_PASS)
		cairo_set_source_rgb(cr, 0.0, 0.5, 0.15);
	else
		cairo_set_source_rgb(cr, 0.65, 0.45, 0.0);
}

static void verdict_banner(struct doc *d)
{
	const struct asph_fit_result *f = d->r->fit;
	char line[128];
	double h = 24;

	need(d, h + 6);
	if (!f->verdict.present) {
		paragraph(d, MARGIN, CONTENT_W, &bold, "No tolerance was given: no verdict.");
		d->y += 4;
		return;
	}
	snprintf(line, sizeof(line), "Verdict (ISO 14253-1): %s",
		 asph_verdict_name(f->verdict.overall));
	if (d->drawing) {
		verdict_colour(d->cr, f->verdict.overall);
		cairo_set_line_width(d->cr, 1.2);
		cairo_rectangle(d->cr, MARGIN, d->y, CONTENT_W, h);
		cairo_stroke(d->cr);
		report_font(d->cr, REPORT_SANS_BOLD, 13);
		verdict_colour(d->cr, f->verdict.overall);
		show(d, MARGIN + 8, d->y + h / 2 + 4.5, line, strlen(line));
	}
	d->y += h + 8;
}

/* One row of the table: what it says, the quantity's path in the summary
 * (quantity.h: its decimals, sign, zone and verdict item), value and U. */
struct result_row {
	const char *name, *path;
	double value, U;
};

#define N_COLS 5
static const double col_x[N_COLS] = { 0, 226, 300, 370, 436 };
static const double col_w[N_COLS] = { 220, 68, 64, 60, 75 };

static void table_row(struct doc *d, const char *cells[N_COLS], const struct style *s,
		      const struct asph_verdict_item *it)
{
	size_t most = 1;

	for (int c = 0; c < N_COLS; c++) {
		size_t n = cell(d, MARGIN + col_x[c], d->y, col_w[c], c > 0 && c < 4, s, cells[c], 0);
		most = n > most ? n : most;
	}
	need(d, (double)most * LEAD * s->size);
	for (int c = 0; c < N_COLS; c++) {
		if (c == 4 && it && d->drawing) {
			report_font(d->cr, REPORT_SANS_BOLD, BODY);
			verdict_colour(d->cr, it->verdict);
			show(d, MARGIN + col_x[c], d->y + BODY, cells[c], strlen(cells[c]));
			continue;
		}
		cell(d, MARGIN + col_x[c], d->y, col_w[c], c > 0 && c < 4, s, cells[c], 1);
	}
	d->y += (double)most * LEAD * s->size + 1.5;
}

static const struct asph_verdict_item *verdict_item(const struct asph_fit_result *f,
						    const char *key)
{
	for (size_t k = 0; k < f->verdict.n_items; k++)
		if (!strcmp(f->verdict.items[k].quantity, key))
			return &f->verdict.items[k];
	return NULL;
}

static void results_table(struct doc *d)
{
	const struct asph_fit_result *f = d->r->fit;
	const struct asph_uncertainty_k2 *u = &f->uncertainty_k2;
	char len[32], slope_rms[96], slope_max[96];
	const char *head[N_COLS] = { "quantity", "value", "U (k = 2)", "limit", "verdict" };

	figure(len, sizeof(len), "slope.length_mm", f->slope.length_mm, 0);
	snprintf(slope_rms, sizeof(slope_rms), "slope deviation RMS over %s mm", len);
	snprintf(slope_max, sizeof(slope_max), "slope deviation max over %s mm", len);
	const struct result_row rows[] = {
		{ "A, sagitta deviation", "form.A_nm", f->form.A.v, u->A.v },
		{ "B, irregularity", "form.B_nm", f->form.B.v, u->B.v },
		{ "C, rotationally symmetric irregularity", "form.C_nm", f->form.C.v, u->C.v },
		{ "RMSt, total RMS deviation", "form.rms_t_nm", f->form.rms_t.v, u->rms_t.v },
		{ "RMSi, RMS irregularity", "form.rms_i_nm", f->form.rms_i.v, u->rms_i.v },
		{ "RMSa, RMS of the rotationally variant part", "form.rms_a_nm", f->form.rms_a.v,
		  u->rms_a.v },
		{ slope_rms, "slope.rms_urad", f->slope.rms.v, u->slope_rms.v },
		{ slope_max, "slope.max_urad", f->slope.max.v, u->slope_max.v },
		{ "R − R₀, radius deviation", "radius.deviation_mm", f->R_deviation_mm, u->R_mm },
	};

	need(d, 4 * LEAD * BODY);
	table_row(d, head, &bold, NULL);
	if (d->drawing) {
		cairo_set_source_rgb(d->cr, 0, 0, 0);
		cairo_set_line_width(d->cr, 0.5);
		cairo_move_to(d->cr, MARGIN, d->y);
		cairo_line_to(d->cr, PAGE_W - MARGIN, d->y);
		cairo_stroke(d->cr);
	}
	d->y += 2;
	for (size_t i = 0; i < sizeof(rows) / sizeof(rows[0]); i++) {
		const struct quantity *q = quantity_by_path(rows[i].path);
		const struct asph_verdict_item *it = verdict_item(f, q->verdict);
		char name[160], value[64], U[64], limit[72] = "-";
		if (isnan(rows[i].value) && !it)
			continue;
		snprintf(name, sizeof(name), "%s (%s)", rows[i].name, quantity_symbol(q));
		quantity_format(q, rows[i].value, 0, value, sizeof(value));
		quantity_format(q, rows[i].U, QUANTITY_NO_SIGN, U, sizeof(U));
		if (it) {
			char l[64];
			quantity_format(q, it->limit, QUANTITY_NO_SIGN, l, sizeof(l));
			/* a zone two-sided about zero: ±L */
			snprintf(limit, sizeof(limit), "%s%s", q->two_sided ? "±" : "", l);
		}
		const char *cells[N_COLS] = { name, value, U, limit,
					      it ? asph_verdict_name(it->verdict) : "" };
		table_row(d, cells, &body, it);
	}
	d->y += 3;
	char note[512];
	snprintf(note, sizeof(note),
		 "U: expanded uncertainty, coverage factor k = 2 (%s). A and R − R₀ carry their "
		 "sign; their limit applies to the magnitude (±L). The slope deviation is the "
		 "difference quotient of the residual over the evaluation length.",
		 asph_uncertainty_method_name(u->method));
	paragraph(d, MARGIN, CONTENT_W, &note_style, note);
	d->y += 4;
}

static void residual_line(struct doc *d)
{
	const struct asph_fit_result *f = d->r->fit;
	char rms[32], pv[32], pvr[32], line[256];

	snprintf(line, sizeof(line),
		 "RMS %s nm (standard deviation about the mean), PV %s nm, PVr %s nm",
		 figure(rms, sizeof(rms), "rms_nm", f->rms.v, 0),
		 figure(pv, sizeof(pv), "pv_nm", f->pv.v, 0),
		 figure(pvr, sizeof(pvr), "pvr_nm", f->pvr.v, 0));
	field(d, "Residual", line, NULL);
	d->y += 6;
}

static int figures(struct doc *d)
{
	double wmap = 300;
	struct report_rect map = { MARGIN, d->y, wmap, FIGURE_H };
	struct report_rect prof = { MARGIN + wmap + 14, d->y, CONTENT_W - wmap - 14, FIGURE_H };
	int r = 0;

	need(d, FIGURE_H);
	map.y = prof.y = d->y;
	if (d->drawing) {
		r = report_map(d->cr, &map, d->r, d->noise_nm);
		if (r == 0)
			r = report_profiles(d->cr, &prof, d->r, d->noise_nm);
	}
	d->y += FIGURE_H + 6;
	return r;
}

/* ------------------------------------------------------------- page 2 */

static void section(struct doc *d, const char *title)
{
	need(d, 40);
	d->y += 4;
	paragraph(d, MARGIN, CONTENT_W, &heading, title);
	d->y += 3;
}

static void pose_table(struct doc *d)
{
	const struct asph_fit_result *f = d->r->fit;
	const char *head[N_COLS] = { "degree of freedom", "value", "u (k = 1)", "unit", "" };

	section(d, "Alignment of the part (best fit)");
	table_row(d, head, &bold, NULL);
	for (int k = 0; k < ASPH_FIT_N_DOF; k++) {
		/* shifts in µm, tilts in µrad, as the text output gives them */
		char path[32], value[64], u[64];
		if (!(f->dof & ASPH_FIT_DOF_BIT(k)))
			continue;
		snprintf(path, sizeof(path), "dof.%s", asph_fit_dof_name((enum asph_fit_dof)k));
		const struct quantity *q = quantity_by_path(path);
		quantity_format(q, f->value[k], 0, value, sizeof(value));
		quantity_format(q, f->uncertainty[k], QUANTITY_NO_SIGN, u, sizeof(u));
		const char *cells[N_COLS] = { asph_fit_dof_name((enum asph_fit_dof)k), value, u,
					      quantity_symbol(q), "" };
		table_row(d, cells, &body, NULL);
	}
	char note[256], sigma[32];
	snprintf(note, sizeof(note), "u: standard uncertainty of the fit (residual σ = %s nm). %s",
		 figure(sigma, sizeof(sigma), "sigma_nm", f->sigma_mm * 1e6, 0), f->reason);
	paragraph(d, MARGIN, CONTENT_W, &note_style, note);
}

static void residual_details(struct doc *d)
{
	const struct asph_fit_result *f = d->r->fit;
	char a[32], b[32], c[32], e[32], line[512];

	section(d, "Residual and slope");
	snprintf(line, sizeof(line),
		 "RMS %s nm (standard deviation about the mean), PV %s nm, PVr %s nm "
		 "(PV of the %d-term Zernike fit + 3 × the RMS it leaves, %s nm)",
		 figure(a, sizeof(a), "rms_nm", f->rms.v, 0),
		 figure(b, sizeof(b), "pv_nm", f->pv.v, 0),
		 figure(c, sizeof(c), "pvr_nm", f->pvr.v, 0), f->n_zernike,
		 figure(e, sizeof(e), "zernike_fit_rms_left_nm", f->zernike_fit_rms_left.v, 0));
	field(d, "Amplitude", line, NULL);
	snprintf(line, sizeof(line), "Zernike slope RMS %s µrad (the gradient of the Zernike fit)",
		 figure(a, sizeof(a), "slope_rms_urad", f->slope_rms.v, 0));
	field(d, "Slope", line, NULL);
	if (f->slope_valid) {
		char len[32];
		snprintf(line, sizeof(line),
			 "over %s mm at %zu positions: radial RMS %s µrad, max %s µrad; azimuthal RMS "
			 "%s µrad, max %s µrad",
			 figure(len, sizeof(len), "slope.length_mm", f->slope.length_mm, 0),
			 f->slope.n,
			 figure(a, sizeof(a), "slope.rms_radial_urad", f->slope.rms_radial.v, 0),
			 figure(c, sizeof(c), "slope.max_radial_urad", f->slope.max_radial.v, 0),
			 figure(b, sizeof(b), "slope.rms_azimuthal_urad", f->slope.rms_azimuthal.v, 0),
			 figure(e, sizeof(e), "slope.max_azimuthal_urad", f->slope.max_azimuthal.v, 0));
		field(d, "Slope deviation", line, NULL);
	}
	if (f->form_valid) {
		const struct asph_uncertainty_k2 *u = &f->uncertainty_k2;
		char ua[32], ub[32], uc[32], lambda[32];
		snprintf(line, sizeof(line),
			 "A %s (U %s), B %s (U %s), C %s (U %s) fringes of λ = %s nm (λ/2 of height)",
			 figure(a, sizeof(a), "form.A_fringes", f->form.A_fringes, 0),
			 figure(ua, sizeof(ua), "form.A_fringes", u->A_fringes, QUANTITY_NO_SIGN),
			 figure(b, sizeof(b), "form.B_fringes", f->form.B_fringes, 0),
			 figure(ub, sizeof(ub), "form.B_fringes", u->B_fringes, QUANTITY_NO_SIGN),
			 figure(c, sizeof(c), "form.C_fringes", f->form.C_fringes, 0),
			 figure(uc, sizeof(uc), "form.C_fringes", u->C_fringes, QUANTITY_NO_SIGN),
			 figure(lambda, sizeof(lambda), "form.wavelength_nm", f->form.wavelength_nm, 0));
		field(d, "In fringes", line, NULL);
	}
}

static int zernike_and_psd(struct doc *d)
{
	double w = (CONTENT_W - 16) / 2;
	struct report_rect z = { MARGIN, 0, w, CHART_H }, p = { MARGIN + w + 16, 0, w, CHART_H };
	int r = 0;

	need(d, CHART_H + 10);
	d->y += 8;
	z.y = p.y = d->y;
	if (d->drawing) {
		if (d->r->fit->n_zernike > 0)
			report_zernike(d->cr, &z, d->r->fit);
		r = report_psd(d->cr, &p, d->r);
	}
	d->y += CHART_H + 4;
	return r;
}

static void zernike_table(struct doc *d)
{
	const struct asph_fit_result *f = d->r->fit;
	int rows = (f->n_zernike + 3) / 4;

	if (f->n_zernike == 0)
		return;
	section(d, "Zernike coefficients of the residual (Noll order, nm, over the aperture)");
	for (int i = 0; i < rows; i++) {
		need(d, LEAD * BODY);
		for (int c = 0; c < 4; c++) {
			int j = c * rows + i;
			char name[16], v[48];
			if (j >= f->n_zernike)
				continue;
			snprintf(name, sizeof(name), "Z%d", j + 1);
			figure(v, sizeof(v), "zernike_nm", f->zernike[j].v, 0);
			double x = MARGIN + c * CONTENT_W / 4;
			cell(d, x, d->y, 30, 0, &bold, name, 1);
			cell(d, x + 30, d->y, CONTENT_W / 4 - 48, 1, &body, v, 1);
		}
		d->y += LEAD * BODY;
	}
	paragraph(d, MARGIN, CONTENT_W, &note_style,
		  "Z1 to Z3 (piston and tilt) are mostly taken up by the fitted rigid-body "
		  "degrees of freedom.");
}

/* ----------------------------------------------------------- appendix */

static void descriptions(struct doc *d)
{
	d->appendix_page = d->page;
	section(d, "Descriptions in full");
	paragraph(d, MARGIN, CONTENT_W, &note_style,
		  "Each text exactly as hashed (SHA-256 of its bytes), wrapped at the margin.");
	for (int i = 0; i < N_DESC; i++) {
		struct description *ds = &d->desc[i];
		char hash[80];
		if (!ds->text)
			continue;
		need(d, 4 * LEAD * BODY);
		d->y += 6;
		paragraph(d, MARGIN, CONTENT_W, &bold, ds->title);
		snprintf(hash, sizeof(hash), "SHA-256 %s", ds->sha256);
		paragraph(d, MARGIN, CONTENT_W, &hash_style, hash);
		d->y += 2;
		d->continued = ds->title;
		paragraph(d, MARGIN, CONTENT_W, &(struct style){ REPORT_MONO, SMALL, 0 }, ds->clean);
		d->continued = NULL;
	}
}

/* ---------------------------------------------------------------- pages */

static int layout(struct doc *d)
{
	int r;

	d->page = 1;
	start_page(d);
	title_block(d);
	identification(d);
	measurement(d);
	verdict_banner(d);
	results_table(d);
	residual_line(d);
	r = figures(d);
	if (r < 0)
		return r;

	new_page(d);
	paragraph(d, MARGIN, CONTENT_W, &(struct style){ REPORT_SANS_BOLD, 14, 0 },
		  "Details of the characterization");
	pose_table(d);
	residual_details(d);
	r = zernike_and_psd(d);
	if (r < 0)
		return r;
	zernike_table(d);

	for (int i = 0; i < N_DESC; i++)
		if (d->desc[i].text) {
			new_page(d);
			descriptions(d);
			break;
		}
	if (d->drawing)
		cairo_show_page(d->cr);
	return d->error;
}

/* ------------------------------------------------------------ the doc */

static int doc_init(struct doc *d, const struct asph_report *r)
{
	static const char *const titles[N_DESC] = { "Lens prescription", "Sampling plan",
						    "Instrument" };
	const char *texts[N_DESC] = { r->lens_json, r->plan_json, r->instrument_json };
	memset(d, 0, sizeof(*d));
	d->r = r;
	d->part = clean_text(r->part);
	d->lot = clean_text(r->lot);
	d->serial = clean_text(r->serial);
	d->operator_name = clean_text(r->operator_name);
	d->lens_name = clean_text(r->lens_name ? r->lens_name : "not named");
	d->label = clean_text(r->label);
	d->software = clean_text(r->software);
	d->data_name = clean_text(r->data_name ? r->data_name : "the measured points");
	d->instrument_name = clean_text(r->instrument_name);
	if (!d->part || !d->lot || !d->serial || !d->operator_name || !d->lens_name || !d->label ||
	    !d->software || !d->data_name || !d->instrument_name)
		return -ENOMEM;
	for (int i = 0; i < N_DESC; i++) {
		struct description *ds = &d->desc[i];
		ds->title = titles[i];
		ds->text = texts[i];
		if (!ds->text)
			continue;
		ds->clean = clean_text(ds->text);
		if (!ds->clean)
			return -ENOMEM;
		sha256_hex(ds->text, strlen(ds->text), ds->sha256);
		ds->summary = summarise(ds->text, i,
					i == DESC_LENS ? d->lens_name
					: i == DESC_INSTRUMENT && d->instrument_name[0] ? d->instrument_name
											: NULL);
		if (!ds->summary)
			return -ENOMEM;
	}
	measured_text(r, d->measured, sizeof(d->measured));
	when(r->reported_ns ? r->reported_ns : now_realtime_ns(), d->reported, sizeof(d->reported));
	if (asprintf(&d->identity, "%s · part %s · lot %s · serial %s", d->lens_name,
		     d->part[0] ? d->part : "-", d->lot[0] ? d->lot : "-",
		     d->serial[0] ? d->serial : "-") < 0) {
		d->identity = NULL;
		return -ENOMEM;
	}
	double pv = d->r->fit->pv.v, floor_nm = asph_report_noise_floor_nm(r->radius);
	d->noise_nm = pv < floor_nm ? floor_nm : 0;
	return 0;
}

static void doc_release(struct doc *d)
{
	char **own[] = { &d->part, &d->lot, &d->serial, &d->operator_name, &d->lens_name,
			 &d->label, &d->software, &d->data_name, &d->instrument_name, &d->identity };

	for (size_t i = 0; i < sizeof(own) / sizeof(own[0]); i++)
		free(*own[i]);
	for (int i = 0; i < N_DESC; i++) {
		free(d->desc[i].clean);
		free(d->desc[i].summary);
	}
}

/* Draws the pages on surface (a PDF surface of name) and finishes it. */
static int draw_report(cairo_surface_t *surface, const char *name, const struct asph_report *r,
		       struct asph_error *err)
{
	_cleanup_(cairo_destroyp) cairo_t *cr = cairo_create(surface);
	struct doc d;
	cairo_status_t st;
	int rc, appendix;

	if (cairo_status(cr) != CAIRO_STATUS_SUCCESS)
		return asph_error_set(err, -EIO, "cannot create %s: %s", name,
				      cairo_status_to_string(cairo_status(cr)));
	cairo_pdf_surface_set_metadata(surface, CAIRO_PDF_METADATA_TITLE, "Form measurement report");
	cairo_pdf_surface_set_metadata(surface, CAIRO_PDF_METADATA_CREATOR,
				       r->software ? r->software : "libasph");
	rc = doc_init(&d, r);
	d.cr = cr;
	/* measure, then draw with the page count and the appendix's page */
	if (rc == 0)
		rc = layout(&d);
	appendix = d.appendix_page;
	d.n_pages = d.page;
	d.drawing = 1;
	d.appendix_page = appendix;
	if (rc == 0)
		rc = layout(&d);
	doc_release(&d);
	if (rc < 0)
		return asph_error_set(err, rc, "%s: out of memory", name);
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
