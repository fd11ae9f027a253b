/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph fit: best fit of measured points to the nominal surface. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/correction.h"
#include "asph/fit.h"
#include "asph/plot.h"
#include "asph/prescription.h"
#include "asph/report.h"
#include "asph/scanfile.h"
#include "asph/x3p.h"
#include "config.h"
#include "fileio.h"
#include "asph/points.h"
#include "asph-tool.h"
#include "fit-report.h"
#include "fit-tool.h"
#include "fit-summary.h"
#include "fit-uncertainty.h"
#include "progress.h"
#include "quantity.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_fit *, asph_fit_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scatter *, asph_scatter_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_grid *, asph_grid_free)

enum {
	OPT_DOF = 0x100,
	OPT_RESIDUAL,
	OPT_ROBUST,
	OPT_JSON,
	OPT_RESIDUALS,
	OPT_MAP,
	OPT_ZERNIKE,
	OPT_TOLERANCE,
	OPT_WAVELENGTH,
	OPT_SLOPE_LENGTH,
	OPT_X3P,
	OPT_GRID_SPACING,
	OPT_CORRECTION,
	OPT_CORRECTION_KIND,
	OPT_CORRECTION_SIGN,
	OPT_CORRECTION_DIRECTION,
	OPT_CORRECTION_MATERIAL,
	OPT_CORRECTION_STEP,
	OPT_CORRECTION_SMOOTH,
	OPT_CORRECTION_EXTEND,
	OPT_CORRECTION_EXTEND_METHOD,
	OPT_REPORT,
	OPT_PART,
	OPT_LOT,
	OPT_SERIAL,
	OPT_OPERATOR,
	OPT_MEASURED,
	OPT_SCAN,
	OPT_BANDS,
};


/* Band-limited RMS of the residual (--bands), from the areal PSD of the
 * residual grid. */
struct band_result {
	int valid;
	double spacing_mm;
	struct asph_band_rms rms;
};

