/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <math.h>
#include <string.h>

#include "fit-summary.h"
#include "quantity.h"

/* The number at a dotted path ("form.A_nm"); NaN when absent or null. */
static double at(const json_t *o, const char *path)
{
	char key[64];

	while (o && *path) {
		size_t n = strcspn(path, ".");
		snprintf(key, sizeof(key), "%.*s", (int)n, path);
		o = json_object_get(o, key);
		path += n + (path[n] == '.');
	}
	return json_is_number(o) ? json_number_value(o) : NAN;
}

static long long count(const json_t *o, const char *key)
{
	return (long long)json_integer_value(json_object_get(o, key));
}

static const char *text(const json_t *o, const char *key)
{
	const char *s = json_string_value(json_object_get(o, key));

	return s ? s : "-";
}

/* The quantity at path in s, as printed with its unit. */
static const char *value(const json_t *s, const char *path, char *buf, size_t size)
{
	return quantity_format(quantity_by_path(path), at(s, path), QUANTITY_UNIT, buf, size);
}

/* Its expanded uncertainty (uncertainty_k2), in the quantity's unit. */
static const char *expanded(const json_t *s, const char *path, char *buf, size_t size)
{
	const struct quantity *q = quantity_by_path(path);
	const json_t *u = json_object_get(s, "uncertainty_k2");

	return quantity_format(q, q && q->u_key ? at(u, q->u_key) : NAN, QUANTITY_NO_SIGN, buf,
			       size);
}

static void print_fit(FILE *f, const json_t *s, const char *indent)
{
	long long passes = count(s, "passes");

	fprintf(f, "%sFit of %lld points to %s (%s residual%s)\n", indent, count(s, "n_points"),
		text(s, "lens"), text(s, "residual"),
		json_is_true(json_object_get(s, "robust")) ? ", robust" : "");
	fprintf(f, "%s%s after %lld iterations in %lld pass%s: %s\n", indent,
		json_is_true(json_object_get(s, "converged")) ? "Converged" : "NOT converged",
		count(s, "iterations"), passes, passes == 1 ? "" : "es", text(s, "reason"));
	fprintf(f, "%sPoints used %lld, outside the aperture %lld, outliers %lld\n", indent,
		count(s, "n_used"), count(s, "n_outside_aperture"), count(s, "n_outliers"));
}

/* The pose: each fitted degree of freedom with its standard uncertainty. */
static void print_pose(FILE *f, const json_t *s, const char *indent)
{
	const json_t *dof = json_object_get(s, "dof"), *u = json_object_get(s, "uncertainty");
	const char *key;
	json_t *v;

	json_object_foreach((json_t *)dof, key, v) {
		char path[32], a[48], b[48];
		const struct quantity *q;

		snprintf(path, sizeof(path), "dof.%s", key);
		q = quantity_by_path(path);
		fprintf(f, "%s  %-3s %16s  +- %s\n", indent, key,
			quantity_format(q, json_is_number(v) ? json_number_value(v) : NAN,
					QUANTITY_UNIT, a, sizeof(a)),
			quantity_format(q, at(u, key), QUANTITY_UNIT | QUANTITY_NO_SIGN, b,
					sizeof(b)));
	}
}

static void print_residual(FILE *f, const json_t *s, const char *indent)
{
	char rms[32], pv[32], pvr[32], slope[32];

	fprintf(f, "%sResidual: RMS %s (about its mean), PV %s, PVr %s; Zernike slope RMS %s\n",
		indent, value(s, "rms_nm", rms, sizeof(rms)),
		value(s, "pv_nm", pv, sizeof(pv)), value(s, "pvr_nm", pvr, sizeof(pvr)),
		value(s, "slope_rms_urad", slope, sizeof(slope)));
}

