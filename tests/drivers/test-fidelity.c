/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Fidelity of the acquisition chain on the physical virtual instrument
 * (mock:bench=realistic): a misaligned part with a form error, measured
 * with the stage's latched positions and the drift control, characterizes
 * as on the ideal instrument (residual RMS within 1 nm, the same pose and
 * form); without the drift control it misses by what the drift model
 * predicts, computed here from the drift's formula and the fit's degrees of
 * freedom; paired with commanded positions it misses too, and says so.
 */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "asph/drift.h"
#include "asph-engine/executor.h"
#include "asph/fit.h"
#include "asph/plan.h"
#include "asph/prescription.h"
#include "scan-fixture.h"

/* The part: shifted, tilted, with coma and spherical aberration (Noll 8
 * and 11, nm), on the plan of the fixture (Fermat, 700 points). */
#define PART "shift_x=0.012,shift_y=-0.007,tilt_x=150,tilt_y=-90,form=8:-19.5;11:12"
/* The realistic bench, with the settling its stage advises (a window of
 * 10 nm for a period of the ringing): a step move rings for settle_time,
 * and a sweep or a reading begun inside a wider window starts on that
 * ringing. */
#define REALISTIC "bench=realistic"
#define DRIFT_Z_NM_PER_MIN 20.0         /* the realistic bench's (docs/drivers.md) */

struct measured {
	struct asph_fit_result res;
	double *residual;       /* mm, by plan index (NaN: none) */
	struct asph_drift_summary drift;
	char *account;          /* the acquisition's account, JSON */
	struct asph_scanfile *scan;
	uint64_t clock0_ns;     /* the instrument's clock when the scan began */
	double seconds;         /* the scan's time on the instrument's clock */
	double estimate_s;      /* asph_scan_estimate()'s prediction of it */
};

static void measured_free(struct measured *m)
{
	free(m->residual);
	free(m->account);
	asph_scanfile_free(m->scan);
}

/* Streams the fixture's plan with spec, characterizes it as asphd and asph
 * replay do (the drift corrected unless raw) with sag residuals. */
