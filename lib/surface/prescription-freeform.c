/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The JSON members of the freeform prescriptions (docs/prescriptions.md). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "prescription-json.h"

int get_radius(const struct parse_ctx *c, json_t *v, const char *field, double *out)
{
	if (json_is_string(v)) {
		const char *s = json_string_value(v);
		int neg = s[0] == '-';
		if (!strcasecmp(s + neg, "infinity")) {
			*out = neg ? -INFINITY : INFINITY;
			return 0;
		}
		return json_error_set_at(c->err, -EINVAL, &c->src, field,
					 "expected a radius in mm, or \"infinity\" for a plane (got \"%s\")", s);
	}
	return get_number(c, v, field, out);
}

static int optional_radius(const struct parse_ctx *c, json_t *root, const char *key,
			   int required, const char *what, double *out)
{
	json_t *v = json_object_get(root, key);

	if (!v && required)
		return json_error_set_at(c->err, -EINVAL, &c->src, NULL,
					 "missing member \"%s\" (%s)", key, what);
	return v ? get_radius(c, v, key, out) : 0;
}

static int optional_number(const struct parse_ctx *c, json_t *root, const char *key, double *out)
{
	json_t *v = json_object_get(root, key);

	return v ? get_number(c, v, key, out) : 0;
}

/* A non-negative integer key written plainly ("12", not "012" or "+12"). */
static int plain_int(const char *s, const char *end, long *out)
{
	char *e;

	if (s == end || (s[0] == '0' && end - s > 1) || s[0] < '0' || s[0] > '9' || end - s > 4)
		return -1;
	*out = strtol(s, &e, 10);
	return e == end ? 0 : -1;
}

/* "c": {"x2y0": ..., "x1y2": ...}: c_ij for x^i y^j. */
static int parse_xy(const struct parse_ctx *c, json_t *obj, struct asph_prescription *out)
{
	const char *key;
	json_t *v;

	if (!json_is_object(obj))
		return json_error_set_at(c->err, -EINVAL, &c->src, "c",
					 "expected an object of coefficients, e.g. {\"x2y0\": 1.5e-3, \"x0y2\": 2e-3}");
	json_object_foreach(obj, key, v) {
		char field[80];
		const char *y = key[0] == 'x' ? strchr(key, 'y') : NULL;
		long i, j;
		snprintf(field, sizeof(field), "c.%.64s", key);
		if (!y || plain_int(key + 1, y, &i) < 0 || plain_int(y + 1, y + strlen(y), &j) < 0)
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "coefficient key '%s' is not xIyJ with plain whole numbers "
						 "(e.g. \"x2y1\" for x^2 y)", key);
		if (i + j < 1 || i + j > ASPH_SURFACE_XY_MAX_DEGREE)
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "x%ldy%ld has degree %ld; the degrees are 1 .. %d", i, j, i + j,
						 ASPH_SURFACE_XY_MAX_DEGREE);
		int r = get_number(c, v, field, &out->C[asph_xy_index((int)i, (int)j)]);
		if (r < 0)
			return r;
	}
	return 0;
}

/* An array of at most max numbers into dst. */
static int parse_array(const struct parse_ctx *c, json_t *arr, const char *name, size_t max,
		       const char *what, double *dst)
{
	size_t i;
	json_t *v;

	if (!json_is_array(arr))
		return json_error_set_at(c->err, -EINVAL, &c->src, name,
					 "expected an array of %s", what);
	if (json_array_size(arr) > max)
		return json_error_set_at(c->err, -EINVAL, &c->src, name,
					 "%zu values; at most %zu (%s)",
					 json_array_size(arr), max, what);
	json_array_foreach(arr, i, v) {
		char field[64];
		snprintf(field, sizeof(field), "%s.[%zu]", name, i);
		int r = get_number(c, v, field, &dst[i]);
		if (r < 0)
			return r;
	}
	return 0;
}

