/* SPDX-License-Identifier: GPL-3.0-or-later */
/* SDF (ISO 25178-71, the BCR Surface Data File): a map of NumPoints x
 * NumProfiles heights, ASCII ("aBCR-1.0", key = value lines, '*', the
 * values, '*', a trailer) or binary ("bBCR-1.0", an 81-byte little-endian
 * header and the values). Scales in metres. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "readers.h"
#include "util-mem.h"

#define SDF_BINARY_HEADER 81
#define M_TO_MM 1000.0

enum sdf_type {
	SDF_UINT8, SDF_UINT16, SDF_UINT32, SDF_FLOAT, SDF_SINT8, SDF_SINT16, SDF_SINT32,
	SDF_DOUBLE, SDF_NTYPES
};

static const size_t sdf_type_size[SDF_NTYPES] = { 1, 2, 4, 4, 1, 2, 4, 8 };

struct sdf_header {
	size_t nx, ny;
	double xscale, yscale, zscale;
	long compression, data_type, check_type;
};

static double sdf_binary_value(enum sdf_type t, const uint8_t *p)
{
	switch (t) {
	case SDF_UINT8: return p[0];
	case SDF_SINT8: return (int8_t)p[0];
	case SDF_UINT16: return get_le16(p);
	case SDF_SINT16: return (int16_t)get_le16(p);
	case SDF_UINT32: return get_le32(p);
	case SDF_SINT32: return (int32_t)get_le32(p);
	case SDF_FLOAT: return get_le_float(p);
	default: return get_le_double(p);
	}
}

/* What both variants check of the header; where names the place. */
static int sdf_check(const struct sdf_header *h, const char *source, int line, const char *field,
		     struct asph_error *err)
{
	if (h->nx == 0 || h->ny == 0)
		return asph_error_set_at(err, -EINVAL, source, line, 0, field,
					 "sdf: NumPoints and NumProfiles must be at least 1");
	if (!(h->xscale > 0) || !(h->yscale > 0) || !isfinite(h->xscale) || !isfinite(h->yscale) ||
	    !isfinite(h->zscale) || h->zscale == 0)
		return asph_error_set_at(err, -EINVAL, source, line, 0, field,
					 "sdf: Xscale and Yscale must be positive and Zscale finite and not 0");
	if (h->compression != 0)
		return asph_error_set_at(err, -ENOTSUP, source, line, 0, "Compression",
					 "sdf: compression %ld is not supported (0 only)", h->compression);
	if (h->data_type < 0 || h->data_type >= SDF_NTYPES)
		return asph_error_set_at(err, -EINVAL, source, line, 0, "DataType",
					 "sdf: data type %ld is not one of 0-7", h->data_type);
	if (h->check_type != 0)
		return asph_error_set_at(err, -ENOTSUP, source, line, 0, "CheckType",
					 "sdf: check type %ld is not supported (0 only)", h->check_type);
	return 0;
}

static int sdf_map(const struct sdf_header *h, double *z, const char *source,
		   struct asph_points **out, struct asph_points_read_info *info,
		   struct asph_error *err)
{
	struct points_map m = { .nx = h->nx, .ny = h->ny, .z = z };

	/* the first profile at the lowest y */
	points_map_centre(&m, h->xscale * M_TO_MM, h->yscale * M_TO_MM, 0);
	return points_from_map(&m, "sdf", source, out, info, err);
}

static int sdf_binary(const uint8_t *d, size_t len, const char *source, struct asph_points **out,
		      struct asph_points_read_info *info, struct asph_error *err)
{
	struct sdf_header h;
	size_t nodes, bytes;

