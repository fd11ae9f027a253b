/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Monte Carlo (GUM Supplement 1) over the instrument model: re-simulated
 * measurements, each characterized as the measurement was. */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>

#include "asph/uncertainty.h"
#include "mc-internal.h"
#include "util-mem.h"

/* One worker's own state, allocated once per run. */
struct asph_mc_worker {
	const struct asph_mc *mc;
	struct asph_fit *fit;
	gsl_rng *rng;
	double *xyz;            /* the trial's measured points */
};

struct asph_mc {
	const struct asph_surface *s;
	size_t n;
	double *truth;          /* 3 n: the best estimate of the points */
	double *direction;      /* 3 n: unit scan direction at each point */
	double *normal;         /* 3 n: unit surface normal, machine frame */
	struct asph_fit_options fit_opts;
	struct asph_uncertainty_model model;
	struct asph_mc_options opt;
	int covered[ASPH_MC_N_QUANTITIES];
	double value[ASPH_MC_N_QUANTITIES];
	size_t capacity;        /* trials the values can hold */
	double *values;         /* capacity x ASPH_MC_N_QUANTITIES */
	double *block_stats;    /* 2 capacity / block: the adaptive stop's */
	size_t planned;         /* trials asked for so far */
	size_t n_run;           /* trials of the last finish */
	int stable;             /* the adaptive stop's last answer */
	double decide_U[ASPH_MC_N_QUANTITIES];  /* opt.decide_U's copy */
};

/* The quantities of one characterization; NaN where it has none. */
void mc_quantities(const struct asph_fit_result *r, double q[ASPH_MC_N_QUANTITIES])
{
	for (int i = 0; i < ASPH_MC_N_QUANTITIES; i++)
		q[i] = NAN;
	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (r->dof & ASPH_FIT_DOF_BIT(d))
			q[d] = r->value[d];
	/* the curvature: defined on a flat too, where R is not */
	if (r->dof & ASPH_FIT_DOF_BIT(ASPH_FIT_R))
		q[ASPH_FIT_R] = r->curvature;
	q[ASPH_MC_RMS] = r->rms.v;
	q[ASPH_MC_PV] = r->pv.v;
	q[ASPH_MC_PVR] = r->n_zernike > 0 ? r->pvr.v : NAN;
	if (r->form_valid) {
		q[ASPH_MC_A] = r->form.A.v;
		q[ASPH_MC_B] = r->form.B.v;
		q[ASPH_MC_C] = r->form.C.v;
		q[ASPH_MC_RMS_T] = r->form.rms_t.v;
		q[ASPH_MC_RMS_I] = r->form.rms_i.v;
		q[ASPH_MC_RMS_A] = r->form.rms_a.v;
	}
	if (r->slope_valid) {
		q[ASPH_MC_SLOPE_RMS] = r->slope.rms.v;
		q[ASPH_MC_SLOPE_MAX] = r->slope.max.v;
	}
}

/* SplitMix64: well-mixed, independent seeds for neighbouring trials. */
static uint64_t trial_seed(unsigned long seed, size_t trial)
{
	uint64_t z = (uint64_t)seed + 0x9e3779b97f4a7c15ull * ((uint64_t)trial + 1);

	z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
	z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
	return z ^ (z >> 31);
}

/* One draw of every contribution onto the best estimate (units in
 * asph/uncertainty.h; mm inside). */