/* "a_m": {"1": [a_0^1, a_1^1, ...], "3": [...]}, likewise "b_m". */
static int parse_q2d_terms(const struct parse_ctx *c, json_t *obj, const char *name,
			   double (*dst)[ASPH_SURFACE_Q2D_MAX_N + 1])
{
	const char *key;
	json_t *v;

	if (!json_is_object(obj))
		return json_error_set_at(c->err, -EINVAL, &c->src, name,
					 "expected an object keyed by the azimuthal order m, e.g. {\"2\": [1e-4, -2e-5]}");
	json_object_foreach(obj, key, v) {
		char field[80];
		long m;
		snprintf(field, sizeof(field), "%s.%.64s", name, key);
		if (plain_int(key, key + strlen(key), &m) < 0 || m < 1 || m > ASPH_SURFACE_Q2D_MAX_M)
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "'%s' is not an azimuthal order m in 1 .. %d (m = 0 is \"a\")",
						 key, ASPH_SURFACE_Q2D_MAX_M);
		int r = parse_array(c, v, field, ASPH_SURFACE_Q2D_MAX_N + 1,
				    "coefficients n = 0, 1, ... in mm", dst[m - 1]);
		if (r < 0)
			return r;
	}
	return 0;
}

static const char *const shape_names[] = {
	[ASPH_APERTURE_CIRCULAR] = "circular",
	[ASPH_APERTURE_RECTANGULAR] = "rectangular",
	[ASPH_APERTURE_ELLIPTICAL] = "elliptical",
};

/* "aperture": {"shape": "rectangular", "width": 30, "height": 20,
 * "offset": [0, 12]}; a circle has "diameter". */
int parse_aperture(const struct parse_ctx *c, json_t *obj, struct asph_aperture *ap)
{
	const char *key, *allowed;
	json_t *v = json_is_object(obj) ? json_object_get(obj, "shape") : NULL;
	int r;

	if (!json_is_object(obj))
		return json_error_set_at(c->err, -EINVAL, &c->src, "aperture",
					 "expected an object such as {\"shape\": \"rectangular\", \"width\": 30, \"height\": 20}");
	if (!v || !json_is_string(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, v ? "aperture.shape" : "aperture",
					 "the aperture needs a \"shape\": circular, rectangular or elliptical");
	for (int s = ASPH_APERTURE_CIRCULAR; s <= ASPH_APERTURE_ELLIPTICAL; s++)
		if (!strcmp(json_string_value(v), shape_names[s]))
			ap->shape = (enum asph_aperture_shape)s;
	if (ap->shape == ASPH_APERTURE_FROM_DIAMETER)
		return json_error_set_at(c->err, -EINVAL, &c->src, "aperture.shape",
					 "unknown aperture shape '%s' (circular, rectangular, elliptical)",
					 json_string_value(v));
	int circle = ap->shape == ASPH_APERTURE_CIRCULAR;
	allowed = circle ? "shape, diameter, offset" : "shape, width, height, offset";
	json_object_foreach(obj, key, v) {
		char field[80];
		snprintf(field, sizeof(field), "aperture.%.64s", key);
		if (strcmp(key, "shape") && strcmp(key, "offset") &&
		    (circle ? strcmp(key, "diameter") : strcmp(key, "width") && strcmp(key, "height")))
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "unknown member '%s' for a %s aperture (expected %s)",
						 key, shape_names[ap->shape], allowed);
	}
	const char *const sizes[2] = { circle ? "diameter" : "width", circle ? "diameter" : "height" };
	double *dst[2] = { &ap->width, &ap->height };
	for (int k = 0; k < 2; k++) {
		char field[32];
		snprintf(field, sizeof(field), "aperture.%s", sizes[k]);
		v = json_object_get(obj, sizes[k]);
		if (!v)
			return json_error_set_at(c->err, -EINVAL, &c->src, "aperture",
						 "missing member \"%s\" (mm)", sizes[k]);
		if ((r = get_number(c, v, field, dst[k])) < 0)
			return r;
	}
	v = json_object_get(obj, "offset");
	if (v && (r = parse_array(c, v, "aperture.offset", 2, "x, y in mm", ap->offset)) < 0)
		return r;
	if (v && json_array_size(v) != 2)
		return json_error_set_at(c->err, -EINVAL, &c->src, "aperture.offset",
					 "expected [x, y] in mm");
	return 0;
}

