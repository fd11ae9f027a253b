/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Line profiles: points on straight traces in x-y, as a tactile
 * profilometer measures an asphere (one trace through the apex, a cross, a
 * star). Finding the traces in the points, the degrees of freedom a
 * profile tells apart, a single profile's trace frame, and what the fit
 * leaves along the traces: RMS, PV, the slope along them and the form
 * quantities (docs/characterization.md, "Line profiles").
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_errno.h>
#include <gsl/gsl_linalg.h>

#include "asph/fit.h"
#include "fit-internal.h"
#include "util-mem.h"

/* Points within this fraction of the points' x-y extent of a line lie on
 * it: 10 um over 50 mm, ten times a stage's straightness and lateral
 * noise, a hundredth of the closest rows of a raster. */
#define LINE_TOL 2e-4
/* A trace among several holds at least this many points and spans at
 * least this fraction of the extent (a half diameter is 0.5): runs of
 * points along an arc of a circle or a spiral are not traces. */
#define MIN_TRACE_POINTS 3
#define MIN_TRACE_LENGTH 0.2
/* Lines closer in azimuth than this are parallel: points on parallel
 * lines are a raster, an areal measurement. */
#define MIN_TRACE_ANGLE (2.0 * M_PI / 180.0)
/* Degree of each trace's smooth fit of the residual (Legendre), at most. */
#define SMOOTH_DEGREE 10

/* ---------------------------------------------------------------- lines */

static void sums_add(struct fit_line_sums *s, double x, double y)
{
	s->n += 1;
	s->sx += x;
	s->sy += y;
	s->sxx += x * x;
	s->sxy += x * y;
	s->syy += y * y;
}

static void sums_merge(struct fit_line_sums *a, const struct fit_line_sums *b)
{
	a->n += b->n;
	a->sx += b->sx;
	a->sy += b->sy;
	a->sxx += b->sxx;
	a->sxy += b->sxy;
	a->syy += b->syy;
}

/* The least-squares line of the points summed: centroid m, unit direction
 * u with its azimuth in (-pi/2, pi/2]. Returns their spread (the trace of
 * their covariance). */
static double sums_line(const struct fit_line_sums *s, double m[2], double u[2])
{
	double n = s->n, cxx, cxy, cyy, angle;

	m[0] = s->sx / n;
	m[1] = s->sy / n;
	cxx = s->sxx / n - m[0] * m[0];
	cxy = s->sxy / n - m[0] * m[1];
	cyy = s->syy / n - m[1] * m[1];
	angle = 0.5 * atan2(2 * cxy, cxx - cyy);
	u[0] = cos(angle);
	u[1] = sin(angle);
	return cxx + cyy;
}

/* Whether (x, y) lies within tol of the line of s; always while s holds
 * too little to give a direction (one point, or points closer than tol). */
static int on_line(const struct fit_line_sums *s, double x, double y, double tol)
{
	double m[2], u[2];

	if (s->n < 2 || sums_line(s, m, u) <= 0.25 * tol * tol)
		return 1;
	return fabs((x - m[0]) * u[1] - (y - m[1]) * u[0]) <= tol;
}

/* ------------------------------------------------------------- traces */

/* Runs of consecutive points on one line; -1 for more than FIT_MAX_RUNS
 * (points that are no profiles). */
static int find_runs(struct asph_fit *w, const double *xyz, size_t n, double tol)
{
	const double *ref = w->traces.ref;
	int nr = 0;

	for (size_t i = 0; i < n; i++) {
		double x = xyz[3 * i] - ref[0], y = xyz[3 * i + 1] - ref[1];
		if (nr == 0 || !on_line(&w->runs[nr - 1].sums, x, y, tol)) {
			if (nr == FIT_MAX_RUNS)
				return -1;
			w->runs[nr++] = (struct fit_run){ .first = i };
		}
		sums_add(&w->runs[nr - 1].sums, x, y);
		w->runs[nr - 1].n++;
	}
	return nr;
}

