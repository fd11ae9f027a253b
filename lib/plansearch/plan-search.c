/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The plan for a tolerance: the quickest plan whose U meets capability x T
 * for every limited quantity, each plan measured in simulation by the
 * characterization and its Monte Carlo (docs/sampling-plans.md, "The plan
 * for a tolerance").
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/plan-search.h"
#include "plansearch-internal.h"
#include "util-mem.h"

/* Runs of one method, at most (the bisection needs a handful). */
#define MAX_EVALS 48
/* The trials of one run, at most: U to 2.5 % (1 / sqrt(2 M)). A run near
 * the threshold would otherwise go on to the Monte Carlo's 2000 trials to
 * settle U to 5 % of the threshold alone; the model pools the runs of a
 * method, and a floor near the threshold (the tip on a weak lens) would
 * have each finer run pay them again. */
#define RUN_MAX_TRIALS 800
/* Probes of a method's time for the points that take as long as the best
 * plan, at most. */
#define MAX_TIME_PROBES 6
/* The part's form error: the Zernike shapes the quantities measure. */
#define N_SHAPES 3
static const int shape_noll[N_SHAPES] = { 4, 6, 11 };  /* defocus, astigmatism, spherical */
/* The amplitude a shape is measured at before it is scaled, nm. */
#define SHAPE_PROBE_NM 100.0

#define set_field(err, code, field, ...) \
	asph_error_set_at(err, code, NULL, 0, 0, field, __VA_ARGS__)

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_plan *, asph_plan_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_characterization *, asph_characterize_free)

enum phase {
	PHASE_ORDER,            /* each method's coarsest plan timed */
	PHASE_SEARCH,           /* the methods in turn */
	PHASE_CONTRIBUTIONS,    /* nothing met the ratio: what dominates */
	PHASE_DONE,
};

struct method_state {
	enum asph_plan_method m;
	int candidate;
	size_t n_min;           /* its coarsest plan's request */
	double t_min;           /* and time */
	size_t n_min_points;    /* and points */
	double min_spacing_mm;
	int chosen;             /* the run of its plan, -1 */
	struct ps_eval evals[MAX_EVALS];
	size_t n_evals;
	size_t cap;             /* the request that takes the best plan's time */
	int capped;             /* searched below cap (another plan is quicker) */
	int done;
};

struct asph_plan_search {
	const struct asph_surface *s;
	struct asph_plan_search_options o;
	double threshold[NQ];   /* capability x T: what U must stay within */
	int n_limited;
	struct method_state ms[ASPH_PLAN_N_METHODS];
	int order[ASPH_PLAN_N_METHODS];
	int n_order, next_order;        /* PHASE_ORDER: methods timed */
	int current;                    /* PHASE_SEARCH: index into order */
	enum phase phase;
	int best;                       /* method of the quickest plan found, -1 */
	struct asph_plan_search_status status;
	struct asph_plan_search_result res;
	/* the part of the last plan characterized */
	struct asph_synth_term terms[N_SHAPES];
	size_t n_terms;
};

/* ------------------------------------------------------------- names */

static const char *const contribution_names[ASPH_PLAN_SEARCH_N_CONTRIBUTIONS] = {
	"probe noise", "position", "drift", "tip",
};
static const char *const contribution_keys[ASPH_PLAN_SEARCH_N_CONTRIBUTIONS] = {
	"probe_noise", "position", "drift", "tip",
};
static const char *const outcome_names[] = {
	[ASPH_PLAN_SEARCH_NOT_TRIED] = "not-tried", [ASPH_PLAN_SEARCH_CHOSEN] = "chosen",
	[ASPH_PLAN_SEARCH_SLOWER] = "slower", [ASPH_PLAN_SEARCH_TOO_SLOW] = "too-slow",
	[ASPH_PLAN_SEARCH_IMPOSSIBLE] = "impossible", [ASPH_PLAN_SEARCH_FAILED] = "failed",
};

const char *asph_plan_search_contribution_name(enum asph_plan_search_contribution c)
{
	return (unsigned)c < ASPH_PLAN_SEARCH_N_CONTRIBUTIONS ? contribution_names[c] : NULL;
}

const char *asph_plan_search_contribution_key(enum asph_plan_search_contribution c)
{
	return (unsigned)c < ASPH_PLAN_SEARCH_N_CONTRIBUTIONS ? contribution_keys[c] : NULL;
}

const char *asph_plan_search_outcome_name(enum asph_plan_search_outcome o)
{
	return (unsigned)o <= ASPH_PLAN_SEARCH_FAILED ? outcome_names[o] : NULL;
}

/* ----------------------------------------------------------- limits */

int asph_plan_search_limits(const struct asph_tolerance *t, double limit[NQ],
			    struct asph_error *err)
{
	const struct {
		int q;
		double v;
	} map[] = {
		{ ASPH_MC_A, t->A.v }, { ASPH_MC_B, t->B.v }, { ASPH_MC_C, t->C.v },
		{ ASPH_MC_RMS_T, t->rms_t.v }, { ASPH_MC_RMS_I, t->rms_i.v },
		{ ASPH_MC_RMS_A, t->rms_a.v }, { ASPH_MC_SLOPE_RMS, t->slope_rms.v },
		{ ASPH_MC_SLOPE_MAX, t->slope_max.v }, { ASPH_FIT_R, t->R_mm },
	};
	int any = 0;

	for (int q = 0; q < NQ; q++)
		limit[q] = 0;
	for (size_t i = 0; i < sizeof(map) / sizeof(map[0]); i++)
		if (isfinite(map[i].v) && map[i].v > 0) {
			limit[map[i].q] = map[i].v;
			any = 1;
		}
	return any ? 0 : asph_error_set(err, -EINVAL, "the tolerance limits nothing");
}