static void simulate(const struct asph_mc *mc, gsl_rng *rng, double *xyz)
{
	const struct asph_uncertainty_model *m = &mc->model;
	double lateral = m->scan_speed_mm_s * gsl_ran_gaussian_ziggurat(rng, 1) * m->latency_us * 1e-6;
	double drift = gsl_ran_gaussian_ziggurat(rng, 1) * m->drift_residual_nm * 1e-6;
	double tip = gsl_ran_gaussian_ziggurat(rng, 1) * m->tip_radius_um * 1e-3;
	double probe = m->probe_noise_nm * 1e-6, pos = m->position_noise_um * 1e-3;
	double step = m->position_resolution_um * 1e-3;
	double last = mc->n > 1 ? (double)(mc->n - 1) : 1;

	for (size_t i = 0; i < mc->n; i++) {
		const double *t = mc->truth + 3 * i, *e = mc->direction + 3 * i;
		const double *nv = mc->normal + 3 * i;
		double *p = xyz + 3 * i;
		for (int k = 0; k < 3; k++)
			p[k] = t[k] + lateral * e[k] + tip * nv[k];
		p[2] += drift * (double)i / last;
		if (probe > 0)
			p[2] += gsl_ran_gaussian_ziggurat(rng, probe);
		for (int k = 0; k < 2; k++) {
			if (pos > 0)
				p[k] += gsl_ran_gaussian_ziggurat(rng, pos);
			if (step > 0)
				p[k] += step * (gsl_rng_uniform(rng) - 0.5);
		}
	}
}

static void run_trial(struct asph_mc *mc, struct asph_mc_worker *w, size_t t)
{
	double *q = mc->values + t * ASPH_MC_N_QUANTITIES;
	struct asph_fit_result r;
	struct asph_error err;

	gsl_rng_set(w->rng, (unsigned long)trial_seed(mc->opt.seed, t));
	simulate(mc, w->rng, w->xyz);
	asph_error_clear(&err);
	if (asph_fit_run(w->fit, w->xyz, mc->n, &r, &err) < 0 || !r.converged) {
		for (int i = 0; i < ASPH_MC_N_QUANTITIES; i++)
			q[i] = NAN;
		return;
	}
	mc_quantities(&r, q);
	for (int i = 0; i < ASPH_MC_N_QUANTITIES; i++)
		if (!mc->covered[i])
			q[i] = NAN;
}

int asph_mc_run_trials(struct asph_mc *mc, struct asph_mc_worker *w, size_t first,
		       size_t count)
{
	if (w->mc != mc || first > mc->capacity || count > mc->capacity - first)
		return -EINVAL;
	for (size_t t = first; t < first + count; t++)
		run_trial(mc, w, t);
	return 0;
}

/* ------------------------------------------------------------ workspace */

static void scan_directions(struct asph_mc *mc)
{
	for (size_t i = 0; i < mc->n; i++) {
		const double *a = mc->truth + 3 * (i > 0 ? i - 1 : i);
		const double *b = mc->truth + 3 * (i + 1 < mc->n ? i + 1 : i);
		double d[3] = { b[0] - a[0], b[1] - a[1], b[2] - a[2] };
		double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
		for (int k = 0; k < 3; k++)
			mc->direction[3 * i + k] = len > 0 ? d[k] / len : 0;
	}
}

/* The fitted surface's normal at each point's place on the part, turned
 * into the machine frame by the fitted pose. */
static void normals(struct asph_mc *mc, const struct asph_pose *pose)
{
	struct asph_pose rot = *pose;

	rot.t[0] = rot.t[1] = rot.t[2] = 0;
	for (size_t i = 0; i < mc->n; i++) {
		double q[3], n[3];
		asph_pose_apply_inverse(pose, mc->truth + 3 * i, q);
		asph_surface_normal(mc->s, q[0], q[1], n);
		if (!(isfinite(n[0]) && isfinite(n[1]) && isfinite(n[2])))
			n[0] = n[1] = 0, n[2] = 1;
		asph_pose_apply(&rot, n, mc->normal + 3 * i);
	}
}

static void covered_quantities(struct asph_mc *mc, const struct asph_fit_result *ref)
{
	mc_quantities(ref, mc->value);
	for (int i = 0; i < ASPH_MC_N_QUANTITIES; i++)
		mc->covered[i] = isfinite(mc->value[i]);
}

