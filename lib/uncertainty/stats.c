/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Statistics of the trials: estimates, uncertainties, the adaptive stop,
 * and what the fit's result and summary get of them. */
#include <errno.h>
#include <math.h>
#include <string.h>

#include <jansson.h>

#include "asph/uncertainty.h"
#include "mc-internal.h"
#include "util-mem.h"

#define NQ ASPH_MC_N_QUANTITIES

static const char *const quantity_keys[ASPH_MC_N_QUANTITIES] = {
	[ASPH_FIT_TX] = "tx", [ASPH_FIT_TY] = "ty", [ASPH_FIT_TZ] = "tz",
	[ASPH_FIT_RX] = "rx", [ASPH_FIT_RY] = "ry", [ASPH_FIT_R] = "c_per_mm",
	[ASPH_FIT_K] = "k", [ASPH_FIT_RZ] = "rz",
	[ASPH_MC_RMS] = "rms_nm", [ASPH_MC_PV] = "pv_nm", [ASPH_MC_PVR] = "pvr_nm",
	[ASPH_MC_A] = "A_nm", [ASPH_MC_B] = "B_nm", [ASPH_MC_C] = "C_nm",
	[ASPH_MC_RMS_T] = "rms_t_nm", [ASPH_MC_RMS_I] = "rms_i_nm", [ASPH_MC_RMS_A] = "rms_a_nm",
	[ASPH_MC_SLOPE_RMS] = "rms_urad", [ASPH_MC_SLOPE_MAX] = "max_urad",
};

const char *asph_mc_quantity_key(enum asph_mc_quantity q)
{
	return (unsigned)q < ASPH_MC_N_QUANTITIES ? quantity_keys[q] : NULL;
}

/* Mean and sample standard deviation of quantity q over trials [lo, hi),
 * NaN values (failed trials) left out. Returns how many counted. */
static size_t mean_sd(const double *values, size_t lo, size_t hi, int q, double *mean,
		      double *sd)
{
	double sum = 0, ss = 0;
	size_t m = 0;

	for (size_t t = lo; t < hi; t++) {
		double v = values[t * NQ + (size_t)q];
		if (isfinite(v))
			sum += v, m++;
	}
	*mean = m ? sum / (double)m : NAN;
	for (size_t t = lo; t < hi; t++) {
		double v = values[t * NQ + (size_t)q];
		if (isfinite(v))
			ss += (v - *mean) * (v - *mean);
	}
	*sd = m > 1 ? sqrt(ss / (double)(m - 1)) : NAN;
	return m;
}

/* Standard deviation of the h block averages, divided by sqrt(h): s_y of
 * GUM S1 7.9.4 c). */
static double spread_of_mean(const double *x, size_t h)
{
	double mean = 0, ss = 0;

	for (size_t r = 0; r < h; r++)
		mean += x[r];
	mean /= (double)h;
	for (size_t r = 0; r < h; r++)
		ss += (x[r] - mean) * (x[r] - mean);
	return sqrt(ss / ((double)h * (double)(h - 1)));
}

/* GUM S1 7.9.2: u written with ndig significant digits is c x 10^l; the
 * numerical tolerance is half a unit of its last digit. */
static double numerical_tolerance(double u, int ndig)
{
	return 0.5 * pow(10, floor(log10(u)) - (ndig - 1));
}

/* The block statistics of quantity q over the first h blocks: y[r], u[r]
 * of block r, and sd over them all. 0 when a block has fewer than two
 * values (failed trials), else 1. */
static int block_stats(const double *values, size_t h, size_t block, int q, double *y,
		       double *u, double *sd)
{
	double mean;

	mean_sd(values, 0, h * block, q, &mean, sd);
	for (size_t r = 0; r < h; r++)
		if (mean_sd(values, r * block, (r + 1) * block, q, &y[r], &u[r]) < 2)
			return 0;
	return 1;
}

/* 1 when quantity q's U is stable (its decision settled), *above then 1
 * when U is beyond the threshold a decision tests it against. */
