/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The feed-rate planner: a path of points timed close to the kinematic
 * limit, with a lookahead over a bounded window (docs/scanning.md,
 * "Motion").
 *
 * The path is planned in stretches, each from rest to rest: the whole path,
 * or after a stop the rest of it from where the stop ended. A stretch's
 * nodes are its points (after a stop the first node is the rest position,
 * which is no point). Along a stretch the planner keeps, in rings indexed by
 * node:
 *
 *   s      the path length at the node (straight segments between nodes);
 *   vlim   the speed limit at the node: the segments' speed (the axes'
 *          speeds along them, the probe's rate for their length) and the
 *          curvature (centripetal acceleration and jerk);
 *   vA     the acceleration-limited speed: a backward pass from the end of
 *          what is in the window (rest there), a forward pass from the last
 *          node that can no longer change;
 *   phases the acceleration-limited motion s_A(t): per segment at most an
 *          acceleration, a cruise and a deceleration, each at constant
 *          acceleration;
 *   ts, vs the time and speed of the jerk-limited motion at the node: the
 *          moving average of s_A over T = 2 a / j, s_T(t) = 1/T int_{t-T}^t
 *          s_A, whose third derivative is bounded by j, solved for
 *          s_T(ts) = s by Newton's method.
 *
 * A node is sampled once everything its moving average reads is final (far
 * enough from the window's artificial end), and checked: where the average
 * passes faster than the node allows (it does near a dip of the limit) or
 * too soon after the previous node for the probe, the node's limit is
 * lowered and the nodes after the last fixed one are planned again. A node
 * is handed out once no such repair can reach it.
 */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "asph/motion.h"

/* Shares of each axis' acceleration and of its jerk for the motion along
 * the path and for the turn of its direction; together they keep every
 * axis inside its limits. The jerk's share along the path is the larger:
 * it sets the moving average's width, which every change of speed pays
 * (a turnaround twice), while a turn's jerk grows only as v^3 and binds at
 * the short, sharp turns that are passed slowly anyway (bench-motion
 * measured the shares). */
#define TANGENTIAL 0.6
#define CENTRIPETAL 0.4
#define TANGENTIAL_JERK 0.75
#define CENTRIPETAL_JERK 0.25

/* Phases per segment: acceleration, cruise, deceleration. */
#define PHASES_PER_NODE 3

/* A sum kept with its rounding error (Knuth's two-sum): the integral of
 * s_A grows with the path while the moving average needs differences of
 * it over a few milliseconds, to the nanometre. */
struct sum {
	double hi, lo;
};

static inline struct sum sum_add(struct sum a, double x)
{
	double hi = a.hi + x, z = hi - a.hi;
	double err = (a.hi - (hi - z)) + (x - z);
	return (struct sum){ hi, a.lo + err };
}

/* a - b, for two sums close to each other. */
static inline double sum_diff(struct sum a, struct sum b)
{
	return (a.hi - b.hi) + (a.lo - b.lo);
}

struct phase {
	double t0;              /* start */
	double s0, v0, a;       /* s_A(t0 + tau) = s0 + v0 tau + a tau^2 / 2 */
	struct sum S0;          /* integral of s_A from the stretch's start to t0 */
};

struct asph_motion_planner {
	size_t cap, cap_ph;
	/* the path */
	asph_motion_point_fn point;
	const void *point_data;
	size_t n_points;
	struct asph_motion_limits lim;
	double a_t;             /* tangential acceleration (INFINITY: none) */
	double T;               /* moving-average width (0: no jerk limit) */
	double v_top;           /* no speed on the path exceeds it */
	double d_stop;          /* distance to stop from v_top */
	/* the current stretch */
	size_t first_point;     /* point of node 0, or of node 1 after a stop */
	bool virtual_start;     /* node 0 is where a stop ended: no point */
	double start_pos[ASPH_MOTION_AXES];
	size_t n_nodes;
	double t_origin;        /* path time at the stretch's start */
	bool stretch_done;      /* every node handed out */
	bool path_done;
	/* rings, by node g % cap */
	double *s, *vlim, *vA, *ts, *vs, *segcap;
	double *vcap;           /* vlim without the rest at the ends */
	double *hacc, *hjerk;   /* segment shapes: see segment_shape() */
	double *vraw;           /* the node's own limit, before the window's */
	double *as;             /* the average's acceleration at the node */
	double *tan3;           /* the path's unit direction at the node, 3 per node */
	double *pos3;           /* the node's position, 3 per node */
	double *tA;             /* time of s_A at the node */
	struct sum *SA;         /* integral of s_A until then */
	size_t *ph_first;       /* global index of the first phase of segment g */
	struct phase *ph;       /* by global phase index % cap_ph */
	size_t g_keep;          /* first node still in the rings */
	size_t g_fill;          /* nodes < g_fill are in */
	size_t g_shape;         /* segments < g_shape have their shape */
	size_t g_raw;           /* nodes < g_raw have their own limit */
	size_t g_vlim;          /* nodes < g_vlim have their limit */
	size_t g_fixed;         /* vA of nodes <= g_fixed and segments < g_fixed are final */
	size_t g_sampled;       /* nodes < g_sampled have ts, vs */
	size_t g_emit;          /* next node to hand out */
	size_t ph_end;          /* phases built: up to ph_end (global) */
	size_t cur_hi, cur_lo;  /* phase cursors */
	double last_t;          /* time of the last knot handed out */
	unsigned unrepaired;    /* limits the planner could not keep (stops) */
};

/* ------------------------------------------------------------ helpers */

/* The rings' sizes are powers of two. */
static inline size_t R(const struct asph_motion_planner *p, size_t g)
{
	return g & (p->cap - 1);
}

static inline struct phase *PH(const struct asph_motion_planner *p, size_t k)
{
	return &p->ph[k & (p->cap_ph - 1)];
}

/* The position of a node in the rings. */
static const double *node_pos(const struct asph_motion_planner *p, size_t g)
{
	return p->pos3 + 3 * R(p, g);
}

/* Reads node g's position into the rings. */
static void load_pos(struct asph_motion_planner *p, size_t g)
{
	double *o = p->pos3 + 3 * R(p, g);

	if (p->virtual_start && g == 0)
		memcpy(o, p->start_pos, 3 * sizeof(double));
	else
		p->point(p->point_data, p->first_point + g - (p->virtual_start ? 1 : 0), o);
}

static void array_point(const void *data, size_t i, double out[3])
{
	memcpy(out, (const double *)data + 3 * i, 3 * sizeof(double));
}

static uint32_t node_point(const struct asph_motion_planner *p, size_t g)
{
	return (uint32_t)(p->first_point + g - (p->virtual_start ? 1 : 0));
}

static double dist(const double *a, const double *b, double u[ASPH_MOTION_AXES])
{
	double d = 0;

	for (int k = 0; k < ASPH_MOTION_AXES; k++) {
		u[k] = b[k] - a[k];
		d += u[k] * u[k];
	}
	d = sqrt(d);
	for (int k = 0; k < ASPH_MOTION_AXES; k++)
		u[k] = d > 0 ? u[k] / d : 0;
	return d;
}

/* The tightest of per-axis limits along the unit vector u (INFINITY: none). */
static double along(const double *lim, const double *u)
{
	double best = INFINITY;

	for (int k = 0; k < ASPH_MOTION_AXES; k++)
		if (lim[k] > 0 && fabs(u[k]) > 1e-15)
			best = fmin(best, lim[k] / fabs(u[k]));
	return best;
}

static double min_positive(const double *v)
{
	double m = INFINITY;

	for (int k = 0; k < ASPH_MOTION_AXES; k++)
		if (v[k] > 0)
			m = fmin(m, v[k]);
	return m;
}

/* ------------------------------------------------------------ alloc */

void asph_motion_planner_free(struct asph_motion_planner *p)
{
	if (!p)
		return;
	free(p->s);
	free(p->vlim);
	free(p->vA);
	free(p->ts);
	free(p->vs);
	free(p->segcap);
	free(p->vcap);
	free(p->hacc);
	free(p->vraw);
	free(p->as);
	free(p->tan3);
	free(p->pos3);
	free(p->hjerk);
	free(p->tA);
	free(p->SA);
	free(p->ph_first);
	free(p->ph);
	free(p);
}

int asph_motion_planner_alloc(size_t window, struct asph_motion_planner **out)
{
	struct asph_motion_planner *p = calloc(1, sizeof(*p));

	if (!p)
		return -ENOMEM;
	size_t want = window ? window : 8192;
	p->cap = 64;
	while (p->cap < want && p->cap < ((size_t)1 << 40))
		p->cap *= 2;
	p->cap_ph = 4 * p->cap;     /* at most PHASES_PER_NODE per node, and the rest */
	p->s = malloc(p->cap * sizeof(double));
	p->vlim = malloc(p->cap * sizeof(double));
	p->vA = malloc(p->cap * sizeof(double));
	p->ts = malloc(p->cap * sizeof(double));
	p->vs = malloc(p->cap * sizeof(double));
	p->segcap = malloc(p->cap * sizeof(double));
	p->vcap = malloc(p->cap * sizeof(double));
	p->hacc = malloc(p->cap * sizeof(double));
	p->vraw = malloc(p->cap * sizeof(double));
	p->as = malloc(p->cap * sizeof(double));
	p->tan3 = malloc(3 * p->cap * sizeof(double));
	p->pos3 = malloc(3 * p->cap * sizeof(double));
	p->hjerk = malloc(p->cap * sizeof(double));
	p->tA = malloc(p->cap * sizeof(double));
	p->SA = malloc(p->cap * sizeof(struct sum));
	p->ph_first = malloc(p->cap * sizeof(size_t));
	p->ph = malloc(p->cap_ph * sizeof(struct phase));
	if (!p->s || !p->vlim || !p->vA || !p->ts || !p->vs || !p->segcap || !p->vcap || !p->hacc || !p->hjerk || !p->vraw || !p->as || !p->tan3 || !p->pos3 || !p->tA || !p->SA ||
	    !p->ph_first || !p->ph) {
		asph_motion_planner_free(p);
		return -ENOMEM;
	}
	*out = p;
	return 0;
}

/* ------------------------------------------------------------ stretch */

static void begin_stretch(struct asph_motion_planner *p, size_t first_point, bool virtual_start,
			  const double *start, double t_origin)
{
	p->first_point = first_point;
	p->virtual_start = virtual_start;
	if (virtual_start)
		memcpy(p->start_pos, start, sizeof(p->start_pos));
	p->n_nodes = p->n_points - first_point + (virtual_start ? 1 : 0);
	p->t_origin = t_origin;
	p->stretch_done = p->n_nodes == 0 || (virtual_start && p->n_nodes == 1);
	p->g_keep = p->g_fill = p->g_shape = p->g_raw = p->g_vlim = p->g_fixed = p->g_sampled = p->g_emit = 0;
	p->ph_end = 0;
	p->cur_hi = p->cur_lo = 0;
	if (p->virtual_start)
		p->g_emit = 1;      /* the stage is there already */
}

int asph_motion_planner_start_path(struct asph_motion_planner *p, asph_motion_point_fn point,
				   const void *data, size_t n, const struct asph_motion_limits *lim,
				   struct asph_error *err)
{
	int r = asph_motion_limits_check(lim, err);

	if (r < 0)
		return r;
	p->point = point;
	p->point_data = data;
	p->n_points = n;
	p->lim = *lim;
	double a = min_positive(lim->accel), j = min_positive(lim->jerk);
	p->v_top = sqrt(lim->speed[0] * lim->speed[0] + lim->speed[1] * lim->speed[1] +
			lim->speed[2] * lim->speed[2]);
	p->a_t = TANGENTIAL * a;
	if (!isfinite(p->a_t) && isfinite(j))
		p->a_t = sqrt(p->v_top * TANGENTIAL * j);  /* what a ramp to v_top peaks at */
	p->T = isfinite(j) && isfinite(p->a_t) ? 2 * p->a_t / (TANGENTIAL_JERK * j) : 0;
	p->d_stop = isfinite(p->a_t) ? p->v_top * p->v_top / (2 * p->a_t) : 0;
	p->last_t = 0;
	p->unrepaired = 0;
	p->path_done = n == 0;
	begin_stretch(p, 0, false, NULL, 0);
	return 0;
}

int asph_motion_planner_start(struct asph_motion_planner *p, const double *points, size_t n,
			      const struct asph_motion_limits *lim, struct asph_error *err)
{
	for (size_t i = 0; i < 3 * n; i++)
		if (!isfinite(points[i]))
			return asph_error_set(err, -EINVAL, "path point %zu is not finite", i / 3);
	return asph_motion_planner_start_path(p, array_point, points, n, lim, err);
}

/* ------------------------------------------------------------- limits */

static bool filled_all(const struct asph_motion_planner *p)
{
	return p->g_fill == p->n_nodes;
}

/*
 * The unit direction of the path at node g, once its neighbours are in: the
 * bisector of the directions of the segments before and after it. It
 * splits a turn evenly between the two segments' shapes; the chord from
 * neighbour to neighbour would lean to the longer segment and bend the
 * shorter one hard (the short step between a raster's rows at a rim). On a
 * smooth, evenly sampled path the two agree. A reversal onto itself, a
 * point given twice and the ends take the chord.
 */
static void compute_tangent(struct asph_motion_planner *p, size_t g)
{
	const double *a = node_pos(p, g > 0 ? g - 1 : g), *c = node_pos(p, g);
	const double *b = node_pos(p, g + 1 < p->n_nodes ? g + 1 : g);
	double *u = p->tan3 + 3 * R(p, g), u0[3], u1[3], m[3];
	static const double zero[3] = { 0, 0, 0 };

	if (dist(a, c, u0) > 0 && dist(c, b, u1) > 0) {
		for (int k = 0; k < 3; k++)
			m[k] = u0[k] + u1[k];
		if (dist(zero, m, u) > 1e-9)
			return;
	}
	if (!(dist(a, b, u) > 0))
		u[0] = u[1] = u[2] = 0;
}

static void tangent(const struct asph_motion_planner *p, size_t g, double u[3])
{
	memcpy(u, p->tan3 + 3 * R(p, g), 3 * sizeof(double));
}

/*
 * The shape of segment g as the stage follows it: the Hermite curve between
 * nodes g and g + 1 with the path's directions there, at a steady speed v
 * (each end's velocity v times its direction, the segment's time L / v).
 * Its acceleration is then v^2 / L times a vector of the geometry (largest
 * at an end) and its jerk v^3 / L^2 times another: hacc and hjerk are the
 * worst axis' ratios to its limits at v = 1, so that v^2 hacc <= 1 and
 * v^3 hjerk <= 1 keep the turn inside the limits.
 */
static void segment_shape(struct asph_motion_planner *p, size_t g)
{
	size_t r = R(p, g);
	double t0[3], t1[3], u[3];
	double l = dist(node_pos(p, g), node_pos(p, g + 1), u);

	p->hacc[r] = p->hjerk[r] = 0;
	if (!(l > 0))
		return;
	tangent(p, g, t0);
	tangent(p, g + 1, t1);
	for (int k = 0; k < 3; k++) {
		double c2 = 3 * u[k] - 2 * t0[k] - t1[k], c3 = -2 * u[k] + t0[k] + t1[k];
		double acc = fmax(fabs(2 * c2), fabs(2 * c2 + 6 * c3)) / l;
		double jerk = 6 * fabs(c3) / (l * l);
		if (p->lim.accel[k] > 0)
			p->hacc[r] = fmax(p->hacc[r], acc / p->lim.accel[k]);
		if (p->lim.jerk[k] > 0)
			p->hjerk[r] = fmax(p->hjerk[r], jerk / p->lim.jerk[k]);
	}
}

/* Adds node g (and the segment before it) to the rings. */
static void fill_node(struct asph_motion_planner *p, size_t g)
{
	size_t r = R(p, g);

	load_pos(p, g);
	if (g == 0) {
		p->s[r] = 0;
	} else {
		double u[3];
		double l = dist(node_pos(p, g - 1), node_pos(p, g), u);
		size_t q = R(p, g - 1);
		p->s[r] = p->s[q] + l;
		double cap = 0;
		if (l > 0) {
			cap = along(p->lim.speed, u);
			if (p->lim.rate > 0)
				cap = fmin(cap, p->lim.rate * l);
		}
		p->segcap[q] = cap;
	}
	p->vA[r] = 0;
}

/* The speed the shapes of the segments at node g allow, with the turn's
 * share of the limits. */
static double turn_limit(const struct asph_motion_planner *p, size_t g)
{
	double h = 0, hj = 0, v = INFINITY;

	for (size_t k = g > 0 ? g - 1 : g; k <= g && k + 1 < p->n_nodes; k++) {
		h = fmax(h, p->hacc[R(p, k)]);
		hj = fmax(hj, p->hjerk[R(p, k)]);
	}
	if (h > 0)
		v = sqrt(CENTRIPETAL / h);
	if (hj > 0)
		v = fmin(v, cbrt(CENTRIPETAL_JERK / hj));
	return v;
}

/* The node's own limit, once the segments on both sides have their shape. */
static void node_raw_limit(struct asph_motion_planner *p, size_t g)
{
	size_t r = R(p, g);
	double v = INFINITY;

	if (g > 0)
		v = fmin(v, p->segcap[R(p, g - 1)]);
	if (g + 1 < p->n_nodes)
		v = fmin(v, p->segcap[r]);
	if (p->n_nodes < 2)
		v = 0;
	if (v > 0)
		v = fmin(v, turn_limit(p, g));
	p->vraw[r] = v;
}

/* How far on either side of a node its moving average reads, at speed v. */
static double reach_at(const struct asph_motion_planner *p, double v)
{
	return 0.6 * p->T * v;
}

/* Whether node g's window of own limits is in. */
static bool window_in(const struct asph_motion_planner *p, size_t g)
{
	if (p->g_raw == p->n_nodes)
		return true;
	double w = reach_at(p, p->vraw[R(p, g)]);
	return p->g_raw > 0 && p->s[R(p, p->g_raw - 1)] > p->s[R(p, g)] + w;
}

/* What node h's own limit makes of the limit of a node d away: no less
 * than the speed at which the moving average reads back just to h. */
static double limit_at(const struct asph_motion_planner *p, size_t h, double d)
{
	double v = p->vraw[R(p, h)];

	return d > 0 && p->T > 0 ? fmax(v, d / (0.6 * p->T)) : v;
}

/*
 * The limit of node g: the lowest own limit within the reach of its moving
 * average on both sides. An average passes a node no faster than the
 * motion anywhere in its window, which then keeps the node's limit (a dip
 * of the limit would otherwise be averaged over). A node at a distance d
 * limits it to no less than d / (0.6 T): at that speed the average reads
 * back just to the node. Ahead of a turnaround the limit so rises with
 * the distance instead of staying at the turn's speed over the whole reach
 * of the speed before it; the repair catches what the average still
 * passes too fast.
 */
static void node_limit(struct asph_motion_planner *p, size_t g)
{
	size_t r = R(p, g);
	double v = p->vraw[r], w = reach_at(p, v), sg = p->s[r];

	for (size_t h = g; h-- > p->g_keep && p->s[R(p, h)] >= sg - w;)
		v = fmin(v, limit_at(p, h, sg - p->s[R(p, h)]));
	for (size_t h = g + 1; h < p->g_raw && p->s[R(p, h)] <= sg + w; h++)
		v = fmin(v, limit_at(p, h, p->s[R(p, h)] - sg));
	p->vcap[r] = v;
	/* at rest at the ends */
	p->vlim[r] = g == 0 || g + 1 == p->n_nodes ? 0 : v;
}

/* Nodes handed out per round of planning: what is planned and sampled
 * again after a repair is this much and the lookahead beyond it. */
#define CHUNK 256

static double lag_distance(const struct asph_motion_planner *p);

/* Whether the window reaches far enough past the next chunk to hand it
 * out. */
static bool far_enough(const struct asph_motion_planner *p)
{
	size_t want = p->g_emit + CHUNK;

	if (p->g_fill <= want)
		return false;
	return p->s[R(p, p->g_fill - 1)] >
	       p->s[R(p, want)] + lag_distance(p) + p->d_stop + 2 * p->v_top * p->T;
}

static void fill(struct asph_motion_planner *p)
{
	while (p->g_fill < p->n_nodes && p->g_fill - p->g_keep < p->cap && !far_enough(p)) {
		fill_node(p, p->g_fill);
		p->g_fill++;
	}
	/* segment g's shape needs the directions at g and g + 1 (nodes g - 1
	 * .. g + 2); node g's limit the shapes of segments g - 1 and g */
	while (p->g_shape + 1 < p->g_fill && (p->g_shape + 2 < p->g_fill || filled_all(p))) {
		if (p->g_shape == 0)
			compute_tangent(p, 0);
		compute_tangent(p, p->g_shape + 1);
		segment_shape(p, p->g_shape);
		p->g_shape++;
	}
	while (p->g_raw < p->g_fill &&
	       (p->g_raw < p->g_shape || (filled_all(p) && p->g_shape + 1 >= p->g_fill))) {
		node_raw_limit(p, p->g_raw);
		p->g_raw++;
	}
	while (p->g_vlim < p->g_raw && window_in(p, p->g_vlim)) {
		node_limit(p, p->g_vlim);
		p->g_vlim++;
	}
}

/* --------------------------------------------------------- the passes */

/* Backward from the last node in (at rest there), forward from the last
 * fixed node. */
static void passes(struct asph_motion_planner *p)
{
	size_t last = p->g_vlim - 1;
	double a2 = 2 * p->a_t;

	p->vA[R(p, last)] = 0;
	for (size_t g = last; g-- > p->g_fixed + 1;) {
		size_t r = R(p, g);
		double l = p->s[R(p, g + 1)] - p->s[r];
		double back = sqrt(p->vA[R(p, g + 1)] * p->vA[R(p, g + 1)] + a2 * l);
		p->vA[r] = fmin(p->vlim[r], back);
	}
	if (p->g_fixed == 0)
		p->vA[R(p, 0)] = 0;
	for (size_t g = p->g_fixed; g < last; g++) {
		size_t r = R(p, g), q = R(p, g + 1);
		double l = p->s[q] - p->s[r];
		double fwd = sqrt(p->vA[r] * p->vA[r] + a2 * l);
		if (g + 1 > p->g_fixed)
			p->vA[q] = fmin(p->vA[q], fwd);
	}
}

/* ------------------------------------------------------------ phases */

static void push_phase(struct asph_motion_planner *p, double t0, double s0, double v0, double a,
		       struct sum S0)
{
	*PH(p, p->ph_end++) = (struct phase){ t0, s0, v0, a, S0 };
}

/* The integral of s_A over the first tau of phase f. */
static double phase_int(const struct phase *f, double tau)
{
	return tau * (f->s0 + tau * (f->v0 / 2 + tau * f->a / 6));
}

/* Appends the phases of segment g, starting at (t, S); returns the end
 * time and integral. */
static void segment_phases(struct asph_motion_planner *p, size_t g, double *t, struct sum *S)
{
	size_t r = R(p, g), q = R(p, g + 1);
	double s0 = p->s[r], l = p->s[q] - s0;
	double v0 = p->vA[r], v1 = p->vA[q], a = p->a_t;

	p->ph_first[r] = p->ph_end;
	p->tA[r] = *t;
	p->SA[r] = *S;
	if (!(l > 0)) {
		/* a point given twice: at rest on it for one reading */
		double dwell = p->lim.rate > 0 ? 1 / p->lim.rate : 1e-6;
		push_phase(p, *t, s0, 0, 0, *S);
		*S = sum_add(*S, s0 * dwell);
		*t += dwell;
		return;
	}
	/* up to vp (at least the faster end: the passes saw to that), cruise,
	 * down to v1; no acceleration limit: the speed jumps */
	double vp = fmax(fmin(p->segcap[r], fmax(p->vcap[r], p->vcap[q])), fmax(v0, v1));
	if (isfinite(a))
		vp = fmin(vp, sqrt((v0 * v0 + v1 * v1) / 2 + a * l));
	vp = fmax(vp, fmax(v0, v1));
	double ta = 0, td = 0, da = 0, dd = 0;
	if (isfinite(a)) {
		ta = (vp - v0) / a;
		td = (vp - v1) / a;
		da = (vp * vp - v0 * v0) / (2 * a);
		dd = (vp * vp - v1 * v1) / (2 * a);
	}
	double dc = fmax(0, l - da - dd);
	if (ta > 0) {
		struct phase f = { *t, s0, v0, a, *S };
		push_phase(p, f.t0, f.s0, f.v0, f.a, f.S0);
		*S = sum_add(*S, phase_int(&f, ta));
		*t += ta;
	}
	if (dc > 0) {
		double tc = dc / vp;
		push_phase(p, *t, s0 + da, vp, 0, *S);
		*S = sum_add(*S, (s0 + da) * tc + vp * tc * tc / 2);
		*t += tc;
	}
	if (td > 0) {
		struct phase d = { *t, s0 + da + dc, vp, -a, *S };
		push_phase(p, d.t0, d.s0, d.v0, d.a, d.S0);
		*S = sum_add(*S, phase_int(&d, td));
		*t += td;
	}
}

/* Rebuilds the phases of the segments from the last fixed node on. */
static void build_phases(struct asph_motion_planner *p)
{
	size_t g = p->g_fixed, last = p->g_vlim - 1;
	double t = p->t_origin;
	struct sum S = { 0, 0 };

	if (g > 0) {
		/* segments before g stay: start where node g is */
		t = p->tA[R(p, g)];
		S = p->SA[R(p, g)];
		p->ph_end = p->ph_first[R(p, g)];
	} else {
		p->ph_end = 0;
	}
	for (; g < last; g++)
		segment_phases(p, g, &t, &S);
	/* at rest after the last node in */
	p->ph_first[R(p, last)] = p->ph_end;
	p->tA[R(p, last)] = t;
	p->SA[R(p, last)] = S;
	push_phase(p, t, p->s[R(p, last)], 0, 0, S);
	p->cur_hi = p->cur_lo = p->ph_first[R(p, p->g_keep)];
}

/* The phase that holds time t, moving the cursor. */
static const struct phase *phase_at(struct asph_motion_planner *p, double t, size_t *cur)
{
	size_t lo = p->ph_first[R(p, p->g_keep)];

	if (*cur < lo)
		*cur = lo;
	if (*cur >= p->ph_end)
		*cur = p->ph_end - 1;
	while (*cur + 1 < p->ph_end && PH(p, *cur + 1)->t0 <= t)
		(*cur)++;
	while (*cur > lo && PH(p, *cur)->t0 > t)
		(*cur)--;
	return PH(p, *cur);
}

/* s_A, v_A and the integral of s_A at t. Before the stretch: at rest at 0. */
static void eval_A(struct asph_motion_planner *p, double t, size_t *cur, double *s, double *v,
		   struct sum *S)
{
	if (t <= p->t_origin) {
		*s = 0;
		*v = 0;
		*S = (struct sum){ 0, 0 };
		return;
	}
	const struct phase *f = phase_at(p, t, cur);
	double tau = t - f->t0;
	*s = f->s0 + tau * (f->v0 + tau * f->a / 2);
	*v = f->v0 + tau * f->a;
	*S = f->S0;
	S->lo += phase_int(f, tau);
}

/* The moving average, its speed and (a may be NULL) its acceleration at t. */
static void eval_T3(struct asph_motion_planner *p, double t, double *s, double *v, double *a)
{
	double s1, v1, s0, v0;
	struct sum S1, S0;

	eval_A(p, t, &p->cur_hi, &s1, &v1, &S1);
	if (p->T == 0) {
		*s = s1;
		*v = v1;
		if (a) {
			const struct phase *f = phase_at(p, t, &p->cur_hi);
			*a = f->a;
		}
		return;
	}
	eval_A(p, t - p->T, &p->cur_lo, &s0, &v0, &S0);
	/* before the stretch began the stage was at rest at s = 0 */
	if (t - p->T < p->t_origin)
		S0 = (struct sum){ 0, 0 };
	*s = sum_diff(S1, S0) / p->T;
	*v = (s1 - s0) / p->T;
	if (a)
		*a = (v1 - v0) / p->T;
}

static void eval_T(struct asph_motion_planner *p, double t, double *s, double *v)
{
	eval_T3(p, t, s, v, NULL);
}

/* The time and speed of the moving average at node g; its acceleration
 * there in *acc. */
static void sample(struct asph_motion_planner *p, size_t g, double *acc)
{
	size_t r = R(p, g);
	double target = p->s[r];
	double t_node = p->tA[r];

	*acc = p->as[r] = 0;
	if (g == 0) {
		p->ts[r] = p->t_origin;
		p->vs[r] = 0;
		return;
	}
	if (g + 1 == p->n_nodes) {
		/* the average comes to rest exactly a width after s_A */
		p->ts[r] = t_node + p->T;
		p->vs[r] = 0;
		return;
	}
	if (p->T == 0) {
		double sa;
		p->ts[r] = t_node;
		p->vs[r] = p->vA[r];
		eval_T3(p, t_node, &sa, &sa, acc);
		p->as[r] = *acc;
		return;
	}
	/* s_T <= s_A, and s_T(t) >= s_A(t - T): t lies in [t_node, t_node + T] */
	double lo = t_node, hi = t_node + p->T, t = NAN, s, v, a;
	size_t q = R(p, g - 1);
	if (g > p->g_emit && p->ts[q] > lo)
		lo = p->ts[q];
	if (g > p->g_emit && p->vs[q] > 0) {
		/* from the node before, at its speed and acceleration */
		double ds = target - p->s[q], vq = p->vs[q], aq = p->as[q];
		double disc = vq * vq + 2 * aq * ds;
		t = p->ts[q] + (disc > 0 && aq != 0 ? (sqrt(disc) - vq) / aq : ds / vq);
	}
	if (!(t > lo && t < hi))
		t = (lo + hi) / 2;
	for (int it = 0;; it++) {
		eval_T3(p, t, &s, &v, &a);
		double f = s - target;
		if (fabs(f) <= 1e-14 * (1 + fabs(target)) || hi - lo <= 1e-14 * (1 + fabs(t)) ||
		    it == 100)
			break;
		if (f > 0)
			hi = t;
		else
			lo = t;
		double nt = v > 0 ? t - f / v : NAN;
		t = nt > lo && nt < hi ? nt : (lo + hi) / 2;
	}
	*acc = a;
	p->ts[r] = t;
	p->vs[r] = v;
	p->as[r] = a;
}

/* ------------------------------------------------------------- repair */

/*
 * How far node g's sampled motion is over a hard limit, as the factor its
 * speed must shrink by (1: within). The hard limits: the segments' speed and
 * the probe's rate (by the caller); each axis' whole acceleration (the
 * average's own along the path plus the turn's) and the turn's jerk. The
 * shares of the planning are a guess; these are the limits.
 */
static double excess(struct asph_motion_planner *p, size_t g, double a_T)
{
	size_t r = R(p, g);
	double v = p->vs[r], f = 1, h = 0, hj = 0, u[3], tang = 0;

	if (!(v > 0))
		return 1;
	double cap = g > 0 ? p->segcap[R(p, g - 1)] : INFINITY;
	if (g + 1 < p->n_nodes)
		cap = fmin(cap, p->segcap[r]);
	if (v > cap * (1 + 1e-9))
		f = fmin(f, cap / v);
	for (size_t k = g > 0 ? g - 1 : g; k <= g && k + 1 < p->n_nodes; k++) {
		h = fmax(h, p->hacc[R(p, k)]);
		hj = fmax(hj, p->hjerk[R(p, k)]);
	}
	tangent(p, g, u);
	for (int k = 0; k < 3; k++)
		if (p->lim.accel[k] > 0)
			tang = fmax(tang, fabs(a_T * u[k]) / p->lim.accel[k]);
	if (v * v * h + tang > 1 + 1e-9 && h > 0)
		f = fmin(f, sqrt(fmax(1 - tang, 0.05) / h) / v);
	if (hj > 0 && v * v * v * hj > 1 + 1e-9)
		f = fmin(f, cbrt(1 / hj) / v);
	return f;
}

/* Whether node g keeps its limits; when not, lowers the limits of the
 * nodes its average reads (what can lower it), and sets *redo to the first
 * node whose sample that may change. */
static bool keeps_limits(struct asph_motion_planner *p, size_t g, double a_T, size_t *redo)
{
	size_t r = R(p, g);
	double f = excess(p, g, a_T);

	/* the rate binds between readings: not from where a stop ended */
	if (p->lim.rate > 0 && g > 0 && !(p->virtual_start && g == 1) && g + 1 > p->g_emit) {
		double dt = p->ts[r] - p->ts[R(p, g - 1)], need = 1 / p->lim.rate;
		if (dt < need * (1 - 1e-9) && p->s[r] > p->s[R(p, g - 1)])
			f = fmin(f, dt / need);
	}
	if (f >= 1)
		return true;
	/* what the average reads: the nodes within its reach on both sides,
	 * no faster than the node may pass */
	double target = p->vs[r] * fmin(f, 0.98), reach = p->v_top * p->T;
	size_t lo = g, hi = g;
	while (lo > p->g_fixed && p->s[R(p, lo - 1)] >= p->s[r] - reach)
		lo--;
	while (hi + 1 < p->g_vlim && p->s[R(p, hi + 1)] <= p->s[r] + reach)
		hi++;
	/* the last fixed node keeps its speed; its cap bounds the segment
	 * after it, which may change */
	for (size_t h = lo; h <= hi; h++) {
		if (h > p->g_fixed)
			p->vlim[R(p, h)] = fmin(p->vlim[R(p, h)], target);
		p->vcap[R(p, h)] = fmin(p->vcap[R(p, h)], target);
	}
	/* the passes slow the motion down to lo from up to a stopping distance
	 * before it; an average reads a reach behind its node */
	double from = p->s[R(p, lo)] - p->d_stop - reach;
	size_t k = lo;
	while (k > p->g_emit && p->s[R(p, k - 1)] >= from)
		k--;
	*redo = k;
	return false;
}

/* ---------------------------------------------------------- pipeline */

static double lag_distance(const struct asph_motion_planner *p)
{
	return p->d_stop + 2 * p->v_top * p->T;
}

/* Whether node g's moving average reads only final motion. */
static bool sampleable(const struct asph_motion_planner *p, size_t g)
{
	if (g >= p->g_vlim)
		return false;
	if (filled_all(p) && p->g_vlim == p->n_nodes)
		return true;
	double end = p->s[R(p, p->g_vlim - 1)];
	return p->s[R(p, g)] + p->v_top * p->T + p->d_stop < end;
}

static bool emittable(const struct asph_motion_planner *p, size_t g)
{
	if (g >= p->g_sampled)
		return false;
	if (p->g_sampled == p->n_nodes)
		return true;
	return p->s[R(p, g)] + lag_distance(p) < p->s[R(p, p->g_sampled - 1)];
}

/* Plans what is in the window again and samples what can be. */
static void advance(struct asph_motion_planner *p)
{
	fill(p);
	if (p->g_vlim == 0)
		return;
	passes(p);
	build_phases(p);
	if (p->g_sampled < p->g_emit)
		p->g_sampled = p->g_emit;
	size_t repair_node = SIZE_MAX, redo, kept = p->g_emit;
	unsigned repairs = 0;
	/* a repair goes back a stopping distance: a node given up on is not
	 * repaired again, else two neighbours each lowering the other's
	 * limits would take turns with 60 repairs each, a plan of long
	 * segments for minutes; and the repairs of one window are bounded */
	size_t budget = 60 * (p->g_vlim - p->g_sampled + 1);
	while (sampleable(p, p->g_sampled)) {
		size_t g = p->g_sampled;
		double acc;
		sample(p, g, &acc);
		int give_up = (g == repair_node && repairs >= 60) || budget == 0;
		if (g >= kept && !give_up && !keeps_limits(p, g, acc, &redo)) {
			repairs = g == repair_node ? repairs + 1 : 1;
			repair_node = g;
			budget--;
			passes(p);
			build_phases(p);
			p->g_sampled = redo;
			continue;
		}
		if (g >= kept && give_up) {
			/* no lower limit helps here: keep what the motion can do */
			p->unrepaired++;
			repair_node = SIZE_MAX;
			kept = budget ? g + 1 : SIZE_MAX;
		}
		p->g_sampled++;
	}
}

static void knot_of(struct asph_motion_planner *p, size_t g, struct asph_motion_knot *k)
{
	size_t r = R(p, g);
	double u[3] = { 0, 0, 0 };

	if (p->vs[r] != 0)
		tangent(p, g, u);
	k->t = p->ts[r];
	memcpy(k->position, node_pos(p, g), sizeof(k->position));
	for (int j = 0; j < 3; j++)
		k->velocity[j] = p->vs[r] * u[j];
	k->flags = p->virtual_start && g == 0 ? 0 : ASPH_MOTION_KNOT_POINT;
	k->point = p->virtual_start && g == 0 ? UINT32_MAX : node_point(p, g);
}

/* After handing out node e: what its average read stays fixed. */
static void fix_after(struct asph_motion_planner *p, size_t e)
{
	double reach = p->s[R(p, e)] + p->v_top * p->T + 1e-9;

	/* the first node past where the average reached: the segment it read
	 * ends there at the latest */
	while (p->g_fixed + 1 < p->g_vlim && p->s[R(p, p->g_fixed)] <= reach)
		p->g_fixed++;
	/* keep the nodes whose phases an average may still read */
	double back = p->s[R(p, e)] - p->v_top * p->T - 1e-9;
	while (p->g_keep + 1 < e && p->g_keep + 2 < p->g_fixed &&
	       p->s[R(p, p->g_keep + 1)] < back)
		p->g_keep++;
}

int asph_motion_planner_next(struct asph_motion_planner *p, struct asph_motion_knot *out,
			     size_t max, size_t *n_out)
{
	size_t n = 0;

	while (n < max && !p->stretch_done) {
		if (!emittable(p, p->g_emit)) {
			size_t before = p->g_sampled, fill_before = p->g_fill;
			advance(p);
			if (!emittable(p, p->g_emit) && p->g_sampled == before &&
			    p->g_fill == fill_before)
				return -EDEADLK;        /* cannot happen: window too small */
			continue;
		}
		knot_of(p, p->g_emit, &out[n++]);
		p->last_t = p->ts[R(p, p->g_emit)];
		fix_after(p, p->g_emit);
		p->g_emit++;
		if (p->g_emit == p->n_nodes)
			p->stretch_done = true;
	}
	if (p->stretch_done)
		p->path_done = true;
	*n_out = n;
	return 0;
}

/* ---------------------------------------------------------------- stop */

int asph_motion_planner_stop(struct asph_motion_planner *p, struct asph_motion_knot *out,
			     size_t max, size_t *n_out)
{
	size_t e = p->g_emit;

	*n_out = 0;
	if (p->stretch_done || e == 0 || (p->virtual_start && e <= 1))
		return 0;
	double t_k = p->ts[R(p, e - 1)], s, v;
	struct sum S;
	size_t cur = p->cur_hi;
	eval_A(p, t_k, &cur, &s, &v, &S);
	/* from t_k the acceleration-limited motion brakes at once */
	double a = p->a_t, tb = isfinite(a) ? v / a : 0;
	double s_rest = s + (isfinite(a) ? v * v / (2 * a) : 0);
	double s_end = p->s[R(p, p->g_vlim - 1)];
	if (s_rest > s_end)
		s_rest = s_end;
	phase_at(p, t_k, &cur);
	p->ph_end = cur + 1;
	push_phase(p, t_k, s, v, isfinite(a) ? -a : 0, S);
	struct phase brk = *PH(p, p->ph_end - 1);
	push_phase(p, t_k + tb, s_rest, 0, 0, sum_add(brk.S0, phase_int(&brk, tb)));
	p->cur_hi = p->cur_lo = p->ph_first[R(p, p->g_keep)];

	/* the points it still passes */
	size_t g = e;
	while (g < p->g_vlim && p->s[R(p, g)] < s_rest - 1e-12) {
		if (*n_out == max)
			return -ENOBUFS;
		/* the node's accel-limited time is the braking's */
		size_t r = R(p, g);
		double target = p->s[r], lo = t_k, hi = t_k + tb + p->T + 1, t = (lo + hi) / 2, ss, vv;
		for (int it = 0; it < 200 && hi - lo > 1e-13 * (1 + hi); it++) {
			eval_T(p, t, &ss, &vv);
			if (ss < target)
				lo = t;
			else
				hi = t;
			double nt = vv > 0 ? t - (ss - target) / vv : NAN;
			t = nt > lo && nt < hi ? nt : (lo + hi) / 2;
		}
		eval_T(p, t, &ss, &vv);
		p->ts[r] = t;
		p->vs[r] = vv;
		knot_of(p, g, &out[(*n_out)++]);
		g++;
	}
	/* at rest: on a point, or between two. Without limits the stop is
	 * instant; a knot still needs a later time than the last. */
	double t_rest = t_k + fmax(tb + p->T, 1e-6);
	double pos[3];
	size_t next_point;
	if (g < p->n_nodes && fabs(p->s[R(p, g)] - s_rest) <= 1e-12 * (1 + s_rest)) {
		p->ts[R(p, g)] = t_rest;
		p->vs[R(p, g)] = 0;
		if (*n_out == max)
			return -ENOBUFS;
		knot_of(p, g, &out[(*n_out)++]);
		memcpy(pos, node_pos(p, g), sizeof(pos));
		next_point = node_point(p, g) + 1;
	} else {
		const double *a0 = node_pos(p, g - 1), *a1 = node_pos(p, g < p->n_nodes ? g : g - 1);
		double l = g < p->n_nodes ? p->s[R(p, g)] - p->s[R(p, g - 1)] : 0;
		double w = l > 0 ? (s_rest - p->s[R(p, g - 1)]) / l : 0;
		for (int k = 0; k < 3; k++)
			pos[k] = a0[k] + w * (a1[k] - a0[k]);
		if (*n_out == max)
			return -ENOBUFS;
		struct asph_motion_knot *k = &out[(*n_out)++];
		memset(k, 0, sizeof(*k));
		k->t = t_rest;
		memcpy(k->position, pos, sizeof(pos));
		k->point = UINT32_MAX;
		next_point = g < p->n_nodes ? node_point(p, g) : p->n_points;
	}
	p->last_t = t_rest;
	if (next_point >= p->n_points) {
		p->stretch_done = p->path_done = true;
		return 0;
	}
	begin_stretch(p, next_point, true, pos, t_rest);
	return 0;
}

unsigned asph_motion_planner_unkept(const struct asph_motion_planner *p)
{
	return p->unrepaired;
}

int asph_motion_path_duration(struct asph_motion_planner *p, const double *points, size_t n,
			      const struct asph_motion_limits *lim, double *seconds,
			      struct asph_error *err)
{
	struct asph_motion_knot k[64];
	size_t got;
	int r = asph_motion_planner_start(p, points, n, lim, err);

	*seconds = 0;
	while (r == 0) {
		r = asph_motion_planner_next(p, k, 64, &got);
		if (r < 0 || got == 0)
			break;
		*seconds = k[got - 1].t;
	}
	if (r < 0)
		return asph_error_set(err, r, "the path could not be planned");
	return 0;
}
