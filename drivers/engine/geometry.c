/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The scan's geometry: kinematics, targets, clearance of moves, the
 * checks made before the first move; the axes' limits for the planner and
 * the cut of untimed sweeps. geometry.h. */
#include <errno.h>
#include <math.h>
#include <string.h>

#include "scan.h"

/* Calls fn at the points of a 201 x 201 grid over a freeform's aperture. */
static void freeform_grid(const struct asph_surface *s, void (*fn)(void *, const struct asph_sag *),
			  void *ctx)
{
	double box[4];
	struct asph_sag d;

	asph_surface_bounds(s, box);
	for (int i = 0; i <= 200; i++)
		for (int j = 0; j <= 200; j++) {
			double x = box[0] + (box[1] - box[0]) * i / 200.0;
			double y = box[2] + (box[3] - box[2]) * j / 200.0;
			if (!asph_surface_contains(s, x, y, 0))
				continue;
			asph_surface_derivs_xy(s, x, y, &d);
			fn(ctx, &d);
		}
}

/* Gershgorin's bound on the Hessian's eigenvalues. */
static void curvature_at(void *ctx, const struct asph_sag *d)
{
	double *k = ctx;

	*k = fmax(*k, fmax(fabs(d->zxx) + fabs(d->zxy), fabs(d->zxy) + fabs(d->zyy)));
}

/* max over the aperture of the surface's principal curvatures' bound,
 * max(|Z''|, |Z'/r|) (a freeform: of its Hessian's), with a margin for the
 * sampling. */
static double curvature_bound(const struct asph_surface *s)
{
	double a = asph_surface_aperture_radius(s), k = 0, d[3];

	if (!asph_surface_is_rotational(s)) {
		freeform_grid(s, curvature_at, &k);
		return 1.25 * k;
	}

	for (int j = 0; j <= 2000; j++) {
		double r = a * j / 2000.0;
		asph_surface_sag_derivs(s, r, d);
		k = fmax(k, fabs(d[2]));
		if (r > 0)
			k = fmax(k, fabs(d[1] / r));
	}
	return 1.25 * k;
}

void scan_geometry_init(struct asph_scan *sc)
{
	sc->geo.curvature = curvature_bound(sc->surface);
}

/* ------------------------------------------------------ kinematics */

void scan_to_machine(struct asph_scan *sc, const double c[3], double m[3])
{
	if (sc->inst->stage_info.kinematics != ASPH_KINEMATICS_RTZ) {
		memcpy(m, c, 3 * sizeof(double));
		return;
	}
	double r = hypot(c[0], c[1]), th = sc->geo.theta_prev;
	if (r > 1e-12) {
		/* the rotary axis takes the short way from where it is */
		double d = remainder(atan2(c[1], c[0]) - sc->geo.theta_prev, 2 * M_PI);
		th = sc->geo.theta_prev + d;
	}
	sc->geo.theta_prev = th;
	m[0] = r;
	m[1] = th;
	m[2] = c[2];
}

void scan_to_cartesian(const struct asph_scan *sc, const double m[3], double c[3])
{
	if (sc->inst->stage_info.kinematics != ASPH_KINEMATICS_RTZ) {
		memcpy(c, m, 3 * sizeof(double));
		return;
	}
	c[0] = m[0] * cos(m[1]);
	c[1] = m[0] * sin(m[1]);
	c[2] = m[2];
}

void scan_turn_from(struct asph_scan *sc, double theta)
{
	sc->geo.theta_prev = theta;
}

/* The stage position measuring plan point i: the tip centre (tactile) on
 * the point's normal, the probe reference a standoff before it. The probe
 * looks along +z, so "before" and "above" are -z. */
void scan_target(struct asph_scan *sc, size_t i, bool need_normal, struct target *t)
{
	scan_target_at(sc, sc->xyz + 3 * i, need_normal, t);
}