static int run_on_trace(const struct asph_fit *w, const double *xyz, const struct fit_run *run,
			const struct fit_trace *t, double tol)
{
	const double *ref = w->traces.ref;

	for (size_t i = run->first; i < run->first + run->n; i++)
		if (!on_line(&t->sums, xyz[3 * i] - ref[0], xyz[3 * i + 1] - ref[1], tol))
			return 0;
	return 1;
}

/* Runs on one line make one trace (a trace needs not be measured in one
 * go), the longest runs first. Returns the traces, -1 for too many. */
static int merge_runs(struct asph_fit *w, const double *xyz, int nr, double tol)
{
	struct fit_trace *tr = w->traces.t;
	int order[FIT_MAX_RUNS], nt = 0;

	for (int r = 0; r < nr; r++) {
		int k = r;
		while (k > 0 && w->runs[order[k - 1]].n < w->runs[r].n) {
			order[k] = order[k - 1];
			k--;
		}
		order[k] = r;
	}
	for (int k = 0; k < nr; k++) {
		struct fit_run *run = &w->runs[order[k]];
		int t = 0;
		while (t < nt && !run_on_trace(w, xyz, run, &tr[t], tol))
			t++;
		if (t == nt) {
			if (nt == ASPH_FIT_MAX_PROFILES)
				return -1;
			memset(&tr[nt++], 0, sizeof(tr[0]));
		}
		sums_merge(&tr[t].sums, &run->sums);
		tr[t].n += run->n;
		run->trace = t;
	}
	return nt;
}

/* The traces in the order of their first point, and each point's. */
static void order_traces(struct asph_fit *w, int nr, int nt)
{
	struct fit_trace sorted[ASPH_FIT_MAX_PROFILES];
	int new_of[ASPH_FIT_MAX_PROFILES], m = 0;

	for (int t = 0; t < nt; t++)
		new_of[t] = -1;
	for (int r = 0; r < nr; r++) {      /* runs are in point order */
		int t = w->runs[r].trace;
		if (new_of[t] < 0) {
			new_of[t] = m;
			sorted[m++] = w->traces.t[t];
		}
	}
	memcpy(w->traces.t, sorted, (size_t)nt * sizeof(sorted[0]));
	for (int r = 0; r < nr; r++) {
		const struct fit_run *run = &w->runs[r];
		memset(w->trace_of + run->first, new_of[run->trace], run->n);
	}
}

/* Each trace's line, azimuth, offset from the machine axis and length. */
static void trace_geometry(struct asph_fit *w, const double *xyz, size_t n)
{
	struct fit_traces *tr = &w->traces;
	double lo[ASPH_FIT_MAX_PROFILES], hi[ASPH_FIT_MAX_PROFILES], m[ASPH_FIT_MAX_PROFILES][2];

	for (int t = 0; t < tr->n; t++) {
		struct fit_trace *f = &tr->t[t];
		sums_line(&f->sums, m[t], f->u);
		f->azimuth = atan2(f->u[1], f->u[0]);
		f->offset = (m[t][0] + tr->ref[0]) * -f->u[1] + (m[t][1] + tr->ref[1]) * f->u[0];
		lo[t] = INFINITY;
		hi[t] = -INFINITY;
	}
	for (size_t i = 0; i < n; i++) {
		int t = w->trace_of[i];
		double s = (xyz[3 * i] - tr->ref[0] - m[t][0]) * tr->t[t].u[0] +
			   (xyz[3 * i + 1] - tr->ref[1] - m[t][1]) * tr->t[t].u[1];
		lo[t] = fmin(lo[t], s);
		hi[t] = fmax(hi[t], s);
	}
	for (int t = 0; t < tr->n; t++)
		tr->t[t].length = hi[t] - lo[t];
}

