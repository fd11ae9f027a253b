/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Monte Carlo (GUM Supplement 1) over the instrument model: re-simulated
 * measurements, each characterized as the measurement was. */
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>

#include "asph/uncertainty.h"
#include "mc-internal.h"
#include "util-mem.h"

/* One worker's own state, allocated once per run's workspace. */
struct mc_worker {
	struct asph_mc *mc;
	struct asph_fit *fit;
	gsl_rng *rng;
	double *xyz;            /* the trial's measured points */
	pthread_t thread;
	int started;
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
	size_t n_run;
	int n_workers;
	struct mc_worker *workers;

	/* The block being run, shared with the workers under lock. */
	pthread_mutex_t lock;
	pthread_cond_t work, done;
	size_t next, end, finished;
	int quit, cancel;
};

static const char *const quantity_keys[ASPH_MC_N_QUANTITIES] = {
	[ASPH_FIT_TX] = "tx", [ASPH_FIT_TY] = "ty", [ASPH_FIT_TZ] = "tz",
	[ASPH_FIT_RX] = "rx", [ASPH_FIT_RY] = "ry", [ASPH_FIT_R] = "R_mm",
	[ASPH_FIT_K] = "k", [ASPH_FIT_RZ] = "rz",
	[ASPH_MC_RMS] = "rms_nm", [ASPH_MC_PV] = "pv_nm", [ASPH_MC_PVR] = "pvr_nm",
	[ASPH_MC_A] = "A_nm", [ASPH_MC_B] = "B_nm", [ASPH_MC_C] = "C_nm",
	[ASPH_MC_RMS_T] = "rms_t_nm", [ASPH_MC_RMS_I] = "rms_i_nm", [ASPH_MC_RMS_A] = "rms_a_nm",
	[ASPH_MC_SLOPE_RMS] = "rms_urad", [ASPH_MC_SLOPE_MAX] = "max_urad",
};

const char *asph_mc_quantity_key(enum asph_mc_quantity q)
{
	return (unsigned)q < ASPH_MC_N_QUANTITIES ? quantity_keys[q] : NULL;
}