static void measure(struct scan_fixture *f, const char *spec, int raw, struct measured *m)
{
	struct asph_scanfile_header_info info = { NULL, "{\"method\":\"fermat\"}",
						  "{\"name\":\"mock\"}", NULL };
	struct asph_scan_options so = { .flags = ASPH_SCAN_STREAM };
	struct asph_fit_options fo = { .dof = ASPH_FIT_DOF_RIGID,
				       .residual = ASPH_FIT_RESIDUAL_SAG };
	struct asph_scanfile_writer *w;
	struct asph_config *c;
	struct asph_instrument *inst;
	struct asph_scan *sc;
	struct asph_points *pts;
	struct asph_fit *fit;
	struct asph_error err;
	char path[128], *lens = NULL;

	memset(m, 0, sizeof(*m));
	assert_int_equal(asph_prescription_to_json(asph_surface_prescription(f->s), &lens), 0);
	info.prescription = lens;
	if (asph_instrument_spec_parse(f->reg, spec, &c, &err) < 0 ||
	    asph_instrument_open(&c->instruments[0], 1000, &inst, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
	assert_int_equal(asph_scan_new(inst, f->s, f->plan->xyz, f->plan->n, &so, &sc, NULL), 0);
	assert_int_equal(asph_scanfile_writer_create(new_path(f, path, sizeof(path)), &info, NULL,
						     &w, NULL), 0);
	free(lens);
	if (asph_scan_estimate(&c->instruments[0], f->s, f->plan->xyz, f->plan->n, &so,
			       &m->estimate_s, &err) < 0)
		fail_msg("estimate: %s", err.message);
	m->clock0_ns = asph_instrument_clock(inst);
	if (asph_scan_run(sc, w, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
	m->seconds = (double)(asph_instrument_clock(inst) - m->clock0_ns) * 1e-9;
	asph_scan_free(sc);
	asph_instrument_close(inst);
	asph_config_free(c);

	m->scan = read_scan(path);
	assert_int_equal(m->scan->n, f->plan->n);
	if (asph_drift_scanfile_points(m->scan, path, 0, raw, &pts, &m->drift, &err) < 0)
		fail_msg("%s: %s", path, err.message);
	assert_int_equal(asph_drift_report_json(m->scan, &m->drift, !raw, &m->account), 0);
	assert_int_equal(pts->n, f->plan->n);
	assert_int_equal(asph_fit_alloc(f->s, pts->n, &fo, &fit, NULL), 0);
	if (asph_fit_run(fit, pts->xyz, pts->n, &m->res, &err) < 0)
		fail_msg("fit: %s", err.message);
	assert_true(m->res.converged);
	m->residual = malloc(f->plan->n * sizeof(double));
	assert_non_null(m->residual);
	for (size_t i = 0; i < f->plan->n; i++)
		m->residual[i] = NAN;
	/* the points come in recording order; all of them were measured */
	for (size_t i = 0; i < m->scan->n; i++)
		m->residual[m->scan->points[i].plan_index] = asph_fit_residuals(fit)[i];
	asph_fit_free(fit);
	asph_points_free(pts);
}

static double rms_nm(const double *v, size_t n)
{
	double s = 0;

	for (size_t i = 0; i < n; i++)
		s += v[i] * v[i];
	return sqrt(s / (double)n) * 1e6;
}

/* Solves the symmetric positive definite system a x = b (n <= 5) in place
 * by Gaussian elimination with partial pivoting. */
static void solve(double a[5][5], double b[5], int n)
{
	for (int k = 0; k < n; k++) {
		int p = k;
		for (int i = k + 1; i < n; i++)
			if (fabs(a[i][k]) > fabs(a[p][k]))
				p = i;
		for (int j = 0; j < n; j++) {
			double t = a[k][j];
			a[k][j] = a[p][j];
			a[p][j] = t;
		}
		double t = b[k];
		b[k] = b[p];
		b[p] = t;
		assert_true(fabs(a[k][k]) > 0);
		for (int i = k + 1; i < n; i++) {
			double f = a[i][k] / a[k][k];
			for (int j = k; j < n; j++)
				a[i][j] -= f * a[k][j];
			b[i] -= f * b[k];
		}
	}
	for (int k = n - 1; k >= 0; k--) {
		for (int j = k + 1; j < n; j++)
			b[k] -= a[k][j] * b[j];
		b[k] /= a[k][k];
	}
}

/*
 * What an uncorrected drift d_i along z does to the sag residuals of the
 * rigid fit: d less its least-squares part in the span of the fit's
 * degrees of freedom, linearized at the nominal surface S: tz moves the
 * surface by 1, tx and ty by S_x and S_y, rx and ry by y + S S_y and
 * x + S S_x (a small rotation of the point (x, y, S)).
 */
static void drift_left(const struct asph_surface *s, const double *xy, const double *d, size_t n,
		       double *out)
{
	double ata[5][5] = { { 0 } }, atb[5] = { 0 };

	for (size_t i = 0; i < n; i++) {
		double x = xy[3 * i], y = xy[3 * i + 1], g[3];
		asph_surface_sag_grad_xy(s, x, y, g);
		double col[5] = { 1, g[1], g[2], y + g[0] * g[2], x + g[0] * g[1] };
		for (int a = 0; a < 5; a++) {
			for (int b = 0; b < 5; b++)
				ata[a][b] += col[a] * col[b];
			atb[a] += col[a] * d[i];
		}
	}
	solve(ata, atb, 5);
	for (size_t i = 0; i < n; i++) {
		double x = xy[3 * i], y = xy[3 * i + 1], g[3];
		asph_surface_sag_grad_xy(s, x, y, g);
		double col[5] = { 1, g[1], g[2], y + g[0] * g[2], x + g[0] * g[1] };
		out[i] = d[i];
		for (int a = 0; a < 5; a++)
			out[i] -= col[a] * atb[a];
	}
}

/* The bench's drift along z at t s of its clock (docs/drivers.md): r (t +
 * 60 s sin(2 pi t / 20 min)), r in mm/s. */
static double drift_z(double t)
{
	const double r = DRIFT_Z_NM_PER_MIN * 1e-6 / 60;

	return r * (t + 60 * sin(2 * M_PI * t / 1200));
}

static void test_fidelity(void **state)
{
	struct scan_fixture *f = *state;
	const size_t n = f->plan->n;
	struct measured ideal, real, nodrift, commanded;
	double *diff = malloc(n * sizeof(double)), *want = malloc(n * sizeof(double));
	double *d = malloc(n * sizeof(double));

	assert_true(diff && want && d);
	measure(f, "mock:time_factor=0,drift_interval=off," PART, 0, &ideal);
	measure(f, "mock:time_factor=0," REALISTIC "," PART, 0, &real);

	/* measured positions and the drift control: as good as the ideal
	 * instrument, to 1 nm RMS; the same pose (shift to 10 nm, tilt to
	 * 0.1 urad: what 1 nm over the 20 mm radius allows) and form */
	double ri = ideal.res.rms.v, rr = real.res.rms.v;
	if (fabs(rr - ri) > 1)
		fail_msg("realistic bench: residual RMS %.4f nm, ideal instrument %.4f nm", rr, ri);
	for (int k = ASPH_FIT_TX; k <= ASPH_FIT_RY; k++) {
		double tol = k <= ASPH_FIT_TZ ? 1e-5 : 1e-7;
		if (fabs(real.res.value[k] - ideal.res.value[k]) > tol)
			fail_msg("%s: %.9g on the realistic bench, %.9g ideal", asph_fit_dof_name(k),
				 real.res.value[k], ideal.res.value[k]);
	}
	/* the injected pose itself (the coma of the form couples into tx by
	 * its own amount, the same on both) */
	assert_true(fabs(ideal.res.value[ASPH_FIT_TY] + 0.007) < 1e-5);
	assert_true(fabs(ideal.res.value[ASPH_FIT_RX] - 150e-6) < 1e-7);
	for (int j = 7; j <= 10; j++)
		if (fabs(real.res.zernike[j].v - ideal.res.zernike[j].v) > 1)
			fail_msg("Z%d: %.4f nm on the realistic bench, %.4f nm ideal", j + 1,
				 real.res.zernike[j].v, ideal.res.zernike[j].v);
	assert_true(real.drift.n_rounds >= 2 && real.drift.components == 1);
	assert_true(strstr(real.account, "\"commanded_points\":0") != NULL);

	/* the drift control off: the residuals move by the drift at each
	 * point's sample instant, less what the rigid fit takes up */
	measure(f, "mock:time_factor=0,drift_interval=off," REALISTIC "," PART, 0, &nodrift);
	for (size_t i = 0; i < nodrift.scan->n; i++) {
		const struct asph_scanfile_point *p = &nodrift.scan->points[i];
		d[p->plan_index] = drift_z((double)(nodrift.clock0_ns + p->t_ns) * 1e-9);
	}
	drift_left(f->s, f->plan->xyz, d, n, want);
	for (size_t i = 0; i < n; i++)
		diff[i] = nodrift.residual[i] - ideal.residual[i] - want[i];
	double predicted = rms_nm(want, n), rn = nodrift.res.rms.v;
	double off = rms_nm(diff, n);
	if (!(predicted > 1.5 && rn - ri > 1))
		fail_msg("without drift control: %.4f nm RMS against %.4f ideal; the model's "
			 "drift left after the fit %.4f nm RMS", rn, ri, predicted);
	/* point by point, as predicted but for the bench's other errors
	 * (what separates the realistic from the ideal scan above) */
	for (size_t i = 0; i < n; i++)
		diff[i] = real.residual[i] - ideal.residual[i];
	double others = rms_nm(diff, n);
	if (off > 0.05 * predicted + 1.5 * others)
		fail_msg("without drift control the residuals differ from the prediction by %.4f nm "
			 "RMS (prediction %.4f nm, the bench's other errors %.4f nm)", off, predicted,
			 others);
	print_message("residual RMS: ideal %.4f nm, realistic %.4f nm (points differ by %.4f nm "
		      "RMS); without drift control %.4f nm, the drift the fit leaves %.4f nm RMS, "
		      "the residuals off that prediction by %.4f nm RMS\n", ri, rr, others, rn,
		      predicted, off);
	/* and its RMS is the ideal's with the predicted drift added */
	for (size_t i = 0; i < n; i++)
		diff[i] = ideal.residual[i] + want[i];
	if (fabs(rn - rms_nm(diff, n)) > 0.05 * predicted + 1.5 * others)
		fail_msg("without drift control: %.4f nm RMS, predicted %.4f nm", rn,
			 rms_nm(diff, n));

	/* paired with commanded positions: every point flagged and counted,
	 * and the result is off by more than the 1 nm */
	measure(f, "mock:time_factor=0,capture=none," REALISTIC "," PART, 0, &commanded);
	for (size_t i = 0; i < commanded.scan->n; i++) {
		const struct asph_scanfile_point *p = &commanded.scan->points[i];
		assert_true(p->flags & ASPH_SCANFILE_POINT_COMMANDED);
		assert_int_equal(p->position_source, ASPH_SCANFILE_POSITION_COMMANDED);
	}
	char count[64];
	snprintf(count, sizeof(count), "\"commanded_points\":%zu", n);
	assert_non_null(strstr(commanded.account, count));
	assert_non_null(strstr(commanded.account, "flagged commanded-position"));
	print_message("paired with commanded positions: %.4f nm RMS\n", commanded.res.rms.v);
	if (!(commanded.res.rms.v - ri > 1))
		fail_msg("commanded positions: %.4f nm RMS against %.4f ideal", commanded.res.rms.v,
			 ri);

	measured_free(&ideal);
	measured_free(&real);
	measured_free(&nodrift);
	measured_free(&commanded);
	free(diff);
	free(want);
	free(d);
}

/* bench=realistic stays bit-reproducible: the same scan twice is the same
 * to the bit, points and drift references. */
static void test_reproducible(void **state)
{
	struct scan_fixture *f = *state;
	struct measured a, b;

	measure(f, "mock:time_factor=0,noise=1.5,seed=31," REALISTIC "," PART, 0, &a);
	measure(f, "mock:time_factor=0,noise=1.5,seed=31," REALISTIC "," PART, 0, &b);
	assert_int_equal(a.scan->n, b.scan->n);
	assert_int_equal(a.scan->n_references, b.scan->n_references);
	assert_true(a.scan->n_references >= 2);
	for (size_t i = 0; i < a.scan->n; i++) {
		const struct asph_scanfile_point *p = &a.scan->points[i], *q = &b.scan->points[i];
		assert_int_equal(p->plan_index, q->plan_index);
		assert_int_equal(p->t_ns, q->t_ns);
		assert_memory_equal(&p->x, &q->x, sizeof(double));
		assert_memory_equal(&p->y, &q->y, sizeof(double));
		assert_memory_equal(&p->z, &q->z, sizeof(double));
		assert_memory_equal(p->stage, q->stage, sizeof(p->stage));
	}
	for (size_t i = 0; i < a.scan->n_references; i++)
		assert_memory_equal(&a.scan->references[i].z, &b.scan->references[i].z,
				    sizeof(double));
	assert_memory_equal(&a.res.rms, &b.res.rms, sizeof(a.res.rms));
	measured_free(&a);
	measured_free(&b);
}

/* The prediction of the measuring time against the simulated duration,
 * streamed on the ideal and the realistic bench, and on a rotary table
 * (which must stream as exactly as the cartesian stage): within 5 %. */
static void test_estimate(void **state)
{
	static const char *const specs[] = {
		"mock:time_factor=0,drift_interval=off",
		"mock:time_factor=0," REALISTIC,
		"mock:time_factor=0,kinematics=r-theta-z,drift_interval=off",
	};
	struct scan_fixture *f = *state;

	for (size_t i = 0; i < sizeof(specs) / sizeof(specs[0]); i++) {
		struct measured m;
		measure(f, specs[i], 0, &m);
		print_message("%s: %.3f s simulated, %.3f s predicted\n", specs[i], m.seconds,
			      m.estimate_s);
		if (!(m.seconds > 1 && fabs(m.estimate_s / m.seconds - 1) <= 0.05))
			fail_msg("%s: %.4f s simulated, %.4f s predicted", specs[i], m.seconds,
				 m.estimate_s);
		/* the ideal instruments measure the perfect part exactly */
		if (!strstr(specs[i], "bench") && !(m.res.rms.v < 1e-3))
			fail_msg("%s: %.6f nm RMS on a perfect part", specs[i], m.res.rms.v);
		measured_free(&m);
	}
}

/* Re-simulation (asph_scan_simulate()): a draw is its configuration, the
 * same one gives the same points to the bit, drift corrected; another seed
 * other noise of the stated size (without drift references, whose own
 * noise would enter the correction: two draws of 2 nm differ by
 * 2 sqrt(2) nm RMS along z). */
static struct asph_points *simulate(struct scan_fixture *f, const char *spec, size_t rounds)
{
	struct asph_config *c;
	struct asph_points *pts;
	struct asph_drift_summary drift;
	struct asph_error err;

	if (asph_instrument_spec_parse(f->reg, spec, &c, &err) < 0 ||
	    asph_scan_simulate(&c->instruments[0], f->s, f->plan->xyz, f->plan->n, f->dir, &pts,
			       &drift, &err) < 0)
		fail_msg("%s: %s", spec, err.message);
	assert_true(rounds ? drift.n_rounds >= rounds : drift.n_rounds == 0);
	asph_config_free(c);
	return pts;
}

static void test_simulate(void **state)
{
	struct scan_fixture *f = *state;
	struct asph_points *a = simulate(f, "mock:time_factor=0," REALISTIC ",noise=2,seed=5", 2);
	struct asph_points *b = simulate(f, "mock:time_factor=0," REALISTIC ",noise=2,seed=5", 2);
	double sq = 0;

	assert_int_equal(a->n, f->plan->n);
	assert_int_equal(b->n, a->n);
	assert_memory_equal(a->xyz, b->xyz, 3 * a->n * sizeof(double));
	asph_points_free(a);
	asph_points_free(b);
	a = simulate(f, "mock:time_factor=0," REALISTIC ",drift_interval=off,noise=2,seed=5", 0);
	struct asph_points *c =
		simulate(f, "mock:time_factor=0," REALISTIC ",drift_interval=off,noise=2,seed=6", 0);
	assert_int_equal(c->n, a->n);
	for (size_t i = 0; i < a->n; i++)
		sq += (a->xyz[3 * i + 2] - c->xyz[3 * i + 2]) * (a->xyz[3 * i + 2] - c->xyz[3 * i + 2]);
	double rms = sqrt(sq / (double)a->n) * 1e6, want = 2 * sqrt(2.0);
	/* the RMS of n = 700 draws: within 4 of its standard errors (7 %) */
	if (fabs(rms - want) > 4 * want / sqrt(2.0 * (double)a->n))
		fail_msg("two seeds differ by %.4f nm RMS along z, the noise says %.4f nm", rms, want);
	asph_points_free(a);
	asph_points_free(c);
}

static int setup(void **state)
{
	struct scan_fixture *f = calloc(1, sizeof(*f));

	assert_non_null(f);
	scan_fixture_init(f, 700, "fidelity");
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	scan_fixture_fini(*state);
	free(*state);
	return 0;
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test(test_fidelity),
		cmocka_unit_test(test_reproducible),
		cmocka_unit_test(test_estimate),
		cmocka_unit_test(test_simulate),
	};
	return cmocka_run_group_tests(tests, setup, teardown);
}
