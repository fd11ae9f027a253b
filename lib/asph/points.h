/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_POINTS_H
#define ASPH_POINTS_H

#include <stddef.h>
#include <stdio.h>
#include <stdint.h>

#include "asph/error.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * A set of 3-D points (mm, in scan order), optionally with one scalar per
 * point (e.g. "residual_nm") and a triangle mesh over them.
 *
 * Files: the format follows the extension.
 *   .csv   header "x,y,z" (plus the value column's name if any); reading
 *          takes the names in any case and order, and quoted fields
 *          ("x","y","z", as R and spreadsheets write them), a UTF-8
 *          byte-order mark, '#' comment lines and blank lines
 *   .ply   ASCII PLY, vertices (+ the value and an RGB colour when a value
 *          exists) and faces when a mesh exists; reading also takes
 *          binary_little_endian PLY
 *   .json  {"points": [[x,y,z],...], "triangles": [[i,j,k],...], ...}
 *   .x3p   written only: ISO 25178-72, the list layout of the points
 *          (asph/x3p.h; the value and the mesh are not part of it)
 *   "-"    CSV on stdin / stdout
 */
struct asph_points {
	size_t n;
	double *xyz;            /* 3 n */
	double *value;          /* n, or NULL */
	char value_name[32];    /* column name of value, e.g. "residual_nm" */
	size_t n_triangles;
	uint32_t *triangles;    /* 3 n_triangles, or NULL */
};

/* Allocates n points (zeroed), no value column, no mesh. NULL on ENOMEM. */
struct asph_points *asph_points_alloc(size_t n);
/* Adds a zeroed value column. */
int asph_points_add_value(struct asph_points *p, const char *name);
void asph_points_free(struct asph_points *p);

/* Errors name the file, line, column (1-based CSV column) and field. A
 * non-finite coordinate, a short row, a missing header: refused. */
int asph_points_read(const char *path, struct asph_points **out,
		     struct asph_error *err);
int asph_points_read_csv_text(const char *text, size_t len,
			      const char *source, struct asph_points **out,
			      struct asph_error *err);
/* Bytes in memory (len bytes, need not be NUL-terminated), in the format
 * source's extension names, as asph_points_read() picks it for a path:
 * .ply (ASCII or binary), .json, else CSV. */
int asph_points_read_memory(const void *data, size_t len, const char *source,
			    struct asph_points **out, struct asph_error *err);

/* PLY colours map value linearly over [lo, hi] (a diverging map centred on
 * zero when lo = -hi); lo = hi = 0 picks the symmetric range of the data. */
struct asph_x3p_info;
struct asph_points_write_options {
	double colour_lo, colour_hi;
	int precision;          /* significant digits, 0 = 17 (round trip) */
	/* An X3P file's Record2 (asph/x3p.h): who wrote it, when and on
	 * what the points were measured; NULL: computed data, now. */
	const struct asph_x3p_info *x3p;
};

int asph_points_write(const char *path, const struct asph_points *p,
		      const struct asph_points_write_options *opts,
		      struct asph_error *err);
/* The same to f (flushed, not closed), in the format name's extension
 * names (CSV when name is NULL; not X3P, a container written by path:
 * -EINVAL); name is what messages call it. */
int asph_points_write_stream(FILE *f, const char *name, const struct asph_points *p,
			     const struct asph_points_write_options *opts,
			     struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
