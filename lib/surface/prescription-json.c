/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The values the prescription's reader and writer share, for every type
 * (prescription.c) and for the freeform members (prescription-freeform.c):
 * prescription-json.h. */
#include <errno.h>
#include <math.h>
#include <stdio.h>

#include "prescription-json.h"

int get_number(const struct parse_ctx *c, json_t *v, const char *field,
	       double *out)
{
	if (!json_is_number(v))
		return json_error_set_at(c->err, -EINVAL, &c->src, field, "expected a number");
	*out = json_number_value(v);
	if (!isfinite(*out))
		return json_error_set_at(c->err, -EINVAL, &c->src, field, "not a finite number");
	return 0;
}

json_t *q_array(const struct asph_prescription *p)
{
	json_t *arr = json_array();
	int n = 0;

	for (int m = 0; m <= ASPH_SURFACE_MAX_Q; m++)
		if (p->Q[m] != 0)
			n = m + 1;
	for (int m = 0; arr && m < n; m++)
		json_array_append_new(arr, json_real(p->Q[m]));
	return arr;
}

json_t *power_object(const struct asph_prescription *p)
{
	json_t *coeffs = json_object();

	for (int i = 1; coeffs && i <= ASPH_SURFACE_MAX_POWER; i++) {
		if (p->A[i] == 0)
			continue;
		char key[8];
		snprintf(key, sizeof(key), "%d", i);
		json_object_set_new(coeffs, key, json_real(p->A[i]));
	}
	return coeffs;
}