void scan_target_at(struct asph_scan *sc, const double p[3], bool need_normal, struct target *t)
{
	/* the normal costs as much as the rest: only when it is used */
	if (need_normal || sc->tip > 0)
		asph_surface_normal(sc->surface, p[0], p[1], t->normal);
	else
		t->normal[0] = t->normal[1] = 0, t->normal[2] = 1;
	for (int k = 0; k < 3; k++)
		t->cart[k] = p[k] - sc->tip * t->normal[k];
	t->cart[2] -= sc->inst->probe_info.standoff;
	scan_to_machine(sc, t->cart, t->machine);
	t->approach[0] = t->machine[0];
	t->approach[1] = t->machine[1];
	t->approach[2] = t->machine[2] - sc->o.clearance;
}

/* ------------------------------------------------------- clearance */

/* How far the probe at cartesian c is from where it measures: the gap
 * along the probe axis between its reference point and the nominal
 * surface, less the standoff and the tip (0 on a measuring position,
 * clearance above it). Nothing below: +infinity. */
double scan_gap(const struct asph_scan *sc, const double c[3])
{
	double d[3];

	if (!asph_surface_is_rotational(sc->surface)) {
		struct asph_sag g;
		asph_surface_derivs_xy(sc->surface, c[0], c[1], &g);
		if (!isfinite(g.z))
			return INFINITY;
		return g.z - c[2] - sc->inst->probe_info.standoff -
		       sc->tip * sqrt(1 + g.zx * g.zx + g.zy * g.zy);
	}
	asph_surface_sag_derivs(sc->surface, sqrt(c[0] * c[0] + c[1] * c[1]), d);
	if (!isfinite(d[0]))
		return INFINITY;
	return d[0] - c[2] - sc->inst->probe_info.standoff - sc->tip * sqrt(1 + d[1] * d[1]);
}

/* Whether the stage's straight move (in its axes) from a to b keeps the
 * gap at least min_gap all along; ga, gb are the gaps at the ends when
 * known, else NAN. */
bool scan_path_clear_g(const struct asph_scan *sc, const double *a, double ga,
			 const double *b, double gb, double min_gap)
{
	double ca[3], cb[3], c[3], m[3];

	scan_to_cartesian(sc, a, ca);
	scan_to_cartesian(sc, b, cb);
	double g = fmin(isnan(ga) ? scan_gap(sc, ca) : ga, isnan(gb) ? scan_gap(sc, cb) : gb);
	if (g < min_gap)
		return false;
	double dx = cb[0] - ca[0], dy = cb[1] - ca[1], len = sqrt(dx * dx + dy * dy);
	bool rtz = sc->inst->stage_info.kinematics == ASPH_KINEMATICS_RTZ;
	/* a straight line dips below its chord by at most curvature len^2 / 8 */
	if (!rtz && sc->tip == 0 && g - sc->geo.curvature * len * len / 8 >= min_gap)
		return true;
	if (rtz)
		len = fabs(b[0] - a[0]) + fmax(a[0], b[0]) * fabs(b[1] - a[1]);
	int steps = 4 + (int)fmin(len / 0.1, 4000);
	for (int k = 1; k < steps; k++) {
		double t = (double)k / steps;
		for (int j = 0; j < 3; j++)
			m[j] = a[j] + t * (b[j] - a[j]);
		scan_to_cartesian(sc, m, c);
		if (scan_gap(sc, c) < min_gap)
			return false;
	}
	return true;
}

bool scan_path_clear(const struct asph_scan *sc, const double *a, const double *b,
		       double min_gap)
{
	return scan_path_clear_g(sc, a, NAN, b, NAN, min_gap);
}

/* Moves to m straight when that keeps min_gap all the way, else up to the
 * travel height, across, and down. Moving up (-z) is always away from the
 * part. */
size_t scan_clear_path(const struct asph_scan *sc, const double from[3], const double *m,
		       double min_gap, double way[3][3])
{
	if (scan_path_clear(sc, from, m, min_gap)) {
		memcpy(way[0], m, sizeof(way[0]));
		return 1;
	}
	double up[3] = { from[0], from[1], fmin(sc->geo.z_safe, from[2]) };
	memcpy(way[0], up, sizeof(way[0]));
	memcpy(way[1], (double[3]){ m[0], m[1], up[2] }, sizeof(way[1]));
	memcpy(way[2], m, sizeof(way[2]));
	return 3;
}

