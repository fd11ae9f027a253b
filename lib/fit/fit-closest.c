/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The fit's surface model, the closest point, the pose and the DOF names. */
#include <errno.h>
#include <math.h>
#include <string.h>

#include "asph/fit.h"
#include "fit-model.h"
#include "util-mem.h"
#include "util-suggest.h"

/* Newton stops when the next step in r is below this (mm, relative to
 * 1 + a). That last step is still applied (by Taylor expansion), which
 * leaves the foot off by about the curvature times the step squared
 * (< 1e-12 mm); the distance, stationary at the foot, is then exact to
 * rounding. */
#define FOOT_TOL FIT_FOOT_TOL
#define FOOT_MAX_ITER 60
/* asph_fit_closest_point() on a freeform: the foot to rounding level. */
#define FOOT_TOL_EXACT 1e-12

void fit_model_init(struct fit_model *m, const struct asph_surface *s)
{
	const struct asph_prescription *p = asph_surface_prescription(s);

	m->s = s;
	m->rotational = asph_surface_is_radial(s);
	m->centred = asph_surface_is_rotational(s);
	m->a = asph_surface_aperture_radius(s);
	m->conic_changed = 0;
	m->c0 = m->c = m->rotational && isfinite(p->R) ? 1.0 / p->R : 0.0;
	m->K0 = m->K = 1.0 + p->k;
}

void fit_model_set_conic(struct fit_model *m, double c, double k)
{
	if (!m->rotational)
		return;
	m->c = c;
	m->K = 1.0 + k;
	m->conic_changed = (m->c != m->c0 || m->K != m->K0);
}

/* Conic sag and its first two derivatives at r >= 0; NaN past the domain. */
static void conic_derivs(double c, double K, double r, double d[3])
{
	double u = 1.0 - K * c * c * r * r;
	double sq = sqrt(u);

	d[0] = c * r * r / (1.0 + sq);
	d[1] = c * r / sq;
	d[2] = c / (u * sq);
}

void fit_model_derivs(const struct fit_model *m, double r, double d[3])
{
	r = fabs(r);
	asph_surface_sag_derivs(m->s, r, d);
	if (m->conic_changed) {
		double dn[3], d0[3];
		conic_derivs(m->c, m->K, r, dn);
		conic_derivs(m->c0, m->K0, r, d0);
		for (int i = 0; i < 3; i++)
			d[i] += dn[i] - d0[i];
	}
}

/*
 * With S = sqrt(1 - K c^2 r^2) and 1 - S^2 = K c^2 r^2:
 *   d conic / dc = r^2 / (S (1 + S)),
 *   d conic / dk = c^3 r^4 / (2 S (1 + S)^2).
 * The fit varies c, not R = 1/c: the sag is nearly linear in c, and c = 0
 * (a plane) is an ordinary value, where dc/dR = -c^2 would vanish.
 */
void fit_model_conic_partials(const struct fit_model *m, double r,
			      double *dz_dc, double *dz_dk)
{
	double c = m->c, r2 = r * r;
	double sq = sqrt(1.0 - m->K * c * c * r2);

	*dz_dc = r2 / (sq * (1.0 + sq));
	*dz_dk = c * c * c * r2 * r2 / (2.0 * sq * (1.0 + sq) * (1.0 + sq));
}

/* Squared distance in the meridian plane, and the model at signed r. */
static double meridian_eval(const struct fit_model *m, double r, double rho,
			    double z, double d[3])
{
	fit_model_derivs(m, r, d);
	if (r < 0)
		d[1] = -d[1];   /* Z is even in r, Z' odd, Z'' even */
	return (r - rho) * (r - rho) + (d[0] - z) * (d[0] - z);
}

/* Newton's step on the squared distance from (r, d), its Hessian safely
 * positive (Gauss-Newton's where it is not). */
static double newton_step(double r, double rho, double z, const double d[3])
{
	double gn = 1.0 + d[1] * d[1];
	double h = gn + (d[0] - z) * d[2];

	return -((r - rho) + (d[0] - z) * d[1]) / (h > 0.1 * gn ? h : gn);
}

