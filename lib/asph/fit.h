/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_FIT_H
#define ASPH_FIT_H

#include <stddef.h>
#include <stdint.h>

#include "asph/areal.h"
#include "asph/error.h"
#include "asph/form.h"
#include "asph/progress.h"
#include "asph/surface.h"
#include "asph/tolerance.h"
#include "asph/units.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Characterization: best fit of measured points to the nominal surface, and
 * the form error that remains. docs/characterization.md states every
 * convention; the short version:
 *
 * Pose. A part lying with misalignment (tx, ty, tz, rx, ry, rz) is
 * measured at
 *     p = Ry(ry) Rx(rx) Rz(rz) q + t
 * where q is a point of the part in its own frame (vertex at the origin,
 * axis +z), Rz(c) clocks the part about its own axis, Rx(a), Ry(b) are
 * right-handed rotations about the machine x and y axes (first rz, then rx,
 * then ry), and t = (tx, ty, tz) is applied last. The fit reports the pose
 * in that same convention, so that fitting points made with a pose returns
 * that pose. rz exists for freeform surfaces only: a rotationally symmetric
 * one looks the same clocked.
 *
 * Residual. The signed distance of q = Rz(-rz) Rx(-rx) Ry(-ry) (p - t) from
 * the nominal surface along its normal (n_z > 0), positive on the +z side of
 * the surface ("normal"), or q_z - S(q_x, q_y) ("sag").
 */

enum asph_fit_dof {
	ASPH_FIT_TX = 0,        /* shift, mm */
	ASPH_FIT_TY,
	ASPH_FIT_TZ,
	ASPH_FIT_RX,            /* tilt, rad */
	ASPH_FIT_RY,
	ASPH_FIT_R,             /* vertex radius R, mm; the fit varies the
				   curvature c = 1/R (1/mm), "c" in lists */
	ASPH_FIT_K,             /* conic constant */
	ASPH_FIT_RZ,            /* clocking about the part's axis, rad */
	ASPH_FIT_N_DOF
};

#define ASPH_FIT_DOF_BIT(d) (1u << (d))
#define ASPH_FIT_DOF_RIGID 0x1fu   /* tx, ty, tz, rx, ry */
/* All six rigid motions, for freeform surfaces. */
#define ASPH_FIT_DOF_RIGID6 (ASPH_FIT_DOF_RIGID | ASPH_FIT_DOF_BIT(ASPH_FIT_RZ))

/* "tx", "ty", "tz", "rx", "ry", "R", "k", "rz". */
const char *asph_fit_dof_name(enum asph_fit_dof d);

/* Parses a comma-separated list such as "tx,ty,tz,rx,ry,rz" into a mask;
 * "c" (the curvature) names the same degree of freedom as "R". -EINVAL for
 * an unknown or repeated name, or an empty list. */
int asph_fit_dof_parse(const char *list, unsigned *mask,
		       struct asph_error *err);

/* --- Pose --------------------------------------------------------------- */

struct asph_pose {
	double t[3];            /* tx, ty, tz, mm */
	double rx, ry;          /* rad */
	double rz;              /* rad, clocking (freeform surfaces) */
};

/* p = Ry(ry) Rx(rx) Rz(rz) q + t: from the part's frame to the machine's. */
void asph_pose_apply(const struct asph_pose *pose, const double q[3],
		     double p[3]);
/* q = Rz(-rz) Rx(-rx) Ry(-ry) (p - t): the inverse. */
void asph_pose_apply_inverse(const struct asph_pose *pose, const double p[3],
			     double q[3]);

/* --- Closest point ------------------------------------------------------ */

struct asph_closest {
	double foot[3];         /* nearest point of the surface, mm */
	double normal[3];       /* unit normal there, n_z > 0 */
	double distance;        /* (p - foot) . normal, mm */
	double foot_radius;     /* |foot_xy|, mm */
	int inside;             /* the foot is in the aperture */
	int iterations;         /* Newton steps taken */
};

/*
 * Orthogonal projection of p onto the surface (continued past the aperture
 * where the sag is defined). A surface of revolution: safeguarded Newton on
 * the squared distance in the meridian plane of p, started from the sag at
 * p's radius. Any other: safeguarded Newton in (x, y) on the squared
 * distance to (x, y, S(x, y)), started below p, its Hessian replaced by
 * Gauss-Newton's where it is not positive and its steps limited and halved
 * until the distance falls. -EDOM when there is no foot (p far outside the
 * surface's domain, or no convergence); a foot past the aperture is
 * returned with inside = 0.
 */
int asph_fit_closest_point(const struct asph_surface *s, const double p[3],
			   struct asph_closest *out);

