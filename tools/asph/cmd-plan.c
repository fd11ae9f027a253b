/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "acquire-tool.h"
#include "asph-engine/executor.h"
#include "asph/plan-search.h"
#include "asph/plan.h"
#include "asph/points.h"
#include "asph/prescription.h"
#include "asph-tool.h"
#include "command.h"
#include "plan-source.h"
#include "plan-tolerance.h"
#include "util-mem.h"

/* Guards against a density typo that would ask for billions of points;
 * --max-points raises it. */
#define PLAN_DEFAULT_MAX_POINTS 50000000

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_plan *, asph_plan_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_registry *, asph_registry_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_config *, asph_config_free)

enum {
	OPT_MAX_POINTS = 0x2000,
	OPT_NO_MESH,
	OPT_ESTIMATE,
};

static void usage(FILE *out)
{
	char mesh[128], text[256];

	plan_mesh_methods(mesh, sizeof(mesh));
	fprintf(out,
		"Usage: asph plan LENS --method M (--h H | --spacing MM | --points N)\n"
		"                 [--profiles N] [-o FILE]\n"
		"       asph plan LENS --for-tolerance TOL --instrument INST [--capability R]\n"
		"                 [--method M] [-o FILE]\n\n"
		"Computes a sampling plan on LENS (a preset: weak, strong, turning-point, or a\n"
		"prescription file) and writes its points in scan order. With --for-tolerance\n"
		"it chooses the plan: the shortest predicted measuring time on INST whose\n"
		"expanded uncertainty decides the tolerance TOL.\n\n");
	plan_method_help(out, "", "");
	fputs(PLAN_DENSITY_HELP, out);
	snprintf(text, sizeof(text), ".csv (x,y,z), .ply (with faces for %s) or .json; default: "
		 "CSV on standard output", mesh);
	command_help_option(out, "-o, --output FILE", text);
	snprintf(text, sizeof(text), "leave the mesh of %s out", mesh);
	command_help_option(out, "--no-mesh", text);
	fprintf(out,
		"  --estimate INSTRUMENT  print the predicted measuring time of the plan on\n"
		"                      INSTRUMENT (a configuration file or a driver spec, as\n"
		"                      asph scan takes it), streamed where the instrument can:\n"
		"                      on standard output with -o, else on standard error\n"
		"  --max-points N      refuse plans with more points (default %d; with\n"
		"                      --for-tolerance the finest plan tried, default %d)\n"
		"  -q, --quiet         no summary line, and no progress of a long plan (CVT),\n"
		"                      on standard error\n"
		"  -h, --help          this help\n\n"
		"The plan for a tolerance:\n"
		"  --for-tolerance TOL the drawing's tolerance: an ISO 10110-5 call-out\n"
		"                      ('3/2(0.5/0.3)'), JSON text or a file, as asph fit\n"
		"                      --tolerance takes it\n"
		"  --instrument INST   the instrument configuration (FILE or FILE#NAME) whose\n"
		"                      \"uncertainty\" section is its model; the time is\n"
		"                      predicted on it, streamed where it can\n"
		"  --capability R      the largest U (k = 2) / T allowed for every quantity,\n"
		"                      in (0, 1] (default 0.25)\n"
		"  --method M          search this method only (default: every method)\n"
		"  --dof LIST          the fit's degrees of freedom (default tx,ty,tz,rx,ry)\n"
		"  --seed S            the Monte Carlo's seed (default 1)\n"
		"  --threads N         its worker threads (default: the online processors)\n"
		"  --json              the search's result as JSON on standard output\n"
		"  -o FILE             writes the chosen plan's points\n\n"
		"Exactly one of --h, --spacing, --points, or --for-tolerance.\n"
		"docs/sampling-plans.md explains the methods, the density relations, the scan\n"
		"orders and the plan for a tolerance. Exit status 1 when no plan meets the\n"
		"ratio.\n",
		PLAN_DEFAULT_MAX_POINTS, ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS);
}

struct plan_args {
	struct plan_source src;
	struct plan_tolerance_cli tol;
	const char *lens, *output, *estimate;
	struct asph_plan_options opts;
	int max_points_given;
	int quiet;
};