/* ---------------------------------------------------------- options */

static int check_options(const struct asph_plan_search_options *o, struct asph_error *err)
{
	int any = 0;

	if (!(o->capability > 0 && o->capability <= 1))
		return set_field(err, -EINVAL, "capability",
					    "the capability ratio must be in (0, 1], not %g",
					    o->capability);
	for (int q = 0; q < NQ; q++) {
		if (!(o->limit[q] >= 0 && isfinite(o->limit[q])))
			return set_field(err, -EINVAL, "limit",
						    "the limit of %s must be a number >= 0",
						    asph_mc_quantity_key((enum asph_mc_quantity)q));
		any |= o->limit[q] > 0;
	}
	if (!any)
		return set_field(err, -EINVAL, "limit", "no quantity is limited");
	if (asph_uncertainty_model_is_empty(&o->model))
		return set_field(err, -EINVAL, "model",
					    "the instrument declares no uncertainty contributions");
	if (!o->run_mc || !o->plan_time)
		return asph_error_set(err, -EINVAL, "the search needs a Monte Carlo runner and a "
				      "measuring time");
	if (o->min_points > o->max_points)
		return set_field(err, -EINVAL, "min_points",
					    "the coarsest plan (%zu points) is finer than the "
					    "finest (%zu)", o->min_points, o->max_points);
	if (!(o->precision > 0 && o->precision < 0.5))
		return set_field(err, -EINVAL, "precision",
					    "the precision must be in (0, 0.5), not %g",
					    o->precision);
	if (!(o->methods & ((1u << ASPH_PLAN_N_METHODS) - 1)))
		return set_field(err, -EINVAL, "methods", "no plan method to try");
	return asph_uncertainty_model_check(&o->model, err);
}

static void defaults(struct asph_plan_search_options *o)
{
	if (o->capability == 0)
		o->capability = ASPH_PLAN_SEARCH_DEFAULT_CAPABILITY;
	/* line profiles do not cover the area an areal tolerance limits */
	if (o->methods == 0)
		o->methods = ((1u << ASPH_PLAN_N_METHODS) - 1) & ~(1u << ASPH_PLAN_PROFILES);
	if (o->max_points == 0)
		o->max_points = ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS;
	if (o->min_points == 0) {
		int terms = o->fit.n_zernike ? o->fit.n_zernike : ASPH_FIT_DEFAULT_ZERNIKE;
		o->min_points = (size_t)(ASPH_PLAN_SEARCH_POINTS_PER_TERM * terms);
		if (o->min_points > o->max_points)
			o->min_points = o->max_points;
	}
	if (o->budget == 0)
		o->budget = ASPH_PLAN_SEARCH_DEFAULT_BUDGET;
	if (o->precision == 0)
		o->precision = 0.05;
	if (o->mc.n_trials == 0 && o->mc.block_size == 0) {
		o->mc.n_trials = 100;
		o->mc.block_size = 25;
	}
}

void asph_plan_search_free(struct asph_plan_search *ps)
{
	free(ps);
}

int asph_plan_search_alloc(const struct asph_surface *s,
			   const struct asph_plan_search_options *opts,
			   struct asph_plan_search **out, struct asph_error *err)
{
	struct asph_plan_search_options o = *opts;
	struct asph_plan_search *ps;
	int r;

	defaults(&o);
	r = check_options(&o, err);
	if (r < 0)
		return r;
	ps = calloc(1, sizeof(*ps));
	if (!ps)
		return asph_error_set(err, -ENOMEM, "out of memory");
	ps->s = s;
	ps->o = o;
	ps->best = -1;
	ps->status.ratio = NAN;
	ps->status.budget = o.budget;
	for (int q = 0; q < NQ; q++) {
		ps->threshold[q] = o.capability * o.limit[q];
		ps->n_limited += o.limit[q] > 0;
	}
	for (int m = 0; m < ASPH_PLAN_N_METHODS; m++) {
		ps->ms[m].m = (enum asph_plan_method)m;
		ps->ms[m].candidate = !!(o.methods & (1u << m));
		ps->ms[m].chosen = -1;
		ps->res.methods[m].method = (enum asph_plan_method)m;
		ps->res.methods[m].ratio = ps->res.methods[m].needed_seconds = NAN;
		ps->res.methods[m].seconds = ps->res.methods[m].h = NAN;
		ps->res.methods[m].spacing_mm = NAN;
		if (ps->ms[m].candidate)
			ps->order[ps->n_order++] = m;
	}
	ps->res.capability = o.capability;
	ps->res.min_points = o.min_points;
	ps->res.max_points = o.max_points;
	for (int c = 0; c < ASPH_PLAN_SEARCH_N_CONTRIBUTIONS; c++)
		ps->res.contribution_U[c] = NAN;
	*out = ps;
	return 0;
}

/* ------------------------------------------------------------- plans */

static int compute_plan(const struct asph_plan_search *ps, enum asph_plan_method m,
			size_t request, struct asph_plan **plan, struct asph_error *err)
{
	struct asph_plan_options po = { .flags = ASPH_PLAN_NO_MESH };
	struct asph_plan_density d = { ASPH_DENSITY_POINTS, (double)request };

	return asph_plan_compute_opts(ps->s, m, d, &po, plan, err);
}

/* The plan of request points and its time. */
static int timed_plan(const struct asph_plan_search *ps, enum asph_plan_method m,
		      size_t request, struct asph_plan **plan, double *seconds,
		      struct asph_error *err)
{
	int r = compute_plan(ps, m, request, plan, err);