static void usage(FILE *out)
{
	fprintf(out,
		"Usage: asph fit LENS POINTS_FILE [OPTIONS]\n\n"
		"Best fit of measured points (mm, machine frame) to the nominal surface of LENS:\n"
		"Levenberg-Marquardt on the residuals over the chosen degrees of freedom, then\n"
		"the form error that remains (RMS, PV, PVr, slope, Zernike terms).\n"
		"docs/characterization.md states the conventions.\n\n"
		"LENS is a preset (weak, strong, turning-point) or a prescription file.\n"
		"POINTS_FILE is .csv (header x,y,z), .ply or .json; '-' reads CSV from stdin.\n\n"
		"  --dof LIST          degrees of freedom, from tx,ty,tz (mm), rx,ry,rz (rad), R (mm),\n"
		"                      k (default tx,ty,tz,rx,ry); rz (clocking) for freeform\n"
		"                      surfaces, R and k for rotationally symmetric ones\n"
		"  --residual KIND     normal (default: distance along the surface normal) or sag\n"
		"                      (z minus the sag)\n"
		"  --robust            down-weight outliers (Tukey biweight) and leave them out\n"
		"  --zernike N         Zernike terms of the decomposition (default 36, max %d)\n"
		"  --residuals OUT     write x,y,z,residual_nm of the points fitted (.csv or .ply,\n"
		"                      PLY coloured by residual)\n"
		"  --map OUT.png       residual map with a colour bar in nm\n"
		"  --tolerance T       a tolerance: an ISO 10110-5 call-out ('3/2(0.5/0.3)'), or\n"
		"                      JSON text or a file holding it (call-out, RMS, slope and R\n"
		"                      limits); decides pass, fail or undecided (ISO 14253-1) and\n"
		"                      sets the exit status\n"
		"  --wavelength NM     test wavelength of the fringes (default: the tolerance's,\n"
		"                      else 546.07)\n"
		"  --slope-length MM   evaluation length of the slope deviation (default: the\n"
		"                      tolerance's, else 1)\n"
		"  --x3p OUT.x3p       the residual resampled on a grid (ISO 25178-72 matrix layout)\n"
		"  --grid-spacing MM   spacing of that grid (default: the median point spacing)\n"
		"  --bands FORM,HIGH   band-limited RMS of the residual from the areal PSD of\n"
		"                      that grid, by spatial wavelength in mm: form (longer\n"
		"                      than FORM), mid-spatial (HIGH to FORM), high (shorter\n"
		"                      than HIGH); JSON key band_rms\n"
		, ASPH_FIT_MAX_ZERNIKE);
	fputs("  --correction OUT    a correction table of the residual (CSV, conventions in its\n"
		"                      header), with:\n"
		"    --correction-kind radial|grid          z(r) of a turned part (default) or XY\n"
		"    --correction-sign height-error|material-to-remove   (default height-error)\n"
		"    --correction-direction z|normal        along z (default) or the normal\n"
		"    --correction-material below|above      the part's side of the surface (below)\n"
		"    --correction-step MM                   spacing (default: the point spacing)\n"
		"    --correction-smooth MM                 Gaussian cut-off (default 0: none)\n"
		"    --correction-extend MM                 beyond the aperture (default 0)\n"
		"    --correction-extend-method constant|linear   (default constant)\n"
		"  --report OUT.pdf    the measurement report (PDF), with:\n"
		"    --part P, --lot L, --serial S          what was measured (default: the\n"
		"                                           scan's, as asphd records the job's)\n"
		"    --operator NAME                        who measured (default: the job's\n"
		"                                           submitter in the scan, else the\n"
		"                                           user running asph)\n"
		"    --measured TIME                        when, ISO 8601 with the zone (default:\n"
		"                                           the scan's start and end)\n"
		"    --scan SCAN                            the recorded scan the points come from\n"
		"                                           (its plan, instrument and times are\n"
		"                                           reported)\n"
		FIT_MC_HELP
		"  --json              one JSON object (n_points, dof, uncertainty, iterations,\n"
		"                      converged, rms_nm (the residual's standard deviation about\n"
		"                      its mean), pv_nm, pvr_nm, zernike_nm, form, slope, radius,\n"
		"                      uncertainty_k2, verdict...)\n"
		"  -q, --quiet         no progress of a long fit or Monte Carlo on the terminal\n"
		"  -h, --help          this text\n\n"
		"Exit status: 0 done (and the part passes its tolerance), 1 refused input or no\n"
		"convergence, 2 bad command line, 3 the part fails its tolerance, 4 the verdict\n"
		"is undecided (asph help exit-status).\n", out);
}

static int parse_int(const char *arg, const char *name, int lo, int hi, int *out)
{
	char *end;
	long v;

	errno = 0;
	v = strtol(arg, &end, 10);
	if (errno || end == arg || *end || v < lo || v > hi) {
		fprintf(stderr, "asph fit: --%s: '%s' is not a whole number in %d..%d\n",
			name, arg, lo, hi);
		return -1;
	}
	*out = (int)v;
	return 0;
}

static int parse_positive(const char *arg, const char *name, double lo, double hi,
			  double *out)
{
	char *end;
	double v;

	errno = 0;
	v = strtod(arg, &end);
	if (errno || end == arg || *end || !(v >= lo && v <= hi)) {
		fprintf(stderr, "asph fit: --%s: '%s' is not a number in %g..%g\n", name, arg,
			lo, hi);
		return -1;
	}
	*out = v;
	return 0;
}

static int parse_nonnegative(const char *arg, const char *name, double *out)
{
	char *end;
	double v;

	errno = 0;
	v = strtod(arg, &end);
	if (errno || end == arg || *end || !(v >= 0) || !isfinite(v)) {
		fprintf(stderr, "asph fit: --%s: '%s' is not a number >= 0\n", name, arg);
		return -1;
	}
	*out = v;
	return 0;
}

static int take_correction_option(struct fit_cli *c, int opt, const char *arg);

