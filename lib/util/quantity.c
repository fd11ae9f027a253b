/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "quantity.h"

/*
 * nm to 0.01 nm and urad to 0.01 urad: well below any probe's noise, and
 * what the tolerances are written in. Fringes to 1e-4 (0.03 nm of 546 nm
 * light). The pose in um and urad to 1e-4 (0.1 nm, 0.1 nrad), R to 1 nm,
 * the curvature c to six significant digits (it may be 0 or 1e-9 /mm).
 */
static const struct quantity quantities[] = {
	/* path, uncertainty key, verdict item, label, unit, scale, decimals, sign,
	 * two-sided */
	{ "dof.tx", "tx", NULL, "tx", "um", 1e3, 4, true, false },
	{ "dof.ty", "ty", NULL, "ty", "um", 1e3, 4, true, false },
	{ "dof.tz", "tz", NULL, "tz", "um", 1e3, 4, true, false },
	{ "dof.rx", "rx", NULL, "rx", "urad", 1e6, 4, true, false },
	{ "dof.ry", "ry", NULL, "ry", "urad", 1e6, 4, true, false },
	{ "dof.rz", "rz", NULL, "rz", "urad", 1e6, 4, true, false },
	{ "dof.R", "R_mm", NULL, "R", "mm", 1, 6, false, false },
	{ "dof.c", "c_per_mm", NULL, "c", "1/mm", 1, -1, true, false },
	{ "dof.k", "k", NULL, "k", "", 1, 6, false, false },
	{ "sigma_nm", NULL, NULL, "sigma", "nm", 1, 2, false, false },
	{ "rms_nm", "rms_nm", NULL, "RMS", "nm", 1, 2, false, false },
	{ "pv_nm", "pv_nm", NULL, "PV", "nm", 1, 2, false, false },
	{ "pvr_nm", "pvr_nm", NULL, "PVr", "nm", 1, 2, false, false },
	{ "zernike_fit_rms_left_nm", NULL, NULL, "RMS left by the Zernike fit", "nm", 1, 2, false,
	  false },
	{ "slope_rms_urad", NULL, NULL, "Zernike slope RMS", "urad", 1, 2, false, false },
	{ "zernike_nm", NULL, NULL, "Zernike term", "nm", 1, 2, true, false },
	{ "form.A_nm", "A_nm", "A_nm", "A", "nm", 1, 2, true, true },
	{ "form.B_nm", "B_nm", "B_nm", "B", "nm", 1, 2, false, false },
	{ "form.C_nm", "C_nm", "C_nm", "C", "nm", 1, 2, false, false },
	{ "form.A_fringes", "A_fringes", NULL, "A", "fr", 1, 4, true, false },
	{ "form.B_fringes", "B_fringes", NULL, "B", "fr", 1, 4, false, false },
	{ "form.C_fringes", "C_fringes", NULL, "C", "fr", 1, 4, false, false },
	{ "form.rms_t_nm", "rms_t_nm", "rms_t_nm", "RMSt", "nm", 1, 2, false, false },
	{ "form.rms_i_nm", "rms_i_nm", "rms_i_nm", "RMSi", "nm", 1, 2, false, false },
	{ "form.rms_a_nm", "rms_a_nm", "rms_a_nm", "RMSa", "nm", 1, 2, false, false },
	{ "form.wavelength_nm", NULL, NULL, "lambda", "nm", 1, 2, false, false },
	{ "slope.rms_urad", "rms_urad", "slope_rms_urad", "slope RMS", "urad", 1, 2, false, false },
	{ "slope.max_urad", "max_urad", "slope_max_urad", "slope max", "urad", 1, 2, false, false },
	{ "slope.rms_radial_urad", NULL, NULL, "radial", "urad", 1, 2, false, false },
	{ "slope.max_radial_urad", NULL, NULL, "radial max", "urad", 1, 2, false, false },
	{ "slope.rms_azimuthal_urad", NULL, NULL, "azimuthal", "urad", 1, 2, false, false },
	{ "slope.max_azimuthal_urad", NULL, NULL, "azimuthal max", "urad", 1, 2, false, false },
	{ "slope.length_mm", NULL, NULL, "evaluation length", "mm", 1, -1, false, false },
	{ "radius.R_mm", NULL, NULL, "R", "mm", 1, 6, false, false },
	{ "radius.nominal_mm", NULL, NULL, "R nominal", "mm", 1, 6, false, false },
	{ "radius.deviation_mm", "deviation_mm", "R_deviation_mm", "R - R nominal", "mm", 1, 6,
	  true, true },
	{ "radius.c_per_mm", NULL, NULL, "c", "1/mm", 1, -1, true, false },
	{ "radius.nominal_c_per_mm", NULL, NULL, "c nominal", "1/mm", 1, -1, true, false },
	/* each trace of line profiles (an array of them in the summary) */
	{ "profiles.azimuth_deg", NULL, NULL, "azimuth", "deg", 1, 2, true, false },
	{ "profiles.offset_mm", NULL, NULL, "offset", "mm", 1, 4, true, false },
	{ "profiles.length_mm", NULL, NULL, "length", "mm", 1, 3, false, false },
	{ "profiles.rms_nm", NULL, NULL, "RMS", "nm", 1, 2, false, false },
	{ "profiles.pv_nm", NULL, NULL, "PV", "nm", 1, 2, false, false },
	{ "profiles.slope_rms_urad", NULL, NULL, "slope RMS", "urad", 1, 2, false, false },
	{ "profiles.slope_max_urad", NULL, NULL, "slope max", "urad", 1, 2, false, false },
	{ "band_rms.form_nm", NULL, NULL, "form", "nm", 1, 2, false, false },
	{ "band_rms.mid_nm", NULL, NULL, "mid", "nm", 1, 2, false, false },
	{ "band_rms.high_nm", NULL, NULL, "high", "nm", 1, 2, false, false },
	{ "band_rms.total_nm", NULL, NULL, "total", "nm", 1, 2, false, false },
	{ "acquisition.drift.max_nm", NULL, NULL, "drift max", "nm", 1, 2, false, false },
	{ "acquisition.drift.rms_nm", NULL, NULL, "drift RMS", "nm", 1, 2, false, false },
};