	if (r == 0)
		r = ps->o.plan_time(ps->o.plan_time_data, *plan, seconds, err);
	return r;
}

/* The coarsest plan of method m: the search's fewest points, and no
 * spacing above the slope's evaluation length when a slope is limited. */
static int coarsest_request(const struct asph_plan_search *ps, enum asph_plan_method m,
			    size_t *request, struct asph_error *err)
{
	const struct asph_tolerance *t = ps->o.fit.tolerance;
	double L = ps->o.fit.slope_length_mm > 0 ? ps->o.fit.slope_length_mm
		   : t && isfinite(t->slope_length_mm) ? t->slope_length_mm : 1.0;
	struct asph_plan_density d = { ASPH_DENSITY_SPACING, L };
	size_t n = 0;

	*request = ps->o.min_points;
	if (!(ps->o.limit[ASPH_MC_SLOPE_RMS] > 0 || ps->o.limit[ASPH_MC_SLOPE_MAX] > 0))
		return 0;
	if (L > asph_surface_aperture_radius(ps->s))
		return 0;
	int r = asph_plan_resolve(ps->s, m, d, NULL, &n, err);
	if (r < 0)
		return r;
	if (n > *request)
		*request = n;
	return 0;
}

static void method_failed(struct asph_plan_search *ps, int m, const struct asph_error *err)
{
	struct asph_plan_search_method *rm = &ps->res.methods[m];

	rm->outcome = ASPH_PLAN_SEARCH_FAILED;
	const char *why = err->message[0] ? err->message : "could not be computed";
	size_t n = strnlen(why, sizeof(rm->message) - 1);

	memcpy(rm->message, why, n);
	rm->message[n] = '\0';
	ps->ms[m].done = 1;
}

/* ----------------------------------------------------------- the part */

/* The Zernike shape quantity q is scaled by: none for the pose. */
static int shape_of(int q)
{
	switch (q) {
	case ASPH_MC_A: case ASPH_MC_RMS_T: case ASPH_MC_RMS: case ASPH_FIT_R:
		return 0;
	case ASPH_MC_B: case ASPH_MC_RMS_A: case ASPH_MC_PV: case ASPH_MC_PVR:
	case ASPH_MC_SLOPE_RMS: case ASPH_MC_SLOPE_MAX:
		return 1;
	case ASPH_MC_C: case ASPH_MC_RMS_I:
		return 2;
	default:
		return -1;
	}
}

/* A quantity's value on the part's characterization (no Monte Carlo). */
static double quantity_value(const struct asph_fit_result *f, int q)
{
	switch (q) {
	case ASPH_MC_A: return f->form_valid ? fabs(f->form.A.v) : NAN;
	case ASPH_MC_B: return f->form_valid ? f->form.B.v : NAN;
	case ASPH_MC_C: return f->form_valid ? f->form.C.v : NAN;
	case ASPH_MC_RMS_T: return f->form_valid ? f->form.rms_t.v : NAN;
	case ASPH_MC_RMS_I: return f->form_valid ? f->form.rms_i.v : NAN;
	case ASPH_MC_RMS_A: return f->form_valid ? f->form.rms_a.v : NAN;
	case ASPH_MC_SLOPE_RMS: return f->slope_valid ? f->slope.rms.v : NAN;
	case ASPH_MC_SLOPE_MAX: return f->slope_valid ? f->slope.max.v : NAN;
	case ASPH_MC_RMS: return f->rms.v;
	case ASPH_MC_PV: return f->pv.v;
	case ASPH_MC_PVR: return f->pvr.v;
	case ASPH_FIT_R: return fabs(f->R_deviation_mm);
	default: return NAN;
	}
}

/* The plan's points with the form error terms, the part lying aligned. */
static int part_points(const struct asph_plan_search *ps, const struct asph_plan *plan,
		       const struct asph_synth_term *terms, size_t n_terms,
		       struct asph_points **out, struct asph_error *err)
{
	_cleanup_(asph_points_freep) struct asph_points *p = asph_points_alloc(plan->n);
	struct asph_synth_options so = { .terms = terms, .n_terms = n_terms };
	int r;

	if (!p)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_fit_synthesize(ps->s, plan->xyz, plan->n, &so, p->xyz, err);
	if (r < 0)
		return r;
	*out = steal_ptr(p);
	return 0;
}

/* A characterization of points with the search's fit options: with the
 * Monte Carlo of model (NULL: none) and mc's options. */
static int characterize(struct asph_plan_search *ps, const struct asph_points *points,
			const struct asph_uncertainty_model *model,
			const struct asph_mc_options *mc,
			struct asph_characterization **out, struct asph_error *err)
{
	struct asph_characterize_options co = {
		.fit = ps->o.fit, .uncertainty = model,
		.run_mc = ps->o.run_mc, .run_mc_data = ps->o.run_mc_data,
	};
	int r;

	if (mc)
		co.mc = *mc;
	r = asph_characterize_alloc(ps->s, &co, out, err);
	if (r == 0)
		r = asph_characterize_points(*out, points, err);
	ps->res.characterizations++;
	if (r == 0 && asph_characterize_result(*out)->mc_done)
		ps->res.characterizations += asph_characterize_result(*out)->mc.n_trials;
	return r;
}

/*
 * The part at the tolerance's limit on this plan: each shape with the
 * largest amplitude any of its quantities needs to read its limit, every
 * shape measured alone (noise-free) on the plan first. The pose has no
 * shape: a limit on it alone leaves the part perfect.
 */