/* --- Best fit ----------------------------------------------------------- */

enum asph_fit_residual_kind {
	ASPH_FIT_RESIDUAL_NORMAL = 0,
	ASPH_FIT_RESIDUAL_SAG,
};

const char *asph_fit_residual_name(enum asph_fit_residual_kind k);
int asph_fit_residual_from_name(const char *name,
				enum asph_fit_residual_kind *out);

#define ASPH_FIT_MAX_ZERNIKE 66     /* radial order 10 */
#define ASPH_FIT_DEFAULT_ZERNIKE 36 /* Evans' PVr uses a 36-term fit */

struct asph_fit_options {
	unsigned dof;               /* mask; 0 = ASPH_FIT_DOF_RIGID (a line
				       profile: tx, tz, ry in its trace's
				       frame); rz is refused for a
				       rotationally symmetric surface, R and k
				       for a freeform, k on a plane base */
	enum asph_fit_residual_kind residual;
	int robust;                 /* Tukey biweight reweighting */
	int max_iterations;         /* per pass; 0 = 200 */
	double xtol;                /* step test; 0 = 1e-9 (see docs) */
	double aperture_tolerance;  /* mm past the aperture radius still
				       inside; 0 = 1e-3, < 0 = none */
	double max_outside_fraction; /* refuse above; 0 = 0.5 */
	int n_zernike;              /* 0 = 36; up to ASPH_FIT_MAX_ZERNIKE */
	struct asph_pose start;     /* initial pose (all 0 is fine for parts
				       within a few 0.1 mm and mrad); of a
				       single line profile, in its trace's
				       frame */
	/* Form deviation quantities (docs/characterization.md). */
	double wavelength_nm;       /* test wavelength of the fringes;
				       0 = the tolerance's, else 546.07 */
	double slope_length_mm;     /* evaluation length of the slope; 0 =
				       the tolerance's, else 1 mm */
	const struct asph_tolerance *tolerance; /* NULL: no verdict; read
				       by asph_fit_get_result(), so it must
				       outlive the workspace */
	/* asph_fit_run()'s steps as they go: Levenberg-Marquardt iterations
	 * done, of 0 (the end is not known in advance), then once done of
	 * done while the statistics are computed; a cancel makes it return
	 * -ECANCELED. The stepwise calls do not use it. */
	struct asph_progress progress;
	/* 1: asph_fit_get_result() frees the solver's workspace (as
	 * asph_fit_release_solver() does) once it has the uncertainties,
	 * before the form quantities triangulate the residual map, so that
	 * the two are not held at once: for a fit whose result is taken once
	 * (the characterization's), not for one run again and again (the
	 * Monte Carlo's, which would make the solver anew each time). */
	int release_solver;
};

/* Per-point state after the fit. */
enum asph_fit_point_status {
	ASPH_FIT_POINT_USED = 0,
	ASPH_FIT_POINT_OUTSIDE,     /* no foot inside the aperture: excluded */
	ASPH_FIT_POINT_OUTLIER,     /* weight 0 in the robust fit */
};

/*
 * Line profiles (docs/characterization.md, "Line profiles"): points in
 * scan order that lie on up to ASPH_FIT_MAX_PROFILES straight traces in
 * x-y. One trace, or several parallel ones, is fitted in the trace's own
 * frame (x along the trace, the machine frame turned by its azimuth about
 * z) with the DOF a profile tells apart: tx (the decentre along the
 * trace), tz, ry (the tilt about the axis across it), R and k. Traces at
 * several azimuths (a cross, a star) are fitted together in the machine
 * frame.
 */
#define ASPH_FIT_MAX_PROFILES 36
/* The DOF one profile tells apart, in its trace's frame, and its default. */
#define ASPH_FIT_DOF_PROFILE                                                            \
	(ASPH_FIT_DOF_BIT(ASPH_FIT_TX) | ASPH_FIT_DOF_BIT(ASPH_FIT_TZ) |                 \
	 ASPH_FIT_DOF_BIT(ASPH_FIT_RY) | ASPH_FIT_DOF_BIT(ASPH_FIT_R) | ASPH_FIT_DOF_BIT(ASPH_FIT_K))
#define ASPH_FIT_DOF_PROFILE_DEFAULT                                                    \
	(ASPH_FIT_DOF_BIT(ASPH_FIT_TX) | ASPH_FIT_DOF_BIT(ASPH_FIT_TZ) | ASPH_FIT_DOF_BIT(ASPH_FIT_RY))

