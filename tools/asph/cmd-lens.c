/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/prescription.h"
#include "asph-tool.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)

struct lens_facts {
	double a, sag_edge, slope_edge, max_slope, r_max_slope, area, gamma;
};

static void lens_facts(const struct asph_surface *s, struct lens_facts *f)
{
	double d[3];

	f->a = asph_surface_aperture_radius(s);
	asph_surface_sag_derivs(s, f->a, d);
	f->sag_edge = d[0];
	f->slope_edge = d[1];
	f->max_slope = asph_surface_max_slope(s, &f->r_max_slope);
	f->area = asph_surface_area(s, f->a);
	f->gamma = asph_surface_gamma(s);
}

static const char *const shape_names[] = { "circular", "circular", "rectangular", "elliptical" };

/* What a freeform spans: its aperture, sag range, steepest slope, area. */
static json_t *freeform_json(const struct asph_surface *s)
{
	struct asph_surface_extent e;
	struct asph_aperture ap;

	asph_surface_extent(s, &e);
	asph_surface_aperture(s, &ap);
	return json_pack("{s:s, s:f, s:f, s:[ff], s:f, s:f, s:[ff], s:f, s:[ff], s:f, s:[ff], s:f, s:f, s:f}",
			 "aperture_shape", shape_names[ap.shape], "aperture_width_mm", ap.width,
			 "aperture_height_mm", ap.height, "aperture_offset_mm", ap.offset[0], ap.offset[1],
			 "sag_min_mm", e.sag_min, "sag_max_mm", e.sag_max,
			 "sag_min_at_mm", e.sag_min_at[0], e.sag_min_at[1],
			 "sag_range_mm", e.sag_max - e.sag_min,
			 "sag_max_at_mm", e.sag_max_at[0], e.sag_max_at[1],
			 "max_slope", e.max_slope, "max_slope_at_mm", e.max_slope_at[0], e.max_slope_at[1],
			 "area_mm2", asph_surface_total_area(s),
			 "projected_area_mm2", asph_surface_projected_area(s),
			 "gamma", asph_surface_gamma(s));
}

