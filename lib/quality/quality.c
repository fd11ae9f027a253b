/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_statistics_double.h>


#include "asph/delaunay.h"
#include "asph/lb.h"
#include "asph/quality.h"
#include "util-mem.h"

#define DEFAULT_MAX_RIM_ANGLE (2 * M_PI / 3)

static void sub3(const double a[3], const double b[3], double out[3])
{
	for (int k = 0; k < 3; k++)
		out[k] = a[k] - b[k];
}

static double dot3(const double a[3], const double b[3])
{
	return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double triangle_area(const double a[3], const double b[3],
			    const double c[3])
{
	double u[3], v[3], n[3];

	sub3(b, a, u);
	sub3(c, a, v);
	n[0] = u[1] * v[2] - u[2] * v[1];
	n[1] = u[2] * v[0] - u[0] * v[2];
	n[2] = u[0] * v[1] - u[1] * v[0];
	return 0.5 * sqrt(dot3(n, n));
}

double asph_quality_triangle_q(const double a[3], const double b[3],
			       const double c[3])
{
	double u[3], v[3], w[3], sum;

	sub3(b, a, u);
	sub3(c, b, v);
	sub3(a, c, w);
	sum = dot3(u, u) + dot3(v, v) + dot3(w, w);
	if (!(sum > 0))
		return 0;
	return 4 * sqrt(3.0) * triangle_area(a, b, c) / sum;
}

/* The p-quantile by linear interpolation between order statistics (R's
 * type 7), each selected in linear time rather than sorted for. */
static double percentile(double *v, size_t n, double p)
{
	double pos = p * (double)(n - 1);
	size_t i = (size_t)floor(pos);
	double lo;

	if (i + 1 >= n)
		return gsl_stats_select(v, 1, n, n - 1);
	lo = gsl_stats_select(v, 1, n, i);
	return lo + (pos - (double)i) * (gsl_stats_select(v, 1, n, i + 1) - lo);
}

int asph_quality_summarize(const double *v, size_t n,
			   struct asph_quality_stats *out,
			   struct asph_error *err)
{
	_cleanup_free_ double *s = NULL;
	double sum = 0, ss = 0, mean;

	if (!v || n == 0)
		return asph_error_set(err, -EINVAL, "no values to summarize");
	s = malloc(n * sizeof(double));
	if (!s)
		return asph_error_set(err, -ENOMEM, "out of memory for %zu values", n);
	for (size_t i = 0; i < n; i++) {
		if (isnan(v[i]))
			return asph_error_set(err, -EINVAL, "value %zu is not a number", i);
		s[i] = v[i];
		sum += v[i];
	}
	mean = sum / (double)n;
	for (size_t i = 0; i < n; i++)
		ss += (v[i] - mean) * (v[i] - mean);
	*out = (struct asph_quality_stats){ .mean = mean,
					    .std = n > 1 ? sqrt(ss / (double)(n - 1)) : 0 };
	gsl_stats_minmax(&out->min, &out->max, s, 1, n);
	out->p25 = percentile(s, n, 0.25);
	out->median = percentile(s, n, 0.5);
	out->p75 = percentile(s, n, 0.75);
	return 0;
}

/* The harmonic chart's pitch on a freeform: this fraction of the radius of
 * the disk about the aperture (~7000 nodes on a circle); the chart's
 * O(pitch^2) error is far below what moves a Delaunay edge of a plan. */
#define FREEFORM_CHART_DIVISIONS 48

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_lb_chart *, asph_lb_chart_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_conformal_chart *, asph_conformal_chart_free)

/* On a freeform the conformal chart has no closed form: the harmonic chart
 * (asph/lb.h), which is the conformal one on a surface of revolution. */
static int harmonic_chart_points(const struct asph_surface *s, const double *xyz, size_t n,
				 double *uv, struct asph_error *err)
{
	_cleanup_(asph_lb_chart_freep) struct asph_lb_chart *c = NULL;
	double centre[2], R;
	int r;

	asph_surface_aperture_disk(s, centre, &R);
	r = asph_lb_chart_alloc(s, R / FREEFORM_CHART_DIVISIONS, &c, err);
	if (r < 0)
		return r;
	for (size_t i = 0; i < n; i++)
		if (asph_lb_chart_map(c, xyz[3 * i], xyz[3 * i + 1], uv + 2 * i) < 0)
			return asph_error_set(err, -EINVAL,
					      "point %zu (%g, %g) mm is outside the aperture", i,
					      xyz[3 * i], xyz[3 * i + 1]);
	return 0;
}

/* Chart coordinates of every point; NaN (a point where the sag is not
 * defined) is refused with the point's index. */
static int chart_points(const struct asph_surface *s, const double *xyz,
			size_t n, enum asph_quality_chart chart, double *uv,
			struct asph_error *err)
{
	_cleanup_(asph_conformal_chart_freep) struct asph_conformal_chart *c = NULL;
	int r = 0;