/* The quantities of one characterization; NaN where it has none. */
void mc_quantities(const struct asph_fit_result *r, double q[ASPH_MC_N_QUANTITIES])
{
	for (int i = 0; i < ASPH_MC_N_QUANTITIES; i++)
		q[i] = NAN;
	for (int d = 0; d < ASPH_FIT_N_DOF; d++)
		if (r->dof & ASPH_FIT_DOF_BIT(d))
			q[d] = r->value[d];
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

static void run_trial(struct mc_worker *w, size_t t)
{
	struct asph_mc *mc = w->mc;
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

static void *worker_main(void *data)
{
	struct mc_worker *w = data;
	struct asph_mc *mc = w->mc;

	pthread_mutex_lock(&mc->lock);
	for (;;) {
		while (!mc->quit && (mc->cancel || mc->next >= mc->end))
			pthread_cond_wait(&mc->work, &mc->lock);
		if (mc->quit)
			break;
		size_t t = mc->next++;
		pthread_mutex_unlock(&mc->lock);
		run_trial(w, t);
		pthread_mutex_lock(&mc->lock);
		mc->finished++;
		pthread_cond_signal(&mc->done);
	}
	pthread_mutex_unlock(&mc->lock);
	return NULL;
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
	if (o->n_threads == 0)
		o->n_threads = 1;
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
	if (o->n_threads < 1 || o->n_threads > 256)
		return asph_error_set(err, -EINVAL, "n_threads must be 1..256");
	return 0;
}

static int workers_alloc(struct asph_mc *mc, struct asph_error *err)
{
	mc->workers = calloc((size_t)mc->opt.n_threads, sizeof(*mc->workers));
	if (!mc->workers)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mc->n_workers = mc->opt.n_threads;
	for (int i = 0; i < mc->n_workers; i++) {
		struct mc_worker *w = &mc->workers[i];
		int r;
		w->mc = mc;
		w->rng = gsl_rng_alloc(gsl_rng_mt19937);
		w->xyz = malloc(3 * mc->n * sizeof(double));
		if (!w->rng || !w->xyz)
			return asph_error_set(err, -ENOMEM, "out of memory");
		r = asph_fit_alloc(mc->s, mc->n, &mc->fit_opts, &w->fit, err);
		if (r < 0)
			return r;
	}
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
	pthread_mutex_init(&mc->lock, NULL);
	pthread_cond_init(&mc->work, NULL);
	pthread_cond_init(&mc->done, NULL);
	mc->s = s;
	mc->n = n;
	mc->model = *model;
	mc->opt = o;
	mc->fit_opts = fit_opts ? *fit_opts : (struct asph_fit_options){ 0 };
	mc->fit_opts.tolerance = NULL;
	/* every trial starts where the measurement's fit ended */
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
	normals(mc, &mc->fit_opts.start);
	r = workers_alloc(mc, err);
	if (r < 0)
		return r;
	*out = steal_ptr(mc);
	return 0;
}

void asph_mc_free(struct asph_mc *mc)
{
	if (!mc)
		return;
	for (int i = 0; mc->workers && i < mc->n_workers; i++) {
		asph_fit_free(mc->workers[i].fit);
		gsl_rng_free(mc->workers[i].rng);
		free(mc->workers[i].xyz);
	}
	free(mc->workers);
	pthread_cond_destroy(&mc->work);
	pthread_cond_destroy(&mc->done);
	pthread_mutex_destroy(&mc->lock);
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

/* Hands trials [mc->finished, end) to the workers and waits for them,
 * reporting progress. 1 when cancelled, else 0. */
static int run_block(struct asph_mc *mc, size_t end, size_t planned)
{
	pthread_mutex_lock(&mc->lock);
	mc->end = end;
	pthread_cond_broadcast(&mc->work);
	while (mc->finished < mc->next || (mc->next < mc->end && !mc->cancel)) {
		size_t done;
		pthread_cond_wait(&mc->done, &mc->lock);
		done = mc->finished;
		if (mc->opt.progress) {
			/* the callback runs unlocked: it may take its time */
			pthread_mutex_unlock(&mc->lock);
			int stop = mc->opt.progress(mc->opt.progress_data, done, planned);
			pthread_mutex_lock(&mc->lock);
			if (stop)
				mc->cancel = 1;
		}
	}
	int cancelled = mc->cancel;
	mc->n_run = mc->finished;
	pthread_mutex_unlock(&mc->lock);
	return cancelled;
}

static void stop_workers(struct asph_mc *mc)
{
	pthread_mutex_lock(&mc->lock);
	mc->quit = 1;
	pthread_cond_broadcast(&mc->work);
	pthread_mutex_unlock(&mc->lock);
	for (int i = 0; i < mc->n_workers; i++)
		if (mc->workers[i].started)
			pthread_join(mc->workers[i].thread, NULL);
	for (int i = 0; i < mc->n_workers; i++)
		mc->workers[i].started = 0;
}

static int start_workers(struct asph_mc *mc, struct asph_error *err)
{
	mc->next = mc->end = mc->finished = 0;
	mc->quit = mc->cancel = 0;
	mc->n_run = 0;
	for (int i = 0; i < mc->n_workers; i++) {
		if (pthread_create(&mc->workers[i].thread, NULL, worker_main, &mc->workers[i])) {
			stop_workers(mc);
			return asph_error_set(err, -EAGAIN, "cannot start a worker thread");
		}
		mc->workers[i].started = 1;
	}
	return 0;
}

int asph_mc_run(struct asph_mc *mc, struct asph_mc_result *out,
		struct asph_error *err)
{
	const struct asph_mc_options *o = &mc->opt;
	size_t end = o->n_trials;
	int cancelled, stable = 0;
	int r = start_workers(mc, err);

	if (r < 0)
		return r;
	for (;;) {
		cancelled = run_block(mc, end, end);
		if (cancelled)
			break;
		if (o->fixed)
			break;
		stable = mc_stable(mc->values, mc->n_run, mc->covered, o->block_size,
				   o->significant_digits, mc->block_stats);
		if (stable || end + o->block_size > o->max_trials)
			break;
		end += o->block_size;
	}
	stop_workers(mc);
	mc_summarize(mc->values, mc->n_run, mc->covered, mc->value, out);
	out->fixed = o->fixed;
	out->stable = stable;
	out->block_size = o->block_size;
	out->significant_digits = o->significant_digits;
	out->seed = o->seed;
	out->model = mc->model;
	if (cancelled)
		return asph_error_set(err, -ECANCELED, "cancelled after %zu of %zu trials",
				      mc->n_run, end);
	if (out->n_failed * 2 > out->n_trials)
		return asph_error_set(err, -EDOM, "%zu of %zu trials could not be characterized",
				      out->n_failed, out->n_trials);
	return 0;
}