const char *quantity_symbol(const struct quantity *q)
{
	static const struct {
		const char *unit, *symbol;
	} symbols[] = { { "um", "µm" }, { "urad", "µrad" } };

	for (size_t i = 0; i < sizeof(symbols) / sizeof(symbols[0]); i++)
		if (!strcmp(q->unit, symbols[i].unit))
			return symbols[i].symbol;
	return q->unit;
}

const struct quantity *quantity_table(size_t *n)
{
	*n = sizeof(quantities) / sizeof(quantities[0]);
	return quantities;
}

#define FIND_BY(member)                                                         \
	for (size_t i = 0; name && i < sizeof(quantities) / sizeof(quantities[0]); i++) \
		if (quantities[i].member && !strcmp(quantities[i].member, name)) \
			return &quantities[i];                                  \
	return NULL

const struct quantity *quantity_by_path(const char *name)
{
	FIND_BY(path);
}

const struct quantity *quantity_by_verdict(const char *name)
{
	FIND_BY(verdict);
}

const struct quantity *quantity_by_u_key(const char *name)
{
	FIND_BY(u_key);
}

const char *quantity_format(const struct quantity *q, double v, unsigned flags, char *buf,
			    size_t size)
{
	bool plus = q && q->sign && !(flags & QUANTITY_NO_SIGN);
	const char *unit = q && (flags & QUANTITY_UNIT) && q->unit[0] ? q->unit : NULL;
	double x;

	if (isnan(v)) {
		snprintf(buf, size, "-");
		return buf;
	}
	x = q ? v * q->scale : v;
	/* no figure of a measurement is this large: its digits would not fit
	 * where it is shown */
	if (fabs(x) >= QUANTITY_MAX_FIXED) {
		snprintf(buf, size, "%.6g%s%s", x, unit ? " " : "", unit ? unit : "");
		return buf;
	}
	/* no "-0.00" or "+0.00": a value that rounds to zero reads as zero */
	if (q && q->decimals >= 0 && fabs(x) < 0.5 * pow(10, -q->decimals)) {
		x = 0;
		plus = false;
	}
	if (!q || q->decimals < 0)
		snprintf(buf, size, plus ? "%+g%s%s" : "%g%s%s", x, unit ? " " : "",
			 unit ? unit : "");
	else
		snprintf(buf, size, plus ? "%+.*f%s%s" : "%.*f%s%s", q->decimals, x, unit ? " " : "",
			 unit ? unit : "");
	return buf;
}