/* ISO 14999-4: A, B, C in nm and fringes, RMSt, RMSi, RMSa, each with U. */
static void print_form(FILE *f, const json_t *s, const char *indent)
{
	static const char *const abc[] = { "A", "B", "C" }, *const rms[] = { "t", "i", "a" };
	char v[48], fr[48], u[48], path[32];

	if (isnan(at(s, "form.A_nm")))
		return;
	fprintf(f, "%sISO 14999-4 (lambda %s; U for k = 2):\n%s ", indent,
		value(s, "form.wavelength_nm", v, sizeof(v)), indent);
	for (int i = 0; i < 3; i++) {
		snprintf(path, sizeof(path), "form.%s_nm", abc[i]);
		value(s, path, v, sizeof(v));
		expanded(s, path, u, sizeof(u));
		snprintf(path, sizeof(path), "form.%s_fringes", abc[i]);
		fprintf(f, "%s %s %s (%s) U %s", i ? " |" : "", abc[i], v,
			value(s, path, fr, sizeof(fr)), u);
	}
	fprintf(f, "\n%s ", indent);
	for (int i = 0; i < 3; i++) {
		snprintf(path, sizeof(path), "form.rms_%s_nm", rms[i]);
		fprintf(f, "%s RMS%s %s U %s", i ? "," : "", rms[i], value(s, path, v, sizeof(v)),
			expanded(s, path, u, sizeof(u)));
	}
	fputc('\n', f);
}

static void print_slope(FILE *f, const json_t *s, const char *indent)
{
	char len[32], rms[32], rad[32], azi[32], max[32], urms[32], umax[32];

	if (isnan(at(s, "slope.rms_urad")))
		return;
	if (json_is_true(json_object_get(s, "profile"))) {
		fprintf(f, "%sSlope along the traces over %s: RMS %s U %s, max %s U %s\n", indent,
			value(s, "slope.length_mm", len, sizeof(len)),
			value(s, "slope.rms_urad", rms, sizeof(rms)),
			expanded(s, "slope.rms_urad", urms, sizeof(urms)),
			value(s, "slope.max_urad", max, sizeof(max)),
			expanded(s, "slope.max_urad", umax, sizeof(umax)));
		return;
	}
	fprintf(f, "%sSlope over %s: RMS %s (radial %s, azimuthal %s) U %s, max %s U %s\n", indent,
		value(s, "slope.length_mm", len, sizeof(len)),
		value(s, "slope.rms_urad", rms, sizeof(rms)),
		value(s, "slope.rms_radial_urad", rad, sizeof(rad)),
		value(s, "slope.rms_azimuthal_urad", azi, sizeof(azi)),
		expanded(s, "slope.rms_urad", urms, sizeof(urms)),
		value(s, "slope.max_urad", max, sizeof(max)),
		expanded(s, "slope.max_urad", umax, sizeof(umax)));
}

static void print_radius(FILE *f, const json_t *s, const char *indent)
{
	char r[32], nom[32], dev[32], u[32];

	char c[48], cnom[48], uc[48];

	if (!json_is_object(json_object_get(s, "radius")))
		return;
	fprintf(f, "%sRadius %s (nominal %s): R - R nominal %s U %s\n", indent,
		value(s, "radius.R_mm", r, sizeof(r)),
		value(s, "radius.nominal_mm", nom, sizeof(nom)),
		value(s, "radius.deviation_mm", dev, sizeof(dev)),
		expanded(s, "radius.deviation_mm", u, sizeof(u)));
	fprintf(f, "%sCurvature c = 1/R %s U %s (nominal %s)%s\n", indent,
		value(s, "radius.c_per_mm", c, sizeof(c)), expanded(s, "dof.c", uc, sizeof(uc)),
		value(s, "radius.nominal_c_per_mm", cnom, sizeof(cnom)),
		isnan(at(s, "radius.R_mm")) ? ": R not determined (c = 0 within U)" : "");
}

/* Line profiles: each trace with what the fit leaves along it. */
static void print_profiles(FILE *f, const json_t *s, const char *indent)
{
	static const char *const keys[] = { "azimuth_deg", "offset_mm", "length_mm", "rms_nm",
					     "pv_nm", "slope_rms_urad", "slope_max_urad" };
	const json_t *a = json_object_get(s, "profiles"), *p;
	size_t i;

	if (!json_is_array(a))
		return;
	fprintf(f, "%sLine profiles (%zu), along each trace:\n", indent, json_array_size(a));
	json_array_foreach(a, i, p) {
		char v[7][48], path[48];
		for (size_t k = 0; k < 7; k++) {
			snprintf(path, sizeof(path), "profiles.%s", keys[k]);
			quantity_format(quantity_by_path(path), at(p, keys[k]), QUANTITY_UNIT, v[k],
					sizeof(v[k]));
		}
		fprintf(f, "%s  %zu: azimuth %s, offset %s, length %s, %lld points: RMS %s, PV %s, "
			"slope RMS %s, max %s\n", indent, i + 1, v[0], v[1], v[2],
			count(p, "n_used"), v[3], v[4], v[5], v[6]);
	}
}

