/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Sampling plans: density resolution, the methods' maps, the disk mesh. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

#include "asph/delaunay.h"
#include "asph/involute.h"
#include "asph/lb.h"
#include "asph/plan.h"
#include "plan-aperture.h"
#include "plan-cvt.h"
#include "plan-freeform.h"
#include "plan-patterns.h"
#include "plan-profiles.h"
#include "util-mem.h"
#include "util-suggest.h"

/* Largest plan: triangle indices are 32-bit. */
#define PLAN_MAX_POINTS ((size_t)UINT32_MAX - 1)

/* Triangles of the disk grid below this q are dropped (paper 5.1). */
#define DISK_MESH_MIN_Q 0.75

/*
 * A sampling method: its name, its lattice, and the three steps of a plan:
 * count (exact, at lattice pitch p), fill (the points in scan order) and
 * lift (onto the surface). Most methods lay a pattern in the disk or the
 * vertex plane (plan-patterns.h: x, y and the radius) and lift it; CI lays
 * its lattice on the surface itself, so its pitch is measured there and its
 * points need no lift. The table is at the end of this file.
 */
struct plan_method {
	const char *name;
	const char *title;      /* in words, docs/sampling-plans.md */
	/* the planar pattern it lays (op: the disk grid) and its lattice */
	const struct plan_pattern *pattern;
	bool on_surface;        /* the lattice lies on the surface (CI) */
	bool mesh;              /* the disk grid's mesh comes with the plan */
	/* NULL: the pattern's count on the disk of radius a */
	size_t (*count)(const struct asph_surface *s, double a, double p);
	/* plan->n is count's; fill allocates plan->xyz and may set plan->n;
	 * NULL: the pattern's points */
	int (*fill)(const struct asph_surface *s, double a, double p,
		    struct asph_plan *plan, struct asph_error *err);
	/* NULL: the points are on the surface already */
	int (*lift)(const struct asph_surface *s, double *xyz, size_t n,
		    struct asph_error *err);
	/* NULL, or a last step once the points are on the surface (CVT's
	 * iterations), which reports its progress */
	int (*settle)(const struct asph_surface *s, double p, double *xyz, size_t n,
		      const struct asph_progress *progress, struct asph_error *err);
	/* The method on a freeform surface; NULL: it has none yet, and
	 * resolve() refuses it there with a message. */
	const struct plan_freeform *freeform;
};

/*
 * A method on a freeform surface, where the radial maps of surfaces of
 * revolution do not apply: the exact count at pitch p (a method whose
 * count computes the plan leaves its points in *keep when keep is not
 * NULL, for fill to take); the plan's points
 * (fill allocates plan->xyz and sets plan->n), in the aperture for a
 * method with a map (the mesh is made of them), else on the surface; and
 * the map onto the surface (plan-freeform.h), NULL for the lift
 * z = S(x, y).
 */
struct plan_freeform {
	size_t (*count)(const struct asph_surface *s, const struct plan_method *meth,
			double p, double **keep);
	int (*fill)(const struct asph_surface *s, const struct plan_method *meth,
		    double p, struct asph_plan *plan, struct asph_error *err);
	int (*map)(const struct asph_surface *s, double p, double *xyz, size_t n,
		   struct asph_error *err);
	/* count computes the plan: --points takes the pitch of one point per
	 * area_per_pitch2 p^2 as it is, uncorrected (CI: one point per p^2 of
	 * surface, which the involute meets to its edge) */
	bool count_is_plan;
};

static const struct plan_method *method_of(enum asph_plan_method m);

/* The area the method's lattice covers: on a freeform, the aperture (or
 * the surface over it, for a lattice laid on the surface). */
static double pattern_area(const struct asph_surface *s,
			   const struct plan_method *meth)
{
	double a = asph_surface_aperture_radius(s);

	if (!asph_surface_is_rotational(s))
		return meth->on_surface ? asph_surface_total_area(s)
					: asph_surface_projected_area(s);
	return meth->on_surface ? asph_surface_area(s, a) : M_PI * a * a;
}

/* The disk that circumscribes the aperture about its centre. */
static double freeform_radius(const struct asph_surface *s)
{
	double c[2], R;

	asph_surface_aperture_disk(s, c, &R);
	return R;
}