	if (len < SDF_BINARY_HEADER)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "sdf: %zu bytes, fewer than the %d of a binary header", len,
					 SDF_BINARY_HEADER);
	/* version 8, ManufacID 10, CreateDate 12, ModDate 12: offset 42 */
	h.nx = get_le16(d + 42);
	h.ny = get_le16(d + 44);
	h.xscale = get_le_double(d + 46);
	h.yscale = get_le_double(d + 54);
	h.zscale = get_le_double(d + 62);
	h.compression = d[78];
	h.data_type = d[79];
	h.check_type = d[80];
	int r = sdf_check(&h, source, 0, "header", err);
	if (r < 0)
		return r;
	size_t size = sdf_type_size[h.data_type];
	if (points_map_size(h.nx, h.ny, size, &nodes, &bytes) < 0 || bytes > len - SDF_BINARY_HEADER)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "sdf: %zu x %zu values of %zu bytes need %zu bytes after the header at byte offset %d; the file has %zu",
					 h.nx, h.ny, size, h.nx * h.ny * size, SDF_BINARY_HEADER,
					 len - SDF_BINARY_HEADER);
	_cleanup_free_ double *z = malloc(nodes * sizeof(double));
	if (!z)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t k = 0; k < nodes; k++)
		z[k] = sdf_binary_value(h.data_type, d + SDF_BINARY_HEADER + k * size) * h.zscale *
		       M_TO_MM;
	return sdf_map(&h, z, source, out, info, err);
}

/* ---- ASCII ---- */

struct sdf_text {
	const char *s;
	size_t len, pos;
	int line;
	const char *source;
};

/* The next line without its end and the blanks around it; false at the
 * end of the text. */
static bool next_line(struct sdf_text *t, const char **s, size_t *n)
{
	if (t->pos >= t->len)
		return false;
	size_t e = t->pos;
	while (e < t->len && t->s[e] != '\n')
		e++;
	size_t b = t->pos;
	t->pos = e + 1;
	t->line++;
	while (b < e && strchr(" \t\r", t->s[b]))
		b++;
	while (e > b && strchr(" \t\r", t->s[e - 1]))
		e--;
	*s = t->s + b;
	*n = e - b;
	return true;
}

static int header_number(struct sdf_text *t, const char *key, const char *v, double *out,
			 struct asph_error *err)
{
	char *stop;

	*out = strtod(v, &stop);
	if (!*v || *stop || !isfinite(*out))
		return asph_error_set_at(err, -EINVAL, t->source, t->line, 0, key,
					 "sdf: not a finite number: '%s'", v);
	return 0;
}

static int header_entry(struct sdf_text *t, const char *line, size_t n, struct sdf_header *h,
			unsigned *seen, struct asph_error *err)
{
	static const char *const keys[] = { "NumPoints", "NumProfiles", "Xscale", "Yscale",
					    "Zscale", "DataType", "Compression", "CheckType" };
	char key[32], value[64];
	const char *eq = memchr(line, '=', n);
	double v;

	if (!eq)
		return asph_error_set_at(err, -EINVAL, t->source, t->line, 1, NULL,
					 "sdf: expected 'Key = value' or the '*' that ends the header, found '%.*s'",
					 (int)(n > 60 ? 60 : n), line);
	size_t kl = (size_t)(eq - line);
	while (kl && strchr(" \t", line[kl - 1]))
		kl--;
	snprintf(key, sizeof(key), "%.*s", (int)(kl < 31 ? kl : 31), line);
	const char *vb = eq + 1;
	while (vb < line + n && strchr(" \t", *vb))
		vb++;
	snprintf(value, sizeof(value), "%.*s", (int)(line + n - vb < 63 ? line + n - vb : 63), vb);
	for (size_t i = 0; i < ARRAY_SIZE(keys); i++) {
		if (strcasecmp(key, keys[i]))
			continue;
		int r = header_number(t, keys[i], value, &v, err);
		if (r < 0)
			return r;
		bool count = i < 2 || i >= 5;
		if (count && (v != floor(v) || v < 0 || v > (double)POINTS_MAX))
			return asph_error_set_at(err, -EINVAL, t->source, t->line, 0, keys[i],
						 "sdf: expected a count, found '%s'", value);
		switch (i) {
		case 0: h->nx = (size_t)v; break;
		case 1: h->ny = (size_t)v; break;
		case 2: h->xscale = v; break;
		case 3: h->yscale = v; break;
		case 4: h->zscale = v; break;
		case 5: h->data_type = (long)v; break;
		case 6: h->compression = (long)v; break;
		default: h->check_type = (long)v; break;
		}
		*seen |= 1u << i;
		return 0;
	}
	return 0; /* ManufacID, dates, and keys of later revisions */
}

