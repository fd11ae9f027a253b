/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The instrument's declared uncertainty contributions. */
#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include <jansson.h>

#include "asph/uncertainty.h"
#include "util-mem.h"

static const struct asph_uncertainty_field fields[] = {
	{ "probe_noise_nm", "nm", "probe reading noise per point, along z (standard deviation)" },
	{ "position_noise_um", "um", "stage position noise per point and axis x, y (standard deviation)" },
	{ "position_resolution_um", "um", "encoder step of x and y (uniform error on +-step/2)" },
	{ "latency_us", "us", "residual latency between position latch and reading (standard uncertainty)" },
	{ "scan_speed_mm_s", "mm/s", "speed along the scan path (turns the latency into a lateral error)" },
	{ "drift_residual_nm", "nm", "z drift left after the drift correction at the end of the scan (standard uncertainty)" },
	{ "tip_radius_um", "um", "tip radius (standard uncertainty), along the surface normal" },
};

/* Where each of fields[] lives in the model, in the same order. */
static const size_t offsets[] = {
	offsetof(struct asph_uncertainty_model, probe_noise_nm),
	offsetof(struct asph_uncertainty_model, position_noise_um),
	offsetof(struct asph_uncertainty_model, position_resolution_um),
	offsetof(struct asph_uncertainty_model, latency_us),
	offsetof(struct asph_uncertainty_model, scan_speed_mm_s),
	offsetof(struct asph_uncertainty_model, drift_residual_nm),
	offsetof(struct asph_uncertainty_model, tip_radius_um),
};

#define N_FIELDS (sizeof(fields) / sizeof(fields[0]))
_Static_assert(sizeof(offsets) / sizeof(offsets[0]) == N_FIELDS, "one offset per field");

static double *member(struct asph_uncertainty_model *m, size_t i)
{
	return (double *)((char *)m + offsets[i]);
}

static double member_value(const struct asph_uncertainty_model *m, size_t i)
{
	return *(const double *)((const char *)m + offsets[i]);
}

void asph_uncertainty_model_init(struct asph_uncertainty_model *m)
{
	memset(m, 0, sizeof(*m));
}

int asph_uncertainty_model_is_empty(const struct asph_uncertainty_model *m)
{
	/* the scan speed alone contributes nothing */
	return m->probe_noise_nm == 0 && m->position_noise_um == 0 &&
	       m->position_resolution_um == 0 && m->latency_us == 0 &&
	       m->drift_residual_nm == 0 && m->tip_radius_um == 0;
}

const struct asph_uncertainty_field *asph_uncertainty_model_fields(size_t *n)
{
	*n = N_FIELDS;
	return fields;
}

int asph_uncertainty_model_set(struct asph_uncertainty_model *m,
			       const char *name, double v,
			       struct asph_error *err)
{
	for (size_t i = 0; i < N_FIELDS; i++) {
		if (strcmp(name, fields[i].name))
			continue;
		if (!isfinite(v) || v < 0)
			return asph_error_set(err, -EINVAL, "%s must be a number >= 0 (%s)", name,
					      fields[i].unit);
		*member(m, i) = v;
		return 0;
	}
	return asph_error_set(err, -ENOENT,
			      "unknown contribution '%s' (probe_noise_nm, position_noise_um, "
			      "position_resolution_um, latency_us, scan_speed_mm_s, "
			      "drift_residual_nm, tip_radius_um)", name);
}

int asph_uncertainty_model_check(const struct asph_uncertainty_model *m,
				 struct asph_error *err)
{
	for (size_t i = 0; i < N_FIELDS; i++) {
		double v = member_value(m, i);
		if (!isfinite(v) || v < 0) {
			asph_error_set(err, -EINVAL, "%s must be a number >= 0 (%s)",
				       fields[i].name, fields[i].unit);
			if (err)
				snprintf(err->field, sizeof(err->field), "%s", fields[i].name);
			return -EINVAL;
		}
	}
	if (m->latency_us > 0 && !(m->scan_speed_mm_s > 0)) {
		asph_error_set(err, -EINVAL, "latency_us needs scan_speed_mm_s > 0 to become a "
			       "position error");
		if (err)
			snprintf(err->field, sizeof(err->field), "scan_speed_mm_s");
		return -EINVAL;
	}
	return 0;
}

int asph_uncertainty_model_to_json(const struct asph_uncertainty_model *m,
				   char **out)
{
	_cleanup_(json_decrefp) json_t *o = json_object();

	for (size_t i = 0; o && i < N_FIELDS; i++)
		json_object_set_new(o, fields[i].name, json_real(member_value(m, i)));
	*out = o ? json_dumps(o, JSON_COMPACT | JSON_PRESERVE_ORDER | JSON_REAL_PRECISION(17))
		 : NULL;
	return *out ? 0 : -ENOMEM;
}
