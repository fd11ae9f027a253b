/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_X3P_H
#define ASPH_X3P_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "asph/areal.h"
#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * X3P files (ISO 25178-72, the openGPS ISO 5436-2 XML format): a ZIP
 * container (libzip) holding main.xml (libxml2), bindata/data.bin
 * (little-endian IEEE doubles, metres) with its MD5 in main.xml, and
 * md5checksum.hex, the MD5 of main.xml. main.xml validates against the
 * ISO 5436-2:2008 schema and the ISO 25178-72:2017/Amd 1:2020 one.
 * docs/characterization.md, "Exports", gives the layout of each kind.
 */

struct asph_x3p_info {
	const char *creator;           /* Record2/Creator, may be NULL */
	const char *manufacturer;      /* Record2/Instrument; NULL: "asphd" */
	const char *model, *serial, *version;
	const char *probing_type;      /* "Contacting", "NonContacting" or
					  "Software"; NULL: "Software" */
	const char *probing_id;        /* Record2/ProbingSystem/Identification */
	const char *comment;           /* Record2/Comment, may be NULL */
	int64_t date_ns;               /* Record2/Date, ns since 1970; 0: now */
	int64_t calibration_date_ns;   /* Record2/CalibrationDate, ns since 1970;
					  0: unknown, written as Date (ISO
					  5436-2:2008 requires one) */
	/* The instrument that measured, as a recorded scan's header
	 * describes it (JSON object text): it names Record2/Instrument and
	 * ProbingSystem where the members above are NULL (docs/
	 * characterization.md, "Exports"). NULL: computed data. */
	const char *instrument_json;
};

/* List layout (FeatureType PCL, ListDimension n): the points xyz (mm, 3 n)
 * as absolute X, Y, Z in metres. -EINVAL for a non-finite coordinate or
 * no point, -EIO and the like for the file. */
int asph_x3p_write_points(const char *path, const double *xyz, size_t n,
			  const struct asph_x3p_info *info,
			  struct asph_error *err);

/* Matrix layout (FeatureType SUR, MatrixDimension nx x ny x 1): the grid
 * (x, y in mm, z in nm) with incremental X and Y axes, their Offset the
 * grid's first node (x0, y0), and absolute Z, in metres; masked nodes are
 * NaN, which ISO 5436-2 reads as invalid. */
int asph_x3p_write_grid(const char *path, const struct asph_grid *g,
			const struct asph_x3p_info *info,
			struct asph_error *err);
/* The same container written to f (name for messages); f is flushed, not
 * closed. */
int asph_x3p_write_grid_stream(FILE *f, const char *name, const struct asph_grid *g,
			       const struct asph_x3p_info *info,
			       struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