struct lowest {
	const struct asph_scan *sc;
	double z;
};

static void lowest_at(void *ctx, const struct asph_sag *d)
{
	struct lowest *l = ctx;

	l->z = fmin(l->z, d->z - l->sc->inst->probe_info.standoff -
			  l->sc->tip * sqrt(1 + d->zx * d->zx + d->zy * d->zy) - l->sc->o.clearance);
}

/* The travel height: clearance above the whole part and every approach. */
static double safe_height(struct asph_scan *sc, double min_approach_z)
{
	const struct asph_surface *s = sc->surface;
	double a = asph_surface_aperture_radius(s), z = min_approach_z, d[3];

	if (!asph_surface_is_rotational(s)) {
		struct asph_surface_extent e;
		struct lowest l = { sc, z };
		freeform_grid(s, lowest_at, &l);
		/* and the lowest sag anywhere, with the steepest slope */
		asph_surface_extent(s, &e);
		return fmin(l.z, e.sag_min - sc->inst->probe_info.standoff -
				 sc->tip * sqrt(1 + e.max_slope * e.max_slope) - sc->o.clearance);
	}
	for (int j = 0; j <= 2000; j++) {
		asph_surface_sag_derivs(s, a * j / 2000.0, d);
		z = fmin(z, d[0] - sc->inst->probe_info.standoff -
			       sc->tip * sqrt(1 + d[1] * d[1]) - sc->o.clearance);
	}
	return z;
}

/* ------------------------------------------------------------ check */

static int refuse_axis(const struct asph_scan *sc, size_t i, const double *m,
		       const char *what, struct asph_error *err)
{
	const struct asph_stage_info *si = &sc->inst->stage_info;

	for (unsigned k = 0; k < si->n_axes; k++) {
		const struct asph_axis_info *a = &si->axes[k];
		if (m[k] >= a->min && m[k] <= a->max)
			continue;
		return asph_error_set_at(err, -ERANGE, NULL, 0, 0, a->name,
					 "plan point %zu (%.6f, %.6f, %.6f): the %s needs axis %s at %.6f %s, outside its travel %.6g .. %.6g",
					 i, sc->xyz[3 * i], sc->xyz[3 * i + 1], sc->xyz[3 * i + 2],
					 what, a->name, m[k], a->unit, a->min, a->max);
	}
	return 0;
}

static inline bool inside(const double *m, const double *lo, const double *hi)
{
	return m[0] >= lo[0] && m[0] <= hi[0] && m[1] >= lo[1] && m[1] <= hi[1] &&
	       m[2] >= lo[2] && m[2] <= hi[2];
}

static int check_point(struct asph_scan *sc, size_t i, const double *lo, const double *hi,
		       double *min_z, struct asph_error *err)
{
	const struct asph_probe_info *pi = &sc->inst->probe_info;
	const double *p = sc->xyz + 3 * i;
	struct target t;

	if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
		return asph_error_set(err, -EINVAL, "plan point %zu is not finite", i);
	scan_target(sc, i, pi->max_slope > 0, &t);
	if (pi->max_slope > 0 && acos(fmin(1.0, t.normal[2])) > pi->max_slope)
		return asph_error_set(err, -ERANGE,
				      "plan point %zu (%.6f, %.6f, %.6f): surface slope %.3f deg is steeper than the probe reads (%.3f deg)",
				      i, p[0], p[1], p[2], acos(fmin(1.0, t.normal[2])) * 180 / M_PI,
				      pi->max_slope * 180 / M_PI);
	if (!inside(t.machine, lo, hi))
		return refuse_axis(sc, i, t.machine, "measuring position", err);
	if (!inside(t.approach, lo, hi))
		return refuse_axis(sc, i, t.approach, "approach", err);
	*min_z = fmin(*min_z, t.approach[2]);
	return 0;
}

