/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Drift correction from a scan's references, and the acquisition's account
 * of its points (asph/drift.h). */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/drift.h"
#include "asph/prescription.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_drift *, asph_drift_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

struct asph_drift {
	size_t n;               /* rounds in the model */
	double *t;              /* their times, s */
	double (*d)[3];         /* their drift, mm */
	size_t n_references;
	unsigned components;
};

void asph_drift_free(struct asph_drift *d)
{
	if (!d)
		return;
	free(d->t);
	free(d->d);
	free(d);
}

static bool measured(const struct asph_scanfile_point *p)
{
	return !(p->flags & ASPH_SCANFILE_NOT_MEASURED) && isfinite(p->x) && isfinite(p->y) &&
	       isfinite(p->z);
}

/* The height of a measured point above the nominal surface, and the
 * surface's gradient there. */
static double height(const struct asph_surface *s, const struct asph_scanfile_point *p,
		     double g[2])
{
	double d[3];

	asph_surface_sag_grad_xy(s, p->x, p->y, d);
	g[0] = d[1];
	g[1] = d[2];
	return p->z - d[0];
}

/* Whether references at these gradients tell a lateral drift from a
 * vertical one: their design matrix [1, -gx, -gy] of full rank, well
 * conditioned. */
static bool spans(const double (*g)[2], size_t n)
{
	double m[3][3] = { { 0 } };

	for (size_t i = 0; i < n; i++) {
		double row[3] = { 1, -g[i][0], -g[i][1] };
		for (int a = 0; a < 3; a++)
			for (int b = 0; b < 3; b++)
				m[a][b] += row[a] * row[b];
	}
	double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
		     m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
		     m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
	double tr = m[0][0] + m[1][1] + m[2][2];
	/* the smallest eigenvalue's share, bounded from below by det / tr^2 */
	return n >= 3 && det > 1e-6 * tr * tr * tr;
}

/* Least squares of delta = dz - g . (dx, dy) over n references. */
static void solve3(const double (*g)[2], const double *delta, size_t n, double d[3])
{
	double m[3][4] = { { 0 } };

	for (size_t i = 0; i < n; i++) {
		double row[3] = { 1, -g[i][0], -g[i][1] };
		for (int a = 0; a < 3; a++) {
			for (int b = 0; b < 3; b++)
				m[a][b] += row[a] * row[b];
			m[a][3] += row[a] * delta[i];
		}
	}
	/* Gauss-Jordan with partial pivoting on the 3 x 3 normal equations */
	for (int c = 0; c < 3; c++) {
		int p = c;
		for (int r = c + 1; r < 3; r++)
			if (fabs(m[r][c]) > fabs(m[p][c]))
				p = r;
		for (int k = 0; k < 4; k++) {
			double tmp = m[c][k];
			m[c][k] = m[p][k];
			m[p][k] = tmp;
		}
		for (int r = 0; r < 3; r++) {
			if (r == c)
				continue;
			double f = m[r][c] / m[c][c];
			for (int k = c; k < 4; k++)
				m[r][k] -= f * m[c][k];
		}
	}
	/* unknowns: dz, dx, dy */
	d[2] = m[0][3] / m[0][0];
	d[0] = m[1][3] / m[1][1];
	d[1] = m[2][3] / m[2][2];
}

int asph_drift_fit(const struct asph_scanfile *s, const struct asph_surface *surface,
		   struct asph_drift **out, struct asph_error *err)
{
	_cleanup_(asph_drift_freep) struct asph_drift *d = calloc(1, sizeof(*d));
	size_t nr = 0, rounds = 0;

