/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_PLAN_H
#define ASPH_PLAN_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/points.h"
#include "asph/progress.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Sampling plans: ordered points on the nominal surface, in the order a
 * stage visits them, and for the grid methods the mesh they come with.
 */
enum asph_plan_method {
	ASPH_PLAN_OP = 0,       /* orthogonal projection of the disk grid (5.2) */
	ASPH_PLAN_OT,           /* optimal transport radial map (5.4) */
	ASPH_PLAN_LB,           /* Laplace-Beltrami map (5.3) */
	ASPH_PLAN_CI,           /* circle involute embedded in the surface (4) */
	ASPH_PLAN_RASTER,       /* x-y raster, projected */
	ASPH_PLAN_CONCENTRIC,   /* concentric circles */
	ASPH_PLAN_SPIRAL,       /* Archimedean spiral in the vertex plane */
	ASPH_PLAN_FERMAT,       /* Fermat / golden-angle spiral */
	ASPH_PLAN_CVT,          /* centroidal Voronoi tessellation on the surface */
	ASPH_PLAN_PROFILES,     /* line profiles through the apex (a tactile
				   instrument's), asph_plan_options.profiles */
	ASPH_PLAN_N_METHODS
};

/* The profiles method: at most this many profiles through the apex. */
#define ASPH_PLAN_MAX_PROFILES 36

/* Name as on the command line ("op", "ot", ...) and back. */
const char *asph_plan_method_name(enum asph_plan_method m);
/* What the method is, in words: "optimal transport", "circle involute". */
const char *asph_plan_method_title(enum asph_plan_method m);
int asph_plan_method_from_name(const char *name, enum asph_plan_method *out);
/* The methods' names in the order of the enum, ", " between them
 * ("op, ot, lb, ..."), as snprintf() writes them: the length of the whole
 * list. */
int asph_plan_method_names(char *buf, size_t size);
/* The method's plan comes with a mesh (the grid methods op, ot, lb). */
bool asph_plan_method_has_mesh(enum asph_plan_method m);
/* The method name closest to a mistyped one ("cvtt": "cvt"), or NULL when
 * none is near. */
const char *asph_plan_method_suggest(const char *name);

/* How dense a plan is: exactly one of three ways. */
enum asph_plan_density_kind {
	ASPH_DENSITY_H = 0,      /* mean edge length / aperture radius (paper) */
	ASPH_DENSITY_SPACING,    /* mean point spacing on the surface, mm */
	ASPH_DENSITY_POINTS,     /* approximate number of points */
	ASPH_PLAN_N_DENSITIES
};

struct asph_plan_density {
	enum asph_plan_density_kind kind;
	double value;
};

/* "h", "spacing", "points" (as the options and JSON keys) and back. */
const char *asph_plan_density_name(enum asph_plan_density_kind k);
int asph_plan_density_from_name(const char *name,
				enum asph_plan_density_kind *out);
/* Their names, ", " between them ("h, spacing, points"), as
 * asph_plan_method_names() writes the methods'. */
int asph_plan_density_names(char *buf, size_t size);

struct asph_plan {
	enum asph_plan_method method;
	struct asph_plan_density density;
	double spacing_mm;       /* the surface spacing the density resolved to */
	size_t n;
	double *xyz;             /* 3 n, mm, scan order */
	size_t n_triangles;      /* 0 when the method has no mesh */
	uint32_t *triangles;     /* 3 n_triangles, indices into xyz, or NULL */
	unsigned profiles;       /* the profiles method: how many; else 0 */
};

/*
 * Computes a plan. -EINVAL (err says which parameter) for a density that is
 * not positive or finite, or that would give more than max_points points
 * (0 = no limit). -E2BIG when the mesh of a grid plan (op, ot, lb) would
 * exceed what the triangulation takes (ASPH_DELAUNAY_MAX_POINTS, 2^29);
 * ASPH_PLAN_NO_MESH of asph_plan_compute_opts() has no such limit.
 * docs/sampling-plans.md describes the methods, densities and scan orders.
 */