int parse_freeform_members(const struct parse_ctx *c, json_t *root,
			   struct asph_prescription *out)
{
	const int biconic = out->type == ASPH_SURFACE_BICONIC;
	json_t *v;
	int r;

	if ((r = optional_radius(c, root, "Rx", biconic, "radius along x, mm", &out->Rx)) < 0 ||
	    (r = optional_radius(c, root, "Ry", biconic, "radius along y, mm", &out->Ry)) < 0 ||
	    (r = optional_number(c, root, "kx", &out->kx)) < 0 ||
	    (r = optional_number(c, root, "ky", &out->ky)) < 0 ||
	    (r = optional_radius(c, root, "R_rotation", out->type == ASPH_SURFACE_TOROIDAL,
				 "radius of rotation, mm", &out->R_rotation)) < 0)
		return r;
	if ((v = json_object_get(root, "c")) && (r = parse_xy(c, v, out)) < 0)
		return r;
	if ((v = json_object_get(root, "zernike")) &&
	    (r = parse_array(c, v, "zernike", ASPH_SURFACE_MAX_ZERNIKE,
			     "Zernike coefficients Z1, Z2, ... (Noll) in mm", out->Zernike)) < 0)
		return r;
	if ((v = json_object_get(root, "zernike_decenter"))) {
		if ((r = parse_array(c, v, "zernike_decenter", 2, "x, y in mm", out->zernike_decenter)) < 0)
			return r;
		if (json_array_size(v) != 2)
			return json_error_set_at(c->err, -EINVAL, &c->src, "zernike_decenter",
						 "expected [x, y] in mm");
	}
	if ((v = json_object_get(root, "a_m")) && (r = parse_q2d_terms(c, v, "a_m", out->q2d_a)) < 0)
		return r;
	if ((v = json_object_get(root, "b_m")) && (r = parse_q2d_terms(c, v, "b_m", out->q2d_b)) < 0)
		return r;
	if (out->type == ASPH_SURFACE_XY_POLYNOMIAL || out->type == ASPH_SURFACE_ZERNIKE_SAG ||
	    out->type == ASPH_SURFACE_Q2D) {
		if (!json_object_get(root, "norm_radius"))
			return json_error_set_at(c->err, -EINVAL, &c->src, NULL,
						 "missing member \"norm_radius\" (normalization radius, mm)");
	}
	return 0;
}

/* ---- writing ------------------------------------------------------------ */

static json_t *radius_json(double R)
{
	return isinf(R) ? json_string(R > 0 ? "infinity" : "-infinity") : json_real(R);
}

static json_t *array_json(const double *v, int n)
{
	json_t *arr = json_array();
	int used = 0;

	for (int i = 0; i < n; i++)
		if (v[i] != 0)
			used = i + 1;
	for (int i = 0; arr && i < used; i++)
		json_array_append_new(arr, json_real(v[i]));
	return arr;
}

static json_t *xy_json(const struct asph_prescription *p)
{
	json_t *o = json_object();

	for (int d = 1; o && d <= ASPH_SURFACE_XY_MAX_DEGREE; d++)
		for (int j = 0; j <= d; j++) {
			double c = p->C[asph_xy_index(d - j, j)];
			char key[16];
			if (c == 0)
				continue;
			snprintf(key, sizeof(key), "x%dy%d", d - j, j);
			json_object_set_new(o, key, json_real(c));
		}
	return o;
}

