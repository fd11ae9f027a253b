/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The kinematic lower bound of motion-bound.h. Why it is one:
 *
 * 1. Segments. Between passing point i and point i + 1 each axis covers
 *    |dx_k| at a speed of at most V_k, and the probe reads once at each:
 *    t_(i+1) - t_i >= max(1 / rate, max_k |dx_k| / V_k).
 *
 * 2. The reach from rest. Let an axis be at rest at t = 0 with an
 *    acceleration of at most alpha0 in its direction of travel. Its
 *    acceleration then obeys a(s) <= min(A, alpha0 + J s) (the jerk). At
 *    a later t with a(t) = alpha >= 0, the speed must still stay <= V
 *    afterwards; with the jerk the acceleration falls no faster than J, so
 *    v(t) <= V - alpha^2 / (2 J). Backwards from t the acceleration was at
 *    most alpha + J (t - s), so v(t) <= int_0^t min(A, alpha0 + J s,
 *    alpha + J (t - s)) ds. The first bound falls with alpha, the second
 *    rises: v(t) is at most their value where they cross, which is the
 *    speed of the profile a(s) = min(A, alpha0 + J s, J (t2 - s)) that
 *    reaches V at t2 and then cruises (the fastest ramp to V). Its
 *    integral P(t) (mb_reach) bounds |x(t) - x(0)|; by time reversal the
 *    same bounds the distance to an instant of rest ahead.
 *
 * 3. Reversals. In a window of points a < b whose largest coordinate of
 *    axis k, x_max, exceeds both x_a and x_b, the axis' own maximum over
 *    [t_a, t_b] is inside the window, where v = 0 and |a| <= A. So
 *    t_b - t_a >= P^-1(x_max - x_a) + P^-1(x_max - x_b) with alpha0 = A
 *    (the same for a minimum). The path's first and last points are at
 *    rest with a = 0: t_b - t_0 >= P^-1(|x_b - x_0|) with alpha0 = 0.
 *
 * Over windows that share at most their end points the intervals of time
 * are disjoint, so the sum of the segments' bounds outside them and the
 * larger of each window's bounds inside it is a lower bound of the whole.
 * The windows are chosen to make it largest (weighted interval
 * scheduling). Nothing here asks how the motion turns between the points:
 * it holds for any path through them.
 */
#include "motion-bound.h"

#include <math.h>
#include <stdlib.h>

/* The ramp of rule 2: the start acceleration, the peak and the phases'
 * durations (jerk up, constant, jerk down; then cruise). */
struct ramp {
	double a0, ap, t[3], jerk;
	double end_t, end_d;    /* where the cruise begins */
};

static void ramp_of(const struct mb_axis *ax, double alpha0, struct ramp *r)
{
	double V = ax->v, A = ax->a > 0 ? ax->a : INFINITY, J = ax->j > 0 ? ax->j : INFINITY;

	r->t[0] = r->t[1] = r->t[2] = 0;
	r->jerk = J;
	if (isinf(A) && isinf(J)) {
		/* the speed jumps */
		r->a0 = r->ap = INFINITY;
		r->end_t = r->end_d = 0;
		return;
	}
	if (isinf(J)) {
		/* the acceleration jumps to A and drops at V */
		r->a0 = r->ap = A;
		r->t[1] = V / A;
	} else {
		/* a start above sqrt(2 J V) would overshoot V */
		double a0 = fmin(fmin(alpha0, A), sqrt(2 * J * V));
		double ap = A, dv = (A * A - a0 * a0) / (2 * J) + A * A / (2 * J);
		if (isinf(A) || dv > V)
			ap = sqrt((2 * J * V + a0 * a0) / 2);       /* never reaches A */
		r->a0 = a0;
		r->ap = ap;
		r->t[0] = (ap - a0) / J;
		r->t[1] = isinf(A) || dv > V ? 0 : (V - dv) / A;
		r->t[2] = ap / J;
	}
	r->end_t = r->t[0] + r->t[1] + r->t[2];
	/* the distance over the ramp, phase by phase */
	double s = 0, v = 0, a = r->a0;
	const double jk[3] = { isinf(J) ? 0 : J, 0, isinf(J) ? 0 : -J };
	for (int k = 0; k < 3; k++) {
		double d = r->t[k];
		s += v * d + a * d * d / 2 + jk[k] * d * d * d / 6;
		v += a * d + jk[k] * d * d / 2;
		a += jk[k] * d;
	}
	r->end_d = s;
}