static int show_json(const struct asph_surface *s, const struct lens_facts *f)
{
	_cleanup_free_ char *ptext = NULL;
	json_error_t jerr;

	if (asph_prescription_to_json(asph_surface_prescription(s), &ptext) < 0)
		return EXIT_FAILURE_RUN;
	_cleanup_(json_decrefp) json_t *root = json_object();
	json_object_set_new(root, "prescription", json_loads(ptext, 0, &jerr));
	if (!asph_surface_is_rotational(s)) {
		_cleanup_(json_decrefp) json_t *ff = freeform_json(s);
		json_object_update(root, ff);
		json_dumpf(root, stdout, JSON_INDENT(2) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
		fputc('\n', stdout);
		return EXIT_OK;
	}
	json_object_set_new(root, "aperture_radius_mm", json_real(f->a));
	json_object_set_new(root, "sag_edge_mm", json_real(f->sag_edge));
	json_object_set_new(root, "slope_edge", json_real(f->slope_edge));
	json_object_set_new(root, "max_slope", json_real(f->max_slope));
	json_object_set_new(root, "r_max_slope_mm", json_real(f->r_max_slope));
	json_object_set_new(root, "area_mm2", json_real(f->area));
	json_object_set_new(root, "gamma", json_real(f->gamma));
	json_dumpf(root, stdout, JSON_INDENT(2) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
	fputc('\n', stdout);
	return EXIT_OK;
}

static void show_freeform_text(const struct asph_surface *s)
{
	const struct asph_prescription *p = asph_surface_prescription(s);
	_cleanup_free_ char *text = NULL;
	struct asph_surface_extent e;
	struct asph_aperture ap;
	json_error_t jerr;
	const char *key;
	json_t *v;

	asph_surface_extent(s, &e);
	asph_surface_aperture(s, &ap);
	printf("Lens %s (%s)\n", p->name[0] ? p->name : "(unnamed)", asph_surface_type_name(p->type));
	/* the members as the prescription file writes them */
	if (asph_prescription_to_json(p, &text) == 0) {
		_cleanup_(json_decrefp) json_t *o = json_loads(text, 0, &jerr);
		json_object_foreach(o, key, v) {
			if (!strcmp(key, "type") || !strcmp(key, "name") || !strncmp(key, "aperture", 8))
				continue;
			_cleanup_free_ char *vt = json_dumps(v, JSON_ENCODE_ANY | JSON_COMPACT |
							     JSON_REAL_PRECISION(10));
			printf("  %-19s %s\n", key, vt ? vt : "?");
		}
	}
	printf("  aperture            %s %.10g x %.10g mm", shape_names[ap.shape], ap.width, ap.height);
	if (ap.offset[0] != 0 || ap.offset[1] != 0)
		printf(", centred at (%.10g, %.10g) mm", ap.offset[0], ap.offset[1]);
	printf("\nSag range             %.9f .. %.9f mm (%.9f mm)\n", e.sag_min, e.sag_max,
	       e.sag_max - e.sag_min);
	printf("  lowest at           (%.4f, %.4f) mm\n", e.sag_min_at[0], e.sag_min_at[1]);
	printf("  highest at          (%.4f, %.4f) mm\n", e.sag_max_at[0], e.sag_max_at[1]);
	printf("Maximum slope         %.6f (%.3f deg) at (%.4f, %.4f) mm\n", e.max_slope,
	       atan(e.max_slope) * 180 / M_PI, e.max_slope_at[0], e.max_slope_at[1]);
	printf("Surface area          %.6f mm^2\n", asph_surface_total_area(s));
	printf("Projected area        %.6f mm^2\n", asph_surface_projected_area(s));
	printf("gamma (area / proj.)  %.4f\n", asph_surface_gamma(s));
}

static void show_text(const struct asph_surface *s, const struct lens_facts *f)
{
	const struct asph_prescription *p = asph_surface_prescription(s);

	if (!asph_surface_is_rotational(s)) {
		show_freeform_text(s);
		return;
	}
	printf("Lens %s (%s)\n", p->name[0] ? p->name : "(unnamed)",
	       asph_surface_type_name(p->type));
	if (isinf(p->R))
		printf("  R                   infinity (a plane base, c = 0)\n");
	else
		printf("  R                   %.10g mm\n", p->R);
	if (asph_surface_type_has_conic(p->type))
		printf("  k                   %.10g\n", p->k);
	for (int i = 1; i <= ASPH_SURFACE_MAX_POWER; i++)
		if (p->A[i] != 0)
			printf("  A%-2d                 %.10g mm^%d\n", i, p->A[i], 1 - i);
	if (p->norm_radius > 0)
		printf("  norm radius         %.10g mm\n", p->norm_radius);
	for (int m = 0; m <= ASPH_SURFACE_MAX_Q; m++)
		if (p->Q[m] != 0)
			printf("  a%-2d                 %.10g mm\n", m, p->Q[m]);
	printf("  aperture diameter   %.10g mm\n", p->aperture_diameter);
	if (p->note[0])
		printf("  note                %s\n", p->note);
	printf("Sag at the edge       %.9f mm\n", f->sag_edge);
	printf("Slope at the edge     %.6f (%.3f deg)\n", f->slope_edge,
	       atan(f->slope_edge) * 180 / M_PI);
	printf("Maximum slope         %.6f (%.3f deg) at r = %.4f mm\n", f->max_slope,
	       atan(f->max_slope) * 180 / M_PI, f->r_max_slope);
	printf("Surface area          %.6f mm^2\n", f->area);
	printf("gamma (area / disk)   %.4f\n", f->gamma);
}

static void usage(FILE *out)
{
	fprintf(out, "Usage: asph lens show LENS [--json]\n"
		     "       asph lens presets\n"
		     "       asph lens import FILE [--surface N] [-o OUT.json]\n\n"
		     "LENS is a preset (weak, strong, turning-point) or a prescription file (JSON).\n"
		     "A freeform shows its aperture, sag range, steepest slope and area.\n"
		     "  --json   print one JSON object (sag_edge_mm, max_slope, area_mm2, gamma, ...;\n"
		     "           a freeform: sag_min_mm, sag_max_mm, max_slope, area_mm2, ...)\n");
}

int cmd_lens(int argc, char **argv)
{
	static const struct option options[] = {
		{ "json", no_argument, NULL, 'j' },
		{ "help", no_argument, NULL, 'h' },
		{ 0 }
	};
	int json = 0, code;

	if (argc >= 2 && !strcmp(argv[1], "import"))
		return cmd_lens_import(argc - 1, argv + 1);
	code = tool_getopt(argc, argv, "h", options, usage, tool_take_flag, &json);
	if (code >= 0)
		return code;
	if (optind < argc && !strcmp(argv[optind], "presets") && optind + 1 == argc) {
		for (const char *const *n = asph_prescription_preset_names(); *n; n++)
			printf("%s\n", *n);
		return EXIT_OK;
	}
	if (optind + 2 != argc || strcmp(argv[optind], "show")) {
		usage(stderr);
		return EXIT_USAGE;
	}
	_cleanup_(asph_surface_freep) struct asph_surface *s = NULL;
	if (tool_load_surface(argv[optind + 1], &s) < 0)
		return EXIT_FAILURE_RUN;
	struct lens_facts f;
	lens_facts(s, &f);
	if (json)
		return show_json(s, &f);
	show_text(s, &f);
	return EXIT_OK;
}
