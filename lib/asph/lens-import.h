/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Lens files of other programs as prescriptions: the surfaces of an
 * OpticStudio sequential lens file (.zmx; UTF-8, UTF-16 with a byte-order
 * mark, or Latin-1; any lens units, converted to mm) or the rows of a CSV
 * table (R,k,A4,...,aperture_diameter).
 * docs/prescriptions.md ("Importing from lens design files") lists what is
 * read. The text is untrusted: a refusal names the line, the column and the
 * keyword or column.
 */
#ifndef ASPH_LENS_IMPORT_H
#define ASPH_LENS_IMPORT_H

#include <stddef.h>

#include "asph/error.h"
#include "asph/prescription.h"

#ifdef __cplusplus
extern "C" {
#endif

enum asph_lens_format {
	ASPH_LENS_ZMX,
	ASPH_LENS_CSV,
};

/* Lens files are small: a larger file is not one (-EFBIG). */
#define ASPH_LENS_IMPORT_MAX_BYTES (16u << 20)

/* A file read: its surfaces, in file order. */
struct asph_lens_import;

/* One surface the file holds: a .zmx SURF block or a CSV row. */
struct asph_lens_surface {
	int number;                 /* the SURF number; a CSV row's, from 1 */
	char type[32];              /* the .zmx TYPE (STANDARD without one); ""
				       in a CSV table */
	double R;                   /* mm; INFINITY for a plane */
	double k;
	double aperture_diameter;   /* mm, twice DIAM; 0 when the file gives none */
	int line;                   /* where it starts, from 1 */
};

/*
 * Reads the bytes of a lens file. name is the file's name, for messages and
 * for the names of the prescriptions; the file is a CSV table when name ends
 * in ".csv" or the text starts with "R,", else a .zmx file. The whole file
 * is checked: a surface block cut short, an unknown CSV column or a value
 * that is not a number refuses it (-EINVAL, with where). -ENOMEM.
 */
int asph_lens_import_parse(const void *data, size_t len, const char *name,
			   struct asph_lens_import **out, struct asph_error *err);

/* As parse, for the file at path ("-" for stdin). -EFBIG for a file larger
 * than ASPH_LENS_IMPORT_MAX_BYTES, -errno when it cannot be read. */
int asph_lens_import_load(const char *path, struct asph_lens_import **out,
			  struct asph_error *err);

void asph_lens_import_free(struct asph_lens_import *im);

enum asph_lens_format asph_lens_import_format(const struct asph_lens_import *im);

/* A .zmx file's lens units as its UNIT line names them ("MM" without one:
 * "MM", "CM", "IN", "INCH", "M", ...); "" for a CSV table. Every length the
 * reader gives is in mm, converted from them. */
const char *asph_lens_import_unit(const struct asph_lens_import *im);

/* How many surfaces (at least 1), and the i-th (i < count). */
size_t asph_lens_import_count(const struct asph_lens_import *im);
void asph_lens_import_surface(const struct asph_lens_import *im, size_t i,
			      struct asph_lens_surface *out);

/*
 * The surface numbered `number` (-1: the only one) as a checked
 * prescription, named "BASE-sN" after the file (BASE: its name without
 * folders and extensions) and the surface, in mm (a file in other lens
 * units says so in the prescription's note). -ENOENT when the file has no
 * such surface (or, for -1, several); -EINVAL, with where, when the surface
 * cannot be a prescription (a type that is not imported, no aperture, a
 * user-defined aperture, bad Q-type data, a parameter or extra datum the
 * type does not have, a conic that ends inside the aperture).
 * STANDARD, EVENASPH, ODDASPHE and QED_TYPE become even_asphere,
 * odd_asphere, qbfs and qcon prescriptions (CURV 0: a plane base; an
 * aperture line with a decenter: an off-axis segment); the freeform types
 * (BICONICX, TOROIDAL, XPOLYNOM, SZERNSAG) biconic, toroidal,
 * xy_polynomial and zernike_sag.
 */
int asph_lens_import_prescription(const struct asph_lens_import *im, int number,
				  struct asph_prescription *out,
				  struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