/* Several traces are profiles when each is one (enough points, long) and
 * no two are parallel. */
static int traces_are_profiles(const struct fit_traces *tr, double extent)
{
	for (int t = 0; t < tr->n; t++) {
		if (tr->t[t].n < MIN_TRACE_POINTS || tr->t[t].length < MIN_TRACE_LENGTH * extent)
			return 0;
		for (int k = 0; k < t; k++) {
			double d = fabs(tr->t[t].azimuth - tr->t[k].azimuth);
			if (fmin(d, M_PI - d) < MIN_TRACE_ANGLE)
				return 0;
		}
	}
	return 1;
}

/* The points' traces into w->traces (n 0 when they are no profiles). */
static void find_traces(struct asph_fit *w, const double *xyz, size_t n, double extent)
{
	struct fit_traces *tr = &w->traces;
	double tol = LINE_TOL * extent;
	int nr = find_runs(w, xyz, n, tol), nt = nr > 0 ? merge_runs(w, xyz, nr, tol) : -1;

	if (nt <= 0)
		return;
	tr->n = nt;
	order_traces(w, nr, nt);
	trace_geometry(w, xyz, n);
	if (nt > 1 && !traces_are_profiles(tr, extent)) {
		tr->n = 0;
		return;
	}
	tr->single = nt == 1;
	if (tr->single) {
		tr->ca = tr->t[0].u[0];
		tr->sa = tr->t[0].u[1];
	}
}

/* The x-y extent of the points and its centre (the lines' reference). */
static double extent_of(const double *xyz, size_t n, double centre[2])
{
	double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };

	for (size_t i = 0; i < n; i++)
		for (int k = 0; k < 2; k++) {
			lo[k] = fmin(lo[k], xyz[3 * i + k]);
			hi[k] = fmax(hi[k], xyz[3 * i + k]);
		}
	centre[0] = 0.5 * (lo[0] + hi[0]);
	centre[1] = 0.5 * (lo[1] + hi[1]);
	return fmax(hi[0] - lo[0], hi[1] - lo[1]);
}

/* ------------------------------------------------------ the DOF, frame */

static void dof_names(unsigned mask, char *buf, size_t size)
{
	buf[0] = '\0';
	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (mask & ASPH_FIT_DOF_BIT(d))
			snprintf(buf + strlen(buf), size - strlen(buf), "%s%s", buf[0] ? ", " : "",
				 asph_fit_dof_name((enum asph_fit_dof)d));
}

/* A single profile tells apart the decentre along it, tz, the tilt about
 * the axis across it, R and k: tx, tz, ry of its trace's frame. */
static int profile_dof(struct asph_fit *w, struct asph_error *err)
{
	unsigned mask = w->dof_asked;
	char names[64];

	if (!w->traces.single)
		return fit_select_dof(w, mask, err);
	if (!w->model.rotational)
		return asph_error_set(err, -EINVAL,
				      "the %zu points are one line profile: the pose of a freeform "
				      "surface needs an area, or profiles at several azimuths",
				      (size_t)w->traces.t[0].n);
	if (w->dof_default) {
		mask = ASPH_FIT_DOF_PROFILE_DEFAULT;
	} else if (mask & ~ASPH_FIT_DOF_PROFILE) {
		dof_names(mask & ~ASPH_FIT_DOF_PROFILE, names, sizeof(names));
		return asph_error_set(err, -EINVAL,
				      "the points are one line profile (azimuth %.2f deg): it tells "
				      "apart tx (the decentre along the trace), tz, ry (the tilt about "
				      "the axis across it), R and k, in the trace's frame, not %s "
				      "(--dof tx,tz,ry[,R,k])",
				      w->traces.t[0].azimuth * 180 / M_PI, names);
	}
	return fit_select_dof(w, mask, err);
}