static int parse_count(const char *arg, size_t *out)
{
	char *end;
	unsigned long long v;

	errno = 0;
	v = strtoull(arg, &end, 10);
	if (errno || end == arg || *end || arg[0] == '-' || v == 0) {
		fprintf(stderr, "asph: --max-points: '%s' is not a positive whole number\n", arg);
		return -1;
	}
	*out = (size_t)v;
	return 0;
}

/* --for-tolerance chooses the density, and needs the instrument. */
static int check_tolerance_args(struct plan_args *a)
{
	if (!a->tol.tolerance) {
		fprintf(stderr, "asph: plan: --instrument, --capability, --dof, --seed, --threads "
			"and --json go with --for-tolerance\n");
		return EXIT_USAGE;
	}
	if (!a->tol.instrument) {
		fprintf(stderr, "asph: plan: --for-tolerance needs --instrument INST: the plan is "
			"chosen on that instrument's uncertainty and measuring time\n");
		return EXIT_USAGE;
	}
	if (a->src.n_density || a->estimate) {
		fprintf(stderr, "asph: plan: --for-tolerance chooses the density and predicts the "
			"time itself: no --h, --spacing, --points or --estimate with it\n");
		return EXIT_USAGE;
	}
	if (!a->max_points_given)
		a->opts.max_points = ASPH_PLAN_SEARCH_DEFAULT_MAX_POINTS;
	return 0;
}

