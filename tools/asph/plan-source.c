/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "asph-tool.h"
#include "command.h"
#include "plan-source.h"
#include "progress.h"
#include "util-mem.h"
#include "util-suggest.h"

/* Guards against a density typo that would ask for billions of points. */
#define PLAN_MAX_POINTS 50000000

static int parse_positive(const char *arg, const char *name, double *out)
{
	char *end;
	double v;

	errno = 0;
	v = strtod(arg, &end);
	if (errno || end == arg || *end || !isfinite(v) || v <= 0) {
		fprintf(stderr, "asph: --%s: '%s' is not a positive number\n", name, arg);
		return -1;
	}
	*out = v;
	return 0;
}

static int set_density(struct plan_source *ps, enum asph_plan_density_kind kind,
		       const char *arg, const char *name)
{
	double v;

	if (parse_positive(arg, name, &v) < 0)
		return -1;
	if (kind == ASPH_DENSITY_POINTS && v != floor(v)) {
		fprintf(stderr, "asph: --points: '%s' is not a whole number\n", arg);
		return -1;
	}
	ps->n_density++;
	ps->density = (struct asph_plan_density){ .kind = kind, .value = v };
	return 0;
}

void plan_method_help(FILE *out, const char *before, const char *after)
{
	char names[256], text[512];

	asph_plan_method_names(names, sizeof(names));
	snprintf(text, sizeof(text), "%s%s%s", before, names, after);
	command_help_option(out, "--method M", text);
}

void plan_source_help(FILE *out)
{
	fputs("  PLAN_FILE           points to judge (.csv x,y,z / .ply / .json), as asph plan writes\n",
	      out);
	plan_method_help(out, "compute the plan instead: ", "; with exactly one of");
	fputs(PLAN_DENSITY_HELP, out);
}

void plan_mesh_methods(char *buf, size_t size)
{
	size_t len = 0;

	buf[0] = '\0';
	for (int m = 0; m < ASPH_PLAN_N_METHODS; m++)
		if (asph_plan_method_has_mesh((enum asph_plan_method)m) && len < size)
			len += (size_t)snprintf(buf + len, size - len, "%s%s", len ? ", " : "",
						asph_plan_method_name((enum asph_plan_method)m));
}

static int set_profiles(struct plan_source *ps, const char *arg)
{
	char *end;
	long v;

	errno = 0;
	v = strtol(arg, &end, 10);
	if (errno || end == arg || *end || v < 1 || v > ASPH_PLAN_MAX_PROFILES) {
		fprintf(stderr, "asph: --profiles: '%s' is not a whole number in 1..%d\n", arg,
			ASPH_PLAN_MAX_PROFILES);
		return -1;
	}
	ps->profiles = (unsigned)v;
	return 0;
}

/* The methods from their table, with the one meant when it is near. */
static void unknown_method(const char *arg)
{
	const char *near = asph_plan_method_suggest(arg);

	fprintf(stderr, "asph: --method: unknown method '%s'", arg);
	if (near)
		fprintf(stderr, " (did you mean '%s'?)", near);
	fprintf(stderr, "; the methods:");
	for (int m = 0; m < ASPH_PLAN_N_METHODS; m++)
		fprintf(stderr, " %s", asph_plan_method_name((enum asph_plan_method)m));
	fputc('\n', stderr);
}

int plan_source_option(struct plan_source *ps, int opt, const char *arg)
{
	switch (opt) {
	case PLAN_OPT_METHOD:
		if (asph_plan_method_from_name(arg, &ps->method) < 0) {
			unknown_method(arg);
			return -1;
		}
		ps->have_method = 1;
		return 0;
	case PLAN_OPT_QUIET:
		ps->quiet = 1;
		return 0;
	case PLAN_OPT_H:
		return set_density(ps, ASPH_DENSITY_H, arg, "h");
	case PLAN_OPT_SPACING:
		return set_density(ps, ASPH_DENSITY_SPACING, arg, "spacing");
	case PLAN_OPT_POINTS:
		return set_density(ps, ASPH_DENSITY_POINTS, arg, "points");
	case PLAN_OPT_PROFILES:
		return set_profiles(ps, arg);
	default:
		return 1;
	}
}

int plan_source_finish(struct plan_source *ps, const char *plan_file)
{
	ps->plan_file = plan_file;
	if (plan_file && (ps->have_method || ps->n_density)) {
		fprintf(stderr, "asph: give either PLAN_FILE or --method with a density, not both\n");
		return -1;
	}
	if (!plan_file && !ps->have_method) {
		fprintf(stderr, "asph: give PLAN_FILE or --method M with --h, --spacing or --points\n");
		return -1;
	}
	if (ps->have_method && ps->n_density != 1) {
		fprintf(stderr, "asph: --method needs exactly one of --h, --spacing, --points\n");
		return -1;
	}
	if (ps->profiles && !(ps->have_method && ps->method == ASPH_PLAN_PROFILES)) {
		fprintf(stderr, "asph: --profiles is for --method profiles\n");
		return -1;
	}
	return 0;
}