/* The values: numbers separated by blanks, NaN for an invalid node, up to
 * a '*' line or the end. */
static int ascii_values(struct sdf_text *t, const struct sdf_header *h, double *z, size_t nodes,
			struct asph_error *err)
{
	const char *s;
	size_t n, k = 0;

	while (next_line(t, &s, &n)) {
		if (n == 1 && s[0] == '*')
			break;
		size_t p = 0;
		while (p < n) {
			while (p < n && strchr(" \t,", s[p]))
				p++;
			if (p == n)
				break;
			size_t e = p;
			while (e < n && !strchr(" \t,", s[e]))
				e++;
			char tmp[64], *stop;
			snprintf(tmp, sizeof(tmp), "%.*s", (int)(e - p < 63 ? e - p : 63), s + p);
			if (k == nodes)
				return asph_error_set_at(err, -EINVAL, t->source, t->line, (int)p + 1, NULL,
							 "sdf: more than the %zu values NumPoints x NumProfiles give",
							 nodes);
			double v = strtod(tmp, &stop);
			if (stop == tmp || *stop || e - p > 63 || (isinf(v)))
				return asph_error_set_at(err, -EINVAL, t->source, t->line, (int)p + 1, NULL,
							 "sdf: not a number: '%s'", tmp);
			z[k++] = isnan(v) ? NAN : v * h->zscale * M_TO_MM;
			p = e;
		}
	}
	if (k != nodes)
		return asph_error_set_at(err, -EINVAL, t->source, t->line, 0, NULL,
					 "sdf: %zu values; NumPoints x NumProfiles give %zu", k, nodes);
	return 0;
}

static int sdf_ascii(const uint8_t *d, size_t len, const char *source, struct asph_points **out,
		     struct asph_points_read_info *info, struct asph_error *err)
{
	struct sdf_text t = { (const char *)d, len, 0, 0, source };
	struct sdf_header h = { 0 };
	unsigned seen = 0;
	const char *s;
	size_t n, nodes;
	bool end = false;

	if (memchr(d, '\0', len))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "sdf: binary data in an ASCII SDF file");
	next_line(&t, &s, &n); /* the version */
	while (!end && next_line(&t, &s, &n)) {
		if (n == 0 || s[0] == ';')
			continue;
		if (n == 1 && s[0] == '*')
			end = true;
		else if (header_entry(&t, s, n, &h, &seen, err) < 0)
			return -EINVAL;
	}
	if (!end)
		return asph_error_set_at(err, -EINVAL, source, t.line, 0, NULL,
					 "sdf: the header does not end with a '*' line");
	if ((seen & 0x3f) != 0x3f)
		return asph_error_set_at(err, -EINVAL, source, t.line, 0, NULL,
					 "sdf: the header lacks one of NumPoints, NumProfiles, Xscale, Yscale, Zscale, DataType");
	int r = sdf_check(&h, source, t.line, "header", err);
	if (r < 0)
		return r;
	/* every value takes two characters at least */
	if (points_map_size(h.nx, h.ny, 2, &nodes, NULL) < 0 || 2 * nodes > len)
		return asph_error_set_at(err, -EINVAL, source, t.line, 0, NULL,
					 "sdf: %zu x %zu values cannot fit in the %zu bytes of the file",
					 h.nx, h.ny, len);
	_cleanup_free_ double *z = malloc(nodes * sizeof(double));
	if (!z)
		return asph_error_set(err, -ENOMEM, "out of memory");
	if ((r = ascii_values(&t, &h, z, nodes, err)) < 0)
		return r;
	return sdf_map(&h, z, source, out, info, err);
}

int points_read_sdf(const uint8_t *data, size_t len, const char *source,
		    struct asph_points **out, struct asph_points_read_info *info,
		    struct asph_error *err)
{
	if (len >= 1 && data[0] == 'b')
		return sdf_binary(data, len, source, out, info, err);
	if (len >= 1 && data[0] == 'a')
		return sdf_ascii(data, len, source, out, info, err);
	return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
				 "sdf: the file does not start with a version such as aBCR-1.0 (ASCII) or bBCR-1.0 (binary)");
}
