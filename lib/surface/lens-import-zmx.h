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
	char type[32];
	int type_line, type_col;
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

/* Whether TYPE names one of the freeform types that are imported. */
int zmx_type_is_freeform(const char *type);

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
