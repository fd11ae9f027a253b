/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * lib/characterize: the one characterization against its pieces run by
 * hand (fit, drift correction, map, PSD, band-limited RMS, the Monte
 * Carlo), the part's pose and form error against what was injected, the
 * writers' files read back (the residual X3P, the result folder and its
 * hashes), Record2 of the X3P files, and bad use refused.
 */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>
#include <gsl/gsl_errno.h>
#include <jansson.h>
#include <nettle/sha2.h>
#include <zip.h>

#include "asph/characterize.h"
#include "asph/drift.h"
#include "asph/prescription.h"
#include "asph/x3p.h"
#include "rmtree.h"

static struct asph_surface *strong(void)
{
	struct asph_prescription p;
	struct asph_surface *s;

	assert_int_equal(asph_prescription_preset("strong", &p), 0);
	assert_int_equal(asph_surface_alloc(&p, &s, NULL), 0);
	return s;
}

/* n points evenly over 0.95 of the aperture (a Vogel spiral), measured
 * on a part with pose, astigmatism and trefoil (which no rigid motion
 * absorbs) and 2 nm noise. */
static const struct asph_synth_term terms[] = { { 5, 31.0 }, { 9, -17.0 } };
#define NOISE_NM 2.0

static struct asph_points *part(const struct asph_surface *s, size_t n,
				const struct asph_pose *pose)
{
	struct asph_points *p = asph_points_alloc(n);
	double a = 0.95 * asph_surface_aperture_radius(s);
	struct asph_synth_options so = { .pose = *pose, .terms = terms, .n_terms = 2,
					 .noise_nm = NOISE_NM, .seed = 11 };

	assert_non_null(p);
	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt((i + 0.5) / (double)n), t = 2.399963229728653 * (double)i;
		p->xyz[3 * i] = r * cos(t);
		p->xyz[3 * i + 1] = r * sin(t);
	}
	assert_int_equal(asph_fit_synthesize(s, p->xyz, n, &so, p->xyz, NULL), 0);
	return p;
}

static const struct asph_pose pose = { .t = { 0.013, -0.007, 0.021 }, .rx = 3.1e-4,
					.ry = -2.3e-4 };

static struct asph_characterization *characterize(const struct asph_surface *s,
						  const struct asph_characterize_options *o,
						  const struct asph_points *p)
{
	struct asph_characterization *c;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_characterize_alloc(s, o, &c, &err), 0);
	assert_int_equal(asph_characterize_points(c, p, &err), 0);
	return c;
}

/* The pipeline is its pieces: the fit, the map's grid at the default
 * spacing, the PSD and the band-limited RMS, each the same bits; and the
 * part comes back as it was made. */