/* Applies the last step, below tolerance, by Taylor expansion: it puts the
 * foot at rounding level for no further evaluation of the surface. */
static void foot_finish(double r, double step, double rho, double z,
			double d[3], struct fit_foot *f)
{
	double inv;

	r += step;
	d[0] += step * (d[1] + 0.5 * step * d[2]);
	d[1] += step * d[2];
	inv = 1.0 / sqrt(1.0 + d[1] * d[1]);
	f->r = r;
	f->rho = rho;
	f->z = d[0];
	f->slope = d[1];
	f->dist = ((rho - r) * -d[1] + (z - d[0])) * inv;
}

/* One safeguarded step from (r, d, phi): Newton's, limited to a quarter of
 * the aperture and halved until the distance does not grow. Returns 1 when
 * converged at r, 0 after a step, -1 on failure. */
static int foot_step(const struct fit_model *m, double rho, double z,
		     double *r, double d[3], double *phi)
{
	double step = newton_step(*r, rho, z, d);
	double tol = FOOT_TOL * (1.0 + m->a), dn[3];

	if (fabs(step) <= tol)
		return 1;
	if (fabs(step) > 0.25 * m->a)
		step = copysign(0.25 * m->a, step);
	for (int k = 0; k < 60; k++) {
		double rn = *r + step;
		double phin = meridian_eval(m, rn, rho, z, dn);
		/* Tiny steps are Newton's quadratic tail: rounding in phi must
		 * not reject them. */
		if (isfinite(phin) && (phin <= *phi || fabs(step) < 1e-6 * (1.0 + m->a))) {
			*r = rn;
			*phi = phin;
			memcpy(d, dn, sizeof(dn));
			return 0;
		}
		step *= 0.5;
		if (fabs(step) <= tol)
			return 1;
	}
	return -1;
}

/* The safeguarded iteration, for starts far from the foot; d holds the
 * surface at r. */
static int foot_search(const struct fit_model *m, double rho, double z,
		       double r, double d[3], struct fit_foot *f)
{
	double phi = (r - rho) * (r - rho) + (d[0] - z) * (d[0] - z);
	int it, st = 0;

	if (!isfinite(phi)) {
		r = 0.0;        /* the vertex is always in the domain */
		phi = meridian_eval(m, r, rho, z, d);
	}
	for (it = 0; it < FOOT_MAX_ITER; it++) {
		st = foot_step(m, rho, z, &r, d, &phi);
		if (st != 0)
			break;
	}
	if (st != 1 || !isfinite(phi))
		return -EDOM;
	foot_finish(r, newton_step(r, rho, z, d), rho, z, d, f);
	f->iterations = it + 1;
	return 0;
}

int fit_foot(const struct fit_model *m, const double q[3], double r0,
	     struct fit_foot *f)
{
	/* hypot's overflow guard is not needed at mm scale, and costs. */
	double rho = sqrt(q[0] * q[0] + q[1] * q[1]), d[3], step;

	if (!isfinite(r0))
		r0 = rho;
	meridian_eval(m, r0, rho, q[2], d);
	step = newton_step(r0, rho, q[2], d);
	/* Fast path: a start (the previous foot) already within tolerance
	 * costs one evaluation of the surface. */
	if (fabs(step) <= FOOT_TOL * (1.0 + m->a)) {
		foot_finish(r0, step, rho, q[2], d, f);
		f->iterations = 0;
		return 0;
	}
	return foot_search(m, rho, q[2], r0, d, f);
}

/* ---- the foot on a freeform: Gauss-Newton in (x, y) --------------------- */

/*
 * phi(x, y) = |q - (x, y, S)|^2 / 2 has the gradient
 *   g = (x - qx + e S_x, y - qy + e S_y),  e = S - qz,
 * and the Hessian G + e Hess S with G = I + grad S grad S^T. Gauss-Newton
 * steps with G alone, which needs S and its gradient only: near the
 * surface, where the fit's points are, e Hess S is small beside I and the
 * iteration contracts by about |e| times the curvature each step (1e-3 for
 * a point 0.05 mm off a surface of radius 50 mm, 1e-7 at nm residuals).
 * Where it contracts slowly (a point far off a strongly curved surface) the
 * iteration turns to Newton's step with the Hessian.
 */
