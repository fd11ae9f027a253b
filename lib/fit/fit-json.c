/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The JSON summary of a fit: one builder for `asph fit --json` and the
 * results asphd stores, so both carry the same keys. */
#include <errno.h>
#include <math.h>
#include <stddef.h>

#include <jansson.h>

#include "asph/fit.h"
#include "util-mem.h"

static json_t *json_num(double v)
{
	return isfinite(v) ? json_real(v) : json_null();
}

/* The DOF fitted, name to value; with R its curvature c beside it. */
static json_t *dof_object(const struct asph_fit_result *r, const double *v, double c)
{
	json_t *o = json_object();

	for (int d = 0; o && d < ASPH_FIT_N_DOF; d++) {
		if (!(r->dof & ASPH_FIT_DOF_BIT(d)))
			continue;
		json_object_set_new(o, asph_fit_dof_name((enum asph_fit_dof)d), json_num(v[d]));
		if (d == ASPH_FIT_R)
			json_object_set_new(o, "c", json_num(c));
	}
	return o;
}

/* Line profiles: each trace with what the fit leaves along it. */
static json_t *profiles_array(const struct asph_fit_result *r)
{
	json_t *a;

	if (!r->profile)
		return json_null();
	a = json_array();
	for (size_t t = 0; a && t < r->n_profiles; t++) {
		const struct asph_fit_profile *p = &r->profiles[t];
		json_t *o = json_object();
		json_object_set_new(o, "azimuth_deg", json_num(p->azimuth * 180 / M_PI));
		json_object_set_new(o, "offset_mm", json_num(p->offset_mm));
		json_object_set_new(o, "length_mm", json_num(p->length_mm));
		json_object_set_new(o, "n_points", json_integer((json_int_t)p->n_points));
		json_object_set_new(o, "n_used", json_integer((json_int_t)p->n_used));
		json_object_set_new(o, "rms_nm", json_num(p->rms.v));
		json_object_set_new(o, "pv_nm", json_num(p->pv.v));
		json_object_set_new(o, "slope_rms_urad", json_num(p->slope_rms.v));
		json_object_set_new(o, "slope_max_urad", json_num(p->slope_max.v));
		json_object_set_new(o, "n_slope_positions", json_integer((json_int_t)p->n_slope));
		json_array_append_new(a, o);
	}
	return a;
}

/* A number of a result's struct, at its offset, under its key. */
struct number_member {
	const char *key;
	size_t offset;          /* of a double */
};

#define NUMBER(type, key, member) { key, offsetof(type, member) }

/* The numbers members[0, n) of base as one object, in that order. */
static json_t *numbers_object(const void *base, const struct number_member *members, size_t n)
{
	json_t *o = json_object();

	for (size_t i = 0; o && i < n; i++)
		json_object_set_new(o, members[i].key,
				    json_num(*(const double *)((const char *)base +
							       members[i].offset)));
	return o;
}

#define NUMBERS_OBJECT(base, members) numbers_object(base, members, ARRAY_SIZE(members))

static const struct number_member form_members[] = {
	NUMBER(struct asph_form, "A_nm", A.v),
	NUMBER(struct asph_form, "B_nm", B.v),
	NUMBER(struct asph_form, "C_nm", C.v),
	NUMBER(struct asph_form, "A_fringes", A_fringes),
	NUMBER(struct asph_form, "B_fringes", B_fringes),
	NUMBER(struct asph_form, "C_fringes", C_fringes),
	NUMBER(struct asph_form, "rms_t_nm", rms_t.v),
	NUMBER(struct asph_form, "rms_i_nm", rms_i.v),
	NUMBER(struct asph_form, "rms_a_nm", rms_a.v),
	NUMBER(struct asph_form, "wavelength_nm", wavelength_nm),
};

static const struct number_member slope_members[] = {
	NUMBER(struct asph_slope, "rms_urad", rms.v),
	NUMBER(struct asph_slope, "max_urad", max.v),
	NUMBER(struct asph_slope, "length_mm", length_mm),
	NUMBER(struct asph_slope, "rms_radial_urad", rms_radial.v),
	NUMBER(struct asph_slope, "max_radial_urad", max_radial.v),
	NUMBER(struct asph_slope, "rms_azimuthal_urad", rms_azimuthal.v),
	NUMBER(struct asph_slope, "max_azimuthal_urad", max_azimuthal.v),
};