/* A single profile's points in its trace's frame: turned by -azimuth. */
static int to_trace_frame(struct asph_fit *w, const double *xyz, size_t n,
			  struct asph_error *err)
{
	const double c = w->traces.ca, s = w->traces.sa;

	if (!w->xyz_frame && !(w->xyz_frame = malloc(3 * w->n_max * sizeof(double) + 1)))
		return asph_error_set(err, -ENOMEM, "out of memory for %zu points", w->n_max);
	for (size_t i = 0; i < n; i++) {
		const double *p = xyz + 3 * i;
		double *q = w->xyz_frame + 3 * i;
		q[0] = c * p[0] + s * p[1];
		q[1] = -s * p[0] + c * p[1];
		q[2] = p[2];
	}
	return 0;
}

int fit_profile_setup(struct asph_fit *w, const double *xyz, size_t n, const double **pts,
		      struct asph_error *err)
{
	struct fit_traces *tr = &w->traces;
	double extent;
	int r;

	*pts = xyz;
	memset(tr, 0, sizeof(*tr));
	tr->ca = 1;
	extent = extent_of(xyz, n, tr->ref);
	if (!(extent > 0))
		return asph_error_set(err, -EINVAL,
				      "the %zu points lie at one place in x-y: no surface to fit", n);
	find_traces(w, xyz, n, extent);
	r = profile_dof(w, err);
	if (r == 0 && tr->single) {
		r = to_trace_frame(w, xyz, n, err);
		*pts = w->xyz_frame;
	}
	return r;
}

/*
 * p = Rz(a) (Ry(ry) Rx(rx) q' + t) in the machine frame for a profile
 * fitted in its trace's frame: t turned by a, and the axis Rz(a) Ry Rx e_z
 * as Ry(ry) Rx(rx) e_z = (sin ry cos rx, -sin rx, cos ry cos rx). What
 * remains is a clocking about the part's own axis, which a surface of
 * revolution does not show (rz 0).
 */
void fit_machine_pose(const struct asph_fit *w, struct asph_pose *pose)
{
	const double *f = w->full, c = w->traces.ca, s = w->traces.sa;
	double ax, ay, az;

	*pose = (struct asph_pose){ { f[ASPH_FIT_TX], f[ASPH_FIT_TY], f[ASPH_FIT_TZ] },
				    f[ASPH_FIT_RX], f[ASPH_FIT_RY], f[ASPH_FIT_RZ] };
	if (!w->traces.single)
		return;
	pose->t[0] = c * f[ASPH_FIT_TX] - s * f[ASPH_FIT_TY];
	pose->t[1] = s * f[ASPH_FIT_TX] + c * f[ASPH_FIT_TY];
	ax = sin(f[ASPH_FIT_RY]) * cos(f[ASPH_FIT_RX]);
	ay = -sin(f[ASPH_FIT_RX]);
	az = cos(f[ASPH_FIT_RY]) * cos(f[ASPH_FIT_RX]);
	pose->rx = -asin(fmax(-1.0, fmin(1.0, s * ax + c * ay)));
	pose->ry = atan2(c * ax - s * ay, az);
	pose->rz = 0;
}

/* ------------------------------------------- positions along the traces */

/* Each point's position along its trace: its foot (the part frame, the
 * machine's azimuths) on the trace's direction. */
static void positions(const struct asph_fit *w, double *s, double *xy)
{
	for (size_t i = 0; i < w->n; i++) {
		const double *u = w->traces.t[w->trace_of[i]].u;
		fit_point_foot(w, i, xy + 2 * i);
		s[i] = xy[2 * i] * u[0] + xy[2 * i + 1] * u[1];
	}
}

static double legendre_next(int k, double t, double p1, double p0)
{
	return ((2 * k + 1) * t * p1 - k * p0) / (k + 1);
}

/* The Legendre polynomials P_0 .. P_deg at t. */
static void legendre(int deg, double t, double *p)
{
	p[0] = 1;
	if (deg > 0)
		p[1] = t;
	for (int k = 1; k < deg; k++)
		p[k + 1] = legendre_next(k, t, p[k], p[k - 1]);
}