#define FOOT_SLOW_CONTRACTION 0.25

/* S and its gradient (and its Hessian for Newton's step) at p's (x, y);
 * phi there. */
static double xy_eval(const struct fit_model *m, const double q[3], int newton,
		      struct fit_surface_point *p, struct asph_sag *h)
{
	double g[3];

	if (newton) {
		asph_surface_derivs_xy(m->s, p->x, p->y, h);
		p->z = h->z, p->zx = h->zx, p->zy = h->zy;
	} else {
		asph_surface_sag_grad_xy(m->s, p->x, p->y, g);
		p->z = g[0], p->zx = g[1], p->zy = g[2];
	}
	p->nz = NAN;
	double ex = p->x - q[0], ey = p->y - q[1], ez = p->z - q[2];
	return 0.5 * (ex * ex + ey * ey + ez * ez);
}

/* The step from p: Gauss-Newton's, -G^-1 g with G^-1 = I - s s^T / (1 + |s|^2)
 * (s = grad S, det G = 1 + |s|^2); or Newton's with h, the Hessian of S at
 * p, where it is safely positive. */
static void xy_step(const struct fit_surface_point *p, const double q[3],
		    const struct asph_sag *h, double st[2])
{
	double e = p->z - q[2];
	double gx = p->x - q[0] + e * p->zx, gy = p->y - q[1] + e * p->zy;
	double gdet = 1.0 + p->zx * p->zx + p->zy * p->zy;

	if (h) {
		double h11 = 1.0 + p->zx * p->zx + e * h->zxx, h12 = p->zx * p->zy + e * h->zxy;
		double h22 = 1.0 + p->zy * p->zy + e * h->zyy, det = h11 * h22 - h12 * h12;
		if (h11 > 0 && det > 0.01 * gdet) {
			st[0] = -(h22 * gx - h12 * gy) / det;
			st[1] = -(h11 * gy - h12 * gx) / det;
			return;
		}
	}
	double sg = (p->zx * gx + p->zy * gy) / gdet;
	st[0] = p->zx * sg - gx;
	st[1] = p->zy * sg - gy;
}

/* The signed distance of q along the normal at p; sets p->nz. */
static double xy_distance(struct fit_surface_point *p, const double q[3])
{
	if (!isfinite(p->nz))
		p->nz = 1.0 / sqrt(1.0 + p->zx * p->zx + p->zy * p->zy);
	return (-(q[0] - p->x) * p->zx - (q[1] - p->y) * p->zy + (q[2] - p->z)) * p->nz;
}

/*
 * A step of at most the cap, halved until phi does not grow; p, phi and h
 * move with it. Returns 0 after a step, -1 when none is found.
 */
static int xy_move(const struct fit_model *m, const double q[3], int newton, double st[2],
		   struct fit_surface_point *p, double *phi, struct asph_sag *h)
{
	const double cap = 0.25 * m->a;
	double len2 = st[0] * st[0] + st[1] * st[1];
	struct asph_sag hn;

	if (len2 > cap * cap) {
		double f = cap / sqrt(len2);
		st[0] *= f, st[1] *= f;
	}
	for (int k = 0; k < 60; k++) {
		struct fit_surface_point t = { p->x + st[0], p->y + st[1], 0, 0, 0, NAN };
		double phin = xy_eval(m, q, newton, &t, &hn);
		/* tiny steps are the iteration's tail: rounding in phi must not
		 * reject them */
		if (isfinite(phin) &&
		    (phin <= *phi || sqrt(st[0] * st[0] + st[1] * st[1]) < 1e-6 * (1.0 + m->a))) {
			*p = t;
			*phi = phin;
			if (newton)
				*h = hn;
			return 0;
		}
		st[0] *= 0.5, st[1] *= 0.5;
	}
	return -1;
}

int fit_foot_xy(const struct fit_model *m, const double q[3], double tol,
		struct fit_surface_point *at, double *dist, int *iterations)
{
	struct fit_surface_point p = *at;
	struct asph_sag h;
	double phi, st[2], last2 = INFINITY;
	int newton = 0;