/* --bands FORM_MM,HIGH_MM, with 0 < HIGH < FORM. */
static int parse_bands(const char *arg, struct fit_cli *c)
{
	char *end, *mid;
	double form, high;

	errno = 0;
	form = strtod(arg, &mid);
	if (errno || mid == arg || *mid != ',') {
		fprintf(stderr, "asph fit: --bands: '%s': expected FORM_MM,HIGH_MM (column %d: %s)\n",
			arg, (int)(mid - arg) + 1, mid == arg ? "not a number" : "expected ','");
		return -1;
	}
	high = strtod(mid + 1, &end);
	if (errno || end == mid + 1 || *end) {
		fprintf(stderr, "asph fit: --bands: '%s': column %d: %s\n", arg,
			(int)(end - arg) + 1, end == mid + 1 ? "HIGH_MM is not a number"
							     : "unexpected text after HIGH_MM");
		return -1;
	}
	if (!(high > 0) || !(form > high) || !isfinite(form)) {
		fprintf(stderr, "asph fit: --bands: '%s': need 0 < HIGH_MM (%g) < FORM_MM (%g), "
			"both finite\n", arg, high, form);
		return -1;
	}
	c->bands = (struct asph_bands){ .form_mm = form, .high_mm = high };
	c->bands_given = 1;
	return 0;
}

/* 0 taken, -1 bad value (message printed). */
static int take_option(struct fit_cli *c, int opt, const char *arg)
{
	struct asph_error err;

	switch (opt) {
	case OPT_DOF:
		asph_error_clear(&err);
		if (asph_fit_dof_parse(arg, &c->opts.dof, &err) < 0) {
			tool_print_error("fit: --dof", &err);
			return -1;
		}
		return 0;
	case OPT_RESIDUAL:
		if (asph_fit_residual_from_name(arg, &c->opts.residual) < 0) {
			fprintf(stderr, "asph fit: --residual: '%s' is not normal or sag\n", arg);
			return -1;
		}
		return 0;
	case OPT_ROBUST:
		c->opts.robust = 1;
		return 0;
	case OPT_JSON:
		c->json = 1;
		return 0;
	case 'q':
		c->quiet = c->mc.quiet = 1;
		return 0;
	case OPT_RESIDUALS:
		c->residuals_out = arg;
		return 0;
	case OPT_MAP:
		c->map_out = arg;
		return 0;
	case OPT_ZERNIKE:
		return parse_int(arg, "zernike", 1, ASPH_FIT_MAX_ZERNIKE, &c->opts.n_zernike);
	case OPT_TOLERANCE:
		asph_error_clear(&err);
		if (asph_tolerance_load(arg, &c->tolerance, &err) < 0) {
			tool_print_error("fit: --tolerance", &err);
			return -1;
		}
		c->tolerance_arg = arg;
		return 0;
	case OPT_WAVELENGTH:
		return parse_positive(arg, "wavelength", 100, 20000, &c->opts.wavelength_nm);
	case OPT_SLOPE_LENGTH:
		return parse_positive(arg, "slope-length", 1e-6, 1e6, &c->opts.slope_length_mm);
	case OPT_X3P:
		c->x3p_out = arg;
		return 0;
	case OPT_GRID_SPACING:
		return parse_positive(arg, "grid-spacing", 1e-6, 1e6, &c->grid_spacing);
	case OPT_BANDS:
		return parse_bands(arg, c);
	case OPT_CORRECTION:
		c->correction_out = arg;
		return 0;
	case OPT_REPORT:
		c->report_out = arg;
		return 0;
	case OPT_PART:
		c->part = arg;
		return 0;
	case OPT_LOT:
		c->lot = arg;
		return 0;
	case OPT_SERIAL:
		c->serial = arg;
		return 0;
	case OPT_OPERATOR:
		c->operator_name = arg;
		return 0;
	case OPT_MEASURED:
		return fit_report_parse_measured(arg, &c->measured_ns);
	case OPT_SCAN:
		c->scan = arg;
		return 0;
	case OPT_MC_UNCERTAINTY:
	case OPT_MC_INSTRUMENT:
	case OPT_MC_TRIALS:
	case OPT_MC_FIXED:
	case OPT_MC_THREADS:
	case OPT_MC_SEED:
		return fit_mc_take_option(&c->mc, opt, arg);
	default:
		return take_correction_option(c, opt, arg);
	}
}