static int quantity_stable(const double *values, size_t n, int q, const struct mc_stop *stop,
			   double *scratch, int *above)
{
	size_t h = n / stop->block;
	double *y = scratch, *u = scratch + h, sd;

	if (!block_stats(values, h, stop->block, q, y, u, &sd))
		return 0;
	if (!(sd > 0))
		return 1;       /* nothing varies: nothing to settle */
	if (stop->decide_U) {
		/* settled when U's spread is small against the precision the
		 * decision asks for, or against U's distance to the threshold */
		double limit = stop->decide_U[q], U = ASPH_MC_COVERAGE_FACTOR * sd;
		double room = fmax(stop->precision * limit, fabs(U - limit) / 2);
		*above = U > limit;
		return 2 * ASPH_MC_COVERAGE_FACTOR * spread_of_mean(u, h) <= room;
	}
	double delta = numerical_tolerance(sd, stop->ndig);
	return 2 * spread_of_mean(y, h) <= delta && 2 * spread_of_mean(u, h) <= delta;
}

int mc_stable(const double *values, size_t n, const int *covered, const struct mc_stop *stop,
	      double *scratch)
{
	int all = 1;

	if (n / stop->block < 2)
		return 0;
	for (int q = 0; q < NQ; q++) {
		int tested = covered[q] && (!stop->decide_U || stop->decide_U[q] > 0), above = 0;
		if (!tested)
			continue;
		if (!quantity_stable(values, n, q, stop, scratch, &above))
			all = 0;
		else if (stop->decide_U && above)
			return 1;       /* one quantity settled beyond: the plan fails */
	}
	return all;
}

void mc_summarize(const double *values, size_t n, const int *covered,
		  const double *value, struct asph_mc_result *out)
{
	memset(out, 0, sizeof(*out));
	out->n_trials = n;
	out->coverage_factor = ASPH_MC_COVERAGE_FACTOR;
	for (size_t t = 0; t < n; t++) {
		int any = 0;
		for (int q = 0; q < NQ; q++)
			any |= covered[q] && isfinite(values[t * NQ + (size_t)q]);
		out->n_failed += !any;
	}
	for (int q = 0; q < NQ; q++) {
		out->covered[q] = covered[q];
		out->value[q] = covered[q] ? value[q] : NAN;
		out->mean[q] = out->u[q] = out->U[q] = NAN;
		if (!covered[q])
			continue;
		mean_sd(values, 0, n, q, &out->mean[q], &out->u[q]);
		out->U[q] = ASPH_MC_COVERAGE_FACTOR * out->u[q];
	}
}

/* U(R) = U(c) / c^2 from the trials' curvature; R, its deviation and U
 * none when c = 0 lies within U(c), as the fit decides it with its own
 * U(c). */
static void mc_apply_radius(const struct asph_mc_result *mc, struct asph_fit_result *fit)
{
	double c = fit->curvature, Uc = mc->U[ASPH_FIT_R];
	struct asph_uncertainty_k2 *u = &fit->uncertainty_k2;

	if (!mc->covered[ASPH_FIT_R])
		return;
	u->c_per_mm = Uc;
	if (c == 0 || fabs(c) <= Uc) {
		fit->value[ASPH_FIT_R] = fit->R_deviation_mm = NAN;
		return;
	}
	fit->value[ASPH_FIT_R] = 1.0 / c;
	fit->R_deviation_mm = fit->value[ASPH_FIT_R] - fit->R_nominal_mm;
	u->R_mm = Uc / (c * c);
}

void asph_mc_apply(const struct asph_mc_result *mc,
		   const struct asph_tolerance *t,
		   struct asph_fit_result *fit)
{
	struct asph_uncertainty_k2 *u = &fit->uncertainty_k2;
	double per_fringe = 2.0 / fit->form.wavelength_nm;