	if (chart == ASPH_CHART_CONFORMAL && !asph_surface_is_rotational(s))
		return harmonic_chart_points(s, xyz, n, uv, err);
	if (chart == ASPH_CHART_CONFORMAL) {
		r = asph_conformal_chart_alloc(s, &c, err);
		if (r < 0)
			return r;
	}
	for (size_t i = 0; i < n && r == 0; i++) {
		if (c) {
			asph_conformal_chart_map(c, xyz[3 * i], xyz[3 * i + 1], uv + 2 * i);
		} else {
			uv[2 * i] = xyz[3 * i];
			uv[2 * i + 1] = xyz[3 * i + 1];
		}
		if (!isfinite(uv[2 * i]) || !isfinite(uv[2 * i + 1]))
			r = asph_error_set(err, -EINVAL,
					   "point %zu (r = %g mm) is outside the surface's domain",
					   i, hypot(xyz[3 * i], xyz[3 * i + 1]));
	}
	return r;
}

/* Angle of triangle t at the vertex opposite its edge e, in 3-D. */
static double opposite_angle(const double *xyz, const uint32_t *tri, int e)
{
	const double *a = xyz + 3 * (size_t)tri[e];
	const double *b = xyz + 3 * (size_t)tri[(e + 1) % 3];
	const double *c = xyz + 3 * (size_t)tri[(e + 2) % 3];
	double u[3], v[3];

	sub3(a, c, u);
	sub3(b, c, v);
	return atan2(sqrt(fmax(dot3(u, u) * dot3(v, v) - dot3(u, v) * dot3(u, v), 0)),
		     dot3(u, v));
}

static int rim_edge(const uint32_t *nb, const unsigned char *alive, size_t t,
		    int e)
{
	uint32_t o = nb[3 * t + (size_t)e];

	return o == UINT32_MAX || !alive[o];
}

/*
 * Peels the rim: a triangle with an edge on the current boundary goes when
 * the angle facing that edge exceeds max_angle (a sliver the convex hull
 * spans between rim points, which no surface reconstruction would make);
 * its neighbours are then examined in turn. Each triangle is queued at most
 * four times (once at the start, once per neighbour removed).
 */
static size_t peel_rim(const double *xyz, const uint32_t *tri,
		       const uint32_t *nb, size_t m, double max_angle,
		       unsigned char *alive)
{
	_cleanup_free_ uint32_t *queue = malloc(4 * m * sizeof(uint32_t) + 1);
	size_t head = 0, tail = 0, dropped = 0;

	if (!queue)
		return SIZE_MAX;
	for (size_t t = 0; t < m; t++) {
		alive[t] = 1;
		for (int e = 0; e < 3; e++)
			/* nb is set: asph_delaunay_neighbors() returned 0. */
			if (nb[3 * t + (size_t)e] == UINT32_MAX) { // NOLINT(clang-analyzer-core.NullDereference)
				queue[tail++] = (uint32_t)t;
				break;
			}
	}
	while (head < tail) {
		size_t t = queue[head++];
		if (!alive[t])
			continue;
		for (int e = 0; e < 3; e++) {
			if (!rim_edge(nb, alive, t, e) ||
			    opposite_angle(xyz, tri + 3 * t, e) <= max_angle)
				continue;
			alive[t] = 0;
			dropped++;
			for (int k = 0; k < 3; k++) {
				uint32_t o = nb[3 * t + (size_t)k];
				if (o != UINT32_MAX && alive[o])
					queue[tail++] = o;
			}
			break;
		}
	}
	return dropped;
}

/* Delaunay in the chart, then the rim peeled. */
static int triangulate(const struct asph_surface *s, const double *xyz,
		       size_t n, const struct asph_quality_options *o,
		       struct asph_quality *q, struct asph_error *err)
{
	_cleanup_free_ double *uv = malloc(2 * n * sizeof(double));
	_cleanup_free_ uint32_t *tri = NULL, *nb = NULL;
	_cleanup_free_ unsigned char *alive = NULL;
	struct asph_delaunay *w;
	size_t m = 0, k = 0, dropped;
	double max_angle = o->max_rim_angle > 0 ? o->max_rim_angle : DEFAULT_MAX_RIM_ANGLE;
	int r;

	if (!uv)
		return asph_error_set(err, -ENOMEM, "out of memory for %zu chart points", n);
	r = chart_points(s, xyz, n, o->chart, uv, err);
	if (r < 0)
		return r;
	w = asph_delaunay_alloc(n);
	if (!w)
		return asph_error_set(err, -ENOMEM, "out of memory triangulating %zu points", n);
	r = asph_delaunay_triangulate(w, uv, n, &tri, &m, err);
	if (r == 0)
		r = asph_delaunay_neighbors(w, &nb, err);
	asph_delaunay_free(w);
	if (r < 0)
		return r;
	alive = malloc(m);
	if (!alive)
		return asph_error_set(err, -ENOMEM, "out of memory for %zu triangles", m);
	dropped = peel_rim(xyz, tri, nb, m, max_angle, alive);
	if (dropped == SIZE_MAX)
		return asph_error_set(err, -ENOMEM, "out of memory for %zu triangles", m);
	for (size_t t = 0; t < m; t++)
		if (alive[t])
			memmove(tri + 3 * k++, tri + 3 * t, 3 * sizeof(uint32_t));
	q->n_triangles = k;
	q->n_dropped = dropped;
	q->triangles = tri;
	tri = NULL;
	return 0;
}

