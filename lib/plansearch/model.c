/* SPDX-License-Identifier: GPL-3.0-or-later */
/* U^2 = a / N + b: what falls as 1/sqrt(N) (the noise of each point) and
 * what does not (what a whole scan shares: drift, tip, latency), fitted to
 * the Monte Carlo runs of one method, which pools their trials. */
#include <errno.h>
#include <math.h>

#include "plansearch-internal.h"

/* Runs within this factor of N take part in the local model at N (the
 * a / N + b form is exact for the noise and the floor alone; between them
 * U may bend otherwise). */
#define WINDOW 4.0

struct sums {
	double sw, sx, sy, sxx, sxy;
	size_t m;
	double n_lo, n_hi;
};

struct fit {
	double a, b, var_b;
	size_t m;
	double span;            /* the largest N over the smallest */
};

static int usable(const struct ps_eval *e, int q)
{
	return isfinite(e->U[q]) && e->n > 0 && e->trials > 1;
}

static void add_run(struct sums *s, const struct ps_eval *e, int q)
{
	/* a U of 0 (nothing varies the quantity) is known exactly: weigh it
	 * as a tiny one */
	double U = fmax(e->U[q], 1e-300), x = 1.0 / (double)e->n, y = U * U;
	double w = (double)e->trials / (2 * y * y);    /* var(U^2) = 2 U^4 / M */

	s->sw += w;
	s->sx += w * x;
	s->sy += w * y;
	s->sxx += w * x * x;
	s->sxy += w * x * y;
	if (s->m == 0 || (double)e->n < s->n_lo)
		s->n_lo = (double)e->n;
	if (s->m == 0 || (double)e->n > s->n_hi)
		s->n_hi = (double)e->n;
	s->m++;
}

/* a, b >= 0 of the weighted least squares, and the variance of b. */
static void solve(const struct sums *s, struct fit *f)
{
	double det = s->sw * s->sxx - s->sx * s->sx;

	f->m = s->m;
	f->span = s->m ? s->n_hi / s->n_lo : 0;
	f->var_b = INFINITY;
	if (s->m >= 2 && det > 1e-12 * s->sw * s->sxx) {
		f->a = (s->sw * s->sxy - s->sx * s->sy) / det;
		f->b = (s->sxx * s->sy - s->sx * s->sxy) / det;
		f->var_b = s->sxx / det;
		if (f->a >= 0 && f->b >= 0)
			return;
		if (f->a < 0) {         /* nothing falls with N: b alone */
			f->a = 0;
			f->b = s->sy / s->sw;
			f->var_b = 1 / s->sw;
			return;
		}
	}
	/* one run, or b < 0: a / N alone */
	f->a = s->sxy / s->sxx;
	f->b = 0;
}

/* The model of quantity q on the runs within window of n (0: all). */
static void fit_runs(const struct ps_eval *evals, size_t n_evals, int q, double n,
		     double window, struct fit *f)
{
	struct sums s = { 0 };

	for (size_t i = 0; i < n_evals; i++) {
		const struct ps_eval *e = &evals[i];
		if (!usable(e, q))
			continue;
		if (window > 0 && ((double)e->n > window * n || (double)e->n * window < n))
			continue;
		add_run(&s, e, q);
	}
	solve(&s, f);
}

/* The finest run of q fails limit by more than twice its own standard
 * error (U's relative one is 1 / sqrt(2 M) for M trials). */
static int finest_fails(const struct ps_eval *evals, size_t n_evals, int q, double limit)
{
	const struct ps_eval *finest = NULL;

	for (size_t i = 0; i < n_evals; i++)
		if (usable(&evals[i], q) && (!finest || evals[i].n > finest->n))
			finest = &evals[i];
	return finest && finest->U[q] * (1 - 2 / sqrt(2.0 * (double)finest->trials)) > limit;
}

/* The floor's margin in its standard errors on runs spanning span. Runs
 * close together tell the floor from runs far beyond the threshold for
 * their span: a U that still falls as 1 / sqrt(N) is taken for a floor at
 * twice the error in about 1.3 % of methods whose root is 100x the
 * coarsest plan with runs 4x apart (100 trials each), 0.1 % 16x apart;
 * at three times, under 0.05 % 4x apart. */
static double floor_margin(double span)
{
	return span >= PS_WIDE_SPAN ? 2 : 3;
}

int ps_model(const struct ps_eval *evals, size_t n_evals, int q, double n, double limit,
	     double *U_out, double *root, int *floor_beyond)
{
	struct fit local, all;
	double L2 = limit * limit, beyond = PS_FLOOR_MARGIN * limit;

	fit_runs(evals, n_evals, q, n, 0, &all);
	if (all.m == 0)
		return -EDOM;
	fit_runs(evals, n_evals, q, n, WINDOW, &local);
	/* too few runs near n to tell the floor: the method's runs all */
	const struct fit *f = local.m >= 2 && local.span >= PS_MIN_SPAN ? &local : &all;
	*U_out = sqrt(f->a / n + f->b);
	*root = f->b >= L2 ? INFINITY : f->a / (L2 - f->b);
	*floor_beyond = all.span >= PS_MIN_SPAN &&
			all.b - floor_margin(all.span) * sqrt(all.var_b) > beyond * beyond &&
			finest_fails(evals, n_evals, q, limit);
	return 0;
}