/* The weighted least-squares fit of values v at positions s (scaled to
 * [-1, 1] over [lo, hi]) by Legendre polynomials up to deg, lowered until
 * the points determine it. Returns the degree fitted, -1 for none. */
static int smooth_fit(const double *s, const double *v, const double *wt, const uint8_t *take,
		      size_t n, double lo, double hi, int deg, double *coef)
{
	for (; deg >= 0; deg--) {
		double M[(SMOOTH_DEGREE + 1) * (SMOOTH_DEGREE + 1)] = { 0 }, b[SMOOTH_DEGREE + 1] = { 0 };
		double p[SMOOTH_DEGREE + 1], rcond = 0, work[3 * (SMOOTH_DEGREE + 1)];
		size_t m = (size_t)deg + 1;
		gsl_matrix_view A = gsl_matrix_view_array(M, m, m);
		gsl_vector_view B = gsl_vector_view_array(b, m), X = gsl_vector_view_array(coef, m);
		gsl_vector_view W = gsl_vector_view_array(work, 3 * m);

		for (size_t i = 0; i < n; i++) {
			if (!take[i])
				continue;
			legendre(deg, hi > lo ? (2 * s[i] - lo - hi) / (hi - lo) : 0, p);
			for (size_t j = 0; j < m; j++) {
				b[j] += wt[i] * p[j] * v[i];
				for (size_t k = 0; k < m; k++)
					M[j * m + k] += wt[i] * p[j] * p[k];
			}
		}
		if (gsl_linalg_cholesky_decomp1(&A.matrix) == GSL_SUCCESS &&
		    gsl_linalg_cholesky_rcond(&A.matrix, &rcond, &W.vector) == GSL_SUCCESS &&
		    rcond > 1e-12 && gsl_linalg_cholesky_solve(&A.matrix, &B.vector, &X.vector) == 0)
			return deg;
	}
	return -1;
}

static double smooth_value(const double *coef, int deg, double s, double lo, double hi)
{
	double p[SMOOTH_DEGREE + 1], v = 0;

	legendre(deg, hi > lo ? (2 * s - lo - hi) / (hi - lo) : 0, p);
	for (int k = 0; k <= deg; k++)
		v += coef[k] * p[k];
	return v;
}

/* left[i] -= the smooth fit of trace t's values at the points take marks. */
static size_t smooth_trace(const struct asph_fit *w, int t, const double *s, double *left,
			   uint8_t *take)
{
	double lo = INFINITY, hi = -INFINITY, coef[SMOOTH_DEGREE + 1];
	size_t m = 0;
	int deg;

	for (size_t i = 0; i < w->n; i++) {
		take[i] = w->trace_of[i] == t && w->status[i] != ASPH_FIT_POINT_OUTSIDE &&
			  w->weight[i] > 0;
		if (!take[i])
			continue;
		lo = fmin(lo, s[i]);
		hi = fmax(hi, s[i]);
		m++;
	}
	deg = m < 3 ? (int)m - 1 : (int)fmin(SMOOTH_DEGREE, (double)(m - 1) / 2);
	if (m == 0 || (deg = smooth_fit(s, left, w->weight, take, w->n, lo, hi, deg, coef)) < 0)
		return 0;
	for (size_t i = 0; i < w->n; i++)
		if (w->trace_of[i] == t && w->status[i] != ASPH_FIT_POINT_OUTSIDE)
			left[i] -= smooth_value(coef, deg, s[i], lo, hi);
	return (size_t)deg + 1;
}

