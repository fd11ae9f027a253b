/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <stdarg.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/prescription.h"
#include "fileio.h"
#include "jsonpos.h"
#include "prescription-json.h"
#include "util-mem.h"
#include "util-suggest.h"


/* Table 1 of the paper (it calls the coefficients alpha_4..alpha_12):
 * X(name, R, k, A4, A6, A8, A10, A12, diameter). */
#define PRESETS(X)                                                           \
	X("weak", 40.6193, 0, -6.79375e-7, -4.85203e-10, -2.05223e-13,        \
	  -6.2324e-17, -4.4857e-20, 39)                                       \
	X("strong", 20.097, -1, -2.0868e-5, -3.9031e-9, 3.4102e-11,           \
	  -3.2381e-14, 0, 40)                                                 \
	X("turning-point", 94.6, -23.2046, -6.86465e-6, -1.21832e-8,          \
	  2.22491e-11, -8.06098e-14, 0, 60)

static const struct preset {
	const char *name;
	double R, k, A4, A6, A8, A10, A12, diameter;
} presets[] = {
#define PRESET_ROW(name, ...) { name, __VA_ARGS__ },
	PRESETS(PRESET_ROW)
#undef PRESET_ROW
};

static const char *const preset_names[] = {
#define PRESET_NAME(name, ...) name,
	PRESETS(PRESET_NAME)
#undef PRESET_NAME
	NULL
};

const char *const *asph_prescription_preset_names(void)
{
	return preset_names;
}

int asph_prescription_preset(const char *name, struct asph_prescription *out)
{
	for (size_t i = 0; i < ARRAY_SIZE(presets); i++) {
		const struct preset *p = &presets[i];
		if (strcmp(name, p->name))
			continue;
		memset(out, 0, sizeof(*out));
		out->type = ASPH_SURFACE_EVEN_ASPHERE;
		snprintf(out->name, sizeof(out->name), "%s", p->name);
		out->R = p->R;
		out->k = p->k;
		out->A[4] = p->A4;
		out->A[6] = p->A6;
		out->A[8] = p->A8;
		out->A[10] = p->A10;
		out->A[12] = p->A12;
		out->aperture_diameter = p->diameter;
		return 0;
	}
	return -ENOENT;
}

static int parse_coefficients(const struct parse_ctx *c, json_t *obj,
			      struct asph_prescription *out)
{
	const int odd = out->type == ASPH_SURFACE_ODD_ASPHERE;
	const char *key;
	json_t *v;

	if (!json_is_object(obj))
		return json_error_set_at(c->err, -EINVAL, &c->src, "A",
					 "expected an object of coefficients, e.g. {\"4\": -2.1e-5}");
	json_object_foreach(obj, key, v) {
		char field[64], *end;
		snprintf(field, sizeof(field), "A.%s", key);
		errno = 0;
		long power = strtol(key, &end, 10);
		/* Only the plain decimal spelling: "04" beside "4" would
		 * otherwise name the same term twice, the later one winning. */
		int plain = (key[0] >= '1' && key[0] <= '9') || !strcmp(key, "0");
		if (!plain || *end != '\0' || errno)
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "coefficient key '%s' is not a power of r written as a plain number (e.g. \"4\")",
						 key);
		if (odd && (power < 1 || power > ASPH_SURFACE_MAX_POWER))
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "an odd asphere has coefficients for powers 1, 2, ..., %d; got %ld",
						 ASPH_SURFACE_MAX_POWER, power);
		if (!odd && (power < 2 || power > ASPH_SURFACE_MAX_POWER || power % 2))
			return json_error_set_at(c->err, -EINVAL, &c->src, field,
						 "an even asphere has coefficients for powers 2, 4, ..., %d; got %ld",
						 ASPH_SURFACE_MAX_POWER, power);
		int r = get_number(c, v, field, &out->A[power]);
		if (r < 0)
			return r;
	}
	return 0;
}

/* "a": [a0, a1, ...], the Q coefficients in mm. */
static int parse_q_coefficients(const struct parse_ctx *c, json_t *arr,
				struct asph_prescription *out)
{
	size_t i;
	json_t *v;