	if (!d)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < s->n_references; i++)
		if (s->references[i].plan_index + 1 > nr)
			nr = s->references[i].plan_index + 1;
	if (nr > 4096)
		return asph_error_set(err, -EBADMSG, "reference number %zu: more references than "
				      "a scan has", nr - 1);
	d->n_references = nr;
	/* each reference's measurements in order: round k is its k-th */
	_cleanup_free_ size_t *count = calloc(nr ? nr : 1, sizeof(*count));
	if (!count)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < s->n_references; i++)
		if (++count[s->references[i].plan_index] > rounds)
			rounds = count[s->references[i].plan_index];
	_cleanup_free_ const struct asph_scanfile_point **at =
		calloc((nr ? nr : 1) * (rounds ? rounds : 1), sizeof(*at));
	d->t = calloc(rounds ? rounds : 1, sizeof(*d->t));
	d->d = calloc(rounds ? rounds : 1, sizeof(*d->d));
	_cleanup_free_ double (*g)[2] = calloc(nr ? nr : 1, sizeof(*g));
	_cleanup_free_ double *delta = calloc(nr ? nr : 1, sizeof(*delta));
	if (!at || !d->t || !d->d || !g || !delta)
		return asph_error_set(err, -ENOMEM, "out of memory");
	memset(count, 0, (nr ? nr : 1) * sizeof(*count));
	for (size_t i = 0; i < s->n_references; i++) {
		uint64_t r = s->references[i].plan_index;
		at[count[r]++ * nr + r] = &s->references[i];
	}
	/* which components round 0's references can tell apart */
	size_t n0 = 0;
	for (size_t r = 0; r < nr; r++)
		if (at[r] && measured(at[r]))
			height(surface, at[r], g[n0++]);
	d->components = rounds >= 2 && n0 ? (spans((const double (*)[2])g, n0) ? 3 : 1) : 0;
	for (size_t k = 0; k < rounds && d->components; k++) {
		size_t m = 0;
		double t = 0;
		for (size_t r = 0; r < nr; r++) {
			const struct asph_scanfile_point *p0 = at[r], *pk = at[k * nr + r];
			double g0[2];
			if (!p0 || !pk || !measured(p0) || !measured(pk))
				continue;
			double e0 = height(surface, p0, g0), ek = height(surface, pk, g[m]);
			delta[m] = ek - e0;
			g[m][0] = g0[0];
			g[m][1] = g0[1];
			t += (double)pk->t_ns * 1e-9;
			m++;
		}
		/* a round short of references stays out of the model */
		if (m == 0 || (d->components == 3 && !spans((const double (*)[2])g, m)))
			continue;
		double *dk = d->d[d->n];
		if (d->components == 3) {
			solve3((const double (*)[2])g, delta, m, dk);
		} else {
			dk[0] = dk[1] = dk[2] = 0;
			for (size_t i = 0; i < m; i++)
				dk[2] += delta[i] / (double)m;
		}
		d->t[d->n++] = t / (double)m;
	}
	if (d->n < 2) {
		d->n = 0;
		d->components = 0;
	}
	*out = steal_ptr(d);
	return 0;
}

void asph_drift_at(const struct asph_drift *d, uint64_t t_ns, double out[3])
{
	double t = (double)t_ns * 1e-9;
	size_t k = 0;

	if (!d || d->n == 0) {
		out[0] = out[1] = out[2] = 0;
		return;
	}
	if (t <= d->t[0] || d->n == 1) {
		memcpy(out, d->d[0], 3 * sizeof(double));
		return;
	}
	if (t >= d->t[d->n - 1]) {
		memcpy(out, d->d[d->n - 1], 3 * sizeof(double));
		return;
	}
	while (k + 2 < d->n && d->t[k + 1] <= t)
		k++;
	double w = (t - d->t[k]) / (d->t[k + 1] - d->t[k]);
	for (int c = 0; c < 3; c++)
		out[c] = d->d[k][c] + w * (d->d[k + 1][c] - d->d[k][c]);
}

static void model_summary(const struct asph_drift *d, struct asph_drift_summary *sum)
{
	memset(sum, 0, sizeof(*sum));
	if (!d)
		return;
	sum->n_references = d->n_references;
	sum->n_rounds = d->n;
	sum->components = d->components;
	sum->span_s = d->n ? d->t[d->n - 1] - d->t[0] : 0;
}

int asph_drift_points(const struct asph_drift *d, const struct asph_scanfile *s,
		      uint32_t exclude_flags, struct asph_points **out,
		      struct asph_drift_summary *sum, struct asph_error *err)
{
	struct asph_drift_summary local;
	int r = asph_scanfile_to_points(s, exclude_flags, out, err);

	if (!sum)
		sum = &local;
	model_summary(d, sum);
	if (r < 0 || !d || d->n == 0)
		return r;
	/* the same selection as asph_scanfile_to_points(), in order */
	double sq = 0;
	size_t k = 0;
	for (size_t i = 0; i < s->n; i++) {
		const struct asph_scanfile_point *p = &s->points[i];
		double c[3];
		if (p->flags & (exclude_flags | ASPH_SCANFILE_NOT_MEASURED))
			continue;
		asph_drift_at(d, p->t_ns, c);
		for (int a = 0; a < 3; a++)
			(*out)->xyz[3 * k + a] -= c[a];
		double len = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
		sum->max_mm = fmax(sum->max_mm, len);
		sum->max_z_mm = fmax(sum->max_z_mm, fabs(c[2]));
		sq += len * len;
		k++;
	}
	sum->n_corrected = k;
	sum->rms_mm = k ? sqrt(sq / (double)k) : 0;
	return 0;
}

/* ------------------------------------------------------------ report */

