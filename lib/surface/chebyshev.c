/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "chebyshev.h"

static void panel_fit(struct cheb_panel *p, double (*f)(double, void *),
		      void *ctx)
{
	double fx[CHEB_DEGREE];
	const int n = CHEB_DEGREE;
	double mid = 0.5 * (p->lo + p->hi), half = 0.5 * (p->hi - p->lo);

	for (int j = 0; j < n; j++) {
		double x = cos(M_PI * (j + 0.5) / n);
		fx[j] = f(mid + half * x, ctx);
	}
	for (int k = 0; k < n; k++) {
		double sum = 0;
		for (int j = 0; j < n; j++)
			sum += fx[j] * cos(M_PI * k * (j + 0.5) / n);
		p->c[k] = (k == 0 ? 1.0 : 2.0) * sum / n;
	}
}

static double panel_eval(const struct cheb_panel *p, double x)
{
	double u = (2.0 * x - p->lo - p->hi) / (p->hi - p->lo);
	double b1 = 0, b2 = 0;

	for (int k = CHEB_DEGREE - 1; k >= 1; k--) {
		double b0 = 2.0 * u * b1 - b2 + p->c[k];
		b2 = b1;
		b1 = b0;
	}
	return u * b1 - b2 + p->c[0];
}

/* Largest relative misfit at points between the interpolation nodes. */
static double panel_misfit(const struct cheb_panel *p,
			   double (*f)(double, void *), void *ctx)
{
	double worst = 0, scale = 0;
	double fx[CHEB_DEGREE + 1], gx[CHEB_DEGREE + 1];

	for (int j = 0; j <= CHEB_DEGREE; j++) {
		double x = p->lo + (p->hi - p->lo) * (j + 0.37) / (CHEB_DEGREE + 1);
		fx[j] = f(x, ctx);
		gx[j] = panel_eval(p, x);
		scale = fmax(scale, fabs(fx[j]));
	}
	if (scale == 0)
		scale = 1;
	for (int j = 0; j <= CHEB_DEGREE; j++)
		worst = fmax(worst, fabs(fx[j] - gx[j]) / scale);
	return worst;
}

int cheb_table_build(struct cheb_table *t, double lo, double hi,
		     double (*f)(double x, void *ctx), void *ctx,
		     double rel_tol, size_t max_panels)
{
	size_t cap = 8, n = 0;
	int result = 0;
	struct cheb_panel *out = malloc(cap * sizeof(*out));
	/* Work list of intervals still to fit, processed left to right. */
	double *stack = malloc(2 * (max_panels + 64) * sizeof(double));
	size_t sp = 0;

	memset(t, 0, sizeof(*t));
	if (!out || !stack) {
		free(out);
		free(stack);
		return -ENOMEM;
	}
	stack[sp++] = hi;
	stack[sp++] = lo;
	while (sp > 0) {
		struct cheb_panel p;
		p.lo = stack[--sp];
		p.hi = stack[--sp];
		panel_fit(&p, f, ctx);
		double misfit = panel_misfit(&p, f, ctx);
		if (misfit > rel_tol && n + sp / 2 + 2 <= max_panels) {
			double mid = 0.5 * (p.lo + p.hi);
			stack[sp++] = p.hi;
			stack[sp++] = mid;
			stack[sp++] = mid;
			stack[sp++] = p.lo;
			continue;
		}
		if (misfit > rel_tol)
			result = -ERANGE;
		if (n == cap) {
			cap *= 2;
			struct cheb_panel *grown = realloc(out, cap * sizeof(*out));
			if (!grown) {
				free(out);
				free(stack);
				return -ENOMEM;
			}
			out = grown;
		}
		out[n++] = p;
	}
	free(stack);
	t->panels = out;
	t->n_panels = n;
	return result;
}

void cheb_table_clear(struct cheb_table *t)
{
	free(t->panels);
	t->panels = NULL;
	t->n_panels = 0;
}

double cheb_table_eval(const struct cheb_table *t, double x)
{
	size_t lo = 0, hi = t->n_panels - 1;

	if (x < t->panels[0].lo)
		x = t->panels[0].lo;
	if (x > t->panels[hi].hi)
		x = t->panels[hi].hi;
	while (lo < hi) {
		size_t mid = (lo + hi) / 2;
		if (x > t->panels[mid].hi)
			lo = mid + 1;
		else
			hi = mid;
	}
	return panel_eval(&t->panels[lo], x);
}