static int scale_part(struct asph_plan_search *ps, const struct asph_plan *plan,
		      struct asph_error *err)
{
	ps->n_terms = 0;
	for (int k = 0; k < N_SHAPES; k++) {
		double amplitude = 0;
		int used = 0;
		for (int q = 0; q < NQ; q++)
			used |= ps->o.limit[q] > 0 && shape_of(q) == k;
		if (!used)
			continue;
		struct asph_synth_term probe = { shape_noll[k], SHAPE_PROBE_NM };
		_cleanup_(asph_points_freep) struct asph_points *p = NULL;
		_cleanup_(asph_characterize_freep) struct asph_characterization *c = NULL;
		int r = part_points(ps, plan, &probe, 1, &p, err);
		if (r == 0)
			r = characterize(ps, p, NULL, NULL, &c, err);
		if (r < 0)
			return r;
		const struct asph_fit_result *f = &asph_characterize_result(c)->fit;
		for (int q = 0; q < NQ; q++) {
			double v = quantity_value(f, q);
			if (ps->o.limit[q] > 0 && shape_of(q) == k && v > 1e-9 * fabs(probe.nm))
				amplitude = fmax(amplitude, SHAPE_PROBE_NM * ps->o.limit[q] / v);
		}
		if (amplitude > 0)
			ps->terms[ps->n_terms++] = (struct asph_synth_term){ shape_noll[k], amplitude };
	}
	return 0;
}

/* ------------------------------------------------------------ a run */

static size_t budget_left(const struct asph_plan_search *ps)
{
	return ps->res.characterizations < ps->o.budget
	       ? ps->o.budget - ps->res.characterizations : 0;
}

/* The trials of a contribution's run: the search's first block count,
 * fixed (a ranking, not a decision). */
static size_t contribution_trials(const struct asph_plan_search *ps)
{
	return ps->o.mc.n_trials;
}

/* What a run needs besides its trials (the part's scaling, the reference
 * fit), and what the contributions' runs at the end need: kept aside. */
static size_t budget_spare(const struct asph_plan_search *ps)
{
	return N_SHAPES + 1 + ASPH_PLAN_SEARCH_N_CONTRIBUTIONS * (contribution_trials(ps) + 1);
}

/* The Monte Carlo's options for a decision against the thresholds, its
 * trials within what the budget has left (less the part's scaling and the
 * reference fit). 0 when the budget cannot pay for a run. */
static int decision_options(const struct asph_plan_search *ps, struct asph_mc_options *mc)
{
	size_t left = budget_left(ps), spare = budget_spare(ps);

	*mc = ps->o.mc;
	mc->decide_U = ps->threshold;
	mc->decide_precision = ps->o.precision;
	if (left < mc->n_trials + spare)
		return 0;
	size_t most = mc->max_trials ? mc->max_trials : RUN_MAX_TRIALS;
	if (most > left - spare)
		most = left - spare;
	if (!mc->fixed && mc->block_size)
		most -= most % mc->block_size;
	mc->max_trials = most < mc->n_trials ? mc->n_trials : most;
	return 1;
}

/* Characterizes the part on method m's plan of request points with the
 * Monte Carlo into a new run of m. 1 done, 0 when the budget cannot pay
 * for it, or a negative errno (the method's own failures are kept in its
 * outcome and return 1). */
static int evaluate(struct asph_plan_search *ps, int m, size_t request, struct asph_error *err)
{
	struct method_state *st = &ps->ms[m];
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	_cleanup_(asph_characterize_freep) struct asph_characterization *c = NULL;
	struct asph_mc_options mc;
	struct ps_eval e = { .request = request };
	struct asph_error perr;
	int r;

	if (!decision_options(ps, &mc))
		return 0;
	if (st->n_evals == MAX_EVALS)
		return asph_error_set(err, -ERANGE, "the search of %s did not settle",
				      asph_plan_method_name(st->m));
	asph_error_clear(&perr);
	r = timed_plan(ps, st->m, request, &plan, &e.seconds, &perr);
	if (r == -ECANCELED)
		return asph_error_set(err, r, "cancelled");
	if (r < 0) {
		method_failed(ps, m, &perr);
		return 1;
	}
	e.n = plan->n;
	e.spacing_mm = plan->spacing_mm;
	r = scale_part(ps, plan, err);
	if (r == 0)
		r = part_points(ps, plan, ps->terms, ps->n_terms, &pts, err);
	if (r == 0)
		r = characterize(ps, pts, &ps->o.model, &mc, &c, err);
	if (r < 0)
		return r;
	memcpy(e.terms, ps->terms, sizeof(e.terms));
	e.n_terms = ps->n_terms;
	const struct asph_characterize_result *cr = asph_characterize_result(c);
	e.computed = cr->mc_done;
	e.trials = cr->mc_done ? cr->mc.n_trials - cr->mc.n_failed : 0;
	for (int q = 0; q < NQ; q++) {
		e.U[q] = NAN;
		if (ps->o.limit[q] > 0) {
			if (cr->mc_done && cr->mc.covered[q] && isfinite(cr->mc.U[q]))
				e.U[q] = cr->mc.U[q];
			else
				e.computed = 0;
		}
	}
	st->evals[st->n_evals++] = e;
	ps->res.evaluations++;
	ps->res.methods[m].evaluations++;
	return 1;
}

/* ------------------------------------------------------ the decisions */

/* The model's U of every limited quantity at n, the largest ratio and
 * whose, and the N where the slowest quantity meets its threshold. */
struct verdict {
	double U[NQ];
	double ratio;
	int worst;
	double root;            /* 0: everywhere; INFINITY: nowhere */
	int floor_beyond;       /* a quantity's floor is beyond its threshold */
	int computed;
};

