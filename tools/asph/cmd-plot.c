/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/plot.h"
#include "asph/quality.h"
#include "asph-tool.h"
#include "plan-source.h"
#include "util-mem.h"

static void usage(FILE *out)
{
	fprintf(out,
		"Usage: asph plot LENS PLAN_FILE -o FILE.png [OPTIONS]\n"
		"       asph plot LENS --method M (--h H | --spacing MM | --points N) -o FILE.png [OPTIONS]\n\n"
		"Draws two maps side by side, both seen from +z in the vertex plane (mm):\n"
		"the plan's points coloured by their height z, and its triangles (as asph quality\n"
		"builds them) coloured by A_i / mean(A) on [0, 4] or by q on [0, 1], as in the\n"
		"paper's Figs. 8 and 9 (docs/quality.md).\n\n"
		"LENS is a preset (weak, strong, turning-point) or a prescription file.\n");
	plan_source_help(out);
	fprintf(out,
		PLAN_SOURCE_QUIET_HELP
		"  -o, --output FILE   the PNG to write (required)\n"
		"  --color area|q      what colours the triangles (default area)\n"
		"  --chart C           conformal (default), xy or plan-mesh, as for asph quality\n"
		"  -h, --help          this text\n");
}

static int draw(const char *path, const char *lens, const char *label,
		const struct asph_points *pts, const struct asph_quality *q, int colour_q)
{
	_cleanup_free_ double *z = malloc(pts->n * sizeof(double));
	char left[320], right[192];
	struct asph_error err;

	if (!z) {
		fprintf(stderr, "asph: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	for (size_t i = 0; i < pts->n; i++)
		z[i] = pts->xyz[3 * i + 2];
	snprintf(left, sizeof(left), "%s, %s: %zu points", lens, label, pts->n);
	snprintf(right, sizeof(right), "%s per triangle (%zu, %s chart)",
		 colour_q ? "q" : "A_i / mean A", q->n_triangles, asph_quality_chart_name(q->chart));

	struct asph_plot_panel panels[2] = {
		{ .kind = ASPH_PLOT_POINTS, .xyz = pts->xyz, .n = pts->n, .value = z,
		  .opts = { .title = left, .colour_label = "z (mm)", .point_size = 0.45 } },
		{ .kind = ASPH_PLOT_TRIANGLES, .xyz = pts->xyz, .n = pts->n,
		  .triangles = q->triangles, .n_triangles = q->n_triangles,
		  .value = colour_q ? q->q : q->area_ratio,
		  .opts = { .title = right, .colour_label = colour_q ? "q" : "A_i / mean A",
			    .lo = 0, .hi = colour_q ? 1 : 4 } },
	};
	asph_error_clear(&err);
	if (asph_plot_panels_png(path, panels, 2, 0, 0, &err) < 0) {
		tool_print_error("plot", &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

struct plot_args {
	struct plan_quality *pq;
	const char *output;
	int colour_q;
};

static int take(int opt, const char *arg, void *data)
{
	struct plot_args *a = data;
	int r = plan_quality_option(a->pq, opt, arg);

	if (r <= 0)
		return r;
	if (opt == 'o') {
		a->output = arg;
		return 0;
	}
	if (strcmp(arg, "area") && strcmp(arg, "q")) {
		fprintf(stderr, "asph: --color: '%s' is not area or q\n", arg);
		return -EINVAL;
	}
	a->colour_q = !strcmp(arg, "q");
	return 0;
}

int cmd_plot(int argc, char **argv)
{
	static const struct option options[] = {
		PLAN_QUALITY_LONG_OPTIONS,
		{ "output", required_argument, NULL, 'o' },
		{ "color", required_argument, NULL, 'C' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 },
	};
	_cleanup_(plan_quality_clear) struct plan_quality pq = { 0 };
	struct plot_args a = { .pq = &pq };
	char label[128];
	int r = tool_getopt(argc, argv, "ho:", options, usage, take, &a);

	if (r >= 0)
		return r;
	if (!a.output) {
		fprintf(stderr, "asph: plot: -o FILE.png is required\n");
		return EXIT_USAGE;
	}
	r = plan_quality_run(&pq, "plot", argc, argv, optind);
	if (r != EXIT_OK)
		return r;
	plan_source_label(&pq.src, label, sizeof(label));
	return draw(a.output, asph_surface_prescription(pq.s)->name, label, pq.pts, pq.q,
		    a.colour_q);
}