static int check_options(struct asph_mc_options *o, struct asph_error *err)
{
	if (o->n_trials == 0)
		o->n_trials = ASPH_MC_DEFAULT_TRIALS;
	if (o->block_size == 0)
		o->block_size = ASPH_MC_DEFAULT_BLOCK;
	if (o->max_trials == 0)
		o->max_trials = o->fixed ? o->n_trials : ASPH_MC_DEFAULT_MAX_TRIALS;
	if (o->significant_digits == 0)
		o->significant_digits = 1;
	if (o->n_trials < 2 || o->n_trials > (size_t)1 << 24)
		return asph_error_set(err, -EINVAL, "the number of trials must be 2..%zu",
				      (size_t)1 << 24);
	if (o->fixed)
		o->max_trials = o->n_trials;
	if (o->max_trials < o->n_trials || o->max_trials > (size_t)1 << 24)
		return asph_error_set(err, -EINVAL, "max_trials must be n_trials..%zu",
				      (size_t)1 << 24);
	if (!o->fixed && (o->block_size < 2 || o->n_trials % o->block_size ||
			  o->n_trials / o->block_size < 2))
		return asph_error_set(err, -EINVAL,
				      "the adaptive stop needs n_trials a multiple (>= 2) of the "
				      "block size, %zu and %zu are not", o->n_trials, o->block_size);
	if (o->significant_digits < 1 || o->significant_digits > 4)
		return asph_error_set(err, -EINVAL, "significant_digits must be 1..4");
	if (o->decide_precision == 0)
		o->decide_precision = 0.05;
	if (!(o->decide_precision > 0 && o->decide_precision < 1))
		return asph_error_set(err, -EINVAL, "decide_precision must be in (0, 1), not %g",
				      o->decide_precision);
	for (int q = 0; o->decide_U && q < ASPH_MC_N_QUANTITIES; q++)
		if (!(o->decide_U[q] >= 0 && isfinite(o->decide_U[q])))
			return asph_error_set(err, -EINVAL, "the threshold of U for %s must be a "
					      "number >= 0", asph_mc_quantity_key((enum asph_mc_quantity)q));
	return 0;
}

void asph_mc_worker_free(struct asph_mc_worker *w)
{
	if (!w)
		return;
	asph_fit_free(w->fit);
	gsl_rng_free(w->rng);
	free(w->xyz);
	free(w);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_mc_worker *, asph_mc_worker_free)

int asph_mc_worker_alloc(const struct asph_mc *mc, struct asph_mc_worker **out,
			 struct asph_error *err)
{
	_cleanup_(asph_mc_worker_freep) struct asph_mc_worker *w = calloc(1, sizeof(*w));
	int r;

	if (!w)
		return asph_error_set(err, -ENOMEM, "out of memory");
	w->mc = mc;
	w->rng = gsl_rng_alloc(gsl_rng_mt19937);
	w->xyz = malloc(3 * mc->n * sizeof(double) + 1);
	if (!w->rng || !w->xyz)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_fit_alloc(mc->s, mc->n, &mc->fit_opts, &w->fit, err);
	if (r < 0)
		return r;
	*out = steal_ptr(w);
	return 0;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_mc *, asph_mc_free)

int asph_mc_alloc(const struct asph_surface *s, const double *xyz, size_t n,
		  const struct asph_fit_options *fit_opts,
		  const struct asph_fit_result *ref,
		  const struct asph_uncertainty_model *model,
		  const struct asph_mc_options *opts, struct asph_mc **out,
		  struct asph_error *err)
{
	_cleanup_(asph_mc_freep) struct asph_mc *mc = NULL;
	struct asph_mc_options o = opts ? *opts : (struct asph_mc_options){ 0 };
	int r;