static int refuse_on_freeform(const struct asph_surface *s, enum asph_plan_method m,
			      struct asph_error *err)
{
	const char *names[ASPH_PLAN_N_METHODS];
	char known[128];

	for (unsigned i = 0; i < ASPH_PLAN_N_METHODS; i++)
		names[i] = method_of(i)->freeform ? method_of(i)->name : NULL;
	suggest_join(known, sizeof(known), names, ASPH_PLAN_N_METHODS, ", ");
	if (asph_surface_is_radial(s))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "method",
					 "the %s plan is for rotationally symmetric parts over a "
					 "centred circle; on this off-axis segment (a %s over an "
					 "off-centre or non-circular aperture) use one of %s",
					 asph_plan_method_name(m),
					 asph_surface_type_name(asph_surface_prescription(s)->type),
					 known);
	return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "method",
				 "the %s plan is for rotationally symmetric surfaces; on a %s "
				 "surface use one of %s",
				 asph_plan_method_name(m),
				 asph_surface_type_name(asph_surface_prescription(s)->type), known);
}

/* The option an error about the density names. */
static const char *density_field(enum asph_plan_density_kind k)
{
	return (unsigned)k < ASPH_PLAN_N_DENSITIES ? asph_plan_density_name(k) : "density";
}

/* What a density resolves to for one method on one surface. */
struct plan_size {
	double e;       /* surface spacing, mm */
	double p;       /* the method's lattice pitch, mm */
	size_t n;       /* points */
	double *xyz;    /* the points, when counting computed them (freeform CI) */
};

static void plan_size_clear(struct plan_size *sz)
{
	free(sz->xyz);
	sz->xyz = NULL;
}

/* Exact point count of the method's pattern at pitch p. SIZE_MAX for
 * anything far too large. */
static size_t pattern_count(const struct asph_surface *s,
			    enum asph_plan_method m, double p, double **keep)
{
	const struct plan_method *meth = method_of(m);
	double a = asph_surface_aperture_radius(s);

	if (!asph_surface_is_rotational(s))
		return meth->freeform->count(s, meth, p, keep);
	/* The exact counters loop over rows and rings: screen absurd sizes
	 * first so they never run for long. */
	if (!(pattern_area(s, meth) / (p * p) < 2.0 * (double)PLAN_MAX_POINTS))
		return SIZE_MAX;
	return meth->count ? meth->count(s, a, p) : meth->pattern->count(a, p);
}

/* Pitch / spacing ratio: vertex-plane and disk lattices are stretched by
 * about sqrt(gamma) on the surface; CI's pitch is measured on it. */
static double pitch_per_spacing(const struct asph_surface *s,
				enum asph_plan_method m)
{
	const struct plan_method *meth = method_of(m);
	double c = meth->pattern->lattice.edge_per_pitch;

	if (meth->on_surface)
		return 1.0 / c;
	return 1.0 / (c * sqrt(asph_surface_gamma(s)));
}

/* --points N: the pitch whose exact count is closest to N, from the
 * lattice's area per point and two secant-like refinements (none where
 * counting is computing the plan). */
static double pitch_for_points(const struct asph_surface *s,
			       enum asph_plan_method m, double n_req)
{
	const struct plan_method *meth = method_of(m);
	double p = sqrt(pattern_area(s, meth) / (meth->pattern->lattice.area_per_pitch2 * n_req));
	bool costly = !asph_surface_is_rotational(s) && meth->freeform->count_is_plan;

	for (int it = 0; it < 2 && !costly; it++) {
		size_t n = pattern_count(s, m, p, NULL);
		/* n == n_req would leave p as it is */
		if (n == 0 || n > PLAN_MAX_POINTS || (double)n == n_req)
			break;
		p *= sqrt((double)n / n_req);
	}
	return p;
}

/* The options' profiles: the profiles method's count (0: one), 0 for the
 * others. */
static int profiles_of(enum asph_plan_method m, const struct asph_plan_options *o,
		       unsigned *profiles, struct asph_error *err)
{
	unsigned n = o ? o->profiles : 0;

	if (m != ASPH_PLAN_PROFILES && n)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "profiles",
					 "a count of profiles is for the profiles method, not %s",
					 asph_plan_method_name(m));
	*profiles = m == ASPH_PLAN_PROFILES && n == 0 ? 1 : n;
	return 0;
}

