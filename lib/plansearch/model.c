/* SPDX-License-Identifier: GPL-3.0-or-later */
/* U^2 = a / N + b: what falls as 1/sqrt(N) (the noise of each point) and
 * what does not (what a whole scan shares: drift, tip, latency), fitted to
 * the Monte Carlo runs of one method, which pools their trials. */
#include <errno.h>
#include <math.h>

#include "plansearch-internal.h"

/* Runs within this factor of N take part in the model at N. */
#define WINDOW 4.0

struct sums {
	double sw, sx, sy, sxx, sxy;
	size_t m;
};

static void add_run(struct sums *s, const struct ps_eval *e, int q, double n)
{
	double U = e->U[q], x, y, w;

	if (!(isfinite(U) && e->n > 0 && e->trials > 1))
		return;
	if ((double)e->n > WINDOW * n || (double)e->n * WINDOW < n)
		return;
	/* a U of 0 (nothing varies the quantity) is known exactly: weigh it
	 * as a tiny one */
	U = fmax(U, 1e-300);
	x = 1.0 / (double)e->n;
	y = U * U;
	w = (double)e->trials / (2 * y * y);
	s->sw += w;
	s->sx += w * x;
	s->sy += w * y;
	s->sxx += w * x * x;
	s->sxy += w * x * y;
	s->m++;
}

/* a, b >= 0 of the weighted least squares, and the variance of b. */
static void solve(const struct sums *s, double *a, double *b, double *var_b)
{
	double det = s->sw * s->sxx - s->sx * s->sx;

	*var_b = INFINITY;
	if (s->m >= 2 && det > 1e-12 * s->sw * s->sxx) {
		*a = (s->sw * s->sxy - s->sx * s->sy) / det;
		*b = (s->sxx * s->sy - s->sx * s->sxy) / det;
		*var_b = s->sxx / det;
		if (*a >= 0 && *b >= 0)
			return;
		if (*a < 0) {           /* nothing falls with N: b alone */
			*a = 0;
			*b = s->sy / s->sw;
			*var_b = 1 / s->sw;
			return;
		}
	}
	/* one run, or b < 0: a / N alone */
	*a = s->sxy / s->sxx;
	*b = 0;
}

int ps_model(const struct ps_eval *evals, size_t n_evals, int q, double n, double limit,
	     double *U_out, double *root, int *floor_beyond)
{
	struct sums s = { 0 };
	double a, b, var_b, L2 = limit * limit;

	for (size_t i = 0; i < n_evals; i++)
		add_run(&s, &evals[i], q, n);
	if (s.m == 0)
		return -EDOM;
	solve(&s, &a, &b, &var_b);
	*U_out = sqrt(a / n + b);
	*floor_beyond = b - 2 * sqrt(var_b) > L2;
	if (b >= L2)
		*root = INFINITY;
	else
		*root = a / (L2 - b);
	return 0;
}