int plan_source_compute(const struct plan_source *ps, const struct asph_surface *s,
			const struct asph_plan_options *opts, struct asph_plan **out,
			struct asph_error *err)
{
	struct asph_plan_options o = opts ? *opts : (struct asph_plan_options){ 0 };
	struct progress p;
	char what[32];
	int r;

	snprintf(what, sizeof(what), "%s plan", asph_plan_method_name(ps->method));
	progress_start(&p, what, "iterations", ps->quiet);
	p.at_most = true;
	o.progress = progress_hook(&p);
	o.profiles = ps->profiles;
	r = asph_plan_compute_opts(s, ps->method, ps->density, &o, out, err);
	progress_stop(&p);
	return r;
}

int plan_source_load(const struct plan_source *ps, const struct asph_surface *s,
		     struct asph_points **out)
{
	struct asph_plan *plan = NULL;
	struct asph_error err;
	int r;

	asph_error_clear(&err);
	if (ps->plan_file) {
		r = asph_points_read(ps->plan_file, out, &err);
		if (r < 0)
			tool_print_error(NULL, &err);
		return r;
	}
	r = plan_source_compute(ps, s, &(struct asph_plan_options){ .max_points = PLAN_MAX_POINTS },
				&plan, &err);
	if (r < 0) {
		tool_print_error("plan", &err);
		return r;
	}
	r = asph_plan_to_points(plan, out);
	asph_plan_free(plan);
	if (r < 0)
		fprintf(stderr, "asph: out of memory copying the plan\n");
	return r;
}

void plan_quality_clear(struct plan_quality *pq)
{
	asph_quality_free(pq->q);
	asph_points_free(pq->pts);
	asph_surface_free(pq->s);
	*pq = (struct plan_quality){ 0 };
}

int plan_quality_option(struct plan_quality *pq, int opt, const char *arg)
{
	if (opt != PLAN_OPT_CHART)
		return plan_source_option(&pq->src, opt, arg);
	const char *names[8];
	char known[128];
	size_t n = 0;

	if (asph_quality_chart_from_name(arg, &pq->opts.chart) == 0)
		return 0;
	while (n < ARRAY_SIZE(names) &&
	       strcmp(names[n] = asph_quality_chart_name((enum asph_quality_chart)n), "unknown"))
		n++;
	suggest_join(known, sizeof(known), names, n, " or ");
	fprintf(stderr, "asph: --chart: '%s' is not %s\n", arg, known);
	return -1;
}

int plan_quality_run(struct plan_quality *pq, const char *cmd, int argc,
		     char **argv, int first)
{
	struct asph_error err;

	if (argc - first < 1 || argc - first > 2) {
		fprintf(stderr, "asph: %s: expected LENS and optionally PLAN_FILE\n", cmd);
		return EXIT_USAGE;
	}
	if (plan_source_finish(&pq->src, argc - first == 2 ? argv[first + 1] : NULL) < 0)
		return EXIT_USAGE;
	if (tool_load_surface(argv[first], &pq->s) < 0 ||
	    plan_source_load(&pq->src, pq->s, &pq->pts) < 0)
		return EXIT_FAILURE_RUN;
	asph_error_clear(&err);
	if (asph_quality_compute(pq->s, pq->pts->xyz, pq->pts->n, pq->pts->triangles,
				 pq->pts->n_triangles, &pq->opts, &pq->q, &err) < 0) {
		tool_print_error("quality", &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

void plan_source_label(const struct plan_source *ps, char *buf, size_t size)
{
	const char *method = ps->have_method ? asph_plan_method_name(ps->method) : "";
	char name[48];

	if (ps->have_method && ps->method == ASPH_PLAN_PROFILES)
		snprintf(name, sizeof(name), "%u profile%s", ps->profiles ? ps->profiles : 1,
			 ps->profiles > 1 ? "s" : "");
	else
		snprintf(name, sizeof(name), "%s", method);

	if (ps->plan_file) {
		const char *slash = strrchr(ps->plan_file, '/');
		snprintf(buf, size, "%s", slash ? slash + 1 : ps->plan_file);
	} else if (ps->density.kind == ASPH_DENSITY_H) {
		snprintf(buf, size, "%s h=%g", name, ps->density.value);
	} else if (ps->density.kind == ASPH_DENSITY_SPACING) {
		snprintf(buf, size, "%s spacing %g mm", name, ps->density.value);
	} else {
		snprintf(buf, size, "%s %.0f points", name, ps->density.value);
	}
}