static double ramp_reach(const struct ramp *r, double V, double t)
{
	if (isinf(r->a0))
		return V * t;
	if (t >= r->end_t)
		return r->end_d + V * (t - r->end_t);
	const double jk[3] = { isinf(r->jerk) ? 0 : r->jerk, 0, isinf(r->jerk) ? 0 : -r->jerk };
	double s = 0, v = 0, a = r->a0;
	for (int k = 0; k < 3 && t > 0; k++) {
		double d = fmin(r->t[k], t);
		s += v * d + a * d * d / 2 + jk[k] * d * d * d / 6;
		v += a * d + jk[k] * d * d / 2;
		a += jk[k] * d;
		t -= d;
	}
	return s;
}

double mb_reach(const struct mb_axis *ax, double alpha0, double t)
{
	struct ramp r;

	ramp_of(ax, alpha0, &r);
	return ramp_reach(&r, ax->v, fmax(t, 0));
}

double mb_reach_ramp(const struct mb_axis *ax, double alpha0, double *d)
{
	struct ramp r;

	ramp_of(ax, alpha0, &r);
	if (d)
		*d = isinf(r.a0) ? 0 : r.end_d;
	return isinf(r.a0) ? 0 : r.end_t;
}

static double ramp_time(const struct ramp *r, double V, double d)
{
	if (!(d > 0))
		return 0;
	if (isinf(r->a0))
		return d / V;
	if (d >= r->end_d)
		return r->end_t + (d - r->end_d) / V;
	/* the reach rises strictly on the ramp: bisection */
	double lo = 0, hi = r->end_t;
	for (int i = 0; i < 200 && hi - lo > 1e-15 * hi; i++) {
		double mid = (lo + hi) / 2;
		if (ramp_reach(r, V, mid) < d)
			lo = mid;
		else
			hi = mid;
	}
	return hi;
}

double mb_reach_time(const struct mb_axis *ax, double alpha0, double d)
{
	struct ramp r;

	ramp_of(ax, alpha0, &r);
	return ramp_time(&r, ax->v, d);
}

/* ------------------------------------------------------------- windows */

struct window {
	size_t a, b;
	double gain;    /* the window's bound over its segments' */
};

static int by_end(const void *x, const void *y)
{
	const struct window *p = x, *q = y;

	return p->b < q->b ? -1 : p->b > q->b ? 1 : p->a < q->a ? -1 : p->a > q->a;
}

struct ctx {
	const double *m;
	size_t n;
	const double *cum;      /* the segments' bound from point 0 to i */
	struct ramp turn[3], rest[3];
	double V[3];
	struct window *w;
	size_t nw, capw;
};

static int add_window(struct ctx *c, size_t a, size_t b, double bound)
{
	double gain = bound - (c->cum[b] - c->cum[a]);

	if (!(gain > 0))
		return 0;
	if (c->nw == c->capw) {
		size_t cap = c->capw ? 2 * c->capw : 256;
		struct window *w = realloc(c->w, cap * sizeof(*w));
		if (!w)
			return -1;
		c->w = w;
		c->capw = cap;
	}
	c->w[c->nw++] = (struct window){ a, b, gain };
	return 0;
}

/* The window around the extremum of axis k at points m0 .. m1 (a plateau),
 * sign +1 for a maximum, -1 for a minimum: out to where the axis is a
 * ramp's distance from it on both sides, beyond which the reversal's bound
 * grows no faster than the segments'. */
static int reversal_window(struct ctx *c, int k, size_t m0, size_t m1, double sign)
{
	const double *m = c->m;
	double x = sign * m[3 * m0 + k], reach = c->turn[k].end_d;
	size_t a = m0, b = m1;

	while (a > 0 && x - sign * m[3 * a + k] < reach)
		a--;
	while (b + 1 < c->n && x - sign * m[3 * b + k] < reach)
		b++;
	double top = -INFINITY;
	for (size_t i = a; i <= b; i++)
		top = fmax(top, sign * m[3 * i + k]);
	double d1 = top - sign * m[3 * a + k], d2 = top - sign * m[3 * b + k];
	if (!(d1 > 0 && d2 > 0))
		return 0;       /* the extremum is at an end: no rest inside */
	return add_window(c, a, b, ramp_time(&c->turn[k], c->V[k], d1) +
					   ramp_time(&c->turn[k], c->V[k], d2));
}