/* One line per toleranced quantity: the value with its sign (a two-sided
 * one is decided on its magnitude: its limit reads "+-"), U and the
 * limit in the value's unit. */
static void print_verdict(FILE *f, const json_t *s, const char *indent)
{
	const json_t *v = json_object_get(s, "verdict"), *it;
	size_t i;

	if (!json_is_object(v))
		return;
	fprintf(f, "%sVerdict (ISO 14253-1, U for k = 2): %s\n", indent, text(v, "overall"));
	json_array_foreach(json_object_get(v, "items"), i, it) {
		const struct quantity *q = quantity_by_verdict(text(it, "quantity"));
		char val[48], u[32], lim[32];

		quantity_format(q, at(it, "value"), QUANTITY_UNIT, val, sizeof(val));
		quantity_format(q, at(it, "U"), QUANTITY_NO_SIGN, u, sizeof(u));
		strcpy(lim, q && q->two_sided ? "+-" : "");
		quantity_format(q, at(it, "limit"), QUANTITY_NO_SIGN, lim + strlen(lim),
				sizeof(lim) - 2);
		fprintf(f, "%s  %-14s %16s  U %-10s limit %-12s %s\n", indent,
			q ? q->label : text(it, "quantity"), val, u, lim, text(it, "verdict"));
	}
}

void fit_summary_print(FILE *f, const json_t *summary, const char *indent)
{
	print_fit(f, summary, indent);
	print_pose(f, summary, indent);
	print_residual(f, summary, indent);
	print_form(f, summary, indent);
	print_slope(f, summary, indent);
	print_profiles(f, summary, indent);
	print_radius(f, summary, indent);
	print_verdict(f, summary, indent);
}

void fit_summary_print_zernike(FILE *f, const json_t *summary, const char *indent)
{
	const struct quantity *q = quantity_by_path("zernike_nm");
	const json_t *z = json_object_get(summary, "zernike_nm"), *v;
	size_t j;

	if (json_is_true(json_object_get(summary, "profile"))) {
		fprintf(f, "%sNo Zernike decomposition of line profiles (the terms alias on lines)\n",
			indent);
		return;
	}
	if (json_array_size(z) == 0) {
		fprintf(f, "%sToo few points for the Zernike decomposition (PVr and slope need it)\n",
			indent);
		return;
	}
	fprintf(f, "%sZernike terms of the residual (Noll, %s; Z1-Z3 are taken by the rigid DOF):\n",
		indent, q->unit);
	json_array_foreach(z, j, v) {
		char buf[32];
		fprintf(f, "%s  Z%-2zu %9s", j % 4 ? "" : indent, j + 1,
			quantity_format(q, json_number_value(v), 0, buf, sizeof(buf)));
		if (j % 4 == 3 || j + 1 == json_array_size(z))
			fputc('\n', f);
	}
}

void fit_summary_print_acquisition(FILE *f, const json_t *a, const char *indent)
{
	const json_t *d = json_object_get(a, "drift"), *v;
	const char *key;
	size_t i;

	if (!json_is_object(a))
		return;
	fprintf(f, "%sPositions:", indent);
	json_object_foreach(json_object_get(a, "positions"), key, v)
		if (json_integer_value(v))
			fprintf(f, " %lld %s", (long long)json_integer_value(v), key);
	fputc('\n', f);
	if (json_is_true(json_object_get(d, "corrected"))) {
		char max[32], rms[32];
		fprintf(f, "%sDrift corrected from %lld rounds of %lld references (%s) over %.0f s: "
			"max %s, RMS %s\n", indent, count(d, "rounds"), count(d, "references"),
			text(d, "components"), at(d, "span_s"),
			quantity_format(quantity_by_path("acquisition.drift.max_nm"), at(d, "max_nm"),
					QUANTITY_UNIT, max, sizeof(max)),
			quantity_format(quantity_by_path("acquisition.drift.rms_nm"), at(d, "rms_nm"),
					QUANTITY_UNIT, rms, sizeof(rms)));
	} else {
		fprintf(f, "%sDrift not corrected: the scan has no drift references to model it\n",
			indent);
	}
	json_array_foreach(json_object_get(a, "warnings"), i, v)
		fprintf(f, "%sWarning: %s\n", indent, json_string_value(v));
}