void fit_profile_smooth(const struct asph_fit *w, double *left, size_t *terms)
{
	/* w->scratch is the solver's; positions and the marks go in left's
	 * company: allocated here, outside the iterations */
	_cleanup_free_ double *s = malloc(3 * w->n * sizeof(double) + 1);
	_cleanup_free_ uint8_t *take = malloc(w->n + 1);

	*terms = 0;
	for (size_t i = 0; i < w->n; i++)
		left[i] = w->status[i] == ASPH_FIT_POINT_OUTSIDE ? NAN : w->resid[i];
	if (!s || !take)
		return;         /* no smooth part: the scale comes from the residual */
	positions(w, s, s + w->n);
	for (int t = 0; t < w->traces.n; t++)
		*terms += smooth_trace(w, t, s, left, take);
}

/* -------------------------------------------------- statistics, slope */

struct along {
	double s, f;            /* position on the trace (mm), residual (nm) */
};

static int along_cmp(const void *a, const void *b)
{
	double x = ((const struct along *)a)->s, y = ((const struct along *)b)->s;

	return (x > y) - (x < y);
}

/* The used points of trace t, their residual with the trace's
 * least-squares straight line removed, in order along it. */
static size_t trace_levelled(const struct asph_fit *w, int t, const double *s,
			     struct along *a)
{
	double n = 0, ss = 0, sf = 0, sss = 0, ssf = 0, det, c0 = 0, c1 = 0;
	size_t m = 0;

	for (size_t i = 0; i < w->n; i++)
		if (w->trace_of[i] == t && w->status[i] == ASPH_FIT_POINT_USED)
			a[m++] = (struct along){ s[i], asph_nm_from_mm(w->resid[i]).v };
	for (size_t k = 0; k < m; k++) {
		n += 1;
		ss += a[k].s;
		sf += a[k].f;
		sss += a[k].s * a[k].s;
		ssf += a[k].s * a[k].f;
	}
	det = n * sss - ss * ss;
	if (det > 0) {
		c1 = (n * ssf - ss * sf) / det;
		c0 = (sf - c1 * ss) / n;
	} else if (n > 0) {
		c0 = sf / n;
	}
	for (size_t k = 0; k < m; k++)
		a[k].f -= c0 + c1 * a[k].s;
	qsort(a, m, sizeof(a[0]), along_cmp);
	return m;
}

/* The interpolant at x inside [a[0].s, a[m-1].s], from index *k on (x
 * increasing from call to call): the two points and their weights. */
static double interpolate(const struct along *a, size_t m, double x, size_t *k, size_t idx[2],
			  double wt[2])
{
	while (*k + 2 < m && a[*k + 1].s < x)
		(*k)++;
	double span = a[*k + 1].s - a[*k].s, t = span > 0 ? (x - a[*k].s) / span : 0;

	t = fmin(fmax(t, 0), 1);
	idx[0] = *k;
	idx[1] = *k + 1;
	wt[0] = 1 - t;
	wt[1] = t;
	return wt[0] * a[*k].f + wt[1] * a[*k + 1].f;
}

/* What the slope samples of all traces add up to. */
struct slope_sums {
	double ss;              /* sum of the squared samples */
	double max;             /* largest |sample| */
	double max_w2;          /* the squared norm of its weights on F */
	double g2;              /* sum over points of (sum_j S_j dS_j/dF_i)^2 */
	size_t n;
};

/* The norm^2 of the weights w on points idx (repeated indices added). */
static double weights_norm2(const size_t *idx, const double *w, int n)
{
	double sum = 0;

	for (int i = 0; i < n; i++) {
		double v = w[i];
		int first = 1;
		for (int j = 0; j < i; j++)
			first &= idx[j] != idx[i];
		if (!first)
			continue;
		for (int j = i + 1; j < n; j++)
			if (idx[j] == idx[i])
				v += w[j];
		sum += v * v;
	}
	return sum;
}

/* The samples (F(p + L/2) - F(p - L/2)) / L of one trace's levelled
 * residual a (m points in order), p spaced as its points with both ends
 * inside it; g (m) gathers sum_j S_j dS_j/dF_i. */