static void judge(const struct asph_plan_search *ps, const struct method_state *st,
		  const struct ps_eval *at, struct verdict *v)
{
	double n = (double)at->n;

	v->ratio = 0;
	v->worst = -1;
	v->root = 0;
	v->floor_beyond = 0;
	v->computed = at->computed;
	for (int q = 0; q < NQ; q++) {
		double U, root;
		int beyond;
		v->U[q] = NAN;
		if (!(ps->o.limit[q] > 0))
			continue;
		if (ps_model(st->evals, st->n_evals, q, n, ps->threshold[q], &U, &root,
			     &beyond) < 0) {
			v->computed = 0;
			v->root = INFINITY;
			continue;
		}
		v->U[q] = U;
		double ratio = U / ps->o.limit[q];
		if (v->worst < 0 || ratio > v->ratio) {
			v->ratio = ratio;
			v->worst = q;
		}
		v->root = fmax(v->root, root);
		v->floor_beyond |= beyond;
	}
}

static int passes(const struct asph_plan_search *ps, const struct verdict *v)
{
	return v->computed && v->worst >= 0 && v->ratio <= ps->o.capability;
}

/* The method's bracket: its largest failing and smallest passing run by
 * the model now (indices, -1 when none). */
static void bracket(const struct asph_plan_search *ps, const struct method_state *st,
		    int *lo, int *hi)
{
	*lo = *hi = -1;
	for (size_t i = 0; i < st->n_evals; i++) {
		struct verdict v;
		judge(ps, st, &st->evals[i], &v);
		const struct ps_eval *e = &st->evals[i];
		if (passes(ps, &v)) {
			if (*hi < 0 || e->n < st->evals[*hi].n)
				*hi = (int)i;
		} else if (*lo < 0 || e->n > st->evals[*lo].n) {
			*lo = (int)i;
		}
	}
}

static int evaluated(const struct method_state *st, size_t request)
{
	for (size_t i = 0; i < st->n_evals; i++)
		if (st->evals[i].request == request)
			return 1;
	return 0;
}

static size_t clamp_request(double n, size_t lo, size_t hi)
{
	if (!(n >= (double)lo))
		return lo;
	if (n >= (double)hi)
		return hi;
	return (size_t)ceil(n);
}

/* The largest step from the finest failing run while growing: 16, or 4
 * while the method's runs do not yet span PS_MIN_SPAN. One run cannot tell
 * the floor from 1 / sqrt(N) (its root assumes no floor), and two runs 4x
 * apart tell a floor far beyond the threshold (4 times it in 95 % of
 * searches, 100 trials each) for a quarter of the points per trial; one
 * nearer it takes a third plan (ps_model's margin). */
static size_t growth(const struct method_state *st)
{
	double lo = INFINITY, hi = 0;

	for (size_t i = 0; i < st->n_evals; i++) {
		lo = fmin(lo, (double)st->evals[i].n);
		hi = fmax(hi, (double)st->evals[i].n);
	}
	return hi >= PS_MIN_SPAN * lo ? 16 : 4;
}

/*
 * The next request of method m, or 0 when its search is over (*outcome
 * then says how). lo and hi are the bracket's runs (-1: none).
 */
static size_t next_request(const struct asph_plan_search *ps, const struct method_state *st,
			   int lo, int hi, enum asph_plan_search_outcome *outcome)
{
	double tol = ps->o.precision, root;
	size_t top = st->capped ? st->cap : ps->o.max_points;
	const struct ps_eval *L = lo >= 0 ? &st->evals[lo] : NULL;
	const struct ps_eval *H = hi >= 0 ? &st->evals[hi] : NULL;
	struct verdict v;

	*outcome = ASPH_PLAN_SEARCH_CHOSEN;
	if (H && (H->request <= st->n_min || (L && H->n <= (double)L->n * (1 + tol))))
		return 0;
	if (!H) {
		/* growing: from the coarsest plan, by the model's root */
		if (!L)
			return st->n_min;
		judge(ps, st, L, &v);
		if (st->capped) {
			*outcome = ASPH_PLAN_SEARCH_SLOWER;
			return 0;
		}
		if (v.computed && v.floor_beyond) {
			*outcome = ASPH_PLAN_SEARCH_IMPOSSIBLE;
			return 0;
		}
		if (L->request >= top || L->n >= top) {
			*outcome = ASPH_PLAN_SEARCH_IMPOSSIBLE;
			return 0;
		}
		root = v.computed ? v.root * (1 + tol / 3) : 4.0 * (double)L->n;
		/* no root: a floor near the threshold that is not yet beyond it
		 * by its error; a step of 4 rather than a plan 16 times finer
		 * that costs 16 times as much per trial */
		if (!isfinite(root))
			root = 4.0 * (double)L->n;
		size_t n = clamp_request(root, 2 * L->request, growth(st) * L->request);
		return n > top ? top : n;
	}
	judge(ps, st, H, &v);
	root = v.root;
	if (!L) {
		/* shrinking from a passing plan (capped at the best's time) */
		size_t below = (size_t)floor((double)H->request / (1 + tol));
		if (!evaluated(st, st->n_min) && (root <= (double)st->n_min || below <= st->n_min))
			return st->n_min;
		return clamp_request(root * (1 - tol / 3), st->n_min, below);
	}
	/* bisecting: towards the side farther from the root, just past it */
	double lo_n = (double)L->n, hi_n = (double)H->n, q = hi_n / lo_n;
	double x = log(hi_n / root) > log(root / lo_n) ? root * (1 + tol / 3)
						       : root * (1 - tol / 3);
	double a = lo_n * pow(q, 0.1), b = lo_n * pow(q, 0.9);
	x = fmin(fmax(x, a), b);
	/* the request that gives about x points: requests give their count
	 * within a few % */
	size_t req = (size_t)llround(x * (double)H->request / hi_n);
	if (req <= L->request || req >= H->request || evaluated(st, req))
		return 0;
	return req;
}

