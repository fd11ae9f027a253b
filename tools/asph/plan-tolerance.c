/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph plan --for-tolerance: the search on the instrument, shown as it goes
 * on a terminal, and what it chose. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "acquire-tool.h"
#include "asph-engine/executor.h"
#include "asph/plan-search.h"
#include "asph/prescription.h"
#include "asph-tool.h"
#include "fit-uncertainty.h"
#include "plan-tolerance.h"
#include "progress.h"
#include "quantity.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_registry *, asph_registry_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_plan_search *, asph_plan_search_free)

static int parse_number(const char *arg, const char *name, double *out)
{
	char *end;
	double v;

	errno = 0;
	v = strtod(arg, &end);
	if (errno || end == arg || *end || !isfinite(v)) {
		fprintf(stderr, "asph: plan: --%s: '%s' is not a number\n", name, arg);
		return -1;
	}
	*out = v;
	return 0;
}

int plan_tolerance_option(struct plan_tolerance_cli *c, int opt, const char *arg)
{
	unsigned long v;

	switch (opt) {
	case OPT_PT_FOR_TOLERANCE:
		c->tolerance = arg;
		break;
	case OPT_PT_INSTRUMENT:
		c->instrument = arg;
		break;
	case OPT_PT_CAPABILITY:
		if (parse_number(arg, "capability", &c->capability) < 0)
			return -1;
		if (!(c->capability > 0 && c->capability <= 1)) {
			fprintf(stderr, "asph: plan: --capability: %s is outside (0, 1]: it is the "
				"largest U (k = 2) a plan may reach, as a fraction of each "
				"quantity's tolerance T\n", arg);
			return -1;
		}
		break;
	case OPT_PT_DOF:
		c->dof = arg;
		break;
	case OPT_PT_SEED:
		if (fit_mc_parse_count("asph: plan", arg, "seed", 0, 4294967295ul, &v) < 0)
			return -1;
		c->seed = v;
		c->seed_set = 1;
		break;
	case OPT_PT_THREADS:
		if (fit_mc_parse_count("asph: plan", arg, "threads", 1, 256, &v) < 0)
			return -1;
		c->threads = (int)v;
		break;
	case OPT_PT_JSON:
		c->json = 1;
		break;
	default:
		return 1;
	}
	c->given = 1;
	return 0;
}

/* ------------------------------------------------------------ the run */

struct search_run {
	struct fit_mc_run mc;                   /* the Monte Carlo's threads */
	const struct asph_plan_search *ps;      /* for the step lines */
	size_t shown;                           /* the run last shown */
};

static const struct quantity *row_of(enum asph_mc_quantity q)
{
	const char *name = asph_plan_search_quantity_name(q);
	const struct quantity *row = quantity_by_verdict(name);

	return row ? row : quantity_by_u_key(asph_mc_quantity_key(q));
}

/* A quantity's value as printed, with its unit. */
static const char *figure(enum asph_mc_quantity q, double v, char *buf, size_t size)
{
	return quantity_format(row_of(q), v, QUANTITY_UNIT | QUANTITY_NO_SIGN, buf, size);
}

/* Each plan characterized, one line on a terminal. */
static int on_step(void *data, size_t done, size_t budget)
{
	struct search_run *run = data;
	struct asph_plan_search_status st;
	char t[16];

	if (run->mc.quiet)
		return 0;
	asph_plan_search_status(run->ps, &st);
	if (!isfinite(st.ratio) || st.evaluations == 0)
		return 0;
	if (st.evaluations == run->shown)
		return 0;
	run->shown = st.evaluations;
	fprintf(stderr, "plan search: %s, %zu points, %s: U/T %.3f %s (%zu of at most %zu "
		"characterizations)\n", asph_plan_method_name(st.method), st.points,
		progress_duration(st.seconds, t, sizeof(t)), st.ratio,
		st.passed ? "meets the ratio" : "does not", done, budget);
	return 0;
}

/* The instrument INST names, with the lens set on it, and its model. */
static int resolve_instrument(const struct plan_tolerance_cli *c, const struct asph_surface *s,
			      struct asph_registry **reg, struct asph_config **cfg, size_t *idx)
{
	_cleanup_free_ char *lens_json = NULL;
	struct asph_error err;

