/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_PRESCRIPTION_H
#define ASPH_PRESCRIPTION_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Prescriptions in JSON:
 *   {"type": "even_asphere", "R": 20.097, "k": -1,
 *    "A": {"4": -2.0868e-5, "6": ...}, "aperture_diameter": 40}
 *   {"type": "odd_asphere", ... "A": {"1": ..., "3": ...}, ...}
 *   {"type": "qbfs", "R": .., "norm_radius": .., "a": [a0, a1, ...], "aperture_diameter": ..}
 *   {"type": "qcon", "R": .., "k": .., "norm_radius": .., "a": [...], "aperture_diameter": ..}
 * Optional: "name" (string). Unknown members are refused, so a misspelt key
 * never silently drops a term. docs/prescriptions.md has the formulas.
 *
 * Errors carry the source (file name), line, column and field.
 */

/* Parses text (len bytes, need not be NUL-terminated). source names it in
 * errors. The result is checked for validity as asph_surface_alloc does. */
int asph_prescription_parse(const char *text, size_t len, const char *source,
			    struct asph_prescription *out,
			    struct asph_error *err);

/* Reads a file. */
int asph_prescription_load_file(const char *path,
				struct asph_prescription *out,
				struct asph_error *err);

/* The paper's Table 1 lenses: "weak", "strong", "turning-point".
 * -ENOENT if name is not a preset. */
int asph_prescription_preset(const char *name, struct asph_prescription *out);

/* NULL-terminated list of preset names. */
const char *const *asph_prescription_preset_names(void);

/* A preset name, else a file path. */
int asph_prescription_load(const char *name_or_path,
			   struct asph_prescription *out,
			   struct asph_error *err);

/* Serializes to JSON text (malloc'd, caller frees) in the format above. */
int asph_prescription_to_json(const struct asph_prescription *p, char **out);

#ifdef __cplusplus
}
#endif

#endif