/* ------------------------------------------------------- the methods */

static void describe_plan(const struct asph_plan_search *ps, struct asph_plan_search_method *rm,
			  const struct ps_eval *e, const struct verdict *v)
{
	rm->points = e->n;
	rm->spacing_mm = e->spacing_mm;
	rm->h = e->spacing_mm / asph_surface_aperture_radius(ps->s);
	rm->seconds = e->seconds;
	rm->ratio = v->worst >= 0 ? v->ratio : NAN;
	rm->worst = v->worst >= 0 ? (enum asph_mc_quantity)v->worst : ASPH_MC_N_QUANTITIES;
}

/* About the time method m would need, U falling as 1/sqrt(N) from its run
 * e that fails: the time of its plan at the model's root. NaN when there
 * is none within the finest plan. */
static double needed_seconds(const struct asph_plan_search *ps, int m, const struct ps_eval *e,
			     const struct verdict *v)
{
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	double seconds;

	if (!isfinite(v->root) || v->root > (double)ps->o.max_points)
		return NAN;
	size_t req = (size_t)ceil(v->root * (double)e->request / (double)e->n);
	if (timed_plan(ps, (enum asph_plan_method)m, req, &plan, &seconds, NULL) < 0)
		return NAN;
	return seconds;
}

/* The request of method m whose plan takes at most t, the largest found
 * by a few probes (the time of a plan grows about as sqrt(N) where the
 * stage's speed limits it, as N where the probe's rate does). 0 with a
 * message in err when a plan cannot be computed or timed. */
static size_t request_within(const struct asph_plan_search *ps, const struct method_state *st,
			     double t, struct asph_error *err)
{
	size_t lo = st->n_min, hi = 0;
	double t_lo = st->t_min, t_hi = NAN;

	for (int i = 0; i < MAX_TIME_PROBES; i++) {
		_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
		double x, seconds;
		if (hi && (double)hi <= 1.02 * (double)lo)
			break;
		if (!hi) {      /* t = t_lo sqrt(n / lo) */
			x = (double)lo * (t / t_lo) * (t / t_lo);
		} else {        /* the secant in sqrt(n) */
			double a = sqrt((double)lo), b = sqrt((double)hi);
			double f = (t - t_lo) / (t_hi - t_lo);
			x = pow(a + f * (b - a), 2);
		}
		size_t req = clamp_request(x, lo + 1, hi ? hi - 1 : ps->o.max_points);
		if (req <= lo)
			break;
		if (timed_plan(ps, st->m, req, &plan, &seconds, err) < 0)
			return 0;
		if (seconds <= t) {
			lo = req;
			t_lo = seconds;
			if (req >= ps->o.max_points)
				break;
		} else {
			hi = req;
			t_hi = seconds;
		}
	}
	return lo;
}

/* Method m's search is over with its outcome: its result, and whether it
 * is now the quickest plan. */
static void method_over(struct asph_plan_search *ps, int m, enum asph_plan_search_outcome outcome,
			int lo, int hi)
{
	struct method_state *st = &ps->ms[m];
	struct asph_plan_search_method *rm = &ps->res.methods[m];
	struct verdict v;

	st->done = 1;
	rm->outcome = outcome;
	if (outcome == ASPH_PLAN_SEARCH_CHOSEN) {
		const struct ps_eval *e = &st->evals[hi];
		judge(ps, st, e, &v);
		describe_plan(ps, rm, e, &v);
		st->chosen = hi;
		if (ps->best >= 0 && ps->res.methods[ps->best].seconds <= e->seconds) {
			rm->outcome = ASPH_PLAN_SEARCH_SLOWER;
			return;
		}
		if (ps->best >= 0)
			ps->res.methods[ps->best].outcome = ASPH_PLAN_SEARCH_SLOWER;
		ps->best = m;
		return;
	}
	if (lo < 0)
		return;
	const struct ps_eval *e = &st->evals[lo];
	judge(ps, st, e, &v);
	describe_plan(ps, rm, e, &v);
	if (outcome == ASPH_PLAN_SEARCH_SLOWER)
		rm->needed_seconds = needed_seconds(ps, m, e, &v);
}

/* The quickest plan so far, against which a method is capped. */
static double best_seconds(const struct asph_plan_search *ps)
{
	return ps->best >= 0 ? ps->res.methods[ps->best].seconds : INFINITY;
}

/* Caps method m at the points that take the best plan's time, or ends it
 * when even its coarsest plan takes longer. 1 when capped (or ended). */
static int cap_method(struct asph_plan_search *ps, int m)
{
	struct method_state *st = &ps->ms[m];
	struct asph_plan_search_method *rm = &ps->res.methods[m];
	struct asph_error perr;
	double t = best_seconds(ps);

	if (st->capped || st->n_evals || !isfinite(t))
		return 0;
	if (st->t_min >= t) {
		st->done = 1;
		rm->outcome = ASPH_PLAN_SEARCH_TOO_SLOW;
		rm->points = st->n_min_points;
		rm->spacing_mm = st->min_spacing_mm;
		rm->h = st->min_spacing_mm / asph_surface_aperture_radius(ps->s);
		rm->seconds = st->t_min;
		return 1;
	}
	asph_error_clear(&perr);
	st->cap = request_within(ps, st, t, &perr);
	if (st->cap == 0) {
		method_failed(ps, m, &perr);
		return 1;
	}
	st->capped = 1;
	return 0;
}