static void test_points(void **state)
{
	struct asph_surface *s = strong();
	struct asph_points *p = part(s, 1500, &pose);
	struct asph_characterize_options o = {
		.outputs = ASPH_CHARACTERIZE_BANDS, .bands = { .form_mm = 4, .high_mm = 1 },
	};
	struct asph_characterization *c = characterize(s, &o, p);
	const struct asph_characterize_result *res = asph_characterize_result(c);
	double radius = asph_surface_aperture_radius(s);
	struct asph_fit *w;
	struct asph_fit_result fr;
	struct asph_scatter *sc, *sc2;
	struct asph_grid *g, *g2;
	struct asph_psd *psd;
	struct asph_psd2 *p2;
	struct asph_band_rms bands;
	double dx;

	assert_int_equal(asph_fit_alloc(s, p->n, NULL, &w, NULL), 0);
	assert_int_equal(asph_fit_run(w, p->xyz, p->n, &fr, NULL), 0);
	assert_true(res->fit.converged && res->fit.n_used == fr.n_used);
	assert_memory_equal(res->fit.value, fr.value, sizeof(fr.value));
	assert_true(res->fit.rms.v == fr.rms.v && res->fit.form.B.v == fr.form.B.v);
	assert_memory_equal(asph_fit_residuals(res->fit_workspace), asph_fit_residuals(w),
			    p->n * sizeof(double));
	/* the injected pose to well within the noise's reach, the RMS of the
	 * injected terms and noise: over the disc of radius b (0.95 of the
	 * aperture) Z5 = sqrt(6) rho^2 cos 2t has RMS b^2, Z9 = sqrt(8) rho^3
	 * sin 3t RMS b^3, within the sampling's 5 % */
	for (int k = 0; k < 3; k++)
		assert_true(fabs(res->fit.value[k] - pose.t[k]) < 1e-5);
	double b = 0.95;
	double want = hypot(hypot(31.0 * b * b, 17.0 * b * b * b), NOISE_NM);
	assert_true(fabs(res->fit.rms.v - want) < 0.05 * want);

	assert_int_equal(asph_fit_residual_scatter(w, &sc, NULL), 0);
	dx = fmax(asph_scatter_median_edge(sc), 2 * radius / ASPH_CHARACTERIZE_GRID_NODES);
	assert_true(res->grid_spacing_mm == dx);
	assert_int_equal(asph_grid_resample(sc, radius, dx, &g, NULL), 0);
	assert_true(res->grid->nx == g->nx && res->grid->ny == g->ny);
	assert_memory_equal(res->grid->z, g->z, g->nx * g->ny * sizeof(double));
	assert_int_equal(asph_psd_residual(sc, radius, &psd, NULL), 0);
	assert_true(res->psd->n == psd->n && res->psd->df == psd->df);
	assert_memory_equal(res->psd->psd, psd->psd, psd->n * sizeof(double));
	assert_int_equal(asph_psd_areal(g, &p2, NULL), 0);
	assert_int_equal(asph_band_rms(p2, &o.bands, &bands, NULL), 0);
	assert_true(res->bands_done && res->bands.form == bands.form &&
		    res->bands.mid == bands.mid && res->bands.high == bands.high &&
		    res->bands.total == bands.total);
	assert_int_equal((int)res->n_map, (int)fr.n_used);
	/* the first call handed on the slope's triangulation with the map's
	 * values; a second one triangulates the map anew, to the same
	 * interpolant */
	assert_int_equal(asph_fit_residual_scatter(w, &sc2, NULL), 0);
	assert_true(sc2 != sc && asph_scatter_n_points(sc2) == asph_scatter_n_points(sc));
	assert_memory_equal(asph_scatter_xy(sc2), asph_scatter_xy(sc),
			    2 * fr.n_used * sizeof(double));
	assert_memory_equal(asph_scatter_values(sc2), asph_scatter_values(sc),
			    fr.n_used * sizeof(double));
	assert_int_equal(asph_grid_resample(sc2, radius, dx, &g2, NULL), 0);
	assert_memory_equal(g2->z, g->z, g->nx * g->ny * sizeof(double));
	asph_grid_free(g2);
	asph_scatter_free(sc2);
	assert_null(res->acquisition_json);
	assert_false(res->mc_done);

	asph_psd2_free(p2);
	asph_psd_free(psd);
	asph_grid_free(g);
	asph_scatter_free(sc);
	asph_fit_free(w);
	asph_characterize_free(c);
	asph_points_free(p);
	asph_surface_free(s);
}

/* The summary: asph_fit_result_to_json()'s keys and bytes, then the
 * band-limited RMS; its lens is the run's, else the prescription's. */
static void test_summary(void **state)
{
	struct asph_surface *s = strong();
	struct asph_points *p = part(s, 400, &pose);
	struct asph_characterize_options o = { .run = { .lens_name = "lens 7" } };
	struct asph_characterization *c = characterize(s, &o, p);
	char *text, *fit;
	json_t *j;

	assert_int_equal(asph_characterize_summary_json(c, 0, &text), 0);
	assert_int_equal(asph_fit_result_to_json(&asph_characterize_result(c)->fit, "lens 7", 0,
						 &fit), 0);
	assert_string_equal(text, fit);
	free(text);
	free(fit);
	asph_characterize_free(c);

	o = (struct asph_characterize_options){
		.outputs = ASPH_CHARACTERIZE_BANDS, .bands = { .form_mm = 4, .high_mm = 1 },
	};
	c = characterize(s, &o, p);
	assert_string_equal(asph_characterize_lens_name(c), "strong");
	assert_int_equal(asph_characterize_summary_json(c, 2, &text), 0);
	assert_non_null(strchr(text, '\n'));
	j = json_loads(text, 0, NULL);
	assert_non_null(j);
	assert_string_equal(json_string_value(json_object_get(j, "lens")), "strong");
	json_t *b = json_object_get(j, "band_rms");
	assert_true(json_real_value(json_object_get(b, "total_nm")) ==
		    asph_characterize_result(c)->bands.total);
	assert_null(json_object_get(j, "acquisition"));
	json_decref(j);
	free(text);
	asph_characterize_free(c);
	asph_points_free(p);
	asph_surface_free(s);
}

/* ---------------------------------------------------------------- scans */

static const double drift_rate = 2.9e-6;   /* mm/s along z */

/* A scan of the part (no pose, no form error) drifting along z, with the
 * vertex as its reference measured in three rounds; header as a job's. */
static struct asph_scanfile *drifting_scan(const struct asph_surface *s, size_t n)
{
	static const double rounds[] = { 0, 40.3, 81.1 };
	struct asph_scanfile *f = calloc(1, sizeof(*f));
	double a = 0.9 * asph_surface_aperture_radius(s);