static int resolve(const struct asph_surface *s, enum asph_plan_method m,
		   struct asph_plan_density d, unsigned profiles, struct plan_size *out,
		   struct asph_error *err)
{
	const char *field = density_field(d.kind);
	double a = asph_surface_aperture_radius(s), ratio;

	if ((unsigned)m >= ASPH_PLAN_N_METHODS)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "method", "unknown method %d",
					 m);
	if (!asph_surface_is_rotational(s)) {
		if (!method_of(m)->freeform)
			return refuse_on_freeform(s, m, err);
		a = freeform_radius(s);
	}
	if (!isfinite(d.value) || d.value <= 0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "must be positive and finite (got %g)", d.value);
	if (m == ASPH_PLAN_PROFILES)
		return plan_profiles_resolve(s, d, profiles, &out->e, &out->p, &out->n, err);
	ratio = pitch_per_spacing(s, m);
	switch (d.kind) {
	case ASPH_DENSITY_H:
		out->e = d.value * a;
		out->p = out->e * ratio;
		break;
	case ASPH_DENSITY_SPACING:
		out->e = d.value;
		out->p = out->e * ratio;
		break;
	case ASPH_DENSITY_POINTS:
		out->p = pitch_for_points(s, m, d.value);
		out->e = out->p / ratio;
		break;
	default:
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "density",
					 "unknown density kind %d", d.kind);
	}
	if (!(out->e <= a))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "%g is too coarse: it gives a spacing of %.6g mm, "
					 "more than the aperture radius %.6g mm (h > 1)",
					 d.value, out->e, a);
	out->xyz = NULL;
	out->n = pattern_count(s, m, out->p, &out->xyz);
	if (out->n > PLAN_MAX_POINTS)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, field,
					 "%g gives more than %zu points, the most a plan can hold",
					 d.value, PLAN_MAX_POINTS);
	return 0;
}

int asph_plan_resolve(const struct asph_surface *s, enum asph_plan_method m,
		      struct asph_plan_density density, double *spacing_mm,
		      size_t *n_points, struct asph_error *err)
{
	return asph_plan_resolve_opts(s, m, density, NULL, spacing_mm, n_points, err);
}

int asph_plan_resolve_opts(const struct asph_surface *s, enum asph_plan_method m,
			   struct asph_plan_density density,
			   const struct asph_plan_options *opts, double *spacing_mm,
			   size_t *n_points, struct asph_error *err)
{
	_cleanup_(plan_size_clear) struct plan_size sz = { 0 };
	unsigned profiles = 0;
	int r = profiles_of(m, opts, &profiles, err);

	if (r == 0)
		r = resolve(s, m, density, profiles, &sz, err);
	if (r < 0)
		return r;
	if (spacing_mm)
		*spacing_mm = sz.e;
	if (n_points)
		*n_points = sz.n;
	return 0;
}

/* ---- maps from the disk or the vertex plane onto the surface ------------ */

double asph_plan_ot_radius(const struct asph_surface *s, double rho)
{
	double a = asph_surface_aperture_radius(s);

	if (!(rho > 0))
		return 0;
	if (rho >= a)
		return a;
	double f = rho / a;
	return asph_surface_radius_at_area(s, asph_surface_area(s, a) * f * f);
}

/* Lifts points of the aperture onto the surface: z = S(x, y). */
static void lift_xy(const struct asph_surface *s, double *xyz, size_t n)
{
	for (size_t i = 0; i < n; i++)
		xyz[3 * i + 2] = asph_surface_sag_xy(s, xyz[3 * i], xyz[3 * i + 1]);
}

/* Vertical projection: z = Z(r), r in the third slot. */
static int lift_projected(const struct asph_surface *s, double *xyz,
			  size_t n, struct asph_error *err)
{
	for (size_t i = 0; i < n; i++)
		xyz[3 * i + 2] = asph_surface_sag(s, xyz[3 * i + 2]);
	return 0;
}

/* Moves the disk point at radius rho to radius r at height z. */
static void place_radial_z(double *p, double r, double z)
{
	double rho = p[2], f = rho > 0 ? r / rho : 0.0;

	p[0] *= f;
	p[1] *= f;
	p[2] = z;
}

static void place_radial(const struct asph_surface *s, double *p, double r)
{
	place_radial_z(p, r, asph_surface_sag(s, r));
}