	if (!isfinite(p.x) || !isfinite(p.y))
		p = (struct fit_surface_point){ q[0], q[1], NAN, NAN, NAN, NAN };
	/* a start that carries its surface values costs no evaluation */
	if (isfinite(p.z) && isfinite(p.zx) && isfinite(p.zy)) {
		double ex = p.x - q[0], ey = p.y - q[1], ez = p.z - q[2];
		phi = 0.5 * (ex * ex + ey * ey + ez * ez);
	} else {
		phi = xy_eval(m, q, 0, &p, &h);
	}
	if (!isfinite(phi)) {
		p.x = p.y = 0.0;        /* the vertex is always in the domain */
		phi = xy_eval(m, q, 0, &p, &h);
	}
	for (int it = 0; it <= FOOT_MAX_ITER; it++) {
		xy_step(&p, q, newton ? &h : NULL, st);
		double len2 = st[0] * st[0] + st[1] * st[1];
		/* Not taking this last step leaves the distance off by about
		 * the curvature times its length squared over 2: below 1e-13 mm
		 * at the fit's tolerance. */
		if (len2 <= tol * tol && isfinite(phi)) {
			*dist = xy_distance(&p, q);
			*at = p;
			*iterations = it;
			return 0;
		}
		if (!newton && it > 0 &&
		    len2 > FOOT_SLOW_CONTRACTION * FOOT_SLOW_CONTRACTION * last2) {
			newton = 1;
			phi = xy_eval(m, q, 1, &p, &h);
			continue;
		}
		last2 = len2;
		if (xy_move(m, q, newton, st, &p, &phi, &h) < 0)
			return -EDOM;
	}
	return -EDOM;
}

void fit_foot_normal(const struct fit_foot *f, const double q[3], double n[3])
{
	double inv = 1.0 / sqrt(1.0 + f->slope * f->slope);
	double ux = f->rho > 0 ? q[0] / f->rho : 1.0;
	double uy = f->rho > 0 ? q[1] / f->rho : 0.0;

	n[0] = -f->slope * ux * inv;
	n[1] = -f->slope * uy * inv;
	n[2] = inv;
}

int asph_fit_closest_point(const struct asph_surface *s, const double p[3],
			   struct asph_closest *out)
{
	struct fit_model m;
	struct fit_foot f;
	int r;

	fit_model_init(&m, s);
	if (!m.rotational) {
		struct fit_surface_point fx = FIT_NO_POINT;
		double dist;
		int it;
		if ((r = fit_foot_xy(&m, p, FOOT_TOL_EXACT * (1.0 + m.a), &fx, &dist, &it)) < 0)
			return r;
		double inv = 1.0 / sqrt(1.0 + fx.zx * fx.zx + fx.zy * fx.zy);
		*out = (struct asph_closest){
			.foot = { fx.x, fx.y, fx.z }, .normal = { -fx.zx * inv, -fx.zy * inv, inv },
			.distance = dist, .foot_radius = hypot(fx.x, fx.y),
			.inside = asph_surface_contains(s, fx.x, fx.y, 0), .iterations = it,
		};
		return 0;
	}
	r = fit_foot(&m, p, NAN, &f);
	if (r < 0)
		return r;
	out->foot[0] = f.rho > 0 ? f.r * p[0] / f.rho : f.r;
	out->foot[1] = f.rho > 0 ? f.r * p[1] / f.rho : 0.0;
	out->foot[2] = f.z;
	fit_foot_normal(&f, p, out->normal);
	out->distance = f.dist;
	out->foot_radius = fabs(f.r);
	out->inside = m.centred ? out->foot_radius <= m.a
				: asph_surface_contains(s, out->foot[0], out->foot[1], 0);
	out->iterations = f.iterations;
	return 0;
}

/* --- Pose --------------------------------------------------------------- */

