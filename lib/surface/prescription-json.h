/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The prescription reader and writer, shared by prescription.c (all types)
 * and prescription-freeform.c (the freeform members); the values both read
 * and write are in prescription-json.c. Internal. */
#ifndef ASPH_PRESCRIPTION_JSON_H
#define ASPH_PRESCRIPTION_JSON_H

#include <jansson.h>

#include "asph/prescription.h"
#include "jsonpos.h"

/* The text being read, for messages that point into it. */
struct parse_ctx {
	struct json_source src;
	struct asph_error *err;
};

/* A finite number. */
int get_number(const struct parse_ctx *c, json_t *v, const char *field, double *out);

/* A radius in mm: a finite number, or "infinity" / "-infinity" for a plane
 * (INFINITY). */
int get_radius(const struct parse_ctx *c, json_t *v, const char *field, double *out);

/* "aperture": {"shape": ..., "width"/"height" or "diameter", "offset"}. */
int parse_aperture(const struct parse_ctx *c, json_t *obj, struct asph_aperture *ap);

/* The members only the freeform types have: Rx, Ry, kx, ky, R_rotation, c,
 * zernike, zernike_decenter, a_m, b_m. */
int parse_freeform_members(const struct parse_ctx *c, json_t *root,
			   struct asph_prescription *out);

/* The prescription of a freeform type as a JSON object; NULL when out of
 * memory. */
json_t *freeform_to_json(const struct asph_prescription *p);

/* "aperture_diameter" or "aperture", as p has it, into o. */
void aperture_to_json(json_t *o, const struct asph_prescription *p);

/* "a": [a0, a1, ...] and "A": {"4": ...}, for the writers. */
json_t *q_array(const struct asph_prescription *p);
json_t *power_object(const struct asph_prescription *p);

#endif