/* 0: parsed; EXIT_OK + 1000 for --help; EXIT_USAGE on error. */
static int parse_args(int argc, char **argv, struct plan_args *a)
{
	static const struct option longopts[] = {
		PLAN_SOURCE_LONG_OPTIONS,
		{ "output", required_argument, NULL, 'o' },
		{ "max-points", required_argument, NULL, OPT_MAX_POINTS },
		{ "no-mesh", no_argument, NULL, OPT_NO_MESH },
		{ "estimate", required_argument, NULL, OPT_ESTIMATE },
		PLAN_TOLERANCE_LONG_OPTIONS,
		{ "quiet", no_argument, NULL, 'q' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	int c;

	a->opts.max_points = PLAN_DEFAULT_MAX_POINTS;
	optind = 0;   /* 0: getopt starts afresh (main read its options in order) */
	opterr = 0;
	while ((c = getopt_long(argc, argv, ":ho:q", longopts, NULL)) != -1) {
		int r = plan_source_option(&a->src, c, optarg);
		if (r == 1)
			r = plan_tolerance_option(&a->tol, c, optarg);
		if (r < 0)
			return EXIT_USAGE;
		if (r == 0)
			continue;
		switch (c) {
		case 'h':
			usage(stdout);
			return EXIT_OK + 1000;
		case 'o':
			a->output = optarg;
			break;
		case 'q':
			a->quiet = 1;
			a->src.quiet = 1;
			break;
		case OPT_MAX_POINTS:
			if (parse_count(optarg, &a->opts.max_points) < 0)
				return EXIT_USAGE;
			a->max_points_given = 1;
			break;
		case OPT_NO_MESH:
			a->opts.flags |= ASPH_PLAN_NO_MESH;
			break;
		case OPT_ESTIMATE:
			a->estimate = optarg;
			break;
		default:        /* '?', ':' */
			return tool_option_error(argv, ":ho:q", longopts);
		}
	}
	if (optind != argc - 1) {
		fprintf(stderr, optind >= argc ? "asph: plan: missing LENS\n"
					       : "asph: plan: one LENS only\n");
		usage(stderr);
		return EXIT_USAGE;
	}
	a->lens = argv[optind];
	if (a->tol.given)
		return check_tolerance_args(a);
	if (!a->src.have_method) {
		fprintf(stderr, "asph: plan: --method is required\n");
		return EXIT_USAGE;
	}
	if (a->src.n_density != 1) {
		fprintf(stderr, "asph: plan: give exactly one of --h, --spacing, --points\n");
		return EXIT_USAGE;
	}
	/* what remains to check: --profiles only with its method */
	if (plan_source_finish(&a->src, NULL) < 0)
		return EXIT_USAGE;
	return 0;
}

static void summary(const struct plan_args *a, const struct asph_plan *p)
{
	char label[128];

	plan_source_label(&a->src, label, sizeof(label));
	fprintf(stderr, "asph: plan %s: %zu points, spacing %.6g mm", label,
		p->n, p->spacing_mm);
	if (p->n_triangles)
		fprintf(stderr, ", %zu triangles", p->n_triangles);
	fprintf(stderr, " -> %s\n", a->output ? a->output : "stdout");
}

/* The instrument --estimate names, resolved before any work is done. */
static int resolve_estimate(const struct plan_args *a, struct asph_registry **reg,
			    struct asph_config **cfg, size_t *idx)
{
	struct asph_error err;

	asph_error_clear(&err);
	if (tool_registry_new(NULL, reg) < 0)
		return EXIT_FAILURE_RUN;
	if (asph_config_resolve(*reg, a->estimate, cfg, idx, &err) < 0) {
		tool_print_error("estimate", &err);
		return EXIT_USAGE;
	}
	return EXIT_OK;
}

/* The predicted measuring time of plan on instrument ic, as asph scan
 * would measure it (streamed where it can). */
static int print_estimate(const struct plan_args *a, const struct asph_surface *s,
			  const struct asph_plan *plan, struct asph_instrument_config *ic)
{
	_cleanup_free_ char *lens_json = NULL;
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	struct asph_error err;
	double t;

	asph_error_clear(&err);
	if (asph_prescription_to_json(asph_surface_prescription(s), &lens_json) < 0 ||
	    asph_instrument_config_set_lens(ic, lens_json, &err) < 0 ||
	    asph_scan_estimate(ic, s, plan->xyz, plan->n, &so, &t, &err) < 0) {
		tool_print_error("estimate", &err);
		return EXIT_FAILURE_RUN;
	}
	fprintf(a->output ? stdout : stderr,
		"estimate: %.1f s (%d min %02d s) to measure %zu points on %s\n", t,
		(int)(t / 60), (int)fmod(round(t), 60), plan->n, a->estimate);
	return EXIT_OK;
}

int cmd_plan(int argc, char **argv)
{
	struct plan_args a = { 0 };
	_cleanup_(asph_surface_freep) struct asph_surface *s = NULL;
	_cleanup_(asph_plan_freep) struct asph_plan *plan = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	struct asph_points_write_options wo = { 0 };
	struct asph_error err;
	int r = parse_args(argc, argv, &a);

	_cleanup_(asph_registry_freep) struct asph_registry *reg = NULL;
	_cleanup_(asph_config_freep) struct asph_config *cfg = NULL;
	size_t idx = 0;

	if (r)
		return r == EXIT_OK + 1000 ? EXIT_OK : r;
	if (a.estimate && (r = resolve_estimate(&a, &reg, &cfg, &idx)) != EXIT_OK)
		return r;
	if (tool_load_surface(a.lens, &s) < 0)
		return EXIT_FAILURE_RUN;
	if (a.tol.given) {
		/* the chosen plan is written only where -o asks for it */
		int found = 0;
		r = plan_tolerance_run(&a.tol, a.lens, s, a.src.have_method ? 1u << a.src.method : 0,
				       a.opts.max_points, a.quiet, &found, &a.src.method,
				       &a.src.density);
		if (r != EXIT_OK || !found || !a.output)
			return r != EXIT_OK ? r : found ? EXIT_OK : EXIT_FAILURE_RUN;
		a.src.have_method = 1;
		a.src.n_density = 1;
	}
	asph_error_clear(&err);
	r = plan_source_compute(&a.src, s, &a.opts, &plan, &err);
	if (r < 0) {
		tool_print_error("plan", &err);
		return EXIT_FAILURE_RUN;
	}
	if (asph_plan_to_points(plan, &pts) < 0) {
		fprintf(stderr, "asph: plan: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	r = asph_points_write(a.output ? a.output : "-", pts, &wo, &err);
	if (r < 0) {
		tool_print_error("plan", &err);
		return EXIT_FAILURE_RUN;
	}
	if (!a.quiet)
		summary(&a, plan);
	return a.estimate ? print_estimate(&a, s, plan, &cfg->instruments[idx]) : EXIT_OK;
}
