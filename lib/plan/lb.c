/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include <gsl/gsl_integration.h>

#include "asph/lb.h"
#include "hermite.h"
#include "numeric/newton.h"
#include "util-mem.h"

/*
 * rho(r) = r q(r), q(r) = exp(F(r)), F(r) = J(r) - J(a),
 * J(r) = int_0^r (w(t) - 1)/t dt (docs/laplace-beltrami.md).
 *
 * J is even and analytic at 0 ((w - 1)/t ~ Z''(0)^2 t / 2), so F and the
 * inverse's G(rho) = ln(r / rho) = -F(r(rho)) are smooth, with first and
 * second derivatives in closed form:
 *   F'  = (w - 1)/r,              F''  = (r w' - (w - 1)) / r^2,
 *   G'  = -(w - 1)/(w rho),       G''  = ((w - 1) w^2 - r w') / (w^3 rho^2),
 *   F''(0) = Z''(0)^2 / 2,        G''(0) = -F''(0) / q(0)^2.
 * Both are held as quintic Hermite pieces on uniform grids over [0, a]
 * (one multiply finds the piece: O(1) per evaluation). Node values of F
 * are Gauss-Legendre sums accumulated interval by interval; those of G come
 * from inverting the F table by Newton's method. The grids are doubled
 * until every midpoint matches its exact value to TOL. Tabulating
 * logarithms keeps the plane exact: there F = 0 and rho = r to the bit.
 * The presets need 64 to 1024 intervals; building takes 0.1 to 2 ms.
 */
#define GL_ORDER 20
#define TOL 2e-15
/* G is only known to ~(w - 1) eps through r(rho): w reaches 14 on the
 * steep flank of turning-point. */
#define TOL_G 1e-14
#define MIN_INTERVALS 64
#define MAX_INTERVALS (1u << 17)

struct hermite_table {
	size_t n;               /* intervals of width h over [0, a] */
	double inv_h;
	double (*c)[6];         /* p(s) = sum c[k] s^k on each interval */
};

struct asph_lb_map {
	const struct asph_surface *s;
	double a;
	gsl_integration_glfixed_table *gl;
	double f2_0;            /* F''(0) */
	struct hermite_table f; /* F(r) = ln(rho / r) */
	struct hermite_table g; /* G(rho) = ln(r / rho) */
};

/* w - 1 = Z'^2 / (1 + w), without cancellation; also w and w'. */
static double slope_excess(const struct asph_surface *s, double r, double *w,
			   double *dw)
{
	double d[3];

	asph_surface_sag_derivs(s, r, d);
	*w = sqrt(1.0 + d[1] * d[1]);
	*dw = d[1] * d[2] / *w;
	return d[1] * d[1] / (1.0 + *w);
}

static double gl_j(const struct asph_lb_map *m, double lo, double hi)
{
	double sum = 0, w, dw;

	for (size_t j = 0; j < GL_ORDER; j++) {
		double x, wt;
		gsl_integration_glfixed_point(lo, hi, j, &x, &wt, m->gl);
		sum += wt * slope_excess(m->s, x, &w, &dw) / x;
	}
	return sum;
}

/* Piece and local coordinate of x in [0, a]. */
static const double *piece(const struct hermite_table *t, double x, double *s)
{
	double u = x * t->inv_h;
	size_t i = (size_t)u;

	if (i >= t->n)
		i = t->n - 1;
	*s = u - (double)i;
	return t->c[i];
}

static double table_eval(const struct hermite_table *t, double x)
{
	double s;
	const double *c = piece(t, x, &s);
	return poly5(c, s);
}

/* F and its derivatives at r, given J(r). */
static void f_node(const struct asph_lb_map *m, double r, double j,
		   double j_a, double y[3])
{
	double w, dw, ex = slope_excess(m->s, r, &w, &dw);

	y[0] = j - j_a;
	y[1] = r > 0 ? ex / r : 0;
	y[2] = r > 0 ? (r * dw - ex) / (r * r) : m->f2_0;
}

static void table_clear(struct hermite_table *t)
{
	free(t->c);
	t->c = NULL;
	t->n = 0;
}

static int table_alloc(struct hermite_table *t, size_t n, double a)
{
	table_clear(t);
	t->c = malloc(n * sizeof(*t->c));
	if (!t->c)
		return -ENOMEM;
	t->n = n;
	t->inv_h = (double)n / a;
	return 0;
}

/*
 * F on n intervals. Returns 1 when every midpoint matched, 0 when not,
 * < 0 on ENOMEM.
 */
static int build_f(struct asph_lb_map *m, size_t n)
{
	const double h = m->a / (double)n;
	_cleanup_free_ double *j = malloc((n + 1) * sizeof(double));
	_cleanup_free_ double *half = malloc(n * sizeof(double));
	double sum = 0, comp = 0;

	if (!j || !half || table_alloc(&m->f, n, m->a) < 0)
		return -ENOMEM;
	/* Compensated running sum: every later node value depends on it. */
	j[0] = 0;
	for (size_t i = 0; i < n; i++) {
		double lo = h * (double)i, mid = lo + 0.5 * h, hi = h * (double)(i + 1);
		half[i] = gl_j(m, lo, mid);
		double y = (half[i] + gl_j(m, mid, hi)) - comp;
		double t = sum + y;
		comp = (t - sum) - y;
		sum = t;
		j[i + 1] = sum;
	}
	int good = 1;
	double y0[3], y1[3];
	f_node(m, 0, 0, sum, y0);
	for (size_t i = 0; i < n; i++) {
		f_node(m, h * (double)(i + 1), j[i + 1], sum, y1);
		hermite5(y0, y1, h, m->f.c[i]);
		double exact = j[i] + half[i] - sum;
		if (fabs(poly5(m->f.c[i], 0.5) - exact) > TOL * (1 + fabs(exact)))
			good = 0;
		y0[0] = y1[0];
		y0[1] = y1[1];
		y0[2] = y1[2];
	}
	return good;
}