struct asph_fit_profile {
	double azimuth;             /* rad, the trace's direction in machine
				       x-y, in (-pi/2, pi/2] */
	double offset_mm;           /* its line's signed distance from the
				       machine z axis, along (-sin, cos) of
				       the azimuth */
	double length_mm;           /* its points' extent along it */
	size_t n_points, n_used;
	asph_nm rms, pv;            /* of the residual over its used points */
	/* The residual's slope along the trace over the slope length, its
	 * tilt removed; NaN when the trace is shorter than the length. */
	asph_urad slope_rms, slope_max;
	size_t n_slope;             /* positions evaluated */
};

struct asph_fit_result {
	size_t n_points;
	size_t n_used;              /* points in the statistics */
	size_t n_outside_aperture;
	size_t n_outliers;          /* zero weight after the robust fit */
	size_t n_downweighted;      /* weight below 1/2 (includes outliers) */
	unsigned dof;               /* the DOF fitted (a profile's, when the
				       options left them to the fit) */
	enum asph_fit_residual_kind residual;
	/* Fitted, in the DOF's unit, and the standard uncertainty; a single
	 * profile's in its trace's frame. R is 1/c; R and its uncertainty
	 * u(c) / c^2 are NaN when c = 0 lies within c's expanded uncertainty
	 * 2 u(c) (a flat: R is not determined, c is). */
	double value[ASPH_FIT_N_DOF];
	double uncertainty[ASPH_FIT_N_DOF];
	/* The fitted pose in the machine frame, the convention above (rz 0
	 * on a surface of revolution). */
	struct asph_pose pose;
	/* With R fitted: the curvature c = 1/R (1/mm) the fit varies, and its
	 * standard uncertainty; else NaN. The nominal curvature always. */
	double curvature, u_curvature, curvature_nominal;
	/* Line profiles: the traces, in the order of their first point. */
	int profile;
	size_t n_profiles;
	struct asph_fit_profile profiles[ASPH_FIT_MAX_PROFILES];
	int iterations;             /* LM iterations, all passes */
	int passes;                 /* LM runs (exclusion, reweighting) */
	int converged;
	char reason[96];
	double sigma_mm;            /* residual standard deviation used for
				       the uncertainties */
	asph_nm rms;                /* of the residual over used points */
	asph_nm pv;
	asph_nm pvr;                /* PV of the Zernike fit + 3 RMS left */
	asph_nm zernike_fit_rms_left;
	asph_urad slope_rms;        /* of the Zernike fit's gradient */
	int n_zernike;
	asph_nm zernike[ASPH_FIT_MAX_ZERNIKE]; /* Noll order, Z_1 first */

	/* ISO 14999-4 quantities of the residual over the used points, with
	 * rho = foot radius / aperture radius; form_valid 0 when the points
	 * cannot determine them (the members are then NaN). */
	int form_valid;
	struct asph_form form;
	/* Slope deviation over slope.length_mm; slope_valid 0 when no
	 * position could be evaluated. */
	int slope_valid;
	struct asph_slope slope;
	/* R - R_nominal when R is fitted, else NaN. */
	double R_nominal_mm, R_deviation_mm;
	/* Expanded uncertainties (k = 2) of the quantities above. */
	struct asph_uncertainty_k2 uncertainty_k2;
	/* With a tolerance: the decision per quantity and overall. */
	struct asph_verdict_report verdict;
};

struct asph_fit;

/*
 * A workspace for up to n_max points. The surface must outlive it. opts may
 * be NULL (defaults). -EINVAL for bad options, -ENOMEM.
 */
int asph_fit_alloc(const struct asph_surface *s, size_t n_max,
		   const struct asph_fit_options *opts, struct asph_fit **out,
		   struct asph_error *err);
void asph_fit_free(struct asph_fit *w);
/* Frees the solver's workspace (GSL's, about seven doubles a point) once
 * the result is taken: the residuals, statuses, weights and feet stay. A
 * later asph_fit_run() makes it again; until then the progress's rms_mm
 * is 0. */
void asph_fit_release_solver(struct asph_fit *w);

/*
 * The fit runs GSL's solvers: a program using it turns GSL's abort-on-error
 * handler off (gsl_set_error_handler_off()), so that a solver failure comes
 * back as an error code.
 *
 * Step by step, as GSL's solvers: init, then iterate until test says done;
 * result. xyz (3 n, machine frame, mm) is read, not copied: it must stay
 * valid until the fit is done.
 *
 * init refuses (-EINVAL) n > n_max, a non-finite coordinate, fewer points
 * than DOF + 1, points all at one place in x-y, a profile asked for DOF it
 * cannot tell apart, and (-EDOM) points that cannot tell the DOF apart
 * (e.g. all at one radius, where a decentre and a tilt look the same).
 * Points on lines are fitted as line profiles (above).
 * iterate runs one Levenberg-Marquardt step; when a pass has converged it
 * starts the next (points whose foot left the aperture excluded, robust
 * weights updated). It returns -EDOM when too many points have no foot inside
 * the aperture (err says how many) and -ERANGE when the solver fails.
 * test returns 1 when the fit is finished, 0 while it needs more steps.
 */