/* The area density f = dA/dr = 2 pi r w and g = f', w = sqrt(1 + Z'^2). */
static void area_density(double r, const double d[3], double *f, double *g)
{
	double u = 1.0 + d[1] * d[1], w = sqrt(u);

	*f = 2.0 * M_PI * r * w;
	*g = 2.0 * M_PI * (u + r * d[1] * d[2]) / w;
}

/* Exact: r = Phi^-1 of the target area, restarting the stepper there. */
static double ot_exact(const struct asph_surface *s, double target,
		       struct inverse_step *st, double *z)
{
	double r = asph_surface_radius_at_area(s, target), d[3];

	double f, g;

	asph_surface_sag_derivs(s, r, d);
	area_density(r, d, &f, &g);
	inverse_step_set(st, r, target, f, g);
	*z = d[0];
	return r;
}

/* One contiguous run of the disk grid with its own stepper. */
struct ot_lane {
	size_t i, end, since;
	double prev;
	struct inverse_step st;
};

static void ot_point(const struct asph_surface *s, double *xyz,
		     struct ot_lane *l, double a, double per_rho2)
{
	double *p = xyz + 3 * l->i++, rho = p[2], r, z, d[3], f, g;

	if (rho >= a) {
		place_radial(s, p, a);
		return;
	}
	double target = per_rho2 * rho * rho;
	if (l->since < INVERSE_STEP_ANCHOR && rho > l->prev) {
		double x0 = inverse_step_predict(&l->st, target);
		asph_surface_sag_derivs(s, x0, d);
		area_density(x0, d, &f, &g);
		if (inverse_step_finish(&l->st, target, x0, f, g, &r) == 0) {
			place_radial_z(p, r, d[0] + d[1] * (r - x0));
			l->since++;
			l->prev = rho;
			return;
		}
	}
	r = ot_exact(s, target, &l->st, &z);
	place_radial_z(p, r, z);
	l->since = 0;
	l->prev = rho;
}

#define OT_LANES 4

/*
 * phi(rho) = Phi^-1(rho^2) of Eq. (9) on the disk of radius a: the target
 * area is A(a) (rho/a)^2. The disk grid comes in spiral order, so rho
 * grows from one point to the next and the stepper of plan.h applies;
 * every INVERSE_STEP_ANCHOR points, and wherever it refuses a step, the
 * radius comes from the exact inverse of the area. A stepper is one long
 * dependency chain, so the grid is cut into OT_LANES runs stepped side by
 * side, which the processor overlaps.
 */
static int lift_ot(const struct asph_surface *s, double *xyz, size_t n,
		   struct asph_error *err)
{
	double a = asph_surface_aperture_radius(s);
	double per_rho2 = asph_surface_area(s, a) / (a * a);
	size_t len = (n + OT_LANES - 1) / OT_LANES;
	struct ot_lane lanes[OT_LANES];

	for (size_t l = 0; l < OT_LANES; l++) {
		size_t b = l * len < n ? l * len : n;
		lanes[l] = (struct ot_lane){ .i = b, .end = b + len < n ? b + len : n,
					     .since = INVERSE_STEP_ANCHOR, .prev = a };
	}
	for (size_t j = 0; j < len; j++)
		for (size_t l = 0; l < OT_LANES; l++)
			if (lanes[l].i < lanes[l].end)
				ot_point(s, xyz, &lanes[l], a, per_rho2);
	return 0;
}

/* CVT: its starting sites, a hexagonal lattice and the rim
 * (plan-cvt.h), for OT to move onto the surface. */
static int cvt_fill(const struct asph_surface *s, double a, double p,
		    struct asph_plan *plan, struct asph_error *err)
{
	plan->xyz = malloc(3 * plan->n * sizeof(*plan->xyz));
	if (!plan->xyz)
		return asph_error_set(err, -ENOMEM, "out of memory (%zu points)", plan->n);
	return plan_cvt_seed(s, plan->n, plan->xyz, err);
}

/* CVT: Lloyd's iterations from the OT map of its starting sites, then
 * their scan order. On a surface of revolution the count is the disk
 * grid's, one point per p^2 of the disk, which gives p back. */
