/* SPDX-License-Identifier: GPL-3.0-or-later */
/* asph fit: best fit of measured points to the nominal surface. */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include <jansson.h>

#include "asph/characterize.h"
#include "asph/correction.h"
#include "asph/fit.h"
#include "asph/points.h"
#include "asph/scanfile.h"
#include "config.h"
#include "fileio.h"
#include "asph-tool.h"
#include "fit-report.h"
#include "fit-tool.h"
#include "fit-summary.h"
#include "fit-uncertainty.h"
#include "progress.h"
#include "quantity.h"
#include "util-mem.h"
#include "util-suggest.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_surface *, asph_surface_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

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
	OPT_OUT,
	OPT_FORMAT,
	OPT_UNITS,
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
		"POINTS_FILE ('-': stdin) is delimited text (comma, semicolon, tab or blank\n"
		"separated, header x,y,z with optional units, or three columns), PLY, JSON,\n"
		"X3P, SDF, Zygo MetroPro .dat or .datx, the format found from the content;\n"
		"maps become points with their invalid nodes left out (docs/characterization.md).\n"
		"Points on one line, or on lines through one point (a tactile profilometer's\n"
		"profiles; a header x,z), are fitted as line profiles.\n\n"
		"  --dof LIST          degrees of freedom, from tx,ty,tz (mm), rx,ry,rz (rad), R (mm),\n"
		"                      k (default tx,ty,tz,rx,ry); rz (clocking) for freeform\n"
		"                      surfaces, R and k for rotationally symmetric ones; R is\n"
		"                      fitted as its curvature c (1/mm; c is the same request),\n"
		"                      and null when c = 0 lies within U(c); one line profile:\n"
		"                      tx (along it), tz, ry, R, k (default tx,tz,ry)\n"
		"  --residual KIND     normal (default: distance along the surface normal) or sag\n"
		"                      (z minus the sag)\n"
		"  --robust            down-weight outliers (Tukey biweight) and leave them out\n"
		"  --zernike N         Zernike terms of the decomposition (default 36, max %d)\n"
		"  --residuals OUT     write x,y,z,residual_nm of the points fitted (.csv or .ply,\n"
		"                      PLY coloured by residual; .x3p: x, y and the residual as Z)\n"
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
		"  --grid-spacing MM   spacing of that grid (default: the median point spacing, at\n"
		"                      most 1000 nodes across the aperture)\n"
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
		POINTS_INPUT_HELP
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
static int take_option(int opt, const char *arg, void *data)
{
	struct fit_cli *c = data;
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
			const char *names[8];
			char known[64];
			size_t n = 0;
			while (n < ARRAY_SIZE(names) &&
			       (names[n] = asph_fit_residual_name((enum asph_fit_residual_kind)n)))
				n++;
			suggest_join(known, sizeof(known), names, n, " or ");
			fprintf(stderr, "asph fit: --residual: '%s' is not %s\n", arg, known);
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
		free(c->tolerance_json);
		c->tolerance_json = NULL;
		if (asph_tolerance_load_text(arg, &c->tolerance, &c->tolerance_json, &err) < 0) {
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
	case OPT_OUT:
		c->out_dir = arg;
		return 0;
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
	case OPT_FORMAT:
		return points_input_format(&c->input, "fit", arg);
	case OPT_UNITS:
		return points_input_units(&c->input, "fit", arg);
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

void fit_cli_release(struct fit_cli *c)
{
	free(c->tolerance_json);
	c->tolerance_json = NULL;
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
		{ "out", required_argument, NULL, OPT_OUT },
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
		{ "format", required_argument, NULL, OPT_FORMAT },
		{ "units", required_argument, NULL, OPT_UNITS },
		FIT_MC_LONGOPTS,
		{ "quiet", no_argument, NULL, 'q' },
		{ "help", no_argument, NULL, 'h' },
		{ NULL, 0, NULL, 0 },
	};
	/* getopt permutes: options may also follow LENS and POINTS_FILE. */
	int r = tool_getopt(argc, argv, "hq", longopts, usage_fn, take_option, c);

	if (r >= 0)
		return r == EXIT_OK ? -1 : r;
	/* asph replay: SCAN, or LENS and MEASURED */
	if (argc - optind != operands && !(operands == 1 && argc - optind == 2)) {
		fprintf(stderr, "asph %s: need %s (see --help)\n", argv[0],
			operands == 2 ? "LENS and POINTS_FILE" : "SCAN, or LENS and MEASURED");
		return EXIT_USAGE;
	}
	c->lens = argc - optind == 2 ? argv[optind] : NULL;
	c->points = argv[argc - 1];
	if (fit_mc_check(&c->mc) != EXIT_OK)
		return EXIT_USAGE;
	return check_tolerance(c);
}

static void show_bands(const struct fit_cli *c, const struct asph_characterize_result *res)
{
	const double v[] = { res->bands.form, res->bands.mid, res->bands.high, res->bands.total };
	static const char *const paths[] = { "band_rms.form_nm", "band_rms.mid_nm",
					     "band_rms.high_nm", "band_rms.total_nm" };
	char t[4][32];

	if (!res->bands_done)
		return;
	for (int i = 0; i < 4; i++)
		quantity_format(quantity_by_path(paths[i]), v[i], QUANTITY_UNIT, t[i], sizeof(t[i]));
	printf("Band-limited RMS (areal PSD, grid %g mm): form (> %g mm) %s, mid (%g..%g mm) %s, "
	       "high (< %g mm) %s, total %s\n", res->grid_spacing_mm, c->bands.form_mm, t[0],
	       c->bands.high_mm, c->bands.form_mm, t[1], c->bands.high_mm, t[2], t[3]);
}

/* --json (the summary asphd stores, byte for byte), or the text of
 * tools/fit-summary.c followed by more_text(). */
static int show(const struct fit_cli *c, const struct asph_characterization *ch,
		void (*more_text)(const struct asph_characterize_result *res))
{
	const struct asph_characterize_result *res = asph_characterize_result(ch);
	_cleanup_(json_decrefp) json_t *root = NULL;
	_cleanup_free_ char *text = NULL;

	if (asph_characterize_summary_json(ch, c->json ? 2 : 0, &text) < 0 ||
	    (!c->json && !(root = json_loads(text, 0, NULL)))) {
		fprintf(stderr, "asph fit: out of memory\n");
		return EXIT_FAILURE_RUN;
	}
	if (c->json) {
		puts(text);
		return EXIT_OK;
	}
	fit_summary_print(stdout, root, "");
	fit_summary_print_zernike(stdout, root, "");
	if (res->mc_done)
		fit_mc_show(&res->mc);
	show_bands(c, res);
	if (more_text)
		more_text(res);
	return EXIT_OK;
}

/* The outputs that need the residual map of the part. */
static unsigned outputs_of(const struct fit_cli *c)
{
	unsigned o = c->bands_given ? ASPH_CHARACTERIZE_BANDS : 0;

	if (c->x3p_out || c->correction_out || c->report_out || c->out_dir)
		o |= ASPH_CHARACTERIZE_MAP;
	return o;
}

/* The map an output needs: 0, or the exit code after saying why there is
 * none. */
static int need_map(const struct asph_characterization *ch, const char *what)
{
	const struct asph_characterize_result *res = asph_characterize_result(ch);

	if (res->scatter)
		return EXIT_OK;
	tool_print_error(what, &res->map_error);
	return EXIT_FAILURE_RUN;
}

/* --correction: a bad option names itself. */
static int write_correction(const struct fit_cli *c, const struct asph_characterization *ch)
{
	struct asph_error err;
	char where[192];

	asph_error_clear(&err);
	if (asph_characterize_write_correction(ch, c->correction_out, &c->correction, &err) == 0)
		return EXIT_OK;
	snprintf(where, sizeof(where), "fit: --correction%s%s", err.field[0] ? "-" : "", err.field);
	err.field[0] = '\0';
	tool_print_error(where, &err);
	return err.code == -EINVAL ? EXIT_USAGE : EXIT_FAILURE_RUN;
}

/* --x3p, --correction and --report. */
static int write_exports(const struct fit_cli *c, const struct asph_characterization *ch)
{
	struct asph_error err;
	int r;

	if (!c->x3p_out && !c->correction_out && !c->report_out)
		return EXIT_OK;
	r = need_map(ch, "fit: the residual map");
	if (r != EXIT_OK)
		return r;
	asph_error_clear(&err);
	if (c->x3p_out && asph_characterize_write_x3p(ch, c->x3p_out, &err) < 0) {
		tool_print_error("fit: --x3p", &err);
		return EXIT_FAILURE_RUN;
	}
	if (c->correction_out && (r = write_correction(c, ch)) != EXIT_OK)
		return r;
	if (c->report_out && asph_characterize_write_report(ch, c->report_out, &err) < 0) {
		tool_print_error("fit: --report", &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

static int write_outputs(const struct fit_cli *c, const struct asph_characterization *ch)
{
	struct asph_error err;
	char title[160];

	asph_error_clear(&err);
	if (c->residuals_out &&
	    asph_characterize_write_residuals(ch, c->residuals_out,
					      ASPH_CHARACTERIZE_FITTED_POINTS, &err) < 0) {
		tool_print_error("fit: --residuals", &err);
		return EXIT_FAILURE_RUN;
	}
	snprintf(title, sizeof(title), "%s: %s residual after the best fit",
		 asph_characterize_lens_name(ch), asph_fit_residual_name(c->opts.residual));
	if (c->map_out &&
	    asph_characterize_write_map(ch, c->map_out, title, ASPH_CHARACTERIZE_USED_POINTS,
					&err) < 0) {
		tool_print_error("fit: --map", &err);
		return EXIT_FAILURE_RUN;
	}
	return write_exports(c, ch);
}

/* --out DIR: the files asphd writes into a job's folder. */
static int write_folder(const struct fit_cli *c, const struct fit_input *in,
			const struct asph_characterization *ch)
{
	static const char software[] = "{\"asph\": \"" ASPH_VERSION "\", \"libasph\": \""
		ASPH_VERSION "\"}";
	const char *slash = strrchr(in->name, '/');
	struct asph_characterize_folder f = {
		.mode = 0666, .scan_file = slash ? slash + 1 : in->name, .software_json = software,
		.tolerance_json = c->tolerance_json,
	};
	_cleanup_close_ int fd = -1;
	struct asph_error err;

	asph_error_clear(&err);
	if (mkdir(c->out_dir, 0777) < 0 && errno != EEXIST) {
		asph_error_set(&err, -errno, "%s: cannot create: %s", c->out_dir, strerror(errno));
		goto fail;
	}
	fd = open(c->out_dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	if (fd < 0) {
		asph_error_set(&err, -errno, "%s: %s", c->out_dir, strerror(errno));
		goto fail;
	}
	if (asph_characterize_write_folder(ch, fd, &f, NULL, &err) == 0)
		return EXIT_OK;
fail:
	tool_print_error("replay: --out", &err);
	return EXIT_FAILURE_RUN;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_characterization *, asph_characterize_free)

/* The characterization the options ask for, the fit's progress on a
 * terminal: 0, or the exit code after saying why not. */
static int characterize(const struct fit_cli *c, const struct fit_input *in,
			struct fit_mc_run *mc, struct asph_characterization **out)
{
	struct asph_characterize_options o = {
		.fit = c->opts, .outputs = outputs_of(c), .grid_spacing_mm = c->grid_spacing,
		.bands = c->bands, .run = in->run,
	};
	const struct asph_scanfile *scan = in->scan ? in->scan : in->run.source;
	const char *scan_name = in->scan ? in->name : c->scan;
	struct progress p;
	struct asph_error err;
	int r = fit_mc_prepare(&c->mc, scan_name, scan ? scan->header.instrument : NULL, mc, &o);

	if (r != EXIT_OK)
		return r;
	progress_start(&p, "fit", "iterations", c->quiet);
	o.fit.progress = progress_hook(&p);
	mc->before = &p;
	asph_error_clear(&err);
	r = asph_characterize_alloc(in->surface, &o, out, &err);
	if (r == 0)
		r = in->scan ? asph_characterize_scan(*out, in->scan, in->name, &err)
			     : asph_characterize_points(*out, in->points, &err);
	progress_stop(&p);
	if (r < 0) {
		const struct asph_characterize_result *res = *out ? asph_characterize_result(*out)
								  : NULL;
		tool_print_error(res && res->uncertainty_failed ? "fit: --uncertainty" : in->name,
				 &err);
		return EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

/* What the options ask for and the characterization could not give:
 * the Monte Carlo (a fit that did not converge), the bands (no grid). */
static int check_asked(const struct fit_cli *c, const struct asph_characterize_result *res)
{
	if (c->mc.enabled && !res->fit.converged) {
		fprintf(stderr, "asph fit: the fit did not converge: %s\n", res->fit.reason);
		return EXIT_FAILURE_RUN;
	}
	if (c->bands_given && !res->bands_done) {
		tool_print_error("fit: --bands", &res->map_error);
		return res->map_error.code == -EINVAL ? EXIT_USAGE : EXIT_FAILURE_RUN;
	}
	return EXIT_OK;
}

/* The exit status: the fit converged, the part passed. */
static int exit_status(const struct asph_fit_result *res)
{
	if (!res->converged) {
		fprintf(stderr, "asph fit: the fit did not converge: %s\n", res->reason);
		return EXIT_FAILURE_RUN;
	}
	if (res->verdict.present && res->verdict.overall != ASPH_VERDICT_PASS)
		return res->verdict.overall == ASPH_VERDICT_FAIL ? EXIT_VERDICT_FAIL
								 : EXIT_VERDICT_UNDECIDED;
	return EXIT_OK;
}

int fit_cli_run(const struct fit_cli *c, const struct fit_input *in,
		void (*more_text)(const struct asph_characterize_result *res))
{
	_cleanup_(asph_characterize_freep) struct asph_characterization *ch = NULL;
	const struct asph_characterize_result *res;
	struct fit_mc_run mc = { 0 };
	int r = characterize(c, in, &mc, &ch);

	if (r != EXIT_OK)
		return r;
	res = asph_characterize_result(ch);
	r = check_asked(c, res);
	if (r != EXIT_OK)
		return r;
	r = show(c, ch, more_text);
	if (r != EXIT_OK)
		return r;
	r = write_outputs(c, ch);
	if (r == EXIT_OK && c->out_dir)
		r = write_folder(c, in, ch);
	return r == EXIT_OK ? exit_status(&res->fit) : r;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

int cmd_fit(int argc, char **argv)
{
	_cleanup_(asph_surface_freep) struct asph_surface *s = NULL;
	_cleanup_(asph_points_freep) struct asph_points *pts = NULL;
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *scan = NULL;
	_cleanup_free_ char *data = NULL;
	_cleanup_(fit_cli_release) struct fit_cli c = { 0 };
	struct fit_input in = { 0 };
	struct asph_error err;
	char user[256];
	int r = fit_cli_parse(&c, argc, argv, 2, usage);

	if (r != EXIT_OK)
		return r < 0 ? EXIT_OK : r;
	if (c.out_dir) {
		fprintf(stderr, "asph fit: --out goes with asph replay (SCAN, or LENS MEASURED)\n");
		return EXIT_USAGE;
	}
	if (tool_load_surface(c.lens, &s) < 0)
		return EXIT_FAILURE_RUN;
	if (points_input_read(&c.input, "fit", c.points, &pts) < 0)
		return EXIT_FAILURE_RUN;
	asph_error_clear(&err);
	/* --scan: its plan, instrument, job and times name the run */
	if (c.scan && asph_scanfile_read(c.scan, &scan, &err) < 0) {
		tool_print_error("fit: --scan", &err);
		return EXIT_FAILURE_RUN;
	}
	in = (struct fit_input){
		.surface = s, .points = pts, .name = c.points,
		.run = { .program = "asph " ASPH_VERSION, .source = scan,
			 .data_name = c.scan ? c.scan : c.points },
	};
	fit_report_run(&c, user, sizeof(user), &in.run);
	/* the report names and hashes the measured data */
	if (c.report_out &&
	    file_read_all(in.run.data_name, (size_t)1 << 31, &data, &in.run.data_len, &err) < 0) {
		tool_print_error("fit: --report", &err);
		return EXIT_FAILURE_RUN;
	}
	in.run.data = data;
	return fit_cli_run(&c, &in, NULL);
}