int asph_fit_init(struct asph_fit *w, const double *xyz, size_t n,
		  struct asph_error *err);
int asph_fit_iterate(struct asph_fit *w, struct asph_error *err);
int asph_fit_test(const struct asph_fit *w);

/* Progress, cheap to call after any iterate. */
struct asph_fit_progress {
	int pass;
	int iteration;              /* in the current pass */
	int total_iterations;
	double rms_mm;              /* weighted RMS residual now */
	double value[ASPH_FIT_N_DOF];
};
void asph_fit_get_progress(const struct asph_fit *w,
			   struct asph_fit_progress *out);

/* Residual statistics, Zernike decomposition, uncertainties. After test
 * says done. When the points used cannot determine the Zernike terms (too
 * few, or badly spread) the fit still stands: n_zernike is 0 and pvr,
 * slope_rms and zernike_fit_rms_left are NaN. */
int asph_fit_get_result(struct asph_fit *w, struct asph_fit_result *out,
			struct asph_error *err);

/* All of the above, telling opts->progress of each iteration. */
int asph_fit_run(struct asph_fit *w, const double *xyz, size_t n,
		 struct asph_fit_result *out, struct asph_error *err);

/*
 * The summary of a fit as JSON text (malloc'd, caller frees): the object
 * `asph fit --json` prints and asphd stores as a job's "summary", keys in
 * docs/characterization.md. lens: the lens name shown (NULL: null); robust:
 * whether the fit was robust. A value that could not be computed is null
 * (JSON has no NaN). 0 or -ENOMEM.
 */
int asph_fit_result_to_json(const struct asph_fit_result *r, const char *lens,
			    int robust, char **out);

/* After the fit: residual per point in mm (NaN where status is OUTSIDE),
 * status per point, and the robust weight per point (1 when not robust). */
const double *asph_fit_residuals(const struct asph_fit *w);
const uint8_t *asph_fit_point_status(const struct asph_fit *w);
const double *asph_fit_weights(const struct asph_fit *w);

/* After the fit: the used points as a map of the part, the foot of each
 * (x, y in the part frame, mm; the point's own x, y for sag residuals) in
 * xy[2k], xy[2k+1] and its residual in nm in value_nm[k], in input order.
 * The arrays hold n_used entries (see the result); returns how many were
 * written. */
size_t asph_fit_residual_map(const struct asph_fit *w, double *xy,
			     double *value_nm);

struct asph_scatter;
/* After the fit: that map as the interpolant over the part (areal.h), for
 * the gridded exports, the correction tables and the report. The first
 * call after the fit hands on the triangulation the slope was computed on
 * (the workspace keeps it until then), later ones triangulate anew: the
 * interpolant is the same either way. */
int asph_fit_residual_scatter(struct asph_fit *w, struct asph_scatter **out,
			      struct asph_error *err);

/* --- Synthetic measurements (tests, the mock instrument) ----------------- */

struct asph_synth_term {
	int j;                      /* Noll index */
	double nm;                  /* coefficient */
};

struct asph_synth_options {
	struct asph_pose pose;
	const struct asph_synth_term *terms;
	size_t n_terms;
	double noise_nm;            /* Gaussian, standard deviation, along the
				       surface normal of the part */
	unsigned long seed;
};

/*
 * A part with form error sum_j c_j Z_j(rho, theta) (nm, along the surface
 * normal at (x, y)) and noise, lying with the given pose, measured at the
 * nominal points xyz_nominal (on the surface; only their x, y are used):
 * xyz_out[i] = pose(S(x, y) + (e(x, y) + noise_i) n(x, y)); rho and theta
 * are polar coordinates about the centre of asph_surface_aperture_disk(),
 * rho over its radius (for a centred circle, r / a). Deterministic
 * for a seed (GSL's MT19937 and ziggurat Gaussian). xyz_out may equal
 * xyz_nominal. -EINVAL for a bad Noll index, a point outside the aperture.
 */
int asph_fit_synthesize(const struct asph_surface *s,
			const double *xyz_nominal, size_t n,
			const struct asph_synth_options *opts, double *xyz_out,
			struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