	if (!json_is_array(arr))
		return json_error_set_at(c->err, -EINVAL, &c->src, "a",
					 "expected an array of Q coefficients [a0, a1, ...] in mm");
	if (json_array_size(arr) > ASPH_SURFACE_MAX_Q + 1)
		return json_error_set_at(c->err, -EINVAL, &c->src, "a",
					 "%zu Q coefficients; at most %d (a0..a%d)",
					 json_array_size(arr), ASPH_SURFACE_MAX_Q + 1,
					 ASPH_SURFACE_MAX_Q);
	json_array_foreach(arr, i, v) {
		char field[32];
		snprintf(field, sizeof(field), "a.[%zu]", i);
		int r = get_number(c, v, field, &out->Q[i]);
		if (r < 0)
			return r;
	}
	return 0;
}

/* The members each type takes, as a comma-separated list for messages. */
static const char *type_members(enum asph_surface_type t)
{
	switch (t) {
	case ASPH_SURFACE_QBFS:
	case ASPH_SURFACE_QCON:
		return "type, name, note, R, c, k, norm_radius, a, aperture_diameter, aperture";
	case ASPH_SURFACE_BICONIC:
		return "type, name, note, Rx, Ry, kx, ky, A, aperture_diameter, aperture";
	case ASPH_SURFACE_TOROIDAL:
		return "type, name, note, R, k, A, R_rotation, norm_radius, zernike, "
		       "aperture_diameter, aperture";
	case ASPH_SURFACE_XY_POLYNOMIAL:
		return "type, name, note, R, k, norm_radius, c, aperture_diameter, aperture";
	case ASPH_SURFACE_ZERNIKE_SAG:
		return "type, name, note, R, k, A, norm_radius, zernike, zernike_decenter, "
		       "aperture_diameter, aperture";
	case ASPH_SURFACE_Q2D:
		return "type, name, note, R, norm_radius, a, a_m, b_m, aperture_diameter, aperture";
	case ASPH_SURFACE_EVEN_ASPHERE:
	case ASPH_SURFACE_ODD_ASPHERE:
		break;
	}
	return "type, name, note, R, c, k, A, aperture_diameter, aperture";
}

static int is_member_of(const char *key, const char *list)
{
	size_t n = strlen(key);

	/* An empty key would match everywhere without advancing. */
	if (n == 0)
		return 0;
	for (const char *p = list; (p = strstr(p, key)); p += n)
		if ((p == list || p[-1] == ' ') && (p[n] == ',' || p[n] == '\0'))
			return 1;
	return 0;
}

static int parse_type(const struct parse_ctx *c, json_t *root,
		      struct asph_prescription *out)
{
	json_t *v = json_object_get(root, "type");

