/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Characterization, assembled once: drift correction, fit, form
 * quantities, slope and verdict (the fit's), the residual map, its PSD and
 * band-limited RMS, and the Monte Carlo through the caller's function.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/characterize.h"
#include "asph/drift.h"
#include "asph/prescription.h"
#include "characterize-internal.h"
#include "util-hash.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_mc *, asph_mc_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_psd2 *, asph_psd2_free)

static int check_options(const struct asph_characterize_options *o, struct asph_error *err)
{
	if (o->grid_spacing_mm < 0 || !isfinite(o->grid_spacing_mm))
		return asph_error_set(err, -EINVAL, "the grid spacing %g mm is not a length",
				      o->grid_spacing_mm);
	if ((o->outputs & ASPH_CHARACTERIZE_BANDS) &&
	    !(o->bands.high_mm > 0 && o->bands.form_mm > o->bands.high_mm &&
	      isfinite(o->bands.form_mm)))
		return asph_error_set(err, -EINVAL, "the bands need 0 < high (%g mm) < form (%g mm)",
				      o->bands.high_mm, o->bands.form_mm);
	if (o->uncertainty && !asph_uncertainty_model_is_empty(o->uncertainty) && !o->run_mc)
		return asph_error_set(err, -EINVAL, "an uncertainty model needs a Monte Carlo runner");
	return 0;
}

int asph_characterize_alloc(const struct asph_surface *s,
			    const struct asph_characterize_options *opts,
			    struct asph_characterization **out, struct asph_error *err)
{
	struct asph_characterization *c;
	int r = check_options(opts, err);

	if (r < 0)
		return r;
	c = calloc(1, sizeof(*c));
	if (!c)
		return asph_error_set(err, -ENOMEM, "out of memory");
	c->surface = s;
	c->opts = *opts;
	if (opts->run.data)
		sha256_hex(opts->run.data, opts->run.data_len, c->data_sha256);
	if (c->opts.outputs & ASPH_CHARACTERIZE_BANDS)
		c->opts.outputs |= ASPH_CHARACTERIZE_MAP;
	c->res.surface = s;
	*out = c;
	return 0;
}

void asph_characterize_free(struct asph_characterization *c)
{
	if (!c)
		return;
	asph_points_free(c->points);
	asph_fit_free(c->fit);
	asph_scatter_free(c->scatter);
	asph_grid_free(c->grid);
	asph_psd_free(c->psd);
	free(c->map_xy);
	free(c->map_nm);
	free(c->acquisition);
	free(c->prescription_json);
	free(c->plan_json);
	free(c->plan_choice_json);
	free(c->instrument_json);
	free(c->metadata_json);
	free(c->created);
	free(c);
}

const struct asph_characterize_result *
asph_characterize_result(const struct asph_characterization *c)
{
	return &c->res;
}

const char *asph_characterize_lens_name(const struct asph_characterization *c)
{
	return c->opts.run.lens_name ? c->opts.run.lens_name
				     : asph_surface_prescription(c->surface)->name;
}

/* ------------------------------------------------------------ the steps */

/* The Monte Carlo on the fitted points, its U and verdict into the fit's
 * result. Only on a converged fit, as its reference. */
static int uncertainty(struct asph_characterization *c, struct asph_error *err)
{
	const struct asph_characterize_options *o = &c->opts;
	_cleanup_(asph_mc_freep) struct asph_mc *mc = NULL;
	int r;

	if (!o->uncertainty || asph_uncertainty_model_is_empty(o->uncertainty) ||
	    !c->res.fit.converged)
		return 0;
	r = asph_mc_alloc(c->surface, c->points->xyz, c->points->n, &o->fit, &c->res.fit,
			  o->uncertainty, &o->mc, &mc, err);
	if (r == 0)
		r = o->run_mc(o->run_mc_data, mc, &c->res.mc, err);
	if (r < 0) {
		c->res.uncertainty_failed = 1;
		return r;
	}
	asph_mc_apply(&c->res.mc, o->fit.tolerance, &c->res.fit);
	c->res.mc_done = 1;
	return 0;
}

/* The grid's spacing: the options', else the points' median spacing, no
 * finer than the diameter / ASPH_CHARACTERIZE_GRID_NODES. */
static double grid_spacing(const struct asph_characterization *c, double radius)
{
	if (c->opts.grid_spacing_mm > 0)
		return c->opts.grid_spacing_mm;
	return fmax(asph_scatter_median_edge(c->scatter),
		    2 * radius / ASPH_CHARACTERIZE_GRID_NODES);
}

/* The used points as a map of the part, in arrays of its own: line
 * profiles, or points too sparse for an interpolant. */
static int residual_map_points(struct asph_characterization *c, struct asph_error *err)
{
	struct asph_characterize_result *res = &c->res;
	size_t n = res->fit.n_used;

	c->map_xy = malloc(2 * n * sizeof(double) + 1);
	c->map_nm = malloc(n * sizeof(double) + 1);
	if (!c->map_xy || !c->map_nm)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(c->map_xy, 2 * n * sizeof(double));
	mem_advise_huge(c->map_nm, n * sizeof(double));
	res->n_map = asph_fit_residual_map(c->fit, c->map_xy, c->map_nm);
	res->map_xy = c->map_xy;
	res->map_nm = c->map_nm;
	return 0;
}

/* The used points as a map of the part, its interpolant, the grid. Points
 * too sparse for a map, or a grid too fine to make (-EDOM, -EINVAL): the
 * error is kept in the result, which stands without them. */
static int residual_map(struct asph_characterization *c, struct asph_error *err)
{
	struct asph_characterize_result *res = &c->res;
	double radius = asph_surface_aperture_radius(c->surface);
	int r;

	asph_error_clear(&res->map_error);
	if (res->fit.profile) {
		asph_error_set(&res->map_error, -EDOM,
			       "the points are line profiles: they have no residual map of the "
			       "area (grid, PSD, correction table, report)");
		return residual_map_points(c, err);
	}
	/* the interpolant of the map, on the triangulation the fit's slope
	 * was computed on; the map's points are its copies */
	r = asph_fit_residual_scatter(c->fit, &c->scatter, &res->map_error);
	if (r == 0) {
		res->n_map = asph_scatter_n_points(c->scatter);
		res->map_xy = asph_scatter_xy(c->scatter);
		res->map_nm = asph_scatter_values(c->scatter);
		res->scatter = c->scatter;
		res->grid_spacing_mm = grid_spacing(c, radius);
		r = asph_grid_resample(c->scatter, radius, res->grid_spacing_mm, &c->grid,
				       &res->map_error);
	} else if (r == -EDOM || r == -EINVAL) {
		return residual_map_points(c, err);
	}
	if (r == -EDOM || r == -EINVAL)
		return 0;
	if (r < 0) {
		*err = res->map_error;
		return r;
	}
	res->grid = c->grid;
	return 0;
}

/* The radial PSD (asph_psd_residual()): none when the map has too few
 * samples for one. */
static int residual_psd(struct asph_characterization *c, struct asph_error *err)
{
	struct asph_error perr;
	int r;

	asph_error_clear(&perr);
	r = asph_psd_residual(c->scatter, asph_surface_aperture_radius(c->surface), &c->psd,
			      &perr);
	if (r == -EDOM || r == -EINVAL)
		return 0;
	if (r < 0) {
		*err = perr;
		return r;
	}
	c->res.psd = c->psd;
	return 0;
}

/* Band-limited RMS from the grid's areal PSD. */
static int band_rms(struct asph_characterization *c, struct asph_error *err)
{
	_cleanup_(asph_psd2_freep) struct asph_psd2 *p = NULL;
	int r = asph_psd_areal(c->grid, &p, err);

	if (r == 0)
		r = asph_band_rms(p, &c->opts.bands, &c->res.bands, err);
	if (r == 0)
		c->res.bands_done = 1;
	return r;
}

static int map_outputs(struct asph_characterization *c, struct asph_error *err)
{
	int r;

	if (!(c->opts.outputs & ASPH_CHARACTERIZE_MAP))
		return 0;
	r = residual_map(c, err);
	if (r < 0 || !c->grid)
		return r;
	r = residual_psd(c, err);
	if (r == 0 && (c->opts.outputs & ASPH_CHARACTERIZE_BANDS))
		r = band_rms(c, err);
	return r;
}

/* The fit, the map and the Monte Carlo of c->points. */
static int run(struct asph_characterization *c, struct asph_error *err)
{
	/* The result is taken once: the solver goes before the form
	 * quantities' triangulation, the fit's peak (docs/daemon.md,
	 * "Memory"); the Monte Carlo keeps c->opts.fit's own. */
	struct asph_fit_options once = c->opts.fit;
	once.release_solver = 1;
	int r = asph_fit_alloc(c->surface, c->points->n, &once, &c->fit, err);

	if (r == 0)
		r = asph_fit_run(c->fit, c->points->xyz, c->points->n, &c->res.fit, err);
	if (r < 0)
		return r;
	c->res.points = c->points;
	c->res.fit_workspace = c->fit;
	r = uncertainty(c, err);
	if (r == 0)
		r = map_outputs(c, err);
	return r;
}

static int once(struct asph_characterization *c, struct asph_error *err)
{
	if (c->done)
		return asph_error_set(err, -EINVAL, "a characterization runs once");
	c->done = 1;
	return 0;
}

/* ------------------------------------------------------------ the inputs */

/* The header's plan, less the record of how it was chosen, which asphd
 * keeps there ("for_tolerance": asph/plan-search.h's JSON) so that a
 * replay of the scan tells it as the job's result did. */
static int keep_plan(struct asph_characterization *c, const char *plan)
{
	json_t *p = json_loads(plan, 0, NULL), *choice = json_object_get(p, "for_tolerance");

	if (!json_is_object(choice)) {
		json_decref(p);
		c->plan_json = strdup(plan);
		return c->plan_json ? 0 : -ENOMEM;
	}
	c->plan_choice_json = json_dumps(choice, JSON_COMPACT);
	json_object_del(p, "for_tolerance");
	c->plan_json = json_dumps(p, JSON_COMPACT);
	json_decref(p);
	return c->plan_json && c->plan_choice_json ? 0 : -ENOMEM;
}

static int keep_header(struct asph_characterization *c, const struct asph_scanfile *s)
{
	const struct asph_scanfile_header *h = &s->header;

	c->prescription_json = strdup(h->prescription);
	if (h->plan && keep_plan(c, h->plan) < 0)
		return -ENOMEM;
	c->instrument_json = h->instrument ? strdup(h->instrument) : NULL;
	c->metadata_json = h->metadata ? strdup(h->metadata) : NULL;
	c->created = strdup(h->created ? h->created : "");
	c->created_ns = h->created_ns;
	c->ended_ns = s->report.ended_ns;
	if (!c->prescription_json ||
	    (h->instrument && !c->instrument_json) || (h->metadata && !c->metadata_json) ||
	    !c->created)
		return -ENOMEM;
	c->res.scan_points = s->n;
	c->res.scan_resumes = s->report.n_resumes;
	c->res.scan_completed = s->report.ended && s->report.outcome == ASPH_SCANFILE_COMPLETED;
	c->res.scan_outcome = asph_scanfile_outcome_name(s->report.ended ? s->report.outcome
									  : ASPH_SCANFILE_UNFINISHED);
	return 0;
}

/* What the characterization keeps of the scan: its header's descriptions,
 * the drift-corrected points and the acquisition's account. */
static int scan_points(struct asph_characterization *c, const struct asph_scanfile *scan,
		       const char *name, struct asph_error *err)
{
	struct asph_drift_summary sum;
	int r = once(c, err);

	if (r < 0)
		return r;
	c->from_scan = 1;
	if (keep_header(c, scan) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = asph_drift_scanfile_points(scan, name, 0, 0, &c->points, &sum, err);
	if (r < 0)
		return r;
	if (asph_drift_report_json(scan, &sum, 1, &c->acquisition) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	c->res.acquisition_json = c->acquisition;
	return 0;
}

int asph_characterize_scan(struct asph_characterization *c, const struct asph_scanfile *scan,
			   const char *name, struct asph_error *err)
{
	int r = scan_points(c, scan, name, err);

	return r < 0 ? r : run(c, err);
}

int asph_characterize_scan_take(struct asph_characterization *c, struct asph_scanfile **scan,
				const char *name, struct asph_error *err)
{
	int r = scan_points(c, *scan, name, err);

	asph_scanfile_free(*scan);
	*scan = NULL;
	return r < 0 ? r : run(c, err);
}

static struct asph_points *points_copy(const struct asph_points *p)
{
	struct asph_points *q = asph_points_alloc(p->n);

	if (q)
		memcpy(q->xyz, p->xyz, 3 * p->n * sizeof(double));
	return q;
}

int asph_characterize_points(struct asph_characterization *c, const struct asph_points *points,
			     struct asph_error *err)
{
	int r = once(c, err);

	if (r < 0)
		return r;
	if (c->opts.run.source && keep_header(c, c->opts.run.source) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");
	/* the lens is the surface fitted, whatever the source recorded */
	free(c->prescription_json);
	c->prescription_json = NULL;
	if (asph_prescription_to_json(asph_surface_prescription(c->surface),
				      &c->prescription_json) < 0 ||
	    !(c->points = points_copy(points)))
		return asph_error_set(err, -ENOMEM, "out of memory");
	return run(c, err);
}

/* --------------------------------------------------- what names the run */

const char *characterize_instrument(const struct asph_characterization *c)
{
	return c->instrument_json;
}

const char *characterize_plan(const struct asph_characterization *c)
{
	return c->plan_json;
}

const char *characterize_plan_choice(const struct asph_characterization *c)
{
	return c->plan_choice_json;
}

const char *characterize_metadata(const struct asph_characterization *c)
{
	return c->opts.run.metadata_json ? c->opts.run.metadata_json : c->metadata_json;
}

int64_t characterize_measured_ns(const struct asph_characterization *c)
{
	return c->opts.run.measured_ns ? c->opts.run.measured_ns : c->created_ns;
}

int64_t characterize_measured_end_ns(const struct asph_characterization *c)
{
	return c->opts.run.measured_ns ? 0 : c->ended_ns;
}

int64_t characterize_job(const struct asph_characterization *c)
{
	const char *text = characterize_metadata(c);
	_cleanup_(json_decrefp) json_t *m = text ? json_loads(text, 0, NULL) : NULL;

	return json_integer_value(json_object_get(m, "job"));
}
