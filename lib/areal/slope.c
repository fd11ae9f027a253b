/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Slope deviation over an evaluation length, radially and along the
 * tangent, with the propagation of independent noise. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "asph/areal.h"
#include "areal-internal.h"
#include "util-mem.h"

/* A difference quotient as the six points it is made of. */
struct quotient {
	double value;            /* nm / mm = urad */
	uint32_t idx[6];
	double w[6];             /* d value / d F_idx */
};

/* (F(p + L/2 e) - F(p - L/2 e)) / L; -EDOM when either end is masked or
 * outside the disc. hint[k] is where the search for end k starts: the
 * triangle of the same end at the previous position, a few triangles
 * away (one hint for both would walk the length L at every step). */
static int quotient_at(const struct asph_scatter *s, double radius, double x,
		       double y, double ex, double ey, double L, uint32_t hint[2],
		       struct quotient *q)
{
	double v[2], w[3];

	for (int k = 0; k < 2; k++) {
		double sign = k ? -0.5 : 0.5;
		double px = x + sign * L * ex, py = y + sign * L * ey;
		if (hypot(px, py) > radius ||
		    asph_scatter_eval(s, px, py, &hint[k], &v[k], q->idx + 3 * k, w) < 0)
			return -EDOM;
		for (int j = 0; j < 3; j++)
			q->w[3 * k + j] = (k ? -w[j] : w[j]) / L;
	}
	q->value = (v[0] - v[1]) / L;
	return 0;
}

struct slope_sums {
	double r2, t2, rmax, tmax, m2, mmax;
	size_t n;
	struct quotient best_r, best_t;     /* at the largest magnitude */
};

/* sum_k (d/dF of the magnitude at the largest sample)^2. */
static double max_sensitivity(const struct slope_sums *a)
{
	double m = a->mmax, g = 0;
	double acc[12];
	uint32_t idx[12];

	for (int k = 0; k < 6; k++) {
		idx[k] = a->best_r.idx[k];
		acc[k] = a->best_r.value * a->best_r.w[k] / m;
		idx[6 + k] = a->best_t.idx[k];
		acc[6 + k] = a->best_t.value * a->best_t.w[k] / m;
	}
	/* Points that appear twice add up before squaring. */
	for (int k = 0; k < 12; k++) {
		double sum = acc[k];
		int first = 1;
		for (int j = 0; j < k; j++)
			if (idx[j] == idx[k])
				first = 0;
		if (!first)
			continue;
		for (int j = k + 1; j < 12; j++)
			if (idx[j] == idx[k])
				sum += acc[j];
		g += sum * sum;
	}
	return g;
}

static int check_args(double radius, double L, double spacing, struct asph_error *err)
{
	if (!(radius > 0) || !isfinite(radius) || !(L > 0) || !isfinite(L) || L > 2 * radius)
		return asph_error_set(err, -EINVAL,
				      "evaluation length %g mm is not in (0, %g] mm", L, 2 * radius);
	if (!(spacing > 0) || !isfinite(spacing) || 2 * (radius / spacing) + 1 > ASPH_GRID_MAX_NODES)
		return asph_error_set(err, -EINVAL, "slope positions every %g mm: out of range",
				      spacing);
	return 0;
}

int asph_slope_compute(const struct asph_scatter *s, double radius,
		       double length_mm, double spacing, double noise_nm,
		       struct asph_slope *out, struct asph_error *err)
{
	_cleanup_free_ double *grad = NULL;
	struct slope_sums a = { 0 };
	long half;
	uint32_t hint[2][2] = { { 0 } };       /* radial, tangential; each end */
	uint32_t row_hint[2][2] = { { 0 } };   /* at the first position of a row */
	int r = check_args(radius, length_mm, spacing, err);

	if (r < 0)
		return r;
	grad = calloc(asph_scatter_n_points(s) + 1, sizeof(double));
	if (!grad)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(grad, asph_scatter_n_points(s) * sizeof(double));
	half = (long)floor(radius / spacing);
	for (long j = -half; j <= half; j++) {
		/* A row's searches start where the previous row's first found
		 * its triangles, one spacing away, rather than at the far end
		 * of the previous row, a diameter away. */
		bool row_started = false;
		memcpy(hint, row_hint, sizeof(hint));
		for (long i = -half; i <= half; i++) {
			double x = (double)i * spacing, y = (double)j * spacing, rr = hypot(x, y);
			struct quotient qr, qt;
			if (rr > radius || rr == 0 ||
			    quotient_at(s, radius, x, y, x / rr, y / rr, length_mm, hint[0], &qr) < 0 ||
			    quotient_at(s, radius, x, y, -y / rr, x / rr, length_mm, hint[1], &qt) < 0)
				continue;
			if (!row_started) {
				memcpy(row_hint, hint, sizeof(hint));
				row_started = true;
			}
			double m2 = qr.value * qr.value + qt.value * qt.value;
			a.r2 += qr.value * qr.value;
			a.t2 += qt.value * qt.value;
			a.m2 += m2;
			a.rmax = fmax(a.rmax, fabs(qr.value));
			a.tmax = fmax(a.tmax, fabs(qt.value));
			if (a.n == 0 || sqrt(m2) > a.mmax) {
				a.mmax = sqrt(m2);
				a.best_r = qr;
				a.best_t = qt;
			}
			for (int k = 0; k < 6; k++) {
				grad[qr.idx[k]] += qr.value * qr.w[k];
				grad[qt.idx[k]] += qt.value * qt.w[k];
			}
			a.n++;
		}
	}
	if (a.n == 0)
		return asph_error_set(err, -EDOM,
				      "no position where both %g mm stencils lie in the measured region",
				      length_mm);
	memset(out, 0, sizeof(*out));
	out->length_mm = length_mm;
	out->n = a.n;
	/* nm over mm is urad. */
	out->rms.v = sqrt(a.m2 / (double)a.n);
	out->max.v = a.mmax;
	out->rms_radial.v = sqrt(a.r2 / (double)a.n);
	out->max_radial.v = a.rmax;
	out->rms_azimuthal.v = sqrt(a.t2 / (double)a.n);
	out->max_azimuthal.v = a.tmax;
	out->u_rms.v = out->u_max.v = NAN;
	if (noise_nm >= 0 && isfinite(noise_nm) && a.mmax > 0) {
		double g2 = 0;
		for (size_t i = 0; i < asph_scatter_n_points(s); i++)
			g2 += grad[i] * grad[i];
		/* d rms / dF = sum_k (s_k . d s_k / dF) / (n rms) */
		out->u_rms.v = 2 * noise_nm * sqrt(g2) / ((double)a.n * out->rms.v);
		out->u_max.v = 2 * noise_nm * sqrt(max_sensitivity(&a));
	}
	return 0;
}