static json_t *q2d_json(const double (*t)[ASPH_SURFACE_Q2D_MAX_N + 1])
{
	json_t *o = json_object();

	for (int m = 1; o && m <= ASPH_SURFACE_Q2D_MAX_M; m++) {
		json_t *arr = array_json(t[m - 1], ASPH_SURFACE_Q2D_MAX_N + 1);
		char key[8];
		snprintf(key, sizeof(key), "%d", m);
		if (arr && json_array_size(arr) > 0)
			json_object_set_new(o, key, arr);
		else
			json_decref(arr);
	}
	return o;
}

static json_t *aperture_json(const struct asph_aperture *ap)
{
	json_t *o = json_object();

	if (!o)
		return NULL;
	json_object_set_new(o, "shape", json_string(shape_names[ap->shape]));
	if (ap->shape == ASPH_APERTURE_CIRCULAR) {
		json_object_set_new(o, "diameter", json_real(ap->width));
	} else {
		json_object_set_new(o, "width", json_real(ap->width));
		json_object_set_new(o, "height", json_real(ap->height));
	}
	if (ap->offset[0] != 0 || ap->offset[1] != 0)
		json_object_set_new(o, "offset", json_pack("[ff]", ap->offset[0], ap->offset[1]));
	return o;
}

void aperture_to_json(json_t *o, const struct asph_prescription *p)
{
	if (p->aperture.shape == ASPH_APERTURE_FROM_DIAMETER)
		json_object_set_new(o, "aperture_diameter", json_real(p->aperture_diameter));
	else
		json_object_set_new(o, "aperture", aperture_json(&p->aperture));
}

json_t *freeform_to_json(const struct asph_prescription *p)
{
	json_t *o = json_object();
	enum asph_surface_type t = p->type;

	if (!o)
		return NULL;
	json_object_set_new(o, "type", json_string(asph_surface_type_name(t)));
	if (p->name[0])
		json_object_set_new(o, "name", json_string(p->name));
	if (p->note[0])
		json_object_set_new(o, "note", json_string(p->note));
	if (t == ASPH_SURFACE_BICONIC) {
		json_object_set_new(o, "Rx", radius_json(p->Rx));
		json_object_set_new(o, "Ry", radius_json(p->Ry));
		json_object_set_new(o, "kx", json_real(p->kx));
		json_object_set_new(o, "ky", json_real(p->ky));
	} else {
		json_object_set_new(o, "R", radius_json(p->R));
		if (asph_surface_type_has_conic(t))
			json_object_set_new(o, "k", json_real(p->k));
	}
	if (t == ASPH_SURFACE_TOROIDAL)
		json_object_set_new(o, "R_rotation", radius_json(p->R_rotation));
	if (t == ASPH_SURFACE_BICONIC || t == ASPH_SURFACE_TOROIDAL || t == ASPH_SURFACE_ZERNIKE_SAG)
		json_object_set_new(o, "A", power_object(p));
	if (p->norm_radius > 0)
		json_object_set_new(o, "norm_radius", json_real(p->norm_radius));
	if (t == ASPH_SURFACE_XY_POLYNOMIAL)
		json_object_set_new(o, "c", xy_json(p));
	if (t == ASPH_SURFACE_ZERNIKE_SAG || t == ASPH_SURFACE_TOROIDAL) {
		json_t *z = array_json(p->Zernike, ASPH_SURFACE_MAX_ZERNIKE);
		if (t == ASPH_SURFACE_ZERNIKE_SAG || json_array_size(z) > 0)
			json_object_set_new(o, "zernike", z);
		else
			json_decref(z);
		if (p->zernike_decenter[0] != 0 || p->zernike_decenter[1] != 0)
			json_object_set_new(o, "zernike_decenter",
					    json_pack("[ff]", p->zernike_decenter[0], p->zernike_decenter[1]));
	}
	if (t == ASPH_SURFACE_Q2D) {
		json_object_set_new(o, "a", q_array(p));
		json_object_set_new(o, "a_m", q2d_json(p->q2d_a));
		json_object_set_new(o, "b_m", q2d_json(p->q2d_b));
	}
	aperture_to_json(o, p);
	return o;
}