/* r with r exp(F(r)) = rho, by Newton's method on the F table from r. */
static double radius_from_f(const struct asph_lb_map *m, double rho, double r)
{
	double lo = 0, hi = m->a;

	if (rho <= 0)
		return 0;
	for (int it = 0; it < 100; it++) {
		double s;
		const double *c = piece(&m->f, r, &s);
		double q = exp(poly5(c, s)), f = r * q - rho;
		if (f == 0)
			return r;
		double next = newton_bracketed_step(r, f, q * (1 + r * poly5_deriv(c, s) * m->f.inv_h),
						    &lo, &hi);
		if (fabs(next - r) <= 4e-16 * r)
			return next;
		r = next;
	}
	return r;
}

/* G and its derivatives at rho, given r = r(rho). */
static void g_node(const struct asph_lb_map *m, double rho, double r,
		   double y[3])
{
	double w, dw, ex = slope_excess(m->s, r, &w, &dw);
	double q0 = exp(table_eval(&m->f, 0));

	y[0] = -table_eval(&m->f, r);
	y[1] = rho > 0 ? -ex / (w * rho) : 0;
	y[2] = rho > 0 ? (ex * w * w - r * dw) / (w * w * w * rho * rho) :
			 -m->f2_0 / (q0 * q0);
}

static int build_g(struct asph_lb_map *m, size_t n)
{
	const double h = m->a / (double)n;
	double y0[3], y1[3], r = 0;
	int good = 1;

	if (table_alloc(&m->g, n, m->a) < 0)
		return -ENOMEM;
	g_node(m, 0, 0, y0);
	for (size_t i = 0; i < n; i++) {
		double rho_mid = h * ((double)i + 0.5), rho1 = h * (double)(i + 1);
		double r_mid = radius_from_f(m, rho_mid, r);
		r = i + 1 == n ? m->a : radius_from_f(m, rho1, r_mid);
		g_node(m, rho1, r, y1);
		hermite5(y0, y1, h, m->g.c[i]);
		double exact = -table_eval(&m->f, r_mid);
		if (fabs(poly5(m->g.c[i], 0.5) - exact) > TOL_G * (1 + fabs(exact)))
			good = 0;
		y0[0] = y1[0];
		y0[1] = y1[1];
		y0[2] = y1[2];
	}
	return good;
}

/* Doubles the grid until build() reports every midpoint within TOL. */
static int refine(struct asph_lb_map *m, int (*build)(struct asph_lb_map *, size_t))
{
	for (size_t n = MIN_INTERVALS;; n *= 2) {
		int r = build(m, n);
		if (r < 0)
			return r;
		/* At the cap the table stands, a few bits short of TOL. */
		if (r == 1 || n >= MAX_INTERVALS)
			return 0;
	}
}

int asph_lb_map_alloc(const struct asph_surface *s, struct asph_lb_map **out,
		      struct asph_error *err)
{
	struct asph_lb_map *m = calloc(1, sizeof(*m));
	double d[3];

	if (!m)
		return asph_error_set(err, -ENOMEM, "out of memory");
	m->s = s;
	m->a = asph_surface_aperture_radius(s);
	asph_surface_sag_derivs(s, 0, d);
	m->f2_0 = 0.5 * d[2] * d[2];
	m->gl = gsl_integration_glfixed_table_alloc(GL_ORDER);
	if (!m->gl || refine(m, build_f) < 0 || refine(m, build_g) < 0) {
		asph_lb_map_free(m);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	*out = m;
	return 0;
}

void asph_lb_map_free(struct asph_lb_map *m)
{
	if (!m)
		return;
	table_clear(&m->f);
	table_clear(&m->g);
	if (m->gl)
		gsl_integration_glfixed_table_free(m->gl);
	free(m);
}

double asph_lb_map_aperture_radius(const struct asph_lb_map *m)
{
	return m->a;
}

/* |x| clamped to [0, a] when it overshoots a by rounding only. */
static double in_disk(const struct asph_lb_map *m, double x)
{
	x = fabs(x);
	if (x <= m->a)
		return x;
	return x <= m->a * (1 + 1e-9) ? m->a : NAN;
}

double asph_lb_map_rho(const struct asph_lb_map *m, double r)
{
	r = in_disk(m, r);
	if (isnan(r) || r == m->a)
		return r;
	return r * exp(table_eval(&m->f, r));
}

double asph_lb_map_rho_deriv(const struct asph_lb_map *m, double r)
{
	double d[3];

	r = in_disk(m, r);
	if (isnan(r))
		return NAN;
	asph_surface_sag_derivs(m->s, r, d);
	return sqrt(1.0 + d[1] * d[1]) * exp(table_eval(&m->f, r));
}

double asph_lb_map_radius(const struct asph_lb_map *m, double rho)
{
	rho = in_disk(m, rho);
	if (isnan(rho) || rho == m->a)
		return rho;
	return rho * exp(table_eval(&m->g, rho));
}