	assert_non_null(f);
	assert_int_equal(asph_prescription_to_json(asph_surface_prescription(s),
						   &f->header.prescription), 0);
	f->header.plan = strdup("{\"method\":\"spiral\"}");
	f->header.instrument = strdup("{\"name\":\"bench 2\",\"stage\":{\"driver\":\"can\","
				      "\"version\":\"1.3\",\"options\":{}},\"probe\":{\"driver\":"
				      "\"usb\",\"version\":\"0.9\",\"options\":{\"probe\":\"tactile\","
				      "\"serial\":\"AB12\"}}}");
	f->header.metadata = strdup("{\"job\":42,\"submitted_by\":{\"uid\":0,\"name\":\"ada\"}}");
	f->header.created = strdup("2026-03-04T05:06:07.5Z");
	f->header.created_ns = 1772600767500000000;
	f->n = n;
	f->points = calloc(n, sizeof(*f->points));
	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt((i + 0.5) / (double)n), t = 2.399963229728653 * (double)i;
		double time = 0.05 * (double)i;
		struct asph_scanfile_point *q = &f->points[i];
		q->plan_index = i;
		q->x = r * cos(t);
		q->y = r * sin(t);
		q->z = asph_surface_sag(s, r) + drift_rate * time;
		q->t_ns = (uint64_t)llround(time * 1e9);
		q->position_source = ASPH_SCANFILE_POSITION_LATCHED;
	}
	f->n_references = 3;
	f->references = calloc(3, sizeof(*f->references));
	for (size_t k = 0; k < 3; k++)
		f->references[k] = (struct asph_scanfile_point){
			.z = drift_rate * rounds[k], .t_ns = (uint64_t)llround(rounds[k] * 1e9),
		};
	f->report.ended = true;
	f->report.outcome = ASPH_SCANFILE_COMPLETED;
	f->report.n_resumes = 1;
	return f;
}

/* A scan: the points drift-corrected as asph_drift_scanfile_points()
 * makes them, the acquisition's account, the header's names kept after
 * the scan is freed. */
static void test_scan(void **state)
{
	struct asph_surface *s = strong();
	struct asph_scanfile *f = drifting_scan(s, 1600);
	struct asph_characterize_options o = { .fit.dof = ASPH_FIT_DOF_BIT(ASPH_FIT_TZ) };
	struct asph_characterization *c;
	struct asph_points *p;
	struct asph_drift_summary sum;
	char *acq;
	struct asph_error err;

	asph_error_clear(&err);
	assert_int_equal(asph_characterize_alloc(s, &o, &c, &err), 0);
	assert_int_equal(asph_characterize_scan(c, f, "drifting", &err), 0);
	assert_int_equal(asph_drift_scanfile_points(f, "drifting", 0, 0, &p, &sum, NULL), 0);
	assert_int_equal(asph_drift_report_json(f, &sum, 1, &acq), 0);
	const struct asph_characterize_result *res = asph_characterize_result(c);
	assert_int_equal((int)res->points->n, (int)p->n);
	assert_memory_equal(res->points->xyz, p->xyz, 3 * p->n * sizeof(double));
	assert_string_equal(res->acquisition_json, acq);
	/* the drift, linear between the rounds and held after the last, is
	 * taken out: the part lies where it was made */
	assert_true(res->fit.converged);
	assert_true(fabs(res->fit.value[ASPH_FIT_TZ]) < 1e-9);
	assert_true(res->fit.rms.v < 1e-3);
	assert_int_equal((int)res->scan_points, 1600);
	assert_int_equal((int)res->scan_resumes, 1);
	assert_true(res->scan_completed);
	assert_string_equal(res->scan_outcome, "completed");
	asph_scanfile_free(f);
	/* what the writers name outlives the scan */
	char *text;
	assert_int_equal(asph_characterize_summary_json(c, 0, &text), 0);
	json_t *j = json_loads(text, 0, NULL);
	assert_true(json_is_true(json_object_get(json_object_get(json_object_get(j, "acquisition"),
								  "drift"), "corrected")));
	json_decref(j);
	free(text);
	/* a characterization runs once */
	assert_int_equal(asph_characterize_points(c, p, &err), -EINVAL);
	free(acq);
	asph_points_free(p);
	asph_characterize_free(c);
	asph_surface_free(s);
}

/* asph_characterize_scan_take(): the same result as
 * asph_characterize_scan() with the scan freed before the fit, also when
 * it refuses; the map held once, by its interpolant. */