	asph_uncertainty_k2_clear(u);
	u->method = ASPH_UNCERTAINTY_MONTE_CARLO;
	u->A.v = mc->U[ASPH_MC_A];
	u->B.v = mc->U[ASPH_MC_B];
	u->C.v = mc->U[ASPH_MC_C];
	u->A_fringes = u->A.v * per_fringe;
	u->B_fringes = u->B.v * per_fringe;
	u->C_fringes = u->C.v * per_fringe;
	u->rms_t.v = mc->U[ASPH_MC_RMS_T];
	u->rms_i.v = mc->U[ASPH_MC_RMS_I];
	u->rms_a.v = mc->U[ASPH_MC_RMS_A];
	u->slope_rms.v = mc->U[ASPH_MC_SLOPE_RMS];
	u->slope_max.v = mc->U[ASPH_MC_SLOPE_MAX];
	mc_apply_radius(mc, fit);
	if (t && fit->verdict.present)
		asph_verdict_evaluate(t, fit->form_valid ? &fit->form : NULL,
				      fit->slope_valid ? &fit->slope : NULL, fit->R_deviation_mm,
				      u, &fit->verdict);
}

static json_t *json_num(double v)
{
	return isfinite(v) ? json_real(v) : json_null();
}

/* One uncertainty per covered quantity under its summary key, the fringes
 * and the radius deviation as the summary names them. */
static json_t *quantity_object(const struct asph_mc_result *mc, const double *x,
			       double wavelength_nm)
{
	static const int fringe_of[3] = { ASPH_MC_A, ASPH_MC_B, ASPH_MC_C };
	static const char *const fringe_key[3] = { "A_fringes", "B_fringes", "C_fringes" };
	json_t *o = json_object();

	for (int q = 0; o && q < NQ; q++)
		if (mc->covered[q])
			json_object_set_new(o, asph_mc_quantity_key((enum asph_mc_quantity)q),
					    json_num(x[q]));
	for (int i = 0; o && i < 3; i++)
		if (mc->covered[fringe_of[i]])
			json_object_set_new(o, fringe_key[i],
					    json_num(x[fringe_of[i]] * 2.0 / wavelength_nm));
	/* R from the curvature c the trials vary: U(R) = U(c) / c^2 */
	double c = mc->value[ASPH_FIT_R];
	if (o && mc->covered[ASPH_FIT_R]) {
		double uR = c == 0 || fabs(c) <= mc->U[ASPH_FIT_R] ? NAN : x[ASPH_FIT_R] / (c * c);
		json_object_set_new(o, "R_mm", json_num(uR));
		json_object_set_new(o, "deviation_mm", json_num(uR));
	}
	return o;
}

static json_t *model_object(const struct asph_mc_result *mc)
{
	_cleanup_free_ char *text = NULL;
	json_t *o;

	if (asph_uncertainty_model_to_json(&mc->model, &text) < 0 ||
	    !(o = json_loads(text, 0, NULL)))
		return NULL;
	json_object_set_new(o, "method", json_string("monte-carlo"));
	json_object_set_new(o, "trials", json_integer((json_int_t)mc->n_trials));
	json_object_set_new(o, "failed_trials", json_integer((json_int_t)mc->n_failed));
	json_object_set_new(o, "adaptive", json_boolean(!mc->fixed));
	json_object_set_new(o, "stable", json_boolean(mc->stable));
	json_object_set_new(o, "block_size", json_integer((json_int_t)mc->block_size));
	json_object_set_new(o, "significant_digits", json_integer(mc->significant_digits));
	json_object_set_new(o, "seed", json_integer((json_int_t)mc->seed));
	json_object_set_new(o, "coverage_factor", json_real(mc->coverage_factor));
	return o;
}

int asph_mc_result_to_json(const struct asph_mc_result *mc,
			   double wavelength_nm, char **out)
{
	_cleanup_(json_decrefp) json_t *root = json_object();
	json_t *k2 = quantity_object(mc, mc->U, wavelength_nm);
	json_t *std = quantity_object(mc, mc->u, wavelength_nm);
	json_t *model = model_object(mc);

	*out = NULL;
	if (!root || !k2 || !std || !model) {
		json_decref(k2);
		json_decref(std);
		json_decref(model);
		return -ENOMEM;
	}
	json_object_set_new(root, "uncertainty_k2", k2);
	json_object_set_new(root, "uncertainty_standard", std);
	json_object_set_new(root, "uncertainty_model", model);
	*out = json_dumps(root, JSON_COMPACT | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17));
	return *out ? 0 : -ENOMEM;
}
