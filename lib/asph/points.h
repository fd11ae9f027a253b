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
 * Files written: the format follows the extension (reading finds it
 * from the content, below).
 *   .csv   header "x,y,z" (plus the value column's name if any); reading
 *          takes the names in any case and order, and quoted fields
 *          ("x","y","z", as R and spreadsheets write them), a UTF-8
 *          byte-order mark, '#' comment lines and blank lines
 *   .ply   ASCII PLY, vertices (+ the value and an RGB colour when a value
 *          exists) and faces when a mesh exists; reading also takes
 *          binary_little_endian PLY
 *   .json  {"points": [[x,y,z],...], "triangles": [[i,j,k],...], ...}
 *   .x3p   ISO 25178-72, the list layout of the points (asph/x3p.h; the
 *          value and the mesh are not part of it)
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

/*
 * Reading. The format is found from the content, never from the name:
 * "PK\3\4" (a ZIP container) is X3P, "aA"/"aB"/"aC" followed by a version
 * SDF (ISO 25178-71, ASCII or binary), the MetroPro magic numbers
 * 0x881B036F..71 (big-endian) a Zygo .dat, the HDF5 signature a Zygo
 * .datx, "ply" PLY, a '{' JSON, anything else delimited text.
 *
 *   text      comma, semicolon, tab or blank separated, with or without a
 *             header; a header names x, y, z (any case, any order, quoted or
 *             not) each with an optional unit: "x [mm]", "z(um)", "Z/nm",
 *             "z_um" (nm, um/µm, mm, cm, m, in); without a header the first
 *             three columns are x, y, z. A decimal comma is read where the
 *             separator is a semicolon or a tab. '#', '%' and '//' lines are
 *             comments; lines before the header or the first row whose first
 *             field is not a number are a preamble (skipped and counted).
 *   X3P       ISO 25178-72: point lists (PCL) and matrices (SUR, PRF), data
 *             in bindata or inline (DataList), types I, L, F, D with their
 *             Increment and Offset, incremental and absolute axes, invalid
 *             points by NaN or bindata/valid.bin; the MD5 sums are checked.
 *   SDF       ISO 25178-71 / BCR SDF: ASCII (aAxx) and binary (aBxx).
 *   MetroPro  Zygo .dat, header formats 1-3: the phase map, its invalid
 *             marker, wavelength, scale and obliquity factors, lateral
 *             resolution.
 *   datx      Zygo .datx (HDF5): the first surface map with its converters.
 *
 * A map (a matrix of heights) becomes points: x, y of its grid nodes (mm),
 * z the height (mm), node order X fastest; invalid nodes are dropped and
 * counted (info->n_invalid). A map that carries no position (SDF,
 * MetroPro, datx) is centred: its middle node at x = y = 0, y up (the
 * first row is the top one in MetroPro and datx).
 *
 * Errors name the format, what is wrong and where: the line and column of
 * text, the byte offset of binary data, the XML element of an X3P.
 */
enum asph_points_format {
	ASPH_POINTS_AUTO = 0,   /* from the content */
	ASPH_POINTS_TEXT,       /* "text" (also "csv") */
	ASPH_POINTS_PLY,        /* "ply" */
	ASPH_POINTS_JSON,       /* "json" */
	ASPH_POINTS_X3P,        /* "x3p" */
	ASPH_POINTS_SDF,        /* "sdf" */
	ASPH_POINTS_METROPRO,   /* "metropro" (also "dat") */
	ASPH_POINTS_DATX,       /* "datx" */
};

/* The format's name ("text", "x3p", ...); "auto" for AUTO. */
const char *asph_points_format_name(enum asph_points_format f);
/* The format a name (or an alias) names; -EINVAL for an unknown name. */
int asph_points_format_parse(const char *name, enum asph_points_format *out);
/* The format names, ", " separated, for usage texts, into buf (cut to
 * size); the length of the whole list, as snprintf() counts it. */
size_t asph_points_format_names(char *buf, size_t size);

struct asph_points_read_options {
	enum asph_points_format format;  /* AUTO: from the content */
	/* Text only: the length unit (mm) of columns whose header names none
	 * (all of them without a header); 0: mm. */
	double unit_mm;
};

/* Length units by name: "nm", "um" (also "µm", "micron"), "mm", "cm",
 * "m", "in" (also "inch"): *mm is one unit in mm. -EINVAL otherwise. */
int asph_points_unit_parse(const char *name, double *mm);
/* The units' names without their aliases, ", " separated, for usage
 * texts, into buf (cut to size); the length of the whole list. */
size_t asph_points_unit_names(char *buf, size_t size);

struct asph_points_read_info {
	enum asph_points_format format;  /* the format read */
	size_t nx, ny;                   /* a map's size; 0 for point lists */
	size_t n_invalid;                /* map nodes dropped as invalid */
	size_t n_preamble;               /* text lines skipped before the data */
	int has_header;                  /* text: a header named the columns */
	char units[3][16];               /* text: the units of x, y, z, as read */
};

/* Reads path ("-": stdin) in the format of o (NULL: found from the
 * content, units mm); info (may be NULL) says what was read. */
int asph_points_read_as(const char *path, const struct asph_points_read_options *o,
			struct asph_points **out, struct asph_points_read_info *info,
			struct asph_error *err);
/* The same from len bytes in memory (need not be NUL-terminated); source
 * names them in messages. */
int asph_points_read_memory_as(const void *data, size_t len, const char *source,
			       const struct asph_points_read_options *o,
			       struct asph_points **out, struct asph_points_read_info *info,
			       struct asph_error *err);

/* asph_points_read_as() and asph_points_read_memory_as() with the format
 * from the content and mm. */
int asph_points_read(const char *path, struct asph_points **out,
		     struct asph_error *err);
int asph_points_read_memory(const void *data, size_t len, const char *source,
			    struct asph_points **out, struct asph_error *err);
/* Delimited text in memory, as ASPH_POINTS_TEXT. */
int asph_points_read_csv_text(const char *text, size_t len,
			      const char *source, struct asph_points **out,
			      struct asph_error *err);

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