static void test_scan_take(void **state)
{
	struct asph_surface *s = strong();
	struct asph_scanfile *f = drifting_scan(s, 1600);
	struct asph_scanfile *g = drifting_scan(s, 1600);
	struct asph_characterize_options o = { .outputs = ASPH_CHARACTERIZE_MAP };
	struct asph_characterization *c, *t;
	char *kept, *taken;

	assert_int_equal(asph_characterize_alloc(s, &o, &c, NULL), 0);
	assert_int_equal(asph_characterize_alloc(s, &o, &t, NULL), 0);
	assert_int_equal(asph_characterize_scan(c, f, "scan", NULL), 0);
	assert_int_equal(asph_characterize_scan_take(t, &g, "scan", NULL), 0);
	assert_null(g);
	assert_int_equal(asph_characterize_summary_json(c, 0, &kept), 0);
	assert_int_equal(asph_characterize_summary_json(t, 0, &taken), 0);
	assert_string_equal(kept, taken);
	const struct asph_characterize_result *a = asph_characterize_result(c);
	const struct asph_characterize_result *b = asph_characterize_result(t);
	assert_non_null(b->scatter);
	assert_int_equal((int)a->n_map, (int)b->n_map);
	assert_true(b->map_xy == asph_scatter_xy(b->scatter));
	assert_true(b->map_nm == asph_scatter_values(b->scatter));
	assert_memory_equal(a->map_xy, b->map_xy, 2 * a->n_map * sizeof(double));
	assert_memory_equal(a->map_nm, b->map_nm, a->n_map * sizeof(double));
	/* a characterization runs once: the scan is freed all the same */
	g = drifting_scan(s, 100);
	assert_int_equal(asph_characterize_scan_take(t, &g, "scan", NULL), -EINVAL);
	assert_null(g);
	free(kept);
	free(taken);
	asph_scanfile_free(f);
	asph_characterize_free(c);
	asph_characterize_free(t);
	asph_surface_free(s);
}

/* ---------------------------------------------------------- Monte Carlo */

struct mc_call {
	int calls;
	int fail;
};

/* The trials on this thread, through the library's pieces. */
static int run_serial(void *data, struct asph_mc *mc, struct asph_mc_result *out,
		      struct asph_error *err)
{
	struct mc_call *call = data;
	struct asph_mc_worker *w;
	size_t done = 0, first, count;

	call->calls++;
	if (call->fail)
		return asph_error_set(err, -ECANCELED, "stopped");
	assert_int_equal(asph_mc_worker_alloc(mc, &w, err), 0);
	while (asph_mc_next_block(mc, done, &first, &count)) {
		assert_int_equal(asph_mc_run_trials(mc, w, first, count), 0);
		done = first + count;
	}
	asph_mc_worker_free(w);
	return asph_mc_finish(mc, done, 0, out, err);
}

/* The Monte Carlo through the caller's function: the same U as run by
 * hand, the verdict decided with it; not run on a fit that did not
 * converge; its failure said to be its own. */
static void test_uncertainty(void **state)
{
	struct asph_surface *s = strong();
	struct asph_points *p = part(s, 300, &pose);
	struct asph_uncertainty_model m;
	struct asph_tolerance t;
	struct mc_call call = { 0 };
	struct asph_characterize_options o = {
		.uncertainty = &m, .mc = { .n_trials = 20, .fixed = 1, .seed = 5 },
		.run_mc = run_serial, .run_mc_data = &call,
	};
	struct asph_characterization *c;
	struct asph_fit *w;
	struct asph_fit_result ref;
	struct asph_mc *mc;
	struct asph_mc_result mr;
	struct mc_call by_hand = { 0 };
	struct asph_error err;

	asph_uncertainty_model_init(&m);
	m.probe_noise_nm = 4;
	static const char tol[] = "{\"rms_nm\": {\"t\": 1000}}";
	assert_int_equal(asph_tolerance_parse_json(tol, strlen(tol), "t", &t, NULL), 0);
	o.fit.tolerance = &t;
	c = characterize(s, &o, p);
	const struct asph_characterize_result *res = asph_characterize_result(c);
	assert_int_equal(call.calls, 1);
	assert_true(res->mc_done && res->mc.n_trials == 20);
	assert_int_equal(res->fit.uncertainty_k2.method, ASPH_UNCERTAINTY_MONTE_CARLO);

	o.fit.tolerance = &t;
	assert_int_equal(asph_fit_alloc(s, p->n, &o.fit, &w, NULL), 0);
	assert_int_equal(asph_fit_run(w, p->xyz, p->n, &ref, NULL), 0);
	assert_int_equal(asph_mc_alloc(s, p->xyz, p->n, &o.fit, &ref, &m, &o.mc, &mc, NULL), 0);
	assert_int_equal(run_serial(&by_hand, mc, &mr, NULL), 0);
	asph_mc_apply(&mr, &t, &ref);
	assert_memory_equal(res->mc.U, mr.U, sizeof(mr.U));
	assert_true(res->fit.uncertainty_k2.rms_t.v == ref.uncertainty_k2.rms_t.v);
	assert_true(res->fit.verdict.present && res->fit.verdict.overall == ref.verdict.overall);
	asph_mc_free(mc);
	asph_fit_free(w);
	asph_characterize_free(c);

	/* a fit that has not converged is no reference: no trials */
	call.calls = 0;
	o.fit.max_iterations = 1;
	c = characterize(s, &o, p);
	assert_false(asph_characterize_result(c)->fit.converged);
	assert_int_equal(call.calls, 0);
	assert_false(asph_characterize_result(c)->mc_done);
	asph_characterize_free(c);

	/* the runner's error is the characterization's, marked as its own */
	o.fit.max_iterations = 0;
	call.fail = 1;
	asph_error_clear(&err);
	assert_int_equal(asph_characterize_alloc(s, &o, &c, &err), 0);
	assert_int_equal(asph_characterize_points(c, p, &err), -ECANCELED);
	assert_true(asph_characterize_result(c)->uncertainty_failed);
	asph_characterize_free(c);
	asph_points_free(p);
	asph_surface_free(s);
}