static void trace_slope(const struct along *a, size_t m, double L, double *g,
			struct asph_fit_profile *p, struct slope_sums *sum)
{
	double lo = m ? a[0].s : 0, hi = m ? a[m - 1].s : 0, h, ss = 0, mx = 0;
	size_t ka = 0, kb = 0, n = 0;

	p->slope_rms.v = p->slope_max.v = NAN;
	p->n_slope = 0;
	if (m < 2 || hi - lo < L)
		return;
	h = (hi - lo) / (double)(m - 1);
	memset(g, 0, m * sizeof(double));
	for (double x = lo + 0.5 * L; x + 0.5 * L <= hi + 1e-12 * (1 + fabs(hi)); x += h) {
		size_t idx[4];
		double wt[4];
		double fb = interpolate(a, m, fmin(x + 0.5 * L, hi), &kb, idx, wt);
		double fa = interpolate(a, m, x - 0.5 * L, &ka, idx + 2, wt + 2);
		double v = (fb - fa) / L;
		for (int j = 0; j < 4; j++)
			wt[j] *= (j < 2 ? 1 : -1) / L;
		for (int j = 0; j < 4; j++)
			g[idx[j]] += v * wt[j];
		ss += v * v;
		mx = fmax(mx, fabs(v));
		if (fabs(v) >= sum->max) {
			sum->max = fabs(v);
			sum->max_w2 = weights_norm2(idx, wt, 4);
		}
		n++;
	}
	for (size_t k = 0; k < m; k++)
		sum->g2 += g[k] * g[k];
	sum->ss += ss;
	sum->n += n;
	p->n_slope = n;
	if (n) {
		p->slope_rms.v = sqrt(ss / (double)n);
		p->slope_max.v = mx;
	}
}

/* RMS (about the mean) and PV of a trace's used residual. */
static void trace_stats(const struct asph_fit *w, int t, struct asph_fit_profile *p)
{
	double sum = 0, sum2 = 0, lo = INFINITY, hi = -INFINITY, mean;
	size_t m = 0;

	p->n_points = p->n_used = 0;
	for (size_t i = 0; i < w->n; i++) {
		if (w->trace_of[i] != t)
			continue;
		p->n_points++;
		if (w->status[i] != ASPH_FIT_POINT_USED)
			continue;
		double v = asph_nm_from_mm(w->resid[i]).v;
		sum += v;
		lo = fmin(lo, v);
		hi = fmax(hi, v);
		m++;
	}
	p->n_used = m;
	mean = m ? sum / (double)m : NAN;
	for (size_t i = 0; i < w->n; i++)
		if (w->trace_of[i] == t && w->status[i] == ASPH_FIT_POINT_USED) {
			double v = asph_nm_from_mm(w->resid[i]).v - mean;
			sum2 += v * v;
		}
	p->rms.v = m ? sqrt(sum2 / (double)m) : NAN;
	p->pv.v = m ? hi - lo : NAN;
}

/* The point-to-point noise of the used points (nm): what the traces'
 * smooth fits leave, with their degrees of freedom; the fit's sigma when
 * they leave none. */
static double profile_noise(const struct asph_fit *w, const struct asph_fit_result *out,
			    double *left)
{
	size_t terms, m = 0;
	double ss = 0;

	fit_profile_smooth(w, left, &terms);
	for (size_t i = 0; i < w->n; i++)
		if (w->status[i] == ASPH_FIT_POINT_USED) {
			ss += left[i] * left[i];
			m++;
		}
	if (m > terms)
		return asph_nm_from_mm(sqrt(ss / (double)(m - terms))).v;
	return asph_nm_from_mm(out->sigma_mm).v;
}

/* The slope along the traces into out->slope (and each profile's), with
 * the expanded uncertainties of its RMS and maximum from the noise. */