/* The --correction-* options: 0, or -1 after saying why. */
static int take_correction_option(struct fit_cli *c, int opt, const char *arg)
{
	struct asph_correction_options *o = &c->correction;
	struct asph_error err;
	int r = 0;

	asph_error_clear(&err);
	switch (opt) {
	case OPT_CORRECTION_KIND:
		r = asph_correction_kind_parse(arg, "--correction-kind", &o->kind, &err);
		break;
	case OPT_CORRECTION_SIGN:
		r = asph_correction_sign_parse(arg, "--correction-sign", &o->sign, &err);
		break;
	case OPT_CORRECTION_DIRECTION:
		r = asph_correction_direction_parse(arg, "--correction-direction", &o->direction, &err);
		break;
	case OPT_CORRECTION_MATERIAL:
		r = asph_correction_material_parse(arg, "--correction-material", &o->material, &err);
		break;
	case OPT_CORRECTION_EXTEND_METHOD:
		r = asph_correction_extension_parse(arg, "--correction-extend-method", &o->extension,
						    &err);
		break;
	case OPT_CORRECTION_STEP:
		return parse_positive(arg, "correction-step", 1e-6, 1e6, &o->step_mm);
	case OPT_CORRECTION_SMOOTH:
		return parse_nonnegative(arg, "correction-smooth", &o->smooth_mm);
	case OPT_CORRECTION_EXTEND:
		return parse_nonnegative(arg, "correction-extend", &o->extend_mm);
	default:
		return -1;
	}
	if (r < 0)
		tool_print_error("fit", &err);
	return r < 0 ? -1 : 0;
}

/* The options a tolerance fixes must agree with it. */
static int check_tolerance(struct fit_cli *c)
{
	const struct asph_tolerance *t = &c->tolerance;

	if (!c->tolerance_arg)
		return EXIT_OK;
	c->opts.tolerance = t;
	if (c->opts.wavelength_nm != 0 && c->opts.wavelength_nm != t->wavelength_nm) {
		fprintf(stderr, "asph fit: --wavelength %g disagrees with the tolerance's %g nm\n",
			c->opts.wavelength_nm, t->wavelength_nm);
		return EXIT_USAGE;
	}
	if (c->opts.slope_length_mm != 0 && !isnan(t->slope_length_mm) &&
	    c->opts.slope_length_mm != t->slope_length_mm) {
		fprintf(stderr, "asph fit: --slope-length %g disagrees with the tolerance's "
			"slope_urad.length_mm %g\n", c->opts.slope_length_mm, t->slope_length_mm);
		return EXIT_USAGE;
	}
	if (!isnan(t->R_mm) && !(c->opts.dof & ASPH_FIT_DOF_BIT(ASPH_FIT_R))) {
		fprintf(stderr, "asph fit: --tolerance: R_mm needs R among the degrees of freedom "
			"(--dof tx,ty,tz,rx,ry,R)\n");
		return EXIT_USAGE;
	}
	return EXIT_OK;
}