/* ------------------------------------------------------------- the map */

/* A grid too fine to make: the fit stands, the map's error is kept for
 * the outputs that need the grid, the interpolant serves the others. */
static void test_map_error(void **state)
{
	struct asph_surface *s = strong();
	struct asph_points *p = part(s, 300, &pose);
	struct asph_characterize_options o = {
		.outputs = ASPH_CHARACTERIZE_BANDS, .bands = { .form_mm = 4, .high_mm = 1 },
		.grid_spacing_mm = 1e-5,
	};
	struct asph_characterization *c = characterize(s, &o, p);
	const struct asph_characterize_result *res = asph_characterize_result(c);
	struct asph_error err;
	char path[64] = "/tmp/asph-char-XXXXXX";

	assert_true(res->fit.converged);
	assert_non_null(res->scatter);
	assert_null(res->grid);
	assert_false(res->bands_done);
	assert_int_equal(res->map_error.code, -EINVAL);
	assert_non_null(mkdtemp(path));
	strcat(path, "/g.x3p");
	asph_error_clear(&err);
	assert_int_equal(asph_characterize_write_x3p(c, path, &err), -EINVAL);
	assert_string_equal(err.message, res->map_error.message);
	*strrchr(path, '/') = '\0';
	assert_int_equal(rmtree(path), 0);
	asph_characterize_free(c);

	/* nothing asked for: no map */
	c = characterize(s, &(struct asph_characterize_options){ 0 }, p);
	assert_null(asph_characterize_result(c)->scatter);
	assert_int_equal(asph_characterize_write_x3p(c, "/nonexistent/x.x3p", NULL), -EINVAL);
	asph_characterize_free(c);
	asph_points_free(p);
	asph_surface_free(s);
}

/* ------------------------------------------------------------- writers */

static void *zip_member(const char *path, const char *name, size_t *len)
{
	zip_t *z = zip_open(path, ZIP_RDONLY, NULL);
	zip_stat_t st;
	zip_file_t *f;
	char *buf;

	assert_non_null(z);
	assert_int_equal(zip_stat(z, name, 0, &st), 0);
	buf = calloc(1, st.size + 1);
	f = zip_fopen(z, name, 0);
	assert_non_null(f);
	assert_int_equal(zip_fread(f, buf, st.size), (zip_int64_t)st.size);
	zip_fclose(f);
	zip_close(z);
	*len = st.size;
	return buf;
}

static double le_double(const uint8_t *b)
{
	uint64_t u = 0;
	double v;

	for (int i = 7; i >= 0; i--)
		u = u << 8 | b[i];
	memcpy(&v, &u, sizeof(v));
	return v;
}

static void expect_element(const char *xml, const char *tag, const char *want)
{
	char open[64], close[64];
	const char *a, *b;

	snprintf(open, sizeof(open), "<%s>", tag);
	snprintf(close, sizeof(close), "</%s>", tag);
	a = strstr(xml, open);
	assert_non_null(a);
	a += strlen(open);
	b = strstr(a, close);
	assert_non_null(b);
	assert_int_equal((int)(b - a), (int)strlen(want));
	assert_memory_equal(a, want, strlen(want));
}

/* The residual points of each set, and --residuals x.x3p: the points'
 * x, y and residual as z, with Record2 naming the scan's instrument and
 * tactile probe, the program and the time of the measurement. */