static int cvt_settle(const struct asph_surface *s, double p, double *xyz, size_t n,
		      const struct asph_progress *progress, struct asph_error *err)
{
	int r;

	if (asph_surface_is_rotational(s))
		p = asph_surface_aperture_radius(s) * sqrt(M_PI / (double)n);
	r = plan_cvt_relax(s, p, xyz, n, progress, NULL, err);
	return r < 0 ? r : plan_cvt_order(s, xyz, n, err);
}

static int lift_lb(const struct asph_surface *s, double *xyz, size_t n,
		   struct asph_error *err)
{
	struct asph_lb_map *m = NULL;
	double a = asph_surface_aperture_radius(s);
	int r = asph_lb_map_alloc(s, &m, err);

	if (r < 0)
		return r;
	for (size_t i = 0; i < n; i++) {
		double rho = xyz[3 * i + 2];
		double rr = rho >= a ? a : asph_lb_map_radius(m, rho);
		place_radial(s, xyz + 3 * i, rr);
	}
	asph_lb_map_free(m);
	return 0;
}

/* ---- disk mesh ------------------------------------------------------------ */

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_delaunay *, asph_delaunay_free)

int plan_disk_mesh(const double *xyr, size_t n, uint32_t **triangles,
		   size_t *n_triangles, struct asph_error *err)
{
	_cleanup_(asph_delaunay_freep) struct asph_delaunay *w = NULL;
	_cleanup_free_ double *xy = NULL;
	_cleanup_free_ uint32_t *tri = NULL;
	size_t nt = 0, kept = 0;
	int r;

	if (n > ASPH_DELAUNAY_MAX_POINTS)
		return asph_error_set(err, -E2BIG,
				      "a mesh of %zu points is more than the triangulation takes (%zu); "
				      "ask for the plan without its mesh",
				      n, ASPH_DELAUNAY_MAX_POINTS);
	xy = malloc(2 * n * sizeof(*xy));
	if (!xy)
		return asph_error_set(err, -ENOMEM, "out of memory");
	w = asph_delaunay_alloc(n);
	if (!w)
		return asph_error_set(err, -ENOMEM, "out of memory (triangulation of %zu points)", n);
	for (size_t i = 0; i < n; i++) {
		xy[2 * i] = xyr[3 * i];
		xy[2 * i + 1] = xyr[3 * i + 1];
	}
	r = asph_delaunay_triangulate(w, xy, n, &tri, &nt, err);
	if (r < 0)
		return r;
	for (size_t t = 0; t < nt; t++) {
		const uint32_t *v = tri + 3 * t;
		if (plan_triangle_q_2d(xy + 2 * v[0], xy + 2 * v[1],
				       xy + 2 * v[2]) < DISK_MESH_MIN_Q)
			continue;
		memmove(tri + 3 * kept++, v, 3 * sizeof(*v));
	}
	*n_triangles = kept;
	*triangles = steal_ptr(tri);
	return 0;
}

/* ---- plans ----------------------------------------------------------------- */

void asph_plan_free(struct asph_plan *p)
{
	if (!p)
		return;
	free(p->xyz);
	free(p->triangles);
	free(p);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_plan *, asph_plan_free)

int asph_plan_to_points(const struct asph_plan *p, struct asph_points **out)
{
	struct asph_points *pts = asph_points_alloc(p->n);

	if (!pts)
		return -ENOMEM;
	memcpy(pts->xyz, p->xyz, 3 * p->n * sizeof(*p->xyz));
	if (p->n_triangles) {
		pts->triangles = malloc(3 * p->n_triangles * sizeof(*p->triangles));
		if (!pts->triangles) {
			asph_points_free(pts);
			return -ENOMEM;
		}
		memcpy(pts->triangles, p->triangles,
		       3 * p->n_triangles * sizeof(*p->triangles));
		pts->n_triangles = p->n_triangles;
	}
	*out = pts;
	return 0;
}