/* One step of method m's search: a run, or its end. 1 done, 0 when the
 * budget cannot pay for the run, else a negative errno. */
static int search_step(struct asph_plan_search *ps, int m, struct asph_error *err)
{
	struct method_state *st = &ps->ms[m];
	enum asph_plan_search_outcome outcome;
	int lo, hi;

	if (cap_method(ps, m))
		return 1;
	if (st->capped && st->n_evals == 0)
		return evaluate(ps, m, st->cap, err);
	bracket(ps, st, &lo, &hi);
	size_t req = next_request(ps, st, lo, hi, &outcome);
	if (req == 0) {
		method_over(ps, m, outcome, lo, hi);
		return 1;
	}
	return evaluate(ps, m, req, err);
}

/* The budget is spent: the method being searched keeps the passing plan
 * it has, the others were not tried. */
static void budget_over(struct asph_plan_search *ps)
{
	ps->res.budget_exhausted = 1;
	for (int i = ps->current; i < ps->n_order; i++) {
		int m = ps->order[i], lo, hi;
		struct method_state *st = &ps->ms[m];
		if (st->done)
			continue;
		bracket(ps, st, &lo, &hi);
		if (hi >= 0)
			method_over(ps, m, ASPH_PLAN_SEARCH_CHOSEN, lo, hi);
		st->done = 1;
	}
}

/* ------------------------------------------------------ the order */

static int compare_time(const void *a, const void *b, void *data)
{
	const struct asph_plan_search *ps = data;
	double ta = ps->ms[*(const int *)a].t_min, tb = ps->ms[*(const int *)b].t_min;

	return ta < tb ? -1 : ta > tb;
}

/* Method order[next_order]'s coarsest plan timed; once all are, the
 * methods sorted quickest first. */
static int order_step(struct asph_plan_search *ps, struct asph_error *err)
{
	int m = ps->order[ps->next_order++];
	struct method_state *st = &ps->ms[m];
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	struct asph_error perr;
	int r;

	asph_error_clear(&perr);
	r = coarsest_request(ps, st->m, &st->n_min, &perr);
	if (r == 0 && st->n_min > ps->o.max_points)
		r = set_field(&perr, -ERANGE, "max_points", "the slope's evaluation length needs "
			      "%zu points, more than the finest plan (%zu)", st->n_min,
			      ps->o.max_points);
	if (r == 0)
		r = timed_plan(ps, st->m, st->n_min, &plan, &st->t_min, &perr);
	if (r == 0) {
		st->n_min_points = plan->n;
		st->min_spacing_mm = plan->spacing_mm;
	}
	if (r == -ECANCELED)
		return asph_error_set(err, r, "cancelled");
	if (r < 0)
		method_failed(ps, m, &perr);
	if (ps->next_order < ps->n_order)
		return 1;
	/* the quickest coarsest plans first: they set the bound the others
	 * are tried at */
	int n = 0;
	for (int i = 0; i < ps->n_order; i++)
		if (!ps->ms[ps->order[i]].done)
			ps->order[n++] = ps->order[i];
	ps->n_order = n;
	qsort_r(ps->order, (size_t)n, sizeof(int), compare_time, ps);
	ps->phase = PHASE_SEARCH;
	return 1;
}

/* --------------------------------------------- what dominates U */

/* The run with the smallest largest ratio of all methods (NULL: none),
 * its method in *m. */
static const struct ps_eval *best_run(const struct asph_plan_search *ps, int *m,
				      struct verdict *best)
{
	const struct ps_eval *found = NULL;

	for (int k = 0; k < ASPH_PLAN_N_METHODS; k++) {
		const struct method_state *st = &ps->ms[k];
		for (size_t i = 0; i < st->n_evals; i++) {
			struct verdict v;
			judge(ps, st, &st->evals[i], &v);
			if (!v.computed || v.worst < 0)
				continue;
			if (!found || v.ratio < best->ratio) {
				found = &st->evals[i];
				*best = v;
				*m = k;
			}
		}
	}
	return found;
}

/* The model with only contribution c's members. */
static void contribution_model(const struct asph_uncertainty_model *all,
			       enum asph_plan_search_contribution c,
			       struct asph_uncertainty_model *out)
{
	asph_uncertainty_model_init(out);
	switch (c) {
	case ASPH_PLAN_SEARCH_PROBE:
		out->probe_noise_nm = all->probe_noise_nm;
		break;
	case ASPH_PLAN_SEARCH_POSITION:
		out->position_noise_um = all->position_noise_um;
		out->position_resolution_um = all->position_resolution_um;
		out->latency_us = all->latency_us;
		out->scan_speed_mm_s = all->scan_speed_mm_s;
		break;
	case ASPH_PLAN_SEARCH_DRIFT:
		out->drift_residual_nm = all->drift_residual_nm;
		break;
	default:
		out->tip_radius_um = all->tip_radius_um;
		break;
	}
}

/* Each declared contribution's U of the failing quantity on the best
 * plan tried, one Monte Carlo each. */