static void test_residual_files(void **state)
{
	struct asph_surface *s = strong();
	struct asph_scanfile *f = drifting_scan(s, 900);
	/* two points far off the surface: outliers of the robust fit */
	f->points[100].z += 0.004;
	f->points[500].z -= 0.004;
	struct asph_characterize_options o = { .fit.robust = 1,
					       .run = { .program = "test 1.0" } };
	struct asph_characterization *c;
	struct asph_points *all, *fitted, *used;
	char dir[] = "/tmp/asph-char-XXXXXX", path[64];
	size_t len;

	assert_int_equal(asph_characterize_alloc(s, &o, &c, NULL), 0);
	assert_int_equal(asph_characterize_scan(c, f, "scan", NULL), 0);
	const struct asph_characterize_result *res = asph_characterize_result(c);
	assert_int_equal(asph_characterize_residual_points(c, ASPH_CHARACTERIZE_ALL_POINTS, &all,
							   NULL), 0);
	assert_int_equal(asph_characterize_residual_points(c, ASPH_CHARACTERIZE_FITTED_POINTS,
							   &fitted, NULL), 0);
	assert_int_equal(asph_characterize_residual_points(c, ASPH_CHARACTERIZE_USED_POINTS, &used,
							   NULL), 0);
	assert_int_equal((int)all->n, 900);
	assert_int_equal((int)fitted->n, (int)(res->fit.n_used + res->fit.n_outliers));
	assert_int_equal((int)used->n, (int)res->fit.n_used);
	assert_true(res->fit.n_outliers >= 2);
	/* 4 um along z, less along the normal where the surface slopes */
	assert_true(all->value[100] > 1000 && all->value[100] < 4001);
	assert_true(all->value[500] < -1000 && all->value[500] > -4001);

	assert_non_null(mkdtemp(dir));
	snprintf(path, sizeof(path), "%s/r.x3p", dir);
	assert_int_equal(asph_characterize_write_residuals(c, path,
							   ASPH_CHARACTERIZE_FITTED_POINTS, NULL), 0);
	uint8_t *data = zip_member(path, "bindata/data.bin", &len);
	assert_int_equal((int)len, (int)(24 * fitted->n));
	for (size_t i = 0; i < fitted->n; i++) {
		assert_true(le_double(data + 24 * i) == fitted->xyz[3 * i] / 1000);
		assert_true(le_double(data + 24 * i + 8) == fitted->xyz[3 * i + 1] / 1000);
		assert_true(fabs(le_double(data + 24 * i + 16) - fitted->value[i] * 1e-9) <=
			    1e-15 * fabs(fitted->value[i] * 1e-9));
	}
	free(data);
	char *xml = zip_member(path, "main.xml", &len);
	expect_element(xml, "Creator", "test 1.0");
	expect_element(xml, "Date", "2026-03-04T05:06:07.500+00:00");
	expect_element(xml, "Manufacturer", "-");
	expect_element(xml, "Model", "bench 2");
	expect_element(xml, "Version", "stage can 1.3, probe usb 0.9");
	expect_element(xml, "Type", "Contacting");
	expect_element(xml, "Identification", "usb 0.9, serial AB12");
	free(xml);

	/* CSV: the same numbers */
	snprintf(path, sizeof(path), "%s/r.csv", dir);
	assert_int_equal(asph_characterize_write_residuals(c, path, ASPH_CHARACTERIZE_USED_POINTS,
							   NULL), 0);
	struct asph_points *back;
	assert_int_equal(asph_points_read(path, &back, NULL), 0);
	assert_int_equal((int)back->n, (int)used->n);
	assert_memory_equal(back->value, used->value, used->n * sizeof(double));
	asph_points_free(back);
	assert_int_equal(rmtree(dir), 0);

	asph_points_free(all);
	asph_points_free(fitted);
	asph_points_free(used);
	asph_scanfile_free(f);
	asph_characterize_free(c);
	asph_surface_free(s);
}

/* An instrument the X3P writer cannot name (not JSON, no name): the
 * defaults of computed data, and the file is written all the same. */
