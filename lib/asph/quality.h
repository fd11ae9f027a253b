/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_QUALITY_H
#define ASPH_QUALITY_H

#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Quality of a sampling plan (the paper's section 2): a triangulation of the
 * points and, per 3-D triangle, the shape measure q of Eq. (1) and the area
 * ratio A_i / mean(A), with summary statistics.
 *
 * The triangulation is a 2-D Delaunay triangulation in a chart of the
 * surface. The conformal chart (docs/conformal-chart.md) preserves angles,
 * so a Delaunay triangulation there is faithful to the surface even on
 * steep flanks; the vertex-plane (x-y) chart is offered for comparison and
 * produces needle triangles where the surface is steep. A mesh that comes
 * with the plan can be used instead.
 *
 * On a freeform surface the conformal chart has no closed form; there
 * ASPH_CHART_CONFORMAL is the harmonic chart of asph/lb.h (the P1 solution
 * of Eq. (6) with the aperture's edge fixed, at 1/48 of the radius of the
 * disk about the aperture), which on a surface of revolution is the
 * conformal chart up to scale.
 */
enum asph_quality_chart {
	ASPH_CHART_CONFORMAL = 0,  /* (rho(r) cos t, rho(r) sin t), isothermal */
	ASPH_CHART_VERTEX_PLANE,   /* (x, y) */
	ASPH_CHART_PLAN_MESH,      /* the triangles given with the points */
};

/* "conformal", "vertex-plane", "plan-mesh"; from_name also takes "xy". */
const char *asph_quality_chart_name(enum asph_quality_chart c);
int asph_quality_chart_from_name(const char *name,
				 enum asph_quality_chart *out);

/*
 * The conformal chart of a surface of revolution: rho(r) = r exp(I(r)),
 * I(r) = int_0^r (w(t) - 1) / t dt, w = sqrt(1 + Z'^2). I is tabulated at
 * alloc time; each evaluation adds one short Gauss-Legendre panel (bisected
 * only next to a slope singularity), so it costs O(1) and is accurate to a
 * few ulp of rho. The chart keeps a
 * pointer to s, which must outlive it.
 */
struct asph_conformal_chart;

int asph_conformal_chart_alloc(const struct asph_surface *s,
			       struct asph_conformal_chart **out,
			       struct asph_error *err);
void asph_conformal_chart_free(struct asph_conformal_chart *c);

/* rho(r) for 0 <= r <= aperture radius (a little beyond is allowed while
 * the sag is defined); NaN outside. */
double asph_conformal_chart_rho(const struct asph_conformal_chart *c,
				double r);

/* (x, y) of a surface point to chart coordinates (rho/r) (x, y). */
void asph_conformal_chart_map(const struct asph_conformal_chart *c, double x,
			      double y, double uv[2]);

/* q of Eq. (1) for the 3-D triangle abc: 1 for an equilateral triangle,
 * 0 for a degenerate one. */
double asph_quality_triangle_q(const double a[3], const double b[3],
			       const double c[3]);

/*
 * Summary of n values: percentiles interpolate linearly between order
 * statistics (position p (n - 1) in the sorted values); std is the sample
 * standard deviation (n - 1 in the denominator; 0 for n = 1).
 */
struct asph_quality_stats {
	double min, p25, median, p75, max, mean, std;
};

int asph_quality_summarize(const double *v, size_t n,
			   struct asph_quality_stats *out,
			   struct asph_error *err);

struct asph_quality_options {
	enum asph_quality_chart chart;
	/* A triangle on the rim of the triangulation is dropped while the
	 * angle opposite its rim edge exceeds this (radians, 3-D angle);
	 * 0 = 2 pi / 3. Not applied to a plan's own mesh. */
	double max_rim_angle;
};

struct asph_quality {
	enum asph_quality_chart chart;
	size_t n_points;
	size_t n_triangles;       /* kept */
	size_t n_dropped;         /* rim triangles removed */
	uint32_t *triangles;      /* 3 n_triangles: CCW in the chart, or the
				   * plan mesh as given */
	double *q;                /* n_triangles */
	double *area_ratio;       /* n_triangles, A_i / mean(A) */
	double mean_area;         /* mm^2 */
	struct asph_quality_stats q_stats, area_stats;
	double q_frac_gt_0_9;             /* fraction with q > 0.9 */
	double area_frac_within_5pct;     /* fraction with 0.95 <= A_i/mean <= 1.05 */
};

/*
 * xyz: n points on the surface (mm). mesh / n_mesh: the plan's own
 * triangles, used (and required) with ASPH_CHART_PLAN_MESH, ignored
 * otherwise. -EINVAL (err says why) for fewer than 3 points, a point off
 * the surface's domain, a mesh index out of range, or a triangulation
 * with no triangle left.
 */
int asph_quality_compute(const struct asph_surface *s, const double *xyz,
			 size_t n, const uint32_t *mesh, size_t n_mesh,
			 const struct asph_quality_options *opts,
			 struct asph_quality **out, struct asph_error *err);
void asph_quality_free(struct asph_quality *q);

#ifdef __cplusplus
}
#endif

#endif