int asph_plan_compute(const struct asph_surface *s, enum asph_plan_method m,
		      struct asph_plan_density density, size_t max_points,
		      struct asph_plan **out, struct asph_error *err);
void asph_plan_free(struct asph_plan *p);

/* Options of asph_plan_compute_opts(); a NULL pointer means all zero. */
enum asph_plan_flags {
	/* Grid methods: leave the mesh out (n_triangles = 0). For scan-only
	 * use and for timing the point generation alone. */
	ASPH_PLAN_NO_MESH = 1u << 0,
};

struct asph_plan_options {
	size_t max_points;       /* refuse larger plans; 0 = no limit */
	unsigned flags;          /* enum asph_plan_flags */
	/* The long part of a plan (CVT's iterations: done of at most
	 * ASPH_PLAN_CVT_MAX_ITERATIONS) as it goes; its cancel makes the
	 * computation return -ECANCELED. */
	struct asph_progress progress;
	/* The profiles method: the profiles, 1..ASPH_PLAN_MAX_PROFILES (0:
	 * one); the other methods refuse any but 0. */
	unsigned profiles;
};

/* The most iterations a CVT plan takes (the total its progress counts to). */
#define ASPH_PLAN_CVT_MAX_ITERATIONS 100

int asph_plan_compute_opts(const struct asph_surface *s,
			   enum asph_plan_method m,
			   struct asph_plan_density density,
			   const struct asph_plan_options *opts,
			   struct asph_plan **out, struct asph_error *err);

/*
 * Resolves a density to the surface spacing e (mm) the method works with
 * and the exact number of points the plan will have. Same refusals as
 * asph_plan_compute, except the point limit. Either output may be NULL.
 * The relations are in docs/sampling-plans.md.
 */
int asph_plan_resolve(const struct asph_surface *s, enum asph_plan_method m,
		      struct asph_plan_density density, double *spacing_mm,
		      size_t *n_points, struct asph_error *err);
/* The same with the options' profiles (the rest is not read; NULL: all 0). */
int asph_plan_resolve_opts(const struct asph_surface *s, enum asph_plan_method m,
			   struct asph_plan_density density,
			   const struct asph_plan_options *opts, double *spacing_mm,
			   size_t *n_points, struct asph_error *err);

/* A copy of the plan as points (xyz and the mesh, if any) for
 * asph_points_write(). */
int asph_plan_to_points(const struct asph_plan *p, struct asph_points **out);

/*
 * A plan's parameters as JSON text (malloc'd, caller frees), the shape of a
 * recorded scan's header and of asphd's job results:
 *   {"method": "ot", "density": "h", "value": 0.05, "spacing_mm": 1.005,
 *    "points": 1653}
 * and "profiles": N for the profiles method. 0 or -ENOMEM.
 */
int asph_plan_to_json(const struct asph_plan *p, char **out);

/* What such a text says. */
struct asph_plan_info {
	enum asph_plan_method method;
	struct asph_plan_density density;
	double spacing_mm;       /* NaN when not given */
	uint64_t points;         /* 0 when not given */
	unsigned profiles;       /* the profiles method's (1 when not given);
				    0 for the others */
};

/*
 * Reads asph_plan_to_json()'s text, and the shape `asph scan` wrote into
 * scan headers before, with the density as an object:
 *   {"method": "ot", "density": {"kind": "h", "value": 0.05}, ...}
 * Other members are ignored. -EINVAL, err naming the member (source: where
 * the text comes from, for the message), for anything else.
 */
int asph_plan_info_from_json(const char *text, size_t len, const char *source,
			     struct asph_plan_info *out, struct asph_error *err);

/*
 * The OT radial map of Eq. (9) on the aperture disk of radius a: the
 * radius r in [0, a] with A(r) / A(a) = (rho / a)^2, A the surface area
 * inside a radius. rho is clamped to [0, a].
 */
double asph_plan_ot_radius(const struct asph_surface *s, double rho);

#ifdef __cplusplus
}
#endif

#endif
