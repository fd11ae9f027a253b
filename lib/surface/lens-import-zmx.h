/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The surface blocks of an OpticStudio .zmx file as read, shared by the
 * reader and the converters of the rotationally symmetric types
 * (lens-import.c) and of the freeform types (lens-import-freeform.c).
 * docs/prescriptions.md ("Importing from lens design files") gives the
 * layout and its sources. Internal to lib/surface.
 */
#ifndef ASPH_LENS_IMPORT_ZMX_H
#define ASPH_LENS_IMPORT_ZMX_H

#include <errno.h>
#include <stddef.h>

#include "asph/error.h"
#include "asph/prescription.h"

#define ZMX_MAX_PARM 40
/* Extra data: the most any imported type uses is 2 + 231 (Zernike). */
#define ZMX_MAX_XDAT 250

/* A keyword's number and where it stands; line 0: the file has none. */
struct zmx_value {
	double v;
	int line, col;
};

/* The clear aperture lines of a surface. */
enum zmx_aperture_kind {
	ZMX_APERTURE_NONE,
	ZMX_APERTURE_CIRCULAR,      /* CLAP r_min r_max */
	ZMX_APERTURE_RECTANGULAR,   /* SQAP x_half_width y_half_width */
	ZMX_APERTURE_ELLIPTICAL,    /* ELAP x_half_width y_half_width */
	ZMX_APERTURE_USER,          /* UDAD: a user-defined aperture */
};

struct zsurf {
	int number;
	int line;                 /* of its SURF line */
	char type[32];            /* "STANDARD" when the file has no TYPE line */
	int type_line, type_col;  /* the SURF line when it has none */
	struct zmx_value curv, coni, diam;   /* diam: the semi-diameter */
	struct zmx_value parm[ZMX_MAX_PARM + 1];
	struct zmx_value xdat[ZMX_MAX_XDAT + 1];
	enum zmx_aperture_kind aperture;
	struct zmx_value aperture_size[2];
	struct zmx_value decenter[2];         /* OBDC: the aperture's centre */
	int aperture_lines;                   /* how many aperture lines */
};

/* A .zmx refusal: -EINVAL with the file, line, column and keyword. */
#define zmx_refuse(err, file, line, col, field, ...) \
	asph_error_set_at(err, -EINVAL, file, line, col, field, __VA_ARGS__)

/* How a type's data become a prescription. */
enum zmx_kind {
	ZMX_STANDARD,   /* a conic */
	ZMX_EVENASPH,   /* PARM i multiplies r^(2i) */
	ZMX_ODDASPH,    /* PARM i multiplies r^i */
	ZMX_QTYPE,      /* Forbes' Qbfs or Qcon in extra data */
	ZMX_FREEFORM,   /* zmx_freeform() */
};

/* One OpticStudio surface type that is imported: the table in
 * lens-import-freeform.c is the one list of them. */
struct zmx_type {
	const char *name;          /* TYPE */
	const char *title;         /* OpticStudio's name of the type */
	enum zmx_kind kind;
	enum asph_surface_type type;
	unsigned parms;            /* bit i: PARM i is a parameter of the type */
	int max_terms;             /* the most terms in extra data; 0: no extra data */
};

/* The imported type TYPE names; NULL when it is not imported. */
const struct zmx_type *zmx_type_of(const char *name);

/* The names of the imported types, ", " between them, for messages. */
void zmx_type_names(char *buf, size_t size);

/* A parameter or an extra datum the type does not have holds a value the
 * prescription would lose: refused, with where, unless it is 0. */
int zmx_check_unknown_data(const struct zsurf *z, const struct zmx_type *t, const char *file,
			   struct asph_error *err);

/*
 * The shape of a freeform surface (BICONICX, TOROIDAL, XPOLYNOM, SZERNSAG)
 * into p, whose aperture is set already: its type, radii, conics and
 * terms. A parameter or extra datum the type does not have, a count of
 * terms out of range, or Zernike terms that stop at their normalization
 * radius inside the aperture are refused with where (-EINVAL).
 */
int zmx_freeform(const struct zsurf *z, const char *file, struct asph_prescription *p,
		 struct asph_error *err);

#endif
