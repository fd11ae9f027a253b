/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The JSON summary of a fit: one builder for `asph fit --json` and the
 * results asphd stores, so both carry the same keys. */
#include <errno.h>
#include <math.h>

#include <jansson.h>

#include "asph/fit.h"
#include "util-mem.h"

static json_t *json_num(double v)
{
	return isfinite(v) ? json_real(v) : json_null();
}

static json_t *dof_object(const struct asph_fit_result *r, const double *v)
{
	json_t *o = json_object();

	for (int d = 0; o && d < ASPH_FIT_N_DOF; d++)
		if (r->dof & ASPH_FIT_DOF_BIT(d))
			json_object_set_new(o, asph_fit_dof_name((enum asph_fit_dof)d),
					    json_num(v[d]));
	return o;
}

static json_t *result_json(const struct asph_fit_result *r, const char *lens,
			   int robust)
{
	json_t *root = json_object();
	json_t *z = json_array();

	if (!root || !z) {
		json_decref(root);
		json_decref(z);
		return NULL;
	}
	for (int j = 0; j < r->n_zernike; j++)
		json_array_append_new(z, json_real(r->zernike[j].v));
	json_object_set_new(root, "lens", lens ? json_string(lens) : json_null());
	json_object_set_new(root, "n_points", json_integer((json_int_t)r->n_points));
	json_object_set_new(root, "n_used", json_integer((json_int_t)r->n_used));
	json_object_set_new(root, "n_outside_aperture", json_integer((json_int_t)r->n_outside_aperture));
	json_object_set_new(root, "n_outliers", json_integer((json_int_t)r->n_outliers));
	json_object_set_new(root, "n_downweighted", json_integer((json_int_t)r->n_downweighted));
	json_object_set_new(root, "residual", json_string(asph_fit_residual_name(r->residual)));
	json_object_set_new(root, "robust", json_boolean(robust));
	json_object_set_new(root, "dof", dof_object(r, r->value));
	json_object_set_new(root, "uncertainty", dof_object(r, r->uncertainty));
	json_object_set_new(root, "iterations", json_integer(r->iterations));
	json_object_set_new(root, "passes", json_integer(r->passes));
	json_object_set_new(root, "converged", json_boolean(r->converged));
	json_object_set_new(root, "reason", json_string(r->reason));
	json_object_set_new(root, "sigma_nm", json_num(asph_nm_from_mm(r->sigma_mm).v));
	json_object_set_new(root, "rms_nm", json_num(r->rms.v));
	json_object_set_new(root, "pv_nm", json_num(r->pv.v));
	json_object_set_new(root, "pvr_nm", json_num(r->pvr.v));
	json_object_set_new(root, "zernike_fit_rms_left_nm", json_num(r->zernike_fit_rms_left.v));
	json_object_set_new(root, "slope_rms_urad", json_num(r->slope_rms.v));
	json_object_set_new(root, "zernike_nm", z);
	return root;
}

int asph_fit_result_to_json(const struct asph_fit_result *r, const char *lens,
			    int robust, char **out)
{
	_cleanup_(json_decrefp) json_t *root = result_json(r, lens, robust);

	*out = root ? json_dumps(root, JSON_COMPACT | JSON_REAL_PRECISION(17)) : NULL;
	return *out ? 0 : -ENOMEM;
}