/* A drift reference: on the part, where the stage and the probe reach. */
static int check_reference(struct asph_scan *sc, size_t k, const double *lo, const double *hi,
			   double *min_z, struct asph_error *err)
{
	const double *xy = sc->acq.references[k];
	double p[3] = { xy[0], xy[1], 0 };
	struct target t;

	if (!asph_surface_contains(sc->surface, xy[0], xy[1], 0))
		return asph_error_set_at(err, -ERANGE, NULL, 0, 0, "drift_references",
					 "drift reference %zu (%g, %g) lies outside the part's aperture",
					 k, xy[0], xy[1]);
	p[2] = asph_surface_sag_xy(sc->surface, xy[0], xy[1]);
	scan_target_at(sc, p, false, &t);
	if (!inside(t.machine, lo, hi) || !inside(t.approach, lo, hi))
		return asph_error_set_at(err, -ERANGE, NULL, 0, 0, "drift_references",
					 "drift reference %zu (%g, %g) is outside the stage's travel",
					 k, xy[0], xy[1]);
	*min_z = fmin(*min_z, t.approach[2]);
	return 0;
}

static int check_probe(const struct asph_scan *sc, struct asph_error *err)
{
	const struct asph_probe_info *pi = &sc->inst->probe_info;

	if (!(pi->standoff >= pi->range_min && pi->standoff <= pi->range_max))
		return asph_error_set(err, -ERANGE,
				      "the probe's standoff %.6g mm is outside its range %.6g .. %.6g mm",
				      pi->standoff, pi->range_min, pi->range_max);
	if (sc->tactile && !(pi->tip_radius > 0))
		return asph_error_set(err, -ERANGE, "tactile probe without a tip radius");
	return 0;
}

int scan_check(struct asph_scan *sc, size_t first, struct asph_error *err)
{
	const struct asph_stage_info *si = &sc->inst->stage_info;
	double lo[3], hi[3];
	int r = check_probe(sc, err);

	if (r < 0)
		return r;
	for (int k = 0; k < 3; k++) {
		lo[k] = si->axes[k].min;
		hi[k] = si->axes[k].max;
	}
	double min_z = INFINITY;
	sc->geo.theta_prev = 0;
	for (size_t i = first; r == 0 && i < sc->n; i++)
		r = check_point(sc, i, lo, hi, &min_z, err);
	for (size_t k = 0; r == 0 && asph_acquisition_drift(&sc->acq) &&
			   k < sc->acq.n_references; k++)
		r = check_reference(sc, k, lo, hi, &min_z, err);
	sc->geo.theta_prev = 0;
	if (r < 0)
		return r;
	sc->geo.z_safe = safe_height(sc, min_z);
	if (!(sc->geo.z_safe >= lo[2]))
		return asph_error_set(err, -ERANGE,
				      "the travel height over the part, %.6f mm, is outside the z travel %.6g .. %.6g",
				      sc->geo.z_safe, lo[2], hi[2]);
	return 0;
}

/* ----------------------------------------------- the planner's limits */

void scan_motion_limits(const struct asph_stage_info *si, const struct asph_probe_info *pi,
			struct asph_motion_limits *lim)
{
	memset(lim, 0, sizeof(*lim));
	for (int k = 0; k < 3; k++) {
		lim->speed[k] = si->axes[k].max_speed > 0 ? si->axes[k].max_speed : 1e6;
		lim->accel[k] = si->max_accel[k] > 0 ? si->max_accel[k] : 0;
		lim->jerk[k] = si->max_jerk[k] > 0 ? si->max_jerk[k] : 0;
	}
	lim->rate = pi->rate > 0 ? pi->rate : 0;
}

void sweep_cut_add(struct sweep_cut *c, const double from[3], const double to[3],
		   const struct asph_motion_limits *lim, double rate)
{
	double step = 0;

	for (int k = 0; k < 3; k++)
		step = fmax(step, fabs(to[k] - from[k]) / lim->speed[k]);
	c->motion += step;
	c->reading += rate > 0 ? 1 / rate : 0;
	c->n++;
}
