/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_CORRECTION_H
#define ASPH_CORRECTION_H

#include "asph/areal.h"
#include "asph/error.h"
#include "asph/surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Correction tables for the machine that made the part
 * (docs/characterization.md, "Correction tables"): the form error of the
 * residual as a z(r) table for a turned, rotationally symmetric part (the
 * mean over azimuth at each radius) or on an XY grid, as CSV with the
 * conventions stated in '#' lines at the top.
 */

enum asph_correction_kind {
	ASPH_CORRECTION_RADIAL = 0,     /* "radial": r_mm,<value> */
	ASPH_CORRECTION_GRID,           /* "grid": x_mm,y_mm,<value> */
};

enum asph_correction_sign {
	ASPH_CORRECTION_HEIGHT_ERROR = 0,   /* measured - nominal, + above the
					       nominal (towards +z) */
	ASPH_CORRECTION_MATERIAL_TO_REMOVE, /* + where material stands above
					       the nominal surface on the
					       material's side, - where it is
					       missing */
};

enum asph_correction_direction {
	ASPH_CORRECTION_ALONG_Z = 0,    /* "z": the sag error */
	ASPH_CORRECTION_ALONG_NORMAL,   /* "normal" */
};

enum asph_correction_extension {
	ASPH_CORRECTION_EXTEND_CONSTANT = 0,  /* the value at the rim */
	ASPH_CORRECTION_EXTEND_LINEAR,        /* the rim's value and slope */
};

enum asph_correction_material {
	ASPH_CORRECTION_MATERIAL_BELOW = 0,   /* on the -z side of the surface
						 (a part measured face up) */
	ASPH_CORRECTION_MATERIAL_ABOVE,
};

struct asph_correction_options {
	enum asph_correction_kind kind;
	enum asph_correction_sign sign;
	enum asph_correction_direction direction;
	enum asph_correction_material material;
	double step_mm;          /* table spacing; 0 = the median point spacing */
	double smooth_mm;        /* Gaussian (ISO 16610-21) cut-off; 0 = none */
	double extend_mm;        /* beyond the aperture radius; 0 = none */
	enum asph_correction_extension extension;
	int n_azimuths;          /* radial: directions averaged; 0 = 360 */
};

/* Names to values, for command lines: -EINVAL with the accepted names in
 * err. what names the option in the message ("--correction-sign"). */
int asph_correction_kind_parse(const char *s, const char *what,
			       enum asph_correction_kind *out,
			       struct asph_error *err);
int asph_correction_sign_parse(const char *s, const char *what,
			       enum asph_correction_sign *out,
			       struct asph_error *err);
int asph_correction_direction_parse(const char *s, const char *what,
				    enum asph_correction_direction *out,
				    struct asph_error *err);
int asph_correction_extension_parse(const char *s, const char *what,
				    enum asph_correction_extension *out,
				    struct asph_error *err);
int asph_correction_material_parse(const char *s, const char *what,
				   enum asph_correction_material *out,
				   struct asph_error *err);

/*
 * Writes the table of the residual `residual` (nm, measured along the
 * surface normal when residual_along_normal, else along z) over the part
 * surface s. lens names the part in the header. -EINVAL for options out of
 * range (err names the option and why), I/O errors with the path.
 */
int asph_correction_write(const char *path, const struct asph_surface *s,
			  const char *lens, const struct asph_scatter *residual,
			  int residual_along_normal,
			  const struct asph_correction_options *opts,
			  struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