static int profile_slope(const struct asph_fit *w, const double *s, double L, double noise,
			 struct asph_fit_result *out, struct asph_error *err)
{
	_cleanup_free_ struct along *a = malloc(w->n * sizeof(*a) + 1);
	_cleanup_free_ double *g = malloc(w->n * sizeof(double) + 1);
	struct slope_sums sum = { 0 };
	double rms;

	if (!a || !g)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (int t = 0; t < w->traces.n; t++) {
		size_t m = trace_levelled(w, t, s, a);
		trace_slope(a, m, L, g, &out->profiles[t], &sum);
	}
	fit_slope_invalid(&out->slope, L);
	if (sum.n == 0)
		return 0;
	rms = sqrt(sum.ss / (double)sum.n);
	out->slope.n = sum.n;
	out->slope.rms.v = rms;
	out->slope.max.v = sum.max;
	/* u(RMS) = sigma |grad RMS|, dRMS/dF_i = sum_j S_j dS_j/dF_i / (n RMS) */
	out->slope.u_rms.v = rms > 0 ? 2 * noise * sqrt(sum.g2) / ((double)sum.n * rms) : NAN;
	out->slope.u_max.v = 2 * noise * sqrt(sum.max_w2);
	out->slope_valid = 1;
	out->uncertainty_k2.slope_rms = out->slope.u_rms;
	out->uncertainty_k2.slope_max = out->slope.u_max;
	return 0;
}

/* The form quantities of the used points over the aperture's disk; of a
 * single profile with u along its trace, v not fitted. */
static int profile_form(const struct asph_fit *w, const double *xy, double wavelength,
			double noise, struct asph_fit_result *out, struct asph_error *err)
{
	_cleanup_free_ double *rho = malloc(w->n * sizeof(double) + 1);
	_cleanup_free_ double *theta = malloc(w->n * sizeof(double) + 1);
	_cleanup_free_ double *val = malloc(w->n * sizeof(double) + 1);
	double centre[2], disk_r, turn = w->traces.single ? w->traces.t[0].azimuth : 0;
	size_t m = 0;

	if (!rho || !theta || !val)
		return asph_error_set(err, -ENOMEM, "out of memory");
	asph_surface_aperture_disk(w->model.s, centre, &disk_r);
	for (size_t i = 0; i < w->n; i++) {
		if (w->status[i] != ASPH_FIT_POINT_USED)
			continue;
		double dx = xy[2 * i] - centre[0], dy = xy[2 * i + 1] - centre[1];
		rho[m] = hypot(dx, dy) / disk_r;
		theta[m] = atan2(dy, dx) - turn;
		val[m++] = asph_nm_from_mm(w->resid[i]).v;
	}
	return fit_form_quantities(rho, theta, val, m, wavelength, noise, w->traces.single, out,
				   err);
}

int fit_profile_fill(struct asph_fit *w, struct asph_fit_result *out, struct asph_error *err)
{
	_cleanup_free_ double *s = malloc(3 * w->n * sizeof(double) + 1);
	_cleanup_free_ double *left = malloc(w->n * sizeof(double) + 1);
	double wavelength, length, noise;
	int r;

	if (!s || !left)
		return asph_error_set(err, -ENOMEM, "out of memory");
	fit_form_lengths(w, &wavelength, &length);
	out->profile = 1;
	out->n_profiles = (size_t)w->traces.n;
	for (int t = 0; t < w->traces.n; t++) {
		const struct fit_trace *f = &w->traces.t[t];
		struct asph_fit_profile *p = &out->profiles[t];
		p->azimuth = f->azimuth;
		p->offset_mm = f->offset;
		p->length_mm = f->length;
		trace_stats(w, t, p);
	}
	positions(w, s, s + w->n);
	noise = profile_noise(w, out, left);
	r = profile_form(w, s + w->n, wavelength, noise, out, err);
	if (r == 0)
		r = profile_slope(w, s, length, noise, out, err);
	return r;
}