static const struct number_member radius_members[] = {
	NUMBER(struct asph_fit_result, "R_mm", value[ASPH_FIT_R]),
	NUMBER(struct asph_fit_result, "nominal_mm", R_nominal_mm),
	NUMBER(struct asph_fit_result, "deviation_mm", R_deviation_mm),
	NUMBER(struct asph_fit_result, "c_per_mm", curvature),
	NUMBER(struct asph_fit_result, "nominal_c_per_mm", curvature_nominal),
};

/* The same keys as the quantities covered (form, slope, radius). */
static const struct number_member uncertainty_members[] = {
	NUMBER(struct asph_uncertainty_k2, "A_nm", A.v),
	NUMBER(struct asph_uncertainty_k2, "B_nm", B.v),
	NUMBER(struct asph_uncertainty_k2, "C_nm", C.v),
	NUMBER(struct asph_uncertainty_k2, "A_fringes", A_fringes),
	NUMBER(struct asph_uncertainty_k2, "B_fringes", B_fringes),
	NUMBER(struct asph_uncertainty_k2, "C_fringes", C_fringes),
	NUMBER(struct asph_uncertainty_k2, "rms_t_nm", rms_t.v),
	NUMBER(struct asph_uncertainty_k2, "rms_i_nm", rms_i.v),
	NUMBER(struct asph_uncertainty_k2, "rms_a_nm", rms_a.v),
	NUMBER(struct asph_uncertainty_k2, "rms_urad", slope_rms.v),
	NUMBER(struct asph_uncertainty_k2, "max_urad", slope_max.v),
	NUMBER(struct asph_uncertainty_k2, "R_mm", R_mm),
	NUMBER(struct asph_uncertainty_k2, "deviation_mm", R_mm),
	NUMBER(struct asph_uncertainty_k2, "c_per_mm", c_per_mm),
};

static json_t *slope_object(const struct asph_slope *sl)
{
	json_t *o = NUMBERS_OBJECT(sl, slope_members);

	if (o)
		json_object_set_new(o, "n_positions", json_integer((json_int_t)sl->n));
	return o;
}

static json_t *radius_object(const struct asph_fit_result *r)
{
	if (!(r->dof & ASPH_FIT_DOF_BIT(ASPH_FIT_R)))
		return json_null();
	return NUMBERS_OBJECT(r, radius_members);
}

static json_t *verdict_object(const struct asph_verdict_report *v)
{
	json_t *o, *items;

	if (!v->present)
		return json_null();
	o = json_object();
	items = json_array();
	if (!o || !items) {
		json_decref(o);
		json_decref(items);
		return NULL;
	}
	for (size_t i = 0; i < v->n_items; i++) {
		const struct asph_verdict_item *it = &v->items[i];
		json_t *e = json_object();
		json_object_set_new(e, "quantity", json_string(it->quantity));
		json_object_set_new(e, "value", json_num(it->value));
		json_object_set_new(e, "U", json_num(it->U));
		json_object_set_new(e, "limit", json_num(it->limit));
		json_object_set_new(e, "verdict", json_string(asph_verdict_name(it->verdict)));
		json_array_append_new(items, e);
	}
	json_object_set_new(o, "overall", json_string(asph_verdict_name(v->overall)));
	json_object_set_new(o, "items", items);
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
	json_object_set_new(root, "profile", json_boolean(r->profile));
	json_object_set_new(root, "dof", dof_object(r, r->value, r->curvature));
	json_object_set_new(root, "uncertainty", dof_object(r, r->uncertainty, r->u_curvature));
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
	json_object_set_new(root, "form", NUMBERS_OBJECT(&r->form, form_members));
	json_object_set_new(root, "slope", slope_object(&r->slope));
	json_object_set_new(root, "radius", radius_object(r));
	json_object_set_new(root, "profiles", profiles_array(r));
	json_object_set_new(root, "uncertainty_k2",
			    NUMBERS_OBJECT(&r->uncertainty_k2, uncertainty_members));
	json_object_set_new(root, "uncertainty_method",
			    json_string(asph_uncertainty_method_name(r->uncertainty_k2.method)));
	json_object_set_new(root, "verdict", verdict_object(&r->verdict));
	return root;
}

int asph_fit_result_to_json(const struct asph_fit_result *r, const char *lens,
			    int robust, char **out)
{
	_cleanup_(json_decrefp) json_t *root = result_json(r, lens, robust);

	*out = root ? json_dumps(root, JSON_COMPACT | JSON_REAL_PRECISION(17)) : NULL;
	return *out ? 0 : -ENOMEM;
}
