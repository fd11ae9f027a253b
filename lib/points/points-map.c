/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What the readers share: the table of formats and their detection from
 * the content, length units, and maps (matrices of heights) made points. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "readers.h"
#include "util-mem.h"

/* One table: the name, its aliases, and the magic that finds the format
 * (checked in this order; text is what nothing else claims). */
static const struct format_entry {
	enum asph_points_format format;
	const char *name, *alias;
} formats[] = {
	{ ASPH_POINTS_TEXT, "text", "csv" },
	{ ASPH_POINTS_PLY, "ply", NULL },
	{ ASPH_POINTS_JSON, "json", NULL },
	{ ASPH_POINTS_X3P, "x3p", NULL },
	{ ASPH_POINTS_SDF, "sdf", NULL },
	{ ASPH_POINTS_METROPRO, "metropro", "dat" },
	{ ASPH_POINTS_DATX, "datx", NULL },
};

const char *asph_points_format_name(enum asph_points_format f)
{
	for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
		if (formats[i].format == f)
			return formats[i].name;
	return "auto";
}

int asph_points_format_parse(const char *name, enum asph_points_format *out)
{
	if (!strcasecmp(name, "auto")) {
		*out = ASPH_POINTS_AUTO;
		return 0;
	}
	for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
		if (!strcasecmp(name, formats[i].name) ||
		    (formats[i].alias && !strcasecmp(name, formats[i].alias))) {
			*out = formats[i].format;
			return 0;
		}
	return -EINVAL;
}

size_t asph_points_format_names(char *buf, size_t size)
{
	size_t used = (size_t)snprintf(buf, size, "auto");

	for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
		used += (size_t)snprintf(buf + (used < size ? used : size),
					 used < size ? size - used : 0, ", %s", formats[i].name);
	return used;
}

static const struct unit_entry {
	const char *name;
	double mm;
	int alias;              /* another name of the unit before it: not listed */
} units[] = {
	{ "nm", 1e-6, 0 }, { "um", 1e-3, 0 }, { "\xc2\xb5m", 1e-3, 1 }, { "\xce\xbcm", 1e-3, 1 },
	{ "micron", 1e-3, 1 }, { "microns", 1e-3, 1 }, { "mm", 1, 0 }, { "cm", 10, 0 },
	{ "m", 1000, 0 }, { "in", 25.4, 0 }, { "inch", 25.4, 1 },
};

size_t asph_points_unit_names(char *buf, size_t size)
{
	size_t used = 0;

	if (size)
		buf[0] = '\0';
	for (size_t i = 0; i < ARRAY_SIZE(units); i++)
		if (!units[i].alias)
			used += (size_t)snprintf(buf + (used < size ? used : size),
						 used < size ? size - used : 0, "%s%s",
						 used ? ", " : "", units[i].name);
	return used;
}

int asph_points_unit_parse(const char *name, double *mm)
{
	for (size_t i = 0; i < ARRAY_SIZE(units); i++)
		if (!strcasecmp(name, units[i].name)) {
			*mm = units[i].mm;
			return 0;
		}
	return -EINVAL;
}

/* ---- detection ---- */

static int is_sdf_magic(const uint8_t *d, size_t len)
{
	/* "aBCR-1.0" (ASCII) and "bBCR-1.0" (binary), and "aISO-1.0" as
	 * ISO 25178-71 names its own revision */
	return len >= 8 && (d[0] == 'a' || d[0] == 'b') &&
	       (!memcmp(d + 1, "BCR-", 4) || !memcmp(d + 1, "ISO-", 4)) &&
	       d[5] >= '0' && d[5] <= '9' && d[6] == '.' && d[7] >= '0' && d[7] <= '9';
}

static int is_metropro_magic(const uint8_t *d, size_t len)
{
	if (len < 4)
		return 0;
	uint32_t m = get_be32(d);
	return m == 0x881B036F || m == 0x881B0370 || m == 0x881B0371;
}

enum asph_points_format points_detect(const uint8_t *d, size_t len)
{
	size_t i = 0;

	if (len >= 4 && !memcmp(d, "PK\x03\x04", 4))
		return ASPH_POINTS_X3P;
	if (len >= 8 && !memcmp(d, "\x89HDF\r\n\x1a\n", 8))
		return ASPH_POINTS_DATX;
	if (is_metropro_magic(d, len))
		return ASPH_POINTS_METROPRO;
	if (is_sdf_magic(d, len))
		return ASPH_POINTS_SDF;
	if (len >= 4 && !memcmp(d, "ply", 3) && (d[3] == '\n' || d[3] == '\r'))
		return ASPH_POINTS_PLY;
	if (len >= 3 && !memcmp(d, "\xef\xbb\xbf", 3))
		i = 3;
	while (i < len && (d[i] == ' ' || d[i] == '\t' || d[i] == '\r' || d[i] == '\n'))
		i++;
	if (i < len && d[i] == '{')
		return ASPH_POINTS_JSON;
	return ASPH_POINTS_TEXT;
}

/* ---- maps ---- */

int points_map_size(size_t nx, size_t ny, size_t size, size_t *nodes, size_t *bytes)
{
	if (nx == 0 || ny == 0 || nx > POINTS_MAX || ny > POINTS_MAX / nx)
		return -EFBIG;
	if (size && nx * ny > POINTS_FILE_LIMIT / size)
		return -EFBIG;
	*nodes = nx * ny;
	if (bytes)
		*bytes = nx * ny * size;
	return 0;
}

void points_map_centre(struct points_map *m, double dx, double dy, int first_row_top)
{
	m->dx = dx;
	m->dy = first_row_top ? -dy : dy;
	m->x0 = -0.5 * (double)(m->nx - 1) * dx;
	m->y0 = (first_row_top ? 0.5 : -0.5) * (double)(m->ny - 1) * dy;
}

int points_from_map(const struct points_map *m, const char *format, const char *source,
		    struct asph_points **out, struct asph_points_read_info *info,
		    struct asph_error *err)
{
	size_t n = 0, total = m->nx * m->ny;
	double x1 = m->x0 + (double)(m->nx - 1) * m->dx, y1 = m->y0 + (double)(m->ny - 1) * m->dy;

	if (!isfinite(m->x0) || !isfinite(m->y0) || !isfinite(x1) || !isfinite(y1))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "%s: the %zu x %zu grid at spacings %g, %g mm reaches past any finite position",
					 format, m->nx, m->ny, m->dx, m->dy);
	for (size_t k = 0; k < total; k++)
		n += isfinite(m->z[k]);
	if (n == 0)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "%s: all %zu nodes of the %zu x %zu map are invalid",
					 format, total, m->nx, m->ny);
	struct asph_points *p = asph_points_alloc(n);
	if (!p)
		return asph_error_set(err, -ENOMEM, "out of memory");
	n = 0;
	for (size_t j = 0; j < m->ny; j++)
		for (size_t i = 0; i < m->nx; i++) {
			double z = m->z[i + m->nx * j];
			if (!isfinite(z))
				continue;
			p->xyz[3 * n] = m->x0 + (double)i * m->dx;
			p->xyz[3 * n + 1] = m->y0 + (double)j * m->dy;
			p->xyz[3 * n + 2] = z;
			n++;
		}
	info->nx = m->nx;
	info->ny = m->ny;
	info->n_invalid = total - n;
	*out = p;
	return 0;
}