static void test_x3p_unnamed_instrument(void **state)
{
	static const char *const bad[] = { "not json", "[1, 2]", "{}", "{\"name\": 7}" };
	struct asph_grid *g = asph_grid_alloc(3, 2);
	char dir[] = "/tmp/asph-char-XXXXXX", path[64];
	size_t len;

	assert_non_null(g);
	g->dx = 0.5;
	for (size_t i = 0; i < 6; i++)
		g->z[i] = (double)i;
	assert_non_null(mkdtemp(dir));
	snprintf(path, sizeof(path), "%s/g.x3p", dir);
	for (size_t k = 0; k < sizeof(bad) / sizeof(bad[0]); k++) {
		struct asph_x3p_info info = { .instrument_json = bad[k] };
		assert_int_equal(asph_x3p_write_grid(path, g, &info, NULL), 0);
		char *xml = zip_member(path, "main.xml", &len);
		expect_element(xml, "Manufacturer", "asphd");
		expect_element(xml, "Type", "Software");
		free(xml);
	}
	assert_int_equal(rmtree(dir), 0);
	asph_grid_free(g);
}

static void sha256_file(int dir_fd, const char *name, char hex[65])
{
	int fd = openat(dir_fd, name, O_RDONLY);
	uint8_t buf[4096], d[SHA256_DIGEST_SIZE];
	struct sha256_ctx h;
	ssize_t n;

	assert_true(fd >= 0);
	sha256_init(&h);
	while ((n = read(fd, buf, sizeof(buf))) > 0)
		sha256_update(&h, (size_t)n, buf);
	close(fd);
	sha256_digest(&h, sizeof(d), d);
	for (int i = 0; i < SHA256_DIGEST_SIZE; i++)
		snprintf(hex + 2 * i, 3, "%02x", d[i]);
}

/* The result folder of a scan: the files listed and present, their
 * hashes the files', the summary, the job and the provenance from the
 * scan; and a folder refused for points. */
static void test_folder(void **state)
{
	struct asph_surface *s = strong();
	struct asph_scanfile *f = drifting_scan(s, 900);
	static const char bytes[] = "the scan's bytes";
	struct asph_characterize_options o = {
		.outputs = ASPH_CHARACTERIZE_MAP,
		.run = { .program = "test 1.0", .data = bytes, .data_len = sizeof(bytes) - 1 },
	};
	const struct asph_characterize_folder folder = {
		.mode = 0600, .scan_file = "scan.asphscan", .software_json = "{\"test\": \"1.0\"}",
		.tolerance_json = "{\"rms_nm\": 5}", .finished_ns = 1772600800000000000,
	};
	struct asph_characterization *c;
	char dir[] = "/tmp/asph-char-XXXXXX", hex[65], *text;
	struct asph_error err;
	const char *key;
	json_t *v;

	assert_int_equal(asph_characterize_alloc(s, &o, &c, NULL), 0);
	assert_int_equal(asph_characterize_scan(c, f, "scan", NULL), 0);
	assert_non_null(mkdtemp(dir));
	int fd = open(dir, O_RDONLY | O_DIRECTORY);
	asph_error_clear(&err);
	assert_int_equal(asph_characterize_write_folder(c, fd, &folder, &text, &err), 0);
	json_t *r = json_loads(text, 0, NULL);
	assert_non_null(r);
	assert_int_equal(json_integer_value(json_object_get(r, "job")), 42);
	json_t *files = json_object_get(r, "files"), *hashes = json_object_get(r, "hashes");
	assert_string_equal(json_string_value(json_object_get(files, "x3p")), "residual.x3p");
	assert_string_equal(json_string_value(json_object_get(files, "psd")), "psd.csv");
	json_object_foreach(files, key, v) {
		const char *name = json_string_value(v);
		if (!strcmp(key, "result") || !strcmp(key, "scan"))
			continue;
		sha256_file(fd, name, hex);
		assert_string_equal(json_string_value(json_object_get(hashes, name)), hex);
	}
	/* the scan's hash is that of the bytes the run names */
	struct sha256_ctx h;
	uint8_t d[SHA256_DIGEST_SIZE];
	sha256_init(&h);
	sha256_update(&h, sizeof(bytes) - 1, (const uint8_t *)bytes);
	sha256_digest(&h, sizeof(d), d);
	for (int i = 0; i < SHA256_DIGEST_SIZE; i++)
		snprintf(hex + 2 * i, 3, "%02x", d[i]);
	assert_string_equal(json_string_value(json_object_get(hashes, "scan.asphscan")), hex);
	json_t *prov = json_object_get(r, "provenance");
	assert_string_equal(json_string_value(json_object_get(prov, "finished")),
			    "2026-03-04T05:06:40Z");
	assert_string_equal(json_string_value(json_object_get(
				    json_object_get(prov, "submitted_by"), "name")), "ada");
	assert_string_equal(json_string_value(json_object_get(
				    json_object_get(prov, "instrument"), "name")), "bench 2");
	assert_string_equal(json_string_value(json_object_get(
				    json_object_get(prov, "fit_options"), "dof")), "tx,ty,tz,rx,ry");
	assert_true(json_number_value(json_object_get(json_object_get(prov, "tolerance"),
						      "rms_nm")) == 5);
	assert_string_equal(json_string_value(json_object_get(json_object_get(prov, "scan"),
							      "sha256")), hex);
	/* result.json holds what was returned */
	char *file = NULL;
	int rfd = openat(fd, "result.json", O_RDONLY);
	size_t n = strlen(text);
	file = calloc(1, n + 2);
	assert_int_equal((int)read(rfd, file, n + 1), (int)n);
	close(rfd);
	assert_string_equal(file, text);
	free(file);
	json_decref(r);
	free(text);
	asph_characterize_free(c);

	/* points read from a file with their data: measured data, no plan */
	struct asph_points *p = part(s, 200, &pose);
	const struct asph_characterize_folder measured = {
		.mode = 0600, .scan_file = "measured.txt", .software_json = "{}",
		.tolerance_json = "{}", .finished_ns = 1772600800000000000,
	};
	/* a folder of its own: the scan's files are in dir already */
	assert_int_equal(mkdirat(fd, "measured", 0700), 0);
	int mfd = openat(fd, "measured", O_RDONLY | O_DIRECTORY);
	assert_true(mfd >= 0);
	c = characterize(s, &o, p);
	assert_int_equal(asph_characterize_write_folder(c, mfd, &measured, &text, NULL), 0);
	r = json_loads(text, 0, NULL);
	assert_non_null(r);
	files = json_object_get(r, "files");
	prov = json_object_get(r, "provenance");
	assert_string_equal(json_string_value(json_object_get(files, "measured")),
			    "measured.txt");
	assert_null(json_object_get(files, "scan"));
	assert_null(json_object_get(prov, "scan"));
	assert_true(json_is_null(json_object_get(prov, "plan")) ||
		    !json_object_get(prov, "plan"));
	assert_int_equal(json_integer_value(json_object_get(json_object_get(prov, "measured"),
							    "points")), 200);
	assert_string_equal(json_string_value(json_object_get(json_object_get(prov, "measured"),
							      "sha256")), hex);
	json_decref(r);
	free(text);
	asph_characterize_free(c);

	/* points without the bytes they were read from make no folder */
	struct asph_characterize_options bare = o;
	bare.run.data = NULL;
	bare.run.data_len = 0;
	c = characterize(s, &bare, p);
	assert_int_equal(asph_characterize_write_folder(c, mfd, &measured, NULL, NULL), -EINVAL);
	asph_characterize_free(c);
	close(mfd);
	asph_points_free(p);
	close(fd);
	assert_int_equal(rmtree(dir), 0);
	asph_scanfile_free(f);
	asph_surface_free(s);
}