static json_t *positions_json(const struct asph_scanfile *s, size_t *commanded, size_t *invalid,
			      size_t *retried)
{
	size_t n[ASPH_SCANFILE_POSITION_COMMANDED + 1] = { 0 };
	json_t *o = json_object();

	*commanded = *invalid = *retried = 0;
	for (size_t i = 0; i < s->n; i++) {
		const struct asph_scanfile_point *p = &s->points[i];
		if (p->position_source <= ASPH_SCANFILE_POSITION_COMMANDED)
			n[p->position_source]++;
		*commanded += (p->flags & ASPH_SCANFILE_POINT_COMMANDED) != 0;
		*retried += (p->flags & ASPH_SCANFILE_POINT_RETRIED) != 0;
	}
	/* a point is invalid when its last measurement is */
	for (size_t i = 0; i < s->n; i++) {
		const struct asph_scanfile_point *p = &s->points[i];
		if (!(p->flags & ASPH_SCANFILE_POINT_INVALID))
			continue;
		bool later = false;
		for (size_t j = i + 1; j < s->n && !later; j++)
			later = s->points[j].plan_index == p->plan_index &&
				(s->points[j].flags & ASPH_SCANFILE_POINT_RETRIED);
		*invalid += !later;
	}
	for (uint32_t k = 0; k <= ASPH_SCANFILE_POSITION_COMMANDED; k++)
		json_object_set_new(o, asph_scanfile_position_source_name(k),
				    json_integer((json_int_t)n[k]));
	return o;
}

int asph_drift_report_json(const struct asph_scanfile *s, const struct asph_drift_summary *sum,
			   int corrected, char **out)
{
	size_t commanded, invalid, retried;
	json_t *positions = positions_json(s, &commanded, &invalid, &retried);
	json_t *warnings = json_array();
	static const char *const comp[] = { "none", "z", "none", "xyz" };

	if (commanded) {
		char w[256];
		snprintf(w, sizeof(w), "%zu of %zu points rest on the position the stage was sent "
			 "to, not one it measured (flagged commanded-position)", commanded, s->n);
		json_array_append_new(warnings, json_string(w));
	}
	if (invalid) {
		char w[160];
		snprintf(w, sizeof(w), "%zu points stayed invalid after their retries and are "
			 "left out", invalid);
		json_array_append_new(warnings, json_string(w));
	}
	json_t *drift = json_pack("{s:s, s:b, s:I, s:I, s:s, s:f, s:I, s:f, s:f, s:f}",
		"model", "piecewise-linear", "corrected", corrected && sum->n_rounds > 0,
		"references", (json_int_t)sum->n_references, "rounds", (json_int_t)sum->n_rounds,
		"components", comp[sum->components < 4 ? sum->components : 0],
		"span_s", sum->span_s, "points_corrected", (json_int_t)sum->n_corrected,
		"max_nm", sum->max_mm * 1e6, "rms_nm", sum->rms_mm * 1e6,
		"max_z_nm", sum->max_z_mm * 1e6);
	_cleanup_(json_decrefp) json_t *root = json_pack("{s:o, s:I, s:I, s:I, s:o, s:o}",
		"positions", positions, "commanded_points", (json_int_t)commanded,
		"invalid_points", (json_int_t)invalid, "retried_points", (json_int_t)retried,
		"drift", drift, "warnings", warnings);
	if (!root)
		return -ENOMEM;
	*out = json_dumps(root, JSON_COMPACT | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
	return *out ? 0 : -ENOMEM;
}

int asph_drift_scanfile_points(const struct asph_scanfile *s, const char *name,
			       uint32_t exclude_flags, int raw, struct asph_points **out,
			       struct asph_drift_summary *sum, struct asph_error *err)
{
	_cleanup_(asph_surface_freep) struct asph_surface *surf = NULL;
	_cleanup_(asph_drift_freep) struct asph_drift *d = NULL;
	struct asph_prescription p;
	int r = 0;

	if (!raw && s->n_references) {
		const char *text = s->header.prescription;
		r = asph_prescription_parse(text, strlen(text), name, &p, err);
		if (r == 0)
			r = asph_surface_alloc(&p, &surf, err);
		if (r == 0)
			r = asph_drift_fit(s, surf, &d, err);
		if (r < 0)
			return r;
	}
	r = asph_drift_points(d, s, exclude_flags, out, sum, err);
	if (r < 0)
		asph_error_locate(err, name, 0, 0, NULL);
	return r;
}

int asph_drift_scan_points(const char *scan_path, uint32_t exclude_flags, int raw,
			   struct asph_scanfile **s_out, struct asph_points **out,
			   struct asph_drift_summary *sum, struct asph_error *err)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	int r = asph_scanfile_read(scan_path, &s, err);

	if (r == 0)
		r = asph_drift_scanfile_points(s, scan_path, exclude_flags, raw, out, sum, err);
	if (r < 0)
		return r;
	if (s_out)
		*s_out = steal_ptr(s);
	return 0;
}