/* Room for plan->n points, laid out by the method's planar pattern. */
static int planar_fill(struct asph_plan *plan, double a, double p,
		       const struct plan_pattern *pattern, struct asph_error *err)
{
	plan->xyz = malloc(3 * plan->n * sizeof(*plan->xyz));
	if (!plan->xyz || pattern->fill(a, p, plan->xyz) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory (%zu points)", plan->n);
	return 0;
}

static int compute_points(const struct asph_surface *s, struct asph_plan *plan,
			  struct plan_size *sz, unsigned flags,
			  const struct asph_progress *progress, struct asph_error *err)
{
	const struct plan_method *meth = method_of(plan->method);
	bool freeform = !asph_surface_is_rotational(s);
	int r;

	plan->n = sz->n;
	if (freeform && sz->xyz) {
		plan->xyz = steal_ptr(sz->xyz);
		r = 0;
	} else if (freeform) {
		r = meth->freeform->fill(s, meth, sz->p, plan, err);
	} else if (meth->fill) {
		r = meth->fill(s, asph_surface_aperture_radius(s), sz->p, plan, err);
	} else {
		r = planar_fill(plan, asph_surface_aperture_radius(s), sz->p, meth->pattern, err);
	}
	if (r < 0)
		return r;
	/* The mesh of the disk grid, before a map moves its points */
	if (meth->mesh && !(flags & ASPH_PLAN_NO_MESH)) {
		r = plan_disk_mesh(plan->xyz, plan->n, &plan->triangles,
				   &plan->n_triangles, err);
		if (r < 0)
			return r;
	}
	if (freeform && meth->freeform->map)
		r = meth->freeform->map(s, sz->p, plan->xyz, plan->n, err);
	else if (freeform)
		lift_xy(s, plan->xyz, plan->n);
	else if (meth->lift)
		r = meth->lift(s, plan->xyz, plan->n, err);
	if (r < 0 || !meth->settle)
		return r;
	return meth->settle(s, sz->p, plan->xyz, plan->n, progress, err);
}

int asph_plan_compute_opts(const struct asph_surface *s,
			   enum asph_plan_method m,
			   struct asph_plan_density density,
			   const struct asph_plan_options *opts,
			   struct asph_plan **out, struct asph_error *err)
{
	size_t max_points = opts ? opts->max_points : 0;
	unsigned flags = opts ? opts->flags : 0;
	const struct asph_progress *progress = opts ? &opts->progress : NULL;
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	_cleanup_(plan_size_clear) struct plan_size sz = { 0 };
	unsigned profiles = 0;
	int r = profiles_of(m, opts, &profiles, err);

	if (r == 0)
		r = resolve(s, m, density, profiles, &sz, err);
	if (r < 0)
		return r;
	if (max_points && sz.n > max_points)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, density_field(density.kind),
					 "%g gives %zu points, more than the limit of %zu",
					 density.value, sz.n, max_points);
	plan = calloc(1, sizeof(*plan));
	if (!plan)
		return asph_error_set(err, -ENOMEM, "out of memory");
	plan->method = m;
	plan->density = density;
	plan->spacing_mm = sz.e;
	plan->profiles = profiles;
	r = compute_points(s, plan, &sz, flags, progress, err);
	if (r < 0)
		return r;
	*out = steal_ptr(plan);
	return 0;
}

int asph_plan_compute(const struct asph_surface *s, enum asph_plan_method m,
		      struct asph_plan_density density, size_t max_points,
		      struct asph_plan **out, struct asph_error *err)
{
	struct asph_plan_options o = { .max_points = max_points };

	return asph_plan_compute_opts(s, m, density, &o, out, err);
}

/* ---- the methods ---------------------------------------------------------- */

/* The profiles plan: its count is resolve()'s (plan_profiles_resolve()),
 * for plan->profiles profiles. */