	if (!v)
		return json_error_set_at(c->err, -EINVAL, &c->src, NULL,
					 "missing member \"type\" (e.g. \"even_asphere\")");
	if (!json_is_string(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, "type", "expected a string");
	if (asph_surface_type_from_name(json_string_value(v), &out->type) < 0)
		return json_error_set_at(c->err, -EINVAL, &c->src, "type",
					 "unknown surface type '%s' (known: even_asphere, odd_asphere, qbfs, qcon, "
					 "biconic, toroidal, xy_polynomial, zernike_sag, q2d)",
					 json_string_value(v));
	return 0;
}

static int parse_optional_number(const struct parse_ctx *c, json_t *root,
				 const char *key, double *out)
{
	json_t *v = json_object_get(root, key);
	return v ? get_number(c, v, key, out) : 0;
}

/* A string member of at most size - 1 bytes into dst. */
static int parse_text(const struct parse_ctx *c, json_t *root, const char *key, char *dst,
		      size_t size)
{
	json_t *v = json_object_get(root, key);

	if (!v)
		return 0;
	if (!json_is_string(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, key, "expected a string");
	if (strlen(json_string_value(v)) >= size)
		return json_error_set_at(c->err, -EINVAL, &c->src, key,
					 "longer than %zu bytes", size - 1);
	snprintf(dst, size, "%s", json_string_value(v));
	return 0;
}

/*
 * The base: "R" (mm; "infinity" for a plane) or, on the rotationally
 * symmetric types, the curvature "c" (1/mm; 0 for a plane), not both.
 * xy_polynomial's "c" is its coefficients, not a curvature.
 */
static int parse_base(const struct parse_ctx *c, json_t *root, const char *members,
		      struct asph_prescription *out)
{
	const int rotational = asph_surface_type_is_rotational(out->type);
	json_t *vr = json_object_get(root, "R"), *vc = rotational ? json_object_get(root, "c") : NULL;
	double curv;
	int r;

	if (vr && vc)
		return json_error_set_at(c->err, -EINVAL, &c->src, "c",
					 "give the radius R or the curvature c, not both");
	if (!vr && !vc && is_member_of("R", members))
		return json_error_set_at(c->err, -EINVAL, &c->src, NULL,
					 rotational ? "missing member \"R\" (vertex radius of curvature, "
						      "mm) or \"c\" (vertex curvature, 1/mm)"
						    : "missing member \"R\" (vertex radius of curvature, mm)");
	if (vr)
		return get_radius(c, vr, "R", &out->R);
	if (!vc)
		return 0;
	if ((r = get_number(c, vc, "c", &curv)) < 0)
		return r;
	/* a curvature too small for its radius to be finite is a plane */
	out->R = curv == 0 ? INFINITY : 1.0 / curv;
	return 0;
}

static int parse_members(const struct parse_ctx *c, json_t *root,
			 struct asph_prescription *out)
{
	const char *key, *members;
	json_t *v;
	int r;

	if ((r = parse_type(c, root, out)) < 0)
		return r;
	members = type_members(out->type);
	json_object_foreach(root, key, v) {
		if (!is_member_of(key, members))
			return json_error_set_at(c->err, -EINVAL, &c->src, key,
						 "unknown member '%s' for type %s (expected %s)",
						 key, asph_surface_type_name(out->type), members);
	}

	v = json_object_get(root, "name");
	if (v) {
		if (!json_is_string(v))
			return json_error_set_at(c->err, -EINVAL, &c->src, "name",
						 "expected a string");
		snprintf(out->name, sizeof(out->name), "%s", json_string_value(v));
	}
	if ((r = parse_text(c, root, "note", out->note, sizeof(out->note))) < 0 ||
	    (r = parse_base(c, root, members, out)) < 0)
		return r;
	if ((r = parse_optional_number(c, root, "k", &out->k)) < 0)
		return r;

	v = json_object_get(root, "A");
	if (v && (r = parse_coefficients(c, v, out)) < 0)
		return r;

	if (is_member_of("norm_radius", members)) {
		/* a toroid's Zernike terms are optional, and their radius with them */
		int required = out->type != ASPH_SURFACE_TOROIDAL || json_object_get(root, "zernike");
		if (required && !json_object_get(root, "norm_radius"))
			return json_error_set_at(c->err, -EINVAL, &c->src, NULL,
						 "missing member \"norm_radius\" (normalization radius, mm)");
		if ((r = parse_optional_number(c, root, "norm_radius", &out->norm_radius)) < 0)
			return r;
	}
	v = json_object_get(root, "a");
	if (v && (r = parse_q_coefficients(c, v, out)) < 0)
		return r;

	if (!asph_surface_type_is_rotational(out->type) &&
	    (r = parse_freeform_members(c, root, out)) < 0)
		return r;
	if ((v = json_object_get(root, "aperture")) &&
	    (r = parse_aperture(c, v, &out->aperture)) < 0)
		return r;
	v = json_object_get(root, "aperture_diameter");
	if (!v && json_object_get(root, "aperture"))
		return 0;
	if (!v)
		return json_error_set_at(c->err, -EINVAL, &c->src, NULL,
					 "missing member \"aperture_diameter\" (mm) or \"aperture\"");
	if ((r = get_number(c, v, "aperture_diameter", &out->aperture_diameter)) < 0)
		return r;
	return 0;
}

int asph_prescription_parse(const char *text, size_t len, const char *source,
			    struct asph_prescription *out,
			    struct asph_error *err)
{
	struct parse_ctx c = { { text, len, source ? source : "<input>" }, err };
	json_error_t jerr;
	int r;

	memset(out, 0, sizeof(*out));
	_cleanup_(json_decrefp) json_t *root =
		json_loadb(text, len, JSON_REJECT_DUPLICATES, &jerr);
	if (!root)
		return asph_error_set_at(err, -EINVAL, c.src.name, jerr.line, jerr.column, NULL,
					 "%s", jerr.text);
	if (!json_is_object(root))
		return json_error_set_at(c.err, -EINVAL, &c.src, "",
					 "a prescription is a JSON object");
	r = parse_members(&c, root, out);
	if (r < 0)
		return r;

	struct asph_error check;
	asph_error_clear(&check);
	r = asph_prescription_check(out, &check);
	if (r < 0)
		return json_error_set_at(c.err, r, &c.src, check.field[0] ? check.field : NULL,
					 "%s", check.message);
	return 0;
}

int asph_prescription_load_file(const char *path,
				struct asph_prescription *out,
				struct asph_error *err)
{
	_cleanup_free_ char *buf = NULL;
	size_t len = 0;
	/* A prescription is small; anything this large is not one. */
	int r = file_read_all(path, 1 << 20, &buf, &len, err);
	if (r < 0)
		return r;
	r = asph_prescription_parse(buf, len, path, out, err);
	if (r == 0 && out->name[0] == '\0') {
		const char *base = strrchr(path, '/');
		base = base ? base + 1 : path;
		snprintf(out->name, sizeof(out->name), "%.*s",
			 (int)strcspn(base, "."), base);
	}
	return r;
}

int asph_prescription_load(const char *name_or_path,
			   struct asph_prescription *out,
			   struct asph_error *err)
{
	if (asph_prescription_preset(name_or_path, out) == 0)
		return 0;
	int r = asph_prescription_load_file(name_or_path, out, err);
	if (r == -ENOENT && !strchr(name_or_path, '/') && !strchr(name_or_path, '.')) {
		char names[128] = "", hint[96];
		struct suggest near;

		suggest_init(&near, name_or_path);
		for (const char *const *n = preset_names; *n; n++) {
			suggest_offer(&near, *n);
			snprintf(names + strlen(names), sizeof(names) - strlen(names), "%s%s",
				 n == preset_names ? "" : ", ", *n);
		}
		asph_error_clear(err);
		return asph_error_set_at(err, -ENOENT, name_or_path, 0, 0, NULL,
					 "neither a preset (%s) nor a file%s", names,
					 suggest_hint(&near, hint, sizeof(hint)));
	}
	return r;
}

int asph_prescription_to_json(const struct asph_prescription *p, char **out)
{
	const int q = p->type == ASPH_SURFACE_QBFS || p->type == ASPH_SURFACE_QCON;
	_cleanup_(json_decrefp) json_t *root = NULL;

	if (!asph_surface_type_is_rotational(p->type)) {
		root = freeform_to_json(p);
		*out = root ? json_dumps(root, JSON_REAL_PRECISION(17) | JSON_PRESERVE_ORDER) : NULL;
		return *out ? 0 : -ENOMEM;
	}
	root = json_object();
	json_t *coeffs = q ? q_array(p) : power_object(p);

	if (!root || !coeffs) {
		json_decref(coeffs);
		return -ENOMEM;
	}
	json_object_set_new(root, "type", json_string(asph_surface_type_name(p->type)));
	if (p->name[0])
		json_object_set_new(root, "name", json_string(p->name));
	if (p->note[0])
		json_object_set_new(root, "note", json_string(p->note));
	/* a plane base as its curvature */
	if (isinf(p->R))
		json_object_set_new(root, "c", json_real(0));
	else
		json_object_set_new(root, "R", json_real(p->R));
	json_object_set_new(root, "k", json_real(p->k));
	if (q)
		json_object_set_new(root, "norm_radius", json_real(p->norm_radius));
	json_object_set_new(root, q ? "a" : "A", coeffs);
	aperture_to_json(root, p);
	*out = json_dumps(root, JSON_REAL_PRECISION(17) | JSON_PRESERVE_ORDER);
	return *out ? 0 : -ENOMEM;
}