static int axis_windows(struct ctx *c, int k)
{
	double last = 0;        /* the sign of the last move of the axis */
	size_t since = 0;       /* where the axis last moved to */

	for (size_t i = 0; i + 1 < c->n; i++) {
		double d = c->m[3 * (i + 1) + k] - c->m[3 * i + k];
		if (d == 0)
			continue;
		double s = d > 0 ? 1 : -1;
		if (last != 0 && s != last && reversal_window(c, k, since, i, last) < 0)
			return -1;
		last = s;
		since = i + 1;
	}
	return 0;
}

/* From rest at point 0 (and to rest at the last point): out to where an
 * axis is a ramp's distance away. */
static int rest_windows(struct ctx *c)
{
	const double *m = c->m;
	size_t n = c->n;

	for (int end = 0; end < 2; end++) {
		size_t o = end ? n - 1 : 0;
		double best = 0;
		for (size_t step = 1; step < n; step++) {
			size_t i = end ? n - 1 - step : step;
			double t = 0;
			int far = 1;
			for (int k = 0; k < 3; k++) {
				double d = fabs(m[3 * i + k] - m[3 * o + k]);
				t = fmax(t, ramp_time(&c->rest[k], c->V[k], d));
				far &= d >= c->rest[k].end_d;
			}
			/* a window from rest to point i (or from i to rest) */
			size_t a = end ? i : 0, b = end ? n - 1 : i;
			if (t - (c->cum[b] - c->cum[a]) > best) {
				best = t - (c->cum[b] - c->cum[a]);
				if (add_window(c, a, b, t) < 0)
					return -1;
			}
			if (far && step > 1)
				break;
		}
	}
	return 0;
}

double mb_path_bound(const double *m, size_t n, const struct mb_axis ax[3], double rate,
		     struct mb_stats *st)
{
	struct ctx c = { .m = m, .n = n };
	double *cum = calloc(n ? n : 1, sizeof(double)), length = 0;

	if (!cum)
		return -1;
	for (size_t i = 0; i + 1 < n; i++) {
		double t = rate > 0 ? 1 / rate : 0, l = 0;
		for (int k = 0; k < 3; k++) {
			double d = m[3 * (i + 1) + k] - m[3 * i + k];
			t = fmax(t, fabs(d) / ax[k].v);
			l += d * d;
		}
		cum[i + 1] = cum[i] + t;
		length += sqrt(l);
	}
	c.cum = cum;
	for (int k = 0; k < 3; k++) {
		c.V[k] = ax[k].v;
		ramp_of(&ax[k], INFINITY, &c.turn[k]);
		ramp_of(&ax[k], 0, &c.rest[k]);
	}
	int r = n > 1 ? rest_windows(&c) : 0;
	for (int k = 0; k < 3 && r == 0 && n > 2; k++)
		r = axis_windows(&c, k);
	double *best = r == 0 ? calloc(c.nw + 1, sizeof(double)) : NULL;
	double total = -1;
	if (best) {
		/* weighted interval scheduling: best[i] over the first i windows
		 * by their end; a window may follow one that ends where it
		 * begins */
		if (c.nw > 0)
			qsort(c.w, c.nw, sizeof(*c.w), by_end);
		for (size_t i = 0; i < c.nw; i++) {
			size_t lo = 0, hi = i;  /* windows [0, lo) end at or before w[i].a */
			while (lo < hi) {
				size_t mid = (lo + hi) / 2;
				if (c.w[mid].b <= c.w[i].a)
					lo = mid + 1;
				else
					hi = mid;
			}
			best[i + 1] = fmax(best[i], best[lo] + c.w[i].gain);
		}
		total = cum[n ? n - 1 : 0] + best[c.nw];
		if (st) {
			st->length = length;
			st->segments = cum[n ? n - 1 : 0];
			/* the windows taken: walk the choices back */
			st->windows = 0;
			for (size_t i = c.nw; i > 0;) {
				if (best[i] == best[i - 1]) {
					i--;
					continue;
				}
				st->windows++;
				size_t lo = 0, hi = i - 1;
				while (lo < hi) {
					size_t mid = (lo + hi) / 2;
					if (c.w[mid].b <= c.w[i - 1].a)
						lo = mid + 1;
					else
						hi = mid;
				}
				i = lo;
			}
		}
	}
	free(best);
	free(c.w);
	free(cum);
	return total;
}
