/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The points module's readers, one per format family, and what they share:
 * byte order, maps made points, the limits. Internal to lib/points. */
#ifndef ASPH_POINTS_READERS_H
#define ASPH_POINTS_READERS_H

#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "asph/points.h"

/* Files larger than this are refused rather than read into memory. */
#define POINTS_FILE_LIMIT ((size_t)4 << 30)
#define POINTS_MAX ((size_t)1 << 28)

/* The format of the content (text when nothing else claims it). */
enum asph_points_format points_detect(const uint8_t *data, size_t len);

/* Each reader takes the whole file in memory (len bytes, not
 * NUL-terminated) and fills *out and the parts of info it knows; source
 * names the file in messages. */
int points_read_text(const char *text, size_t len, const char *source,
		     const struct asph_points_read_options *o, struct asph_points **out,
		     struct asph_points_read_info *info, struct asph_error *err);
int points_read_x3p(const uint8_t *data, size_t len, const char *source,
		    struct asph_points **out, struct asph_points_read_info *info,
		    struct asph_error *err);
int points_read_sdf(const uint8_t *data, size_t len, const char *source,
		    struct asph_points **out, struct asph_points_read_info *info,
		    struct asph_error *err);
int points_read_metropro(const uint8_t *data, size_t len, const char *source,
			 struct asph_points **out, struct asph_points_read_info *info,
			 struct asph_error *err);
int points_read_datx(const uint8_t *data, size_t len, const char *source,
		     struct asph_points **out, struct asph_points_read_info *info,
		     struct asph_error *err);

/* A map: nx x ny nodes, node (i, j) at (x0 + i dx, y0 + j dy) mm, z[i + nx j]
 * in mm, NaN where the node is invalid. */
struct points_map {
	size_t nx, ny;
	double x0, y0, dx, dy;
	const double *z;
};

/* The valid nodes as points, X fastest; info gets the size and the count
 * of invalid nodes. -EINVAL (named by format) when no node is valid. */
int points_from_map(const struct points_map *m, const char *format, const char *source,
		    struct asph_points **out, struct asph_points_read_info *info,
		    struct asph_error *err);

/* The origin and steps of a map with no position of its own: centred on
 * x = y = 0, y up; first_row_top: the first row is the top one (images). */
void points_map_centre(struct points_map *m, double dx, double dy, int first_row_top);

/* nx * ny nodes of size bytes each, within POINTS_MAX nodes: 0, or
 * -EFBIG with the product left unset. */
int points_map_size(size_t nx, size_t ny, size_t size, size_t *nodes, size_t *bytes);

static inline uint16_t get_be16(const uint8_t *p)
{
	return (uint16_t)(p[0] << 8 | p[1]);
}

static inline uint32_t get_be32(const uint8_t *p)
{
	return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

static inline uint16_t get_le16(const uint8_t *p)
{
	return (uint16_t)(p[1] << 8 | p[0]);
}

static inline uint32_t get_le32(const uint8_t *p)
{
	return (uint32_t)p[3] << 24 | (uint32_t)p[2] << 16 | (uint32_t)p[1] << 8 | p[0];
}

static inline uint64_t get_le64(const uint8_t *p)
{
	return (uint64_t)get_le32(p + 4) << 32 | get_le32(p);
}

static inline float get_be_float(const uint8_t *p)
{
	uint32_t u = get_be32(p);
	float f;

	memcpy(&f, &u, sizeof(f));
	return f;
}

static inline float get_le_float(const uint8_t *p)
{
	uint32_t u = get_le32(p);
	float f;

	memcpy(&f, &u, sizeof(f));
	return f;
}

static inline double get_le_double(const uint8_t *p)
{
	uint64_t u = get_le64(p);
	double d;

	memcpy(&d, &u, sizeof(d));
	return d;
}

#endif