static int copy_mesh(const uint32_t *mesh, size_t n_mesh, size_t n,
		     struct asph_quality *q, struct asph_error *err)
{
	if (!mesh || n_mesh == 0)
		return asph_error_set(err, -EINVAL, "the plan has no mesh of its own");
	for (size_t k = 0; k < 3 * n_mesh; k++)
		if (mesh[k] >= n)
			return asph_error_set(err, -EINVAL,
					      "mesh triangle %zu uses point %u of %zu",
					      k / 3, mesh[k], n);
	q->triangles = malloc(3 * n_mesh * sizeof(uint32_t));
	if (!q->triangles)
		return asph_error_set(err, -ENOMEM, "out of memory for %zu triangles", n_mesh);
	memcpy(q->triangles, mesh, 3 * n_mesh * sizeof(uint32_t));
	q->n_triangles = n_mesh;
	return 0;
}

static int measure(const double *xyz, struct asph_quality *q,
		   struct asph_error *err)
{
	size_t m = q->n_triangles, n_good_q = 0, n_near_mean = 0;
	double sum = 0;
	int r;

	if (m == 0)
		return asph_error_set(err, -EINVAL, "no triangle is left to measure");
	q->q = malloc(m * sizeof(double));
	q->area_ratio = malloc(m * sizeof(double));
	if (!q->q || !q->area_ratio)
		return asph_error_set(err, -ENOMEM, "out of memory for %zu triangles", m);
	for (size_t t = 0; t < m; t++) {
		const double *a = xyz + 3 * (size_t)q->triangles[3 * t];
		const double *b = xyz + 3 * (size_t)q->triangles[3 * t + 1];
		const double *c = xyz + 3 * (size_t)q->triangles[3 * t + 2];
		q->area_ratio[t] = triangle_area(a, b, c);
		q->q[t] = asph_quality_triangle_q(a, b, c);
		sum += q->area_ratio[t];
	}
	q->mean_area = sum / (double)m;
	if (!(q->mean_area > 0))
		return asph_error_set(err, -EINVAL, "every triangle is degenerate");
	for (size_t t = 0; t < m; t++) {
		q->area_ratio[t] /= q->mean_area;
		n_good_q += q->q[t] > 0.9;
		n_near_mean += q->area_ratio[t] >= 0.95 && q->area_ratio[t] <= 1.05;
	}
	q->q_frac_gt_0_9 = (double)n_good_q / (double)m;
	q->area_frac_within_5pct = (double)n_near_mean / (double)m;
	r = asph_quality_summarize(q->q, m, &q->q_stats, err);
	if (r == 0)
		r = asph_quality_summarize(q->area_ratio, m, &q->area_stats, err);
	return r;
}

int asph_quality_compute(const struct asph_surface *s, const double *xyz,
			 size_t n, const uint32_t *mesh, size_t n_mesh,
			 const struct asph_quality_options *opts,
			 struct asph_quality **out, struct asph_error *err)
{
	struct asph_quality_options o = { 0 };
	struct asph_quality *q;
	int r;

	if (opts)
		o = *opts;
	if (!s || !xyz || !out)
		return asph_error_set(err, -EINVAL, "quality: no surface or no points");
	if (n < 3)
		return asph_error_set(err, -EINVAL, "quality needs at least 3 points, got %zu", n);
	if (n > ASPH_DELAUNAY_MAX_POINTS)
		return asph_error_set(err, -E2BIG, "quality: %zu points is more than %zu", n,
				      ASPH_DELAUNAY_MAX_POINTS);
	if ((unsigned)o.chart > ASPH_CHART_PLAN_MESH)
		return asph_error_set(err, -EINVAL, "quality: unknown chart %d", (int)o.chart);
	if (!(o.max_rim_angle >= 0 && o.max_rim_angle < M_PI))
		return asph_error_set(err, -EINVAL,
				      "quality: rim angle %g is not in [0, pi) radians",
				      o.max_rim_angle);
	for (size_t i = 0; i < 3 * n; i++)
		if (!isfinite(xyz[i]))
			return asph_error_set(err, -EINVAL, "point %zu has a non-finite coordinate",
					      i / 3);
	q = calloc(1, sizeof(*q));
	if (!q)
		return asph_error_set(err, -ENOMEM, "quality: out of memory");
	q->chart = o.chart;
	q->n_points = n;
	if (o.chart == ASPH_CHART_PLAN_MESH)
		r = copy_mesh(mesh, n_mesh, n, q, err);
	else
		r = triangulate(s, xyz, n, &o, q, err);
	if (r == 0)
		r = measure(xyz, q, err);
	if (r < 0) {
		asph_quality_free(q);
		return r;
	}
	*out = q;
	return 0;
}

void asph_quality_free(struct asph_quality *q)
{
	if (!q)
		return;
	free(q->triangles);
	free(q->q);
	free(q->area_ratio);
	free(q);
}