static int profiles_fill(const struct asph_surface *s, double a, double p,
			 struct asph_plan *plan, struct asph_error *err)
{
	plan->xyz = malloc(3 * plan->n * sizeof(*plan->xyz));
	if (!plan->xyz || plan_profiles_fill(a, p, plan->profiles, plan->xyz) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory (%zu points)", plan->n);
	return 0;
}

/* CI: the involute's own count, asph/involute.h. */
static size_t ci_count(const struct asph_surface *s, double a, double p)
{
	double r0 = p / (2.0 * M_PI);

	return (size_t)floor((asph_surface_area(s, a) - asph_surface_area(s, r0)) /
			     (p * p)) + 1;
}

static int ci_fill(const struct asph_surface *s, double a, double p,
		   struct asph_plan *plan, struct asph_error *err)
{
	return asph_involute_points(s, p, 0, &plan->xyz, &plan->n, err);
}

/* ---- freeform surfaces ----------------------------------------------------- */

/* Screens absurd sizes before a pattern over the aperture runs, as
 * pattern_count() does for the disk. */
static bool aperture_too_dense(const struct asph_surface *s, double p)
{
	double R = freeform_radius(s);

	return !(M_PI * R * R / (p * p) < 2.0 * (double)PLAN_MAX_POINTS);
}

static size_t aperture_count(const struct asph_surface *s, const struct plan_method *meth,
			     double p, double **keep)
{
	struct plan_points pp = { 0 };
	size_t n = SIZE_MAX;

	if (aperture_too_dense(s, p))
		return SIZE_MAX;
	if (plan_aperture_pattern(s, meth->pattern, p, &pp, NULL) == 0)
		n = pp.n;
	plan_points_clear(&pp);
	return n;
}

static int aperture_fill(const struct asph_surface *s, const struct plan_method *meth,
			 double p, struct asph_plan *plan, struct asph_error *err)
{
	struct plan_points pp = { 0 };

	if (plan_aperture_pattern(s, meth->pattern, p, &pp, NULL) < 0) {
		plan_points_clear(&pp);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	plan->xyz = pp.xyz;
	plan->n = pp.n;
	return 0;
}

/* The plans of the vertex plane (op and the classic patterns): laid over
 * the aperture (plan-aperture.h), lifted with S(x, y). */
static const struct plan_freeform over_aperture = { aperture_count, aperture_fill, NULL };

/* LB: the disk grid of the aperture moved by the inverse of the discrete
 * harmonic map. */
static const struct plan_freeform lb_freeform = { aperture_count, aperture_fill,
						  plan_lb_freeform_map };

/* OT: the disk grid of the aperture moved by the map of the Monge-Ampere
 * equation (asph/ot.h). */
static const struct plan_freeform ot_freeform = { aperture_count, aperture_fill,
						  plan_ot_freeform_map };

static int cvt_aperture_fill(const struct asph_surface *s, const struct plan_method *meth,
			     double p, struct asph_plan *plan, struct asph_error *err)
{
	return cvt_fill(s, 0, p, plan, err);
}

/* The starting sites' outline has its own step (plan-cvt.h), which tells
 * the map which points are on the edge; cvt_settle() follows. */
static int cvt_freeform_map(const struct asph_surface *s, double p, double *xyz, size_t n,
			    struct asph_error *err)
{
	return plan_ot_freeform_map(s, plan_cvt_edge_step(s, n), xyz, n, err);
}

/* CVT: the OT map of a hexagonal lattice relaxed by Lloyd's iterations on
 * the surface, with the count of the op pattern. */
static const struct plan_freeform cvt_freeform = { aperture_count, cvt_aperture_fill,
						   cvt_freeform_map };

/* CI: the involute by geodesics on the surface (asph/involute.h). Its
 * count is the plan's own, so counting computes the plan and keeps it for
 * fill; a failure counts 0 points, and fill then says why. */
static size_t ci_freeform_count(const struct asph_surface *s, const struct plan_method *meth,
				double p, double **keep)
{
	_cleanup_free_ double *xyz = NULL;
	size_t n = 0;

	if (!(asph_surface_total_area(s) / (p * p) < 2.0 * (double)PLAN_MAX_POINTS))
		return SIZE_MAX;
	if (asph_involute_points_geodesic(s, p, PLAN_MAX_POINTS, &xyz, &n, NULL) < 0)
		return 0;
	if (keep)
		*keep = steal_ptr(xyz);
	return n;
}

static int ci_freeform_fill(const struct asph_surface *s, const struct plan_method *meth,
			    double p, struct asph_plan *plan, struct asph_error *err)
{
	return asph_involute_points_geodesic(s, p, PLAN_MAX_POINTS, &plan->xyz, &plan->n, err);
}

static const struct plan_freeform ci_freeform = { ci_freeform_count, ci_freeform_fill, NULL,
						  true };

/* The methods, docs/sampling-plans.md: a method is its row here and its
 * value in enum asph_plan_method; every list of their names (the tools'
 * help, the protocol's schema, the completion) comes from this table. CI
 * is the disk grid's lattice laid on the surface. */
static const struct plan_method methods[ASPH_PLAN_N_METHODS] = {
	[ASPH_PLAN_OP] = {
		.name = "op", .title = "orthogonal projection", .pattern = &plan_disk_grid,
		.mesh = true, .lift = lift_projected, .freeform = &over_aperture,
	},
	[ASPH_PLAN_OT] = {
		.name = "ot", .title = "optimal transport", .pattern = &plan_disk_grid,
		.mesh = true, .lift = lift_ot, .freeform = &ot_freeform,
	},
	[ASPH_PLAN_LB] = {
		.name = "lb", .title = "Laplace-Beltrami", .pattern = &plan_disk_grid,
		.mesh = true, .lift = lift_lb, .freeform = &lb_freeform,
	},
	[ASPH_PLAN_CI] = {
		.name = "ci", .title = "circle involute", .pattern = &plan_disk_grid,
		.on_surface = true, .count = ci_count, .fill = ci_fill, .freeform = &ci_freeform,
	},
	[ASPH_PLAN_RASTER] = {
		.name = "raster", .title = "x-y raster", .pattern = &plan_raster,
		.lift = lift_projected, .freeform = &over_aperture,
	},
	[ASPH_PLAN_CONCENTRIC] = {
		.name = "concentric", .title = "concentric circles", .pattern = &plan_concentric,
		.lift = lift_projected, .freeform = &over_aperture,
	},
	[ASPH_PLAN_SPIRAL] = {
		.name = "spiral", .title = "Archimedean spiral", .pattern = &plan_spiral,
		.lift = lift_projected, .freeform = &over_aperture,
	},
	[ASPH_PLAN_FERMAT] = {
		.name = "fermat", .title = "Fermat (golden-angle) spiral", .pattern = &plan_fermat,
		.lift = lift_projected, .freeform = &over_aperture,
	},
	[ASPH_PLAN_CVT] = {
		.name = "cvt", .title = "centroidal Voronoi tessellation", .pattern = &plan_disk_grid,
		.fill = cvt_fill, .lift = lift_ot, .settle = cvt_settle, .freeform = &cvt_freeform,
	},
	/* lines through the apex, not a pattern over the area: resolve()
	 * counts them (plan-profiles.c); rotationally symmetric parts only */
	[ASPH_PLAN_PROFILES] = {
		.name = "profiles", .title = "line profiles through the apex",
		.pattern = &plan_profile_lines, .fill = profiles_fill, .lift = lift_projected,
	},
};

/* m is checked by the callers (resolve); an unknown one reads as OP. */
static const struct plan_method *method_of(enum asph_plan_method m)
{
	return &methods[(unsigned)m < ASPH_PLAN_N_METHODS ? m : 0];
}

const struct plan_pattern *plan_pattern_of(enum asph_plan_method m)
{
	return method_of(m)->pattern;
}

const struct plan_lattice *plan_lattice_of(enum asph_plan_method m)
{
	return &method_of(m)->pattern->lattice;
}

const char *asph_plan_method_name(enum asph_plan_method m)
{
	return (unsigned)m < ASPH_PLAN_N_METHODS ? methods[m].name : "unknown";
}

int asph_plan_method_names(char *buf, size_t size)
{
	const char *names[ASPH_PLAN_N_METHODS];

	for (unsigned i = 0; i < ASPH_PLAN_N_METHODS; i++)
		names[i] = methods[i].name;
	return suggest_join(buf, size, names, ASPH_PLAN_N_METHODS, ", ");
}

const char *asph_plan_method_title(enum asph_plan_method m)
{
	return (unsigned)m < ASPH_PLAN_N_METHODS ? methods[m].title : "unknown";
}

bool asph_plan_method_has_mesh(enum asph_plan_method m)
{
	return (unsigned)m < ASPH_PLAN_N_METHODS && methods[m].mesh;
}

int asph_plan_method_from_name(const char *name, enum asph_plan_method *out)
{
	for (unsigned i = 0; name && i < ASPH_PLAN_N_METHODS; i++) {
		if (!strcmp(name, methods[i].name)) {
			*out = (enum asph_plan_method)i;
			return 0;
		}
	}
	return -EINVAL;
}

const char *asph_plan_method_suggest(const char *name)
{
	struct suggest s;

	suggest_init(&s, name);
	for (unsigned i = 0; i < ASPH_PLAN_N_METHODS; i++)
		suggest_offer(&s, methods[i].name);
	return suggest_best(&s);
}