static void test_bad_options(void **state)
{
	struct asph_surface *s = strong();
	struct asph_uncertainty_model m;
	struct asph_characterization *c = NULL;
	struct asph_error err;
	const struct asph_characterize_options bad[] = {
		{ .grid_spacing_mm = -1 },
		{ .grid_spacing_mm = NAN },
		{ .outputs = ASPH_CHARACTERIZE_BANDS, .bands = { .form_mm = 1, .high_mm = 2 } },
		{ .outputs = ASPH_CHARACTERIZE_BANDS },
		{ .uncertainty = &m },
	};

	asph_uncertainty_model_init(&m);
	m.probe_noise_nm = 1;
	for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
		asph_error_clear(&err);
		assert_int_equal(asph_characterize_alloc(s, &bad[i], &c, &err), -EINVAL);
		assert_true(err.message[0] != '\0');
		assert_null(c);
	}
	/* nothing characterized: nothing to write */
	char *text;
	assert_int_equal(asph_characterize_alloc(s, &(struct asph_characterize_options){ 0 }, &c,
						 NULL), 0);
	assert_int_equal(asph_characterize_summary_json(c, 0, &text), -EINVAL);
	assert_null(text);
	assert_int_equal(asph_characterize_write_residuals(c, "/nonexistent/r.csv",
							   ASPH_CHARACTERIZE_ALL_POINTS, &err),
			 -EINVAL);
	asph_characterize_free(c);
	asph_surface_free(s);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_points),
		cmocka_unit_test(test_summary),
		cmocka_unit_test(test_scan),
		cmocka_unit_test(test_scan_take),
		cmocka_unit_test(test_uncertainty),
		cmocka_unit_test(test_map_error),
		cmocka_unit_test(test_residual_files),
		cmocka_unit_test(test_x3p_unnamed_instrument),
		cmocka_unit_test(test_folder),
		cmocka_unit_test(test_bad_options),
	};

	gsl_set_error_handler_off();
	return cmocka_run_group_tests(tests, NULL, NULL);
}