	if (!ref->converged)
		return asph_error_set(err, -EINVAL, "the reference fit did not converge");
	if (ref->n_points != n)
		return asph_error_set(err, -EINVAL, "the reference fit has %zu points, not %zu",
				      ref->n_points, n);
	r = asph_uncertainty_model_check(model, err);
	if (r == 0)
		r = check_options(&o, err);
	if (r < 0)
		return r;
	mc = calloc(1, sizeof(*mc));
	if (!mc)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mc->s = s;
	mc->n = n;
	mc->model = *model;
	mc->opt = o;
	if (o.decide_U) {
		memcpy(mc->decide_U, o.decide_U, sizeof(mc->decide_U));
		mc->opt.decide_U = mc->decide_U;
	}
	mc->fit_opts = fit_opts ? *fit_opts : (struct asph_fit_options){ 0 };
	mc->fit_opts.tolerance = NULL;
	/* the trials' fits run on the runner's workers: the caller hears of
	 * trials, not of their steps */
	mc->fit_opts.progress = (struct asph_progress){ 0 };
	/* every trial starts where the measurement's fit ended (a single
	 * profile's pose is its trace frame's, as the trials' fits run) */
	mc->fit_opts.start = (struct asph_pose){
		{ ref->value[ASPH_FIT_TX], ref->value[ASPH_FIT_TY], ref->value[ASPH_FIT_TZ] },
		ref->value[ASPH_FIT_RX], ref->value[ASPH_FIT_RY],
		ref->dof & ASPH_FIT_DOF_BIT(ASPH_FIT_RZ) ? ref->value[ASPH_FIT_RZ] : 0,
	};
	covered_quantities(mc, ref);
	mc->capacity = o.max_trials;
	mc->truth = malloc(3 * n * sizeof(double) + 1);
	mc->direction = malloc(3 * n * sizeof(double) + 1);
	mc->normal = malloc(3 * n * sizeof(double) + 1);
	mc->values = malloc(mc->capacity * ASPH_MC_N_QUANTITIES * sizeof(double));
	mc->block_stats = malloc((2 * (mc->capacity / o.block_size) + 1) * sizeof(double));
	if (!mc->truth || !mc->direction || !mc->normal || !mc->values || !mc->block_stats)
		return asph_error_set(err, -ENOMEM, "out of memory");
	memcpy(mc->truth, xyz, 3 * n * sizeof(double));
	scan_directions(mc);
	normals(mc, &ref->pose);
	*out = steal_ptr(mc);
	return 0;
}

void asph_mc_free(struct asph_mc *mc)
{
	if (!mc)
		return;
	free(mc->truth);
	free(mc->direction);
	free(mc->normal);
	free(mc->values);
	free(mc->block_stats);
	free(mc);
}

const double *asph_mc_values(const struct asph_mc *mc, size_t *n_trials)
{
	*n_trials = mc->n_run;
	return mc->values;
}

/* ------------------------------------------------------------------ run */

int asph_mc_next_block(struct asph_mc *mc, size_t done, size_t *first, size_t *count)
{
	const struct asph_mc_options *o = &mc->opt;

	if (done == 0) {
		mc->planned = o->n_trials;
		mc->stable = 0;
	} else if (done > mc->planned) {
		done = mc->planned;
	}
	if (done == mc->planned) {
		if (o->fixed)
			return 0;
		struct mc_stop stop = { .block = o->block_size, .ndig = o->significant_digits,
					.decide_U = o->decide_U, .precision = o->decide_precision };
		mc->stable = mc_stable(mc->values, done, mc->covered, &stop, mc->block_stats);
		if (mc->stable || mc->planned + o->block_size > o->max_trials)
			return 0;
		mc->planned += o->block_size;
	}
	*first = done;
	*count = mc->planned - done;
	return 1;
}

size_t asph_mc_planned(const struct asph_mc *mc)
{
	return mc->planned;
}

int asph_mc_finish(struct asph_mc *mc, size_t done, int cancelled,
		   struct asph_mc_result *out, struct asph_error *err)
{
	const struct asph_mc_options *o = &mc->opt;

	if (done > mc->planned)
		done = mc->planned;
	cancelled |= done < mc->planned;
	mc->n_run = done;
	mc_summarize(mc->values, done, mc->covered, mc->value, out);
	out->fixed = o->fixed;
	out->stable = !o->fixed && !cancelled && mc->stable;
	out->block_size = o->block_size;
	out->significant_digits = o->significant_digits;
	out->seed = o->seed;
	out->model = mc->model;
	if (cancelled)
		return asph_error_set(err, -ECANCELED, "cancelled after %zu of %zu trials",
				      done, mc->planned);
	if (out->n_failed * 2 > out->n_trials)
		return asph_error_set(err, -EDOM, "%zu of %zu trials could not be characterized",
				      out->n_failed, out->n_trials);
	return 0;
}