void asph_pose_apply(const struct asph_pose *pose, const double q_in[3],
		     double p[3])
{
	double cx = cos(pose->rx), sx = sin(pose->rx);
	double cy = cos(pose->ry), sy = sin(pose->ry);
	double q[3] = { q_in[0], q_in[1], q_in[2] };
	/* Rz(rz) first ... */
	if (pose->rz != 0) {
		double cz = cos(pose->rz), sz = sin(pose->rz);
		q[0] = cz * q_in[0] - sz * q_in[1];
		q[1] = sz * q_in[0] + cz * q_in[1];
	}
	/* ... then Rx(rx) ... */
	double y1 = cx * q[1] - sx * q[2], z1 = sx * q[1] + cx * q[2];
	/* ... then Ry(ry), then the shift. */
	p[0] = cy * q[0] + sy * z1 + pose->t[0];
	p[1] = y1 + pose->t[1];
	p[2] = -sy * q[0] + cy * z1 + pose->t[2];
}

void asph_pose_apply_inverse(const struct asph_pose *pose, const double p[3],
			     double q[3])
{
	double cx = cos(pose->rx), sx = sin(pose->rx);
	double cy = cos(pose->ry), sy = sin(pose->ry);
	double u[3] = { p[0] - pose->t[0], p[1] - pose->t[1], p[2] - pose->t[2] };
	/* Ry(-ry) ... */
	double x1 = cy * u[0] - sy * u[2], z1 = sy * u[0] + cy * u[2];
	/* ... then Rx(-rx) ... */
	q[0] = x1;
	q[1] = cx * u[1] + sx * z1;
	q[2] = -sx * u[1] + cx * z1;
	/* ... then Rz(-rz). */
	if (pose->rz != 0) {
		double cz = cos(pose->rz), sz = sin(pose->rz), q0 = q[0];
		q[0] = cz * q0 + sz * q[1];
		q[1] = -sz * q0 + cz * q[1];
	}
}

/* --- Names -------------------------------------------------------------- */

static const char *const dof_names[ASPH_FIT_N_DOF] = {
	"tx", "ty", "tz", "rx", "ry", "R", "k", "rz",
};

const char *asph_fit_dof_name(enum asph_fit_dof d)
{
	return (unsigned)d < ASPH_FIT_N_DOF ? dof_names[d] : NULL;
}

static int dof_lookup(const char *name, size_t len)
{
	/* c, the curvature, is the degree of freedom the fit varies for R */
	if (len == 1 && name[0] == 'c')
		return ASPH_FIT_R;
	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (strlen(dof_names[d]) == len && !strncmp(dof_names[d], name, len))
			return d;
	return -1;
}

int asph_fit_dof_parse(const char *list, unsigned *mask,
		       struct asph_error *err)
{
	unsigned out = 0;
	const char *p = list;

	if (!list || !*list)
		return asph_error_set(err, -EINVAL, "empty list of degrees of freedom");
	for (;;) {
		size_t len = strcspn(p, ",");
		int d = dof_lookup(p, len);
		if (d < 0) {
			char known[64];
			suggest_join(known, sizeof(known), dof_names, ASPH_FIT_N_DOF, ", ");
			return asph_error_set(err, -EINVAL, "unknown degree of freedom '%.*s' (%s; c for R's curvature)",
					      (int)len, p, known);
		}
		if (out & ASPH_FIT_DOF_BIT(d))
			return asph_error_set(err, -EINVAL,
					      "degree of freedom '%s' given twice%s", dof_names[d],
					      d == ASPH_FIT_R ? " (c is R's curvature)" : "");
		out |= ASPH_FIT_DOF_BIT(d);
		if (p[len] == '\0')
			break;
		p += len + 1;
	}
	*mask = out;
	return 0;
}

static const char *const residual_names[] = { "normal", "sag" };

const char *asph_fit_residual_name(enum asph_fit_residual_kind k)
{
	return (unsigned)k < ARRAY_SIZE(residual_names) ? residual_names[k] : NULL;
}

int asph_fit_residual_from_name(const char *name,
				enum asph_fit_residual_kind *out)
{
	for (size_t i = 0; i < ARRAY_SIZE(residual_names); i++)
		if (!strcmp(name, residual_names[i])) {
			*out = (enum asph_fit_residual_kind)i;
			return 0;
		}
	return -EINVAL;
}