static int contributions_step(struct asph_plan_search *ps, struct asph_error *err)
{
	struct asph_plan_search_result *res = &ps->res;
	struct verdict v;
	int m = 0;
	const struct ps_eval *e = best_run(ps, &m, &v);

	ps->phase = PHASE_DONE;
	if (!e)
		return 0;
	res->failing = (enum asph_mc_quantity)v.worst;
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	int r = compute_plan(ps, (enum asph_plan_method)m, e->request, &plan, err);
	if (r == 0)
		r = part_points(ps, plan, e->terms, e->n_terms, &pts, err);
	if (r < 0)
		return r;
	double most = -1;
	for (int c = 0; c < ASPH_PLAN_SEARCH_N_CONTRIBUTIONS; c++) {
		struct asph_uncertainty_model only;
		contribution_model(&ps->o.model, (enum asph_plan_search_contribution)c, &only);
		if (asph_uncertainty_model_is_empty(&only))
			continue;
		struct asph_mc_options mc = ps->o.mc;
		_cleanup_(asph_characterize_freep) struct asph_characterization *ch = NULL;
		mc.fixed = 1;
		mc.n_trials = mc.max_trials = contribution_trials(ps);
		r = characterize(ps, pts, &only, &mc, &ch, err);
		if (r < 0)
			return r;
		const struct asph_characterize_result *cr = asph_characterize_result(ch);
		double U = cr->mc_done ? cr->mc.U[v.worst] : NAN;
		res->contribution_U[c] = U;
		if (U > most) {
			most = U;
			res->dominant = (enum asph_plan_search_contribution)c;
		}
	}
	return 0;
}

/* ---------------------------------------------------------- the result */

static void fill_quantities(struct asph_plan_search *ps, const struct method_state *st,
			    const struct ps_eval *e)
{
	struct asph_plan_search_result *res = &ps->res;
	struct verdict v;

	judge(ps, st, e, &v);
	res->n_quantities = 0;
	for (int q = 0; q < NQ; q++) {
		if (!(ps->o.limit[q] > 0) || res->n_quantities == ASPH_PLAN_SEARCH_MAX_QUANTITIES)
			continue;
		res->quantity[res->n_quantities++] = (struct asph_plan_search_quantity){
			.q = (enum asph_mc_quantity)q, .limit = ps->o.limit[q], .U = v.U[q],
			.ratio = v.U[q] / ps->o.limit[q], .U_run = e->U[q],
		};
	}
	res->n_terms = e->n_terms;
	memcpy(res->terms, e->terms, e->n_terms * sizeof(e->terms[0]));
}

static void finish(struct asph_plan_search *ps)
{
	struct asph_plan_search_result *res = &ps->res;

	if (ps->best >= 0) {
		const struct method_state *st = &ps->ms[ps->best];
		const struct asph_plan_search_method *rm = &res->methods[ps->best];
		const struct ps_eval *chosen = &st->evals[st->chosen];
		res->found = 1;
		res->method = st->m;
		res->density = (struct asph_plan_density){ ASPH_DENSITY_POINTS,
							   (double)chosen->request };
		res->points = rm->points;
		res->spacing_mm = rm->spacing_mm;
		res->h = rm->h;
		res->seconds = rm->seconds;
		fill_quantities(ps, st, chosen);
		return;
	}
	struct verdict v;
	int m = 0;
	const struct ps_eval *e = best_run(ps, &m, &v);
	if (e)
		fill_quantities(ps, &ps->ms[m], e);
}

/* ------------------------------------------------------------ the steps */

static void note_status(struct asph_plan_search *ps, int m, size_t evals_before)
{
	struct asph_plan_search_status *s = &ps->status;
	const struct method_state *st = &ps->ms[m];

	s->evaluations = ps->res.evaluations;
	s->characterizations = ps->res.characterizations;
	if (st->n_evals == evals_before)
		return;
	const struct ps_eval *e = &st->evals[st->n_evals - 1];
	struct verdict v;
	judge(ps, st, e, &v);
	s->method = st->m;
	s->points = e->n;
	s->seconds = e->seconds;
	s->ratio = v.worst >= 0 ? v.ratio : NAN;
	s->passed = passes(ps, &v);
}

int asph_plan_search_iterate(struct asph_plan_search *ps, struct asph_error *err)
{
	int r;

	switch (ps->phase) {
	case PHASE_ORDER:
		if (ps->n_order == 0) {
			ps->phase = PHASE_CONTRIBUTIONS;
			return 1;
		}
		return order_step(ps, err);
	case PHASE_SEARCH:
		while (ps->current < ps->n_order && ps->ms[ps->order[ps->current]].done)
			ps->current++;
		if (ps->current == ps->n_order) {
			ps->phase = ps->best >= 0 ? PHASE_DONE : PHASE_CONTRIBUTIONS;
			if (ps->best >= 0)
				finish(ps);
			return 1;
		}
		int m = ps->order[ps->current];
		size_t before = ps->ms[m].n_evals, chars = ps->res.characterizations;
		r = search_step(ps, m, err);
		ps->res.methods[m].characterizations += ps->res.characterizations - chars;
		note_status(ps, m, before);
		if (r == 0) {
			budget_over(ps);
			ps->current = ps->n_order;
			return 1;
		}
		return r < 0 ? r : 1;
	case PHASE_CONTRIBUTIONS:
		r = contributions_step(ps, err);
		if (r < 0)
			return r;
		finish(ps);
		return 1;
	case PHASE_DONE:
	default:
		return 0;
	}
}

int asph_plan_search_run(struct asph_plan_search *ps, struct asph_error *err)
{
	const struct asph_progress *p = &ps->o.progress;
	int r;

	while ((r = asph_plan_search_iterate(ps, err)) > 0)
		if (p->fn && p->fn(p->data, ps->res.characterizations, ps->o.budget))
			return asph_error_set(err, -ECANCELED, "cancelled");
	return r;
}

void asph_plan_search_status(const struct asph_plan_search *ps,
			     struct asph_plan_search_status *out)
{
	*out = ps->status;
}

const struct asph_plan_search_result *asph_plan_search_result(const struct asph_plan_search *ps)
{
	return &ps->res;
}
