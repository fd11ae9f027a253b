/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/quality.h"
#include "asph-tool.h"
#include "plan-source.h"
#include "util-mem.h"

static void usage(FILE *out)
{
	fprintf(out,
		"Usage: asph quality LENS PLAN_FILE [OPTIONS]\n"
		"       asph quality LENS --method M (--h H | --spacing MM | --points N) [OPTIONS]\n\n"
		"Triangulates the plan in a chart of the surface and prints, over the 3-D\n"
		"triangles, the shape measure q = 4 sqrt(3) A / (l1^2 + l2^2 + l3^2) and the\n"
		"area ratio A_i / mean(A): min, quartiles, max, mean, std, the fraction with\n"
		"q > 0.9 and the fraction with A_i / mean within 0.95..1.05 (docs/quality.md).\n\n"
		"LENS is a preset (weak, strong, turning-point) or a prescription file.\n");
	plan_source_help(out);
	fprintf(out,
		PLAN_SOURCE_QUIET_HELP
		"  --chart C           conformal (default), xy (the vertex plane, for comparison),\n"
		"                      or plan-mesh (the mesh that comes with the plan)\n"
		"  --rim-angle DEG     drop rim triangles whose angle facing the rim exceeds DEG\n"
		"                      (default 120)\n"
		"  --json              one JSON object: chart, n_points, n_triangles, q, area_ratio\n"
		"  -h, --help          this text\n");
}

static json_t *stats_json(const struct asph_quality_stats *st, const char *frac_key,
			  double frac)
{
	json_t *o = json_object();

	json_object_set_new(o, "min", json_real(st->min));
	json_object_set_new(o, "p25", json_real(st->p25));
	json_object_set_new(o, "median", json_real(st->median));
	json_object_set_new(o, "p75", json_real(st->p75));
	json_object_set_new(o, "max", json_real(st->max));
	json_object_set_new(o, "mean", json_real(st->mean));
	json_object_set_new(o, "std", json_real(st->std));
	json_object_set_new(o, frac_key, json_real(frac));
	return o;
}

static void show_json(const struct asph_quality *q)
{
	_cleanup_(json_decrefp) json_t *root = json_object();

	json_object_set_new(root, "chart", json_string(asph_quality_chart_name(q->chart)));
	json_object_set_new(root, "n_points", json_integer((json_int_t)q->n_points));
	json_object_set_new(root, "n_triangles", json_integer((json_int_t)q->n_triangles));
	json_object_set_new(root, "q", stats_json(&q->q_stats, "frac_gt_0_9", q->q_frac_gt_0_9));
	json_object_set_new(root, "area_ratio",
			    stats_json(&q->area_stats, "frac_within_5pct", q->area_frac_within_5pct));
	json_dumpf(root, stdout, JSON_INDENT(2) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
	fputc('\n', stdout);
}

static void stats_row(const char *name, const struct asph_quality_stats *st)
{
	printf("  %-12s %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f\n", name, st->min, st->p25,
	       st->median, st->p75, st->max, st->mean, st->std);
}

static void show_text(const char *lens, const char *label, const struct asph_quality *q)
{
	printf("Lens %s, plan %s: %zu points\n", lens, label, q->n_points);
	printf("Chart %s: %zu triangles", asph_quality_chart_name(q->chart), q->n_triangles);
	if (q->n_dropped)
		printf(" (%zu rim slivers dropped)", q->n_dropped);
	printf(", mean area %.6g mm^2\n\n", q->mean_area);
	printf("  %-12s %8s %8s %8s %8s %8s %8s %8s\n", "", "min", "p25", "median", "p75", "max",
	       "mean", "std");
	stats_row("q", &q->q_stats);
	stats_row("A_i/mean", &q->area_stats);
	printf("\n  q > 0.9:                    %5.1f %% of triangles\n", 100 * q->q_frac_gt_0_9);
	printf("  A_i/mean within 0.95..1.05: %5.1f %% of triangles\n",
	       100 * q->area_frac_within_5pct);
}

static int parse_rim_angle(const char *arg, double *out)
{
	char *end;
	double deg = strtod(arg, &end);

	if (end == arg || *end || !(deg > 0 && deg < 180)) {
		fprintf(stderr, "asph: --rim-angle: '%s' is not an angle between 0 and 180 degrees\n",
			arg);
		return -1;
	}
	*out = deg * M_PI / 180;
	return 0;
}

struct quality_args {
	struct plan_quality *pq;
	int json;
};

static int take(int opt, const char *arg, void *data)
{
	struct quality_args *a = data;
	int r = plan_quality_option(a->pq, opt, arg);

	if (r <= 0)
		return r;
	if (opt == 'j') {
		a->json = 1;
		return 0;
	}
	return parse_rim_angle(arg, &a->pq->opts.max_rim_angle);
}

int cmd_quality(int argc, char **argv)
{
	static const struct option options[] = {
		PLAN_QUALITY_LONG_OPTIONS,
		{ "rim-angle", required_argument, NULL, 'r' },
		{ "json", no_argument, NULL, 'j' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 },
	};
	_cleanup_(plan_quality_clear) struct plan_quality pq = { 0 };
	struct quality_args a = { .pq = &pq };
	char label[128];
	int r = tool_getopt(argc, argv, "h", options, usage, take, &a);

	if (r >= 0)
		return r;
	r = plan_quality_run(&pq, "quality", argc, argv, optind);
	if (r != EXIT_OK)
		return r;
	plan_source_label(&pq.src, label, sizeof(label));
	if (a.json)
		show_json(pq.q);
	else
		show_text(asph_surface_prescription(pq.s)->name, label, pq.q);
	return EXIT_OK;
}