	asph_error_clear(&err);
	if (tool_registry_new(NULL, reg) < 0)
		return EXIT_FAILURE_RUN;
	if (asph_config_resolve(*reg, c->instrument, cfg, idx, &err) < 0) {
		tool_print_error("plan: --instrument", &err);
		return EXIT_USAGE;
	}
	struct asph_instrument_config *ic = &(*cfg)->instruments[*idx];
	if (!ic->has_uncertainty || asph_uncertainty_model_is_empty(&ic->uncertainty)) {
		fprintf(stderr, "asph: plan: --instrument %s: the instrument '%s' declares no "
			"uncertainty contributions (an \"uncertainty\" section of its "
			"configuration, docs/drivers.md): the plan for a tolerance needs them\n",
			c->instrument, ic->name);
		return EXIT_USAGE;
	}
	if (asph_prescription_to_json(asph_surface_prescription(s), &lens_json) < 0 ||
	    asph_instrument_config_set_lens(ic, lens_json, &err) < 0) {
		tool_print_error("plan: --instrument", &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

/* The search's options from the command line: the tolerance's limits, its
 * wavelength and slope length, the DOF. */
static int search_options(const struct plan_tolerance_cli *c, struct asph_tolerance *tol,
			  struct asph_plan_search_options *o)
{
	struct asph_error err;

	asph_error_clear(&err);
	if (asph_tolerance_load(c->tolerance, tol, &err) < 0) {
		tool_print_error("plan: --for-tolerance", &err);
		return EXIT_USAGE;
	}
	if (asph_plan_search_limits(tol, o->limit, &err) < 0) {
		tool_print_error("plan: --for-tolerance", &err);
		return EXIT_USAGE;
	}
	o->fit.tolerance = tol;
	if (c->dof && asph_fit_dof_parse(c->dof, &o->fit.dof, &err) < 0) {
		tool_print_error("plan: --dof", &err);
		return EXIT_USAGE;
	}
	if (isfinite(tol->R_mm) && !(o->fit.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_R))) {
		fprintf(stderr, "asph: plan: --for-tolerance: R_mm limits R - R_nominal, which needs "
			"R among the DOF (--dof tx,ty,tz,rx,ry,R)\n");
		return EXIT_USAGE;
	}
	o->capability = c->capability;
	o->mc.seed = c->seed_set ? c->seed : 1;
	return EXIT_OK;
}

/* ---------------------------------------------------------- the report */

static void print_quantities(const struct asph_plan_search_result *r)
{
	printf("  %-16s %14s %14s %8s\n", "quantity", "T", "U (k = 2)", "U/T");
	for (size_t i = 0; i < r->n_quantities; i++) {
		const struct asph_plan_search_quantity *q = &r->quantity[i];
		char T[48], U[48];
		printf("  %-16s %14s %14s %8.3f\n", asph_plan_search_quantity_name(q->q),
		       figure(q->q, q->limit, T, sizeof(T)), figure(q->q, q->U, U, sizeof(U)),
		       q->ratio);
	}
}

static void print_method(const struct asph_plan_search_result *r,
			 const struct asph_plan_search_method *x)
{
	const char *name = asph_plan_method_name(x->method);
	char t[16], need[16];

	switch (x->outcome) {
	case ASPH_PLAN_SEARCH_SLOWER:
		if (x->evaluations && isfinite(x->ratio) && x->ratio > r->capability)
			printf("  %-10s slower: in the chosen plan's time (%zu points) U/T is %.3f "
			       "(%s)%s%s\n", name, x->points, x->ratio,
			       asph_plan_search_quantity_name(x->worst),
			       isfinite(x->needed_seconds) ? "; it needs about " : "",
			       isfinite(x->needed_seconds)
			       ? progress_duration(x->needed_seconds, need, sizeof(need)) : "");
		else
			printf("  %-10s slower: %zu points, h = %.4g, %s (U/T %.3f)\n", name,
			       x->points, x->h, progress_duration(x->seconds, t, sizeof(t)),
			       x->ratio);
		break;
	case ASPH_PLAN_SEARCH_TOO_SLOW:
		printf("  %-10s slower: its coarsest plan (%zu points) takes %s already\n", name,
		       x->points, progress_duration(x->seconds, t, sizeof(t)));
		break;
	case ASPH_PLAN_SEARCH_IMPOSSIBLE:
		printf("  %-10s no plan meets the ratio: at %zu points U/T is %.3f (%s)\n", name,
		       x->points, x->ratio, asph_plan_search_quantity_name(x->worst));
		break;
	case ASPH_PLAN_SEARCH_FAILED:
		printf("  %-10s not searched: %s\n", name, x->message);
		break;
	case ASPH_PLAN_SEARCH_NOT_TRIED:
		if (r->budget_exhausted)
			printf("  %-10s not searched: the budget ran out first\n", name);
		break;
	default:
		break;
	}
}

static void print_result(const struct plan_tolerance_cli *c, const char *lens,
			 const struct asph_plan_search_result *r)
{
	char t[16];

	if (r->found) {
		printf("Plan for the tolerance on %s (U <= %g T for every quantity, k = 2): %s, "
		       "h = %.4g, %zu points, %.1f s (%s) on %s\n", lens, r->capability,
		       asph_plan_method_name(r->method), r->h, r->points, r->seconds,
		       progress_duration(r->seconds, t, sizeof(t)), c->instrument);
		printf("  (asph plan %s --method %s --points %.0f)\n", lens,
		       asph_plan_method_name(r->method), r->density.value);
	} else {
		printf("No plan of %zu to %zu points meets U <= %g T on %s with %s%s\n",
		       r->min_points, r->max_points, r->capability, lens, c->instrument,
		       r->budget_exhausted ? " within the search's budget" : "");
		if (r->n_quantities && isfinite(r->contribution_U[r->dominant]))
			printf("  %s: U is dominated by the instrument's %s (U %s of it alone)\n",
			       asph_plan_search_quantity_name(r->failing),
			       asph_plan_search_contribution_name(r->dominant),
			       quantity_format(row_of(r->failing), r->contribution_U[r->dominant],
					       QUANTITY_UNIT | QUANTITY_NO_SIGN, t, sizeof(t)));
		printf("The best plan tried:\n");
	}
	print_quantities(r);
	int others = 0;
	for (int m = 0; m < ASPH_PLAN_N_METHODS; m++)
		others |= r->methods[m].outcome != ASPH_PLAN_SEARCH_CHOSEN &&
			  r->methods[m].outcome != ASPH_PLAN_SEARCH_NOT_TRIED;
	if (others) {
		printf(r->found ? "The other methods:\n" : "The methods:\n");
		for (int m = 0; m < ASPH_PLAN_N_METHODS; m++)
			print_method(r, &r->methods[m]);
	}
	printf("Search: %zu plans characterized with the Monte Carlo, %zu characterizations%s\n",
	       r->evaluations, r->characterizations,
	       r->budget_exhausted ? " (its budget: it stopped there)" : "");
}

static int print_json(const struct asph_plan_search_result *r)
{
	_cleanup_free_ char *text = NULL;

	if (asph_plan_search_result_to_json(r, &text) < 0) {
		fprintf(stderr, "asph: plan: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	printf("%s\n", text);
	return EXIT_OK;
}

int plan_tolerance_run(const struct plan_tolerance_cli *c, const char *lens,
		       const struct asph_surface *s, unsigned methods, size_t max_points,
		       int quiet, int *found, enum asph_plan_method *method,
		       struct asph_plan_density *density)
{
	_cleanup_(asph_registry_freep) struct asph_registry *reg = NULL;
	_cleanup_(asph_config_freep) struct asph_config *cfg = NULL;
	_cleanup_(asph_plan_search_freep) struct asph_plan_search *ps = NULL;
	struct asph_plan_search_options o = { .methods = methods, .max_points = max_points };
	struct asph_tolerance tol;
	struct search_run run = { .mc = { .threads = c->threads, .quiet = quiet } };
	struct asph_error err;
	size_t idx = 0;
	int r;

	if ((r = search_options(c, &tol, &o)) != EXIT_OK ||
	    (r = resolve_instrument(c, s, &reg, &cfg, &idx)) != EXIT_OK)
		return r;
	struct asph_scan_timing timing = { .instrument = &cfg->instruments[idx], .surface = s,
					   .options = { .flags = ASPH_SCAN_STREAM } };
	o.model = cfg->instruments[idx].uncertainty;
	o.run_mc = fit_mc_run_threads;
	o.run_mc_data = &run.mc;
	o.plan_time = asph_scan_plan_time;
	o.plan_time_data = &timing;
	o.progress = (struct asph_progress){ .fn = on_step, .data = &run };
	asph_error_clear(&err);
	r = asph_plan_search_alloc(s, &o, &ps, &err);
	if (r < 0) {
		tool_print_error("plan: --for-tolerance", &err);
		return EXIT_USAGE;
	}
	run.ps = ps;
	r = asph_plan_search_run(ps, &err);
	if (r < 0) {
		tool_print_error("plan: --for-tolerance", &err);
		return EXIT_FAILURE_RUN;
	}
	const struct asph_plan_search_result *res = asph_plan_search_result(ps);
	*found = res->found;
	*method = res->method;
	*density = res->density;
	if (c->json)
		return print_json(res);
	print_result(c, lens, res);
	return EXIT_OK;
}