int fit_cli_parse(struct fit_cli *c, int argc, char **argv, int operands,
		  void (*usage_fn)(FILE *out))
{
	static const struct option longopts[] = {
		{ "dof", required_argument, NULL, OPT_DOF },
		{ "residual", required_argument, NULL, OPT_RESIDUAL },
		{ "robust", no_argument, NULL, OPT_ROBUST },
		{ "json", no_argument, NULL, OPT_JSON },
		{ "residuals", required_argument, NULL, OPT_RESIDUALS },
		{ "map", required_argument, NULL, OPT_MAP },
		{ "zernike", required_argument, NULL, OPT_ZERNIKE },
		{ "tolerance", required_argument, NULL, OPT_TOLERANCE },
		{ "wavelength", required_argument, NULL, OPT_WAVELENGTH },
		{ "slope-length", required_argument, NULL, OPT_SLOPE_LENGTH },
		{ "x3p", required_argument, NULL, OPT_X3P },
		{ "grid-spacing", required_argument, NULL, OPT_GRID_SPACING },
		{ "bands", required_argument, NULL, OPT_BANDS },
		{ "correction", required_argument, NULL, OPT_CORRECTION },
		{ "correction-kind", required_argument, NULL, OPT_CORRECTION_KIND },
		{ "correction-sign", required_argument, NULL, OPT_CORRECTION_SIGN },
		{ "correction-direction", required_argument, NULL, OPT_CORRECTION_DIRECTION },
		{ "correction-material", required_argument, NULL, OPT_CORRECTION_MATERIAL },
		{ "correction-step", required_argument, NULL, OPT_CORRECTION_STEP },
		{ "correction-smooth", required_argument, NULL, OPT_CORRECTION_SMOOTH },
		{ "correction-extend", required_argument, NULL, OPT_CORRECTION_EXTEND },
		{ "correction-extend-method", required_argument, NULL, OPT_CORRECTION_EXTEND_METHOD },
		{ "report", required_argument, NULL, OPT_REPORT },
		{ "part", required_argument, NULL, OPT_PART },
		{ "lot", required_argument, NULL, OPT_LOT },
		{ "serial", required_argument, NULL, OPT_SERIAL },
		{ "operator", required_argument, NULL, OPT_OPERATOR },
		{ "measured", required_argument, NULL, OPT_MEASURED },
		{ "scan", required_argument, NULL, OPT_SCAN },
		FIT_MC_LONGOPTS,
		{ "quiet", no_argument, NULL, 'q' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	int opt;

	/* getopt permutes: options may also follow LENS and POINTS_FILE. */
	optind = 0;
	opterr = 0;
	while ((opt = getopt_long(argc, argv, "hq", longopts, NULL)) != -1) {
		if (opt == 'h') {
			usage_fn(stdout);
			return -1;
		}
		if (opt == '?' || opt == ':')
			return tool_option_error(argv, "hq", longopts);
		if (take_option(c, opt, optarg) < 0)
			return EXIT_USAGE;
	}
	if (argc - optind != operands) {
		fprintf(stderr, "asph %s: need %s (see --help)\n", argv[0],
			operands == 2 ? "LENS and POINTS_FILE" : "SCAN");
		return EXIT_USAGE;
	}
	c->lens = operands == 2 ? argv[optind] : NULL;
	c->points = argv[optind + operands - 1];
	if (fit_mc_check(&c->mc) != EXIT_OK)
		return EXIT_USAGE;
	return check_tolerance(c);
}

static json_t *bands_json(const struct fit_cli *c, const struct band_result *b)
{
	if (!b->valid)
		return json_null();
	return json_pack("{s:f, s:f, s:f, s:f, s:f, s:f, s:f}",
			 "form_mm", c->bands.form_mm, "high_mm", c->bands.high_mm,
			 "grid_spacing_mm", b->spacing_mm, "form_nm", b->rms.form,
			 "mid_nm", b->rms.mid, "high_nm", b->rms.high, "total_nm", b->rms.total);
}

/* The summary as asph_fit_result_to_json() makes it, with the Monte
 * Carlo's keys, band_rms and the acquisition; NULL when out of memory. */
static json_t *summary_json(const struct fit_cli *c, const struct asph_surface *s,
			    const struct asph_fit_result *r, const struct asph_mc_result *mc,
			    const struct band_result *b, const char *acquisition)
{
	_cleanup_free_ char *text = NULL;
	json_t *root = NULL;

	if (asph_fit_result_to_json(r, asph_surface_prescription(s)->name,
				    c->opts.robust, &text) < 0 ||
	    !(root = json_loads(text, 0, NULL)) ||
	    (mc && fit_mc_json(root, mc, r->form.wavelength_nm) < 0)) {
		json_decref(root);
		return NULL;
	}
	if (c->bands_given)
		json_object_set_new(root, "band_rms", bands_json(c, b));
	if (acquisition)
		json_object_set_new(root, "acquisition", json_loads(acquisition, 0, NULL));
	return root;
}

static void show_bands(const struct fit_cli *c, const struct band_result *b)
{
	const double v[] = { b->rms.form, b->rms.mid, b->rms.high, b->rms.total };
	static const char *const paths[] = { "band_rms.form_nm", "band_rms.mid_nm",
					     "band_rms.high_nm", "band_rms.total_nm" };
	char t[4][32];

	if (!c->bands_given || !b->valid)
		return;
	for (int i = 0; i < 4; i++)
		quantity_format(quantity_by_path(paths[i]), v[i], QUANTITY_UNIT, t[i], sizeof(t[i]));
	printf("Band-limited RMS (areal PSD, grid %g mm): form (> %g mm) %s, mid (%g..%g mm) %s, "
	       "high (< %g mm) %s, total %s\n", b->spacing_mm, c->bands.form_mm, t[0],
	       c->bands.high_mm, c->bands.form_mm, t[1], c->bands.high_mm, t[2], t[3]);
}

/* --json, or the text of tools/fit-summary.c. */
static int show(const struct fit_cli *c, const struct asph_surface *s,
		const struct asph_fit_result *r, const struct asph_mc_result *mc,
		const struct band_result *b, const char *acquisition,
		void (*more_text)(void *data), void *data)
{
	_cleanup_(json_decrefp) json_t *root = summary_json(c, s, r, mc, b, acquisition);

	if (!root) {
		fprintf(stderr, "asph fit: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	if (c->json) {
		json_dumpf(root, stdout, JSON_INDENT(2) | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
		fputc('\n', stdout);
		return EXIT_OK;
	}
	fit_summary_print(stdout, root, "");
	fit_summary_print_zernike(stdout, root, "");
	if (mc)
		fit_mc_show(mc);
	show_bands(c, b);
	if (more_text)
		more_text(data);
	return EXIT_OK;
}

/* The points fitted (outliers included, points outside the aperture not)
 * with their residual in nm. */
static int residual_points(const struct asph_points *pts, const struct asph_fit *w,
			   int with_outliers, struct asph_points **out)
{
	const uint8_t *st = asph_fit_point_status(w);
	const double *res = asph_fit_residuals(w);
	struct asph_points *p;
	size_t m = 0;

	for (size_t i = 0; i < pts->n; i++)
		m += st[i] == ASPH_FIT_POINT_USED || (with_outliers && st[i] == ASPH_FIT_POINT_OUTLIER);
	p = asph_points_alloc(m);
	if (!p || asph_points_add_value(p, "residual_nm") < 0) {
		asph_points_free(p);
		return -ENOMEM;
	}
	m = 0;
	for (size_t i = 0; i < pts->n; i++) {
		if (!(st[i] == ASPH_FIT_POINT_USED || (with_outliers && st[i] == ASPH_FIT_POINT_OUTLIER)))
			continue;
		memcpy(p->xyz + 3 * m, pts->xyz + 3 * i, 3 * sizeof(double));
		p->value[m++] = asph_nm_from_mm(res[i]).v;
	}
	*out = p;
	return 0;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

/* --report: the provenance from the scan when there is one. */
static int write_report(const struct fit_cli *c, const struct asph_surface *s,
			const struct asph_fit *w, const struct asph_fit_result *res,
			const struct asph_scatter *sc)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *scan = NULL;
	_cleanup_free_ char *lens_json = NULL, *data = NULL;
	_cleanup_free_ double *xy = malloc(2 * res->n_used * sizeof(double) + 1);
	_cleanup_free_ double *v = malloc(res->n_used * sizeof(double) + 1);
	struct asph_error err;
	size_t len = 0;

	asph_error_clear(&err);
	if (!xy || !v || asph_prescription_to_json(asph_surface_prescription(s), &lens_json) < 0) {
		fprintf(stderr, "asph fit: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	if ((c->scan && asph_scanfile_read(c->scan, &scan, &err) < 0) ||
	    file_read_all(c->scan ? c->scan : c->points, (size_t)1 << 31, &data, &len, &err) < 0) {
		tool_print_error("fit: --report", &err);
		return EXIT_FAILURE_RUN;
	}
	_cleanup_(fit_report_who_release) struct fit_report_who who;
	fit_report_who(c, scan, &who);
	struct asph_report r = {
		.part = who.part, .lot = who.lot, .serial = who.serial,
		.operator_name = who.operator_name, .measured_ns = who.measured_ns,
		.measured_end_ns = who.measured_end_ns, .job = who.job, .label = who.label,
		.lens_name = asph_surface_prescription(s)->name, .lens_json = lens_json,
		.plan_json = scan ? scan->header.plan : NULL,
		.instrument_json = scan ? scan->header.instrument : NULL,
		.data_name = c->scan ? c->scan : c->points, .data = data, .data_len = len,
		.software = "asph " ASPH_VERSION, .fit = res,
		.tolerance = c->tolerance_arg ? &c->tolerance : NULL,
		.xy = xy, .residual_nm = v, .n = asph_fit_residual_map(w, xy, v),
		.scatter = sc, .radius = asph_surface_aperture_radius(s),
	};
	if (asph_report_write_pdf(c->report_out, &r, &err) < 0) {
		tool_print_error("fit: --report", &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_psd2 *, asph_psd2_free)

/* --bands: the residual on the grid of --grid-spacing (default the median
 * point spacing), its areal PSD, and the RMS in each band. */
static int compute_bands(const struct fit_cli *c, const struct asph_surface *s,
			 const struct asph_fit *w, struct band_result *out)
{
	_cleanup_(asph_scatter_freep) struct asph_scatter *sc = NULL;
	_cleanup_(asph_grid_freep) struct asph_grid *g = NULL;
	_cleanup_(asph_psd2_freep) struct asph_psd2 *p = NULL;
	struct asph_error err;

	if (!c->bands_given)
		return EXIT_OK;
	asph_error_clear(&err);
	if (asph_fit_residual_scatter(w, &sc, &err) < 0)
		goto fail;
	out->spacing_mm = c->grid_spacing > 0 ? c->grid_spacing : asph_scatter_median_edge(sc);
	if (asph_grid_resample(sc, asph_surface_aperture_radius(s), out->spacing_mm, &g, &err) < 0 ||
	    asph_psd_areal(g, &p, &err) < 0 || asph_band_rms(p, &c->bands, &out->rms, &err) < 0)
		goto fail;
	out->valid = 1;
	return EXIT_OK;
fail:
	tool_print_error("fit: --bands", &err);
	return err.code == -EINVAL ? EXIT_USAGE : EXIT_FAILURE_RUN;
}

/* --x3p, --correction and --report. */
static int write_exports(const struct fit_cli *c, const struct asph_surface *s,
			 const struct asph_fit *w, const struct asph_fit_result *res)
{
	_cleanup_(asph_scatter_freep) struct asph_scatter *sc = NULL;
	_cleanup_(asph_grid_freep) struct asph_grid *g = NULL;
	const char *lens = asph_surface_prescription(s)->name;
	struct asph_error err;
	char comment[256];

	if (!c->x3p_out && !c->correction_out && !c->report_out)
		return EXIT_OK;
	asph_error_clear(&err);
	if (asph_fit_residual_scatter(w, &sc, &err) < 0) {
		tool_print_error("fit: the residual map", &err);
		return EXIT_FAILURE_RUN;
	}
	if (c->x3p_out) {
		double dx = c->grid_spacing > 0 ? c->grid_spacing : asph_scatter_median_edge(sc);
		struct asph_x3p_info info = { .creator = "asph fit", .comment = comment };
		snprintf(comment, sizeof(comment), "%s residual of %s after the best fit (z in m)",
			 asph_fit_residual_name(res->residual), lens);
		if (asph_grid_resample(sc, asph_surface_aperture_radius(s), dx, &g, &err) < 0 ||
		    asph_x3p_write_grid(c->x3p_out, g, &info, &err) < 0) {
			tool_print_error("fit: --x3p", &err);
			return EXIT_FAILURE_RUN;
		}
	}
	if (c->correction_out &&
	    asph_correction_write(c->correction_out, s, lens, sc,
				  res->residual == ASPH_FIT_RESIDUAL_NORMAL, &c->correction, &err) < 0) {
		char where[192];
		snprintf(where, sizeof(where), "fit: --correction%s%s", err.field[0] ? "-" : "",
			 err.field);
		err.field[0] = '\0';
		tool_print_error(where, &err);
		return err.code == -EINVAL ? EXIT_USAGE : EXIT_FAILURE_RUN;
	}
	if (c->report_out)
		return write_report(c, s, w, res, sc);
	return EXIT_OK;
}

static int write_outputs(const struct fit_cli *c, const struct asph_surface *s,
			 const struct asph_points *pts, const struct asph_fit *w)
{
	_cleanup_(asph_points_freep) struct asph_points *all = NULL;
	_cleanup_(asph_points_freep) struct asph_points *used = NULL;
	struct asph_error err;
	char title[160];

	asph_error_clear(&err);
	if (c->residuals_out) {
		if (residual_points(pts, w, 1, &all) < 0 ||
		    asph_points_write(c->residuals_out, all, NULL, &err) < 0) {
			tool_print_error("fit: --residuals", &err);
			return EXIT_FAILURE_RUN;
		}
	}
	if (c->map_out) {
		struct asph_plot_options po = {
			.title = title, .colour_label = "residual (nm)", .diverging = 1,
		};
		snprintf(title, sizeof(title), "%s: %s residual after the best fit",
			 asph_surface_prescription(s)->name, asph_fit_residual_name(c->opts.residual));
		if (residual_points(pts, w, 0, &used) < 0 ||
		    asph_plot_points_png(c->map_out, used->xyz, used->value, used->n, &po, &err) < 0) {
			tool_print_error("fit: --map", &err);
			return EXIT_FAILURE_RUN;
		}
	}
	return EXIT_OK;
}

int fit_cli_run(const struct fit_cli *c, const struct asph_surface *s,
		const struct asph_points *pts, const char *acquisition,
		void (*more_text)(void *data), void *data)
{
	_cleanup_(asph_fit_freep) struct asph_fit *w = NULL;
	struct asph_fit_options fo = c->opts;
	struct asph_fit_result res;
	struct asph_mc_result mc;
	struct band_result bands = { 0 };
	struct asph_error err;
	struct progress p;
	int r;

	asph_error_clear(&err);
	progress_start(&p, "fit", "iterations", c->quiet);
	fo.progress = progress_hook(&p);
	r = asph_fit_alloc(s, pts->n, &fo, &w, &err);
	if (r == 0)
		r = asph_fit_run(w, pts->xyz, pts->n, &res, &err);
	progress_stop(&p);
	if (r < 0) {
		tool_print_error(c->points, &err);
		return EXIT_FAILURE_RUN;
	}
	if (c->mc.enabled) {
		if (!res.converged) {
			fprintf(stderr, "asph fit: the fit did not converge: %s\n", res.reason);
			return EXIT_FAILURE_RUN;
		}
		r = fit_mc_run(&c->mc, c->scan, s, pts, &c->opts, c->opts.tolerance, &res, &mc);
		if (r != EXIT_OK)
			return r;
	}
	r = compute_bands(c, s, w, &bands);
	if (r != EXIT_OK)
		return r;
	r = show(c, s, &res, c->mc.enabled ? &mc : NULL, &bands, acquisition, more_text, data);
	if (r != EXIT_OK)
		return r;
	r = write_outputs(c, s, pts, w);
	if (r == EXIT_OK)
		r = write_exports(c, s, w, &res);
	if (r == EXIT_OK && !res.converged) {
		fprintf(stderr, "asph fit: the fit did not converge: %s\n", res.reason);
		r = EXIT_FAILURE_RUN;
	}
	if (r == EXIT_OK && res.verdict.present && res.verdict.overall != ASPH_VERDICT_PASS)
		r = res.verdict.overall == ASPH_VERDICT_FAIL ? EXIT_VERDICT_FAIL
							     : EXIT_VERDICT_UNDECIDED;
	return r;
}

int cmd_fit(int argc, char **argv)
{
	_cleanup_(asph_surface_freep) struct asph_surface *s = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	struct fit_cli c = { 0 };
	struct asph_error err;
	int r = fit_cli_parse(&c, argc, argv, 2, usage);

	if (r != EXIT_OK)
		return r < 0 ? EXIT_OK : r;
	if (tool_load_surface(c.lens, &s) < 0)
		return EXIT_FAILURE_RUN;
	asph_error_clear(&err);
	if (asph_points_read(c.points, &pts, &err) < 0) {
		tool_print_error(NULL, &err);
		return EXIT_FAILURE_RUN;
	}
	return fit_cli_run(&c, s, pts, NULL, NULL, NULL);
}
