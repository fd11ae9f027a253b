/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <jansson.h>

#include "asph/points.h"
#include "asph/x3p.h"
#include "plot/colormap.h"
#include "readers.h"
#include "fileio.h"
#include "util-mem.h"
#include "util-number.h"



DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_points *, asph_points_free)

enum format { FMT_CSV, FMT_PLY, FMT_JSON };

static enum format format_of(const char *path)
{
	const char *dot = strrchr(path, '.');
	if (dot && !strcasecmp(dot, ".ply"))
		return FMT_PLY;
	if (dot && !strcasecmp(dot, ".json"))
		return FMT_JSON;
	return FMT_CSV;
}

/* ---- PLY ---- */

enum ply_type { PLY_NONE, PLY_I8, PLY_U8, PLY_I16, PLY_U16, PLY_I32, PLY_U32, PLY_F32, PLY_F64 };

static enum ply_type ply_type_of(const char *s)
{
	static const struct { const char *name; enum ply_type t; } map[] = {
		{ "char", PLY_I8 }, { "int8", PLY_I8 }, { "uchar", PLY_U8 }, { "uint8", PLY_U8 },
		{ "short", PLY_I16 }, { "int16", PLY_I16 }, { "ushort", PLY_U16 }, { "uint16", PLY_U16 },
		{ "int", PLY_I32 }, { "int32", PLY_I32 }, { "uint", PLY_U32 }, { "uint32", PLY_U32 },
		{ "float", PLY_F32 }, { "float32", PLY_F32 }, { "double", PLY_F64 }, { "float64", PLY_F64 },
	};
	for (size_t i = 0; i < ARRAY_SIZE(map); i++)
		if (!strcmp(s, map[i].name))
			return map[i].t;
	return PLY_NONE;
}

static size_t ply_size(enum ply_type t)
{
	switch (t) {
	case PLY_I8: case PLY_U8: return 1;
	case PLY_I16: case PLY_U16: return 2;
	case PLY_I32: case PLY_U32: case PLY_F32: return 4;
	case PLY_F64: return 8;
	case PLY_NONE: break;
	}
	return 0;
}

#define PLY_MAX_PROPS 32

struct ply_header {
	int binary;
	size_t n_vertex, n_face;
	int n_props;
	enum ply_type prop_type[PLY_MAX_PROPS];
	char prop_name[PLY_MAX_PROPS][32];
	enum ply_type face_count_type, face_index_type;
	int vertex_first;   /* vertex element precedes face element */
	size_t data_offset;
	int data_line;
};

static int ply_parse_header(const char *text, size_t len, const char *source,
			    struct ply_header *h, struct asph_error *err)
{
	size_t pos = 0;
	int lineno = 0, in = 0; /* 1 vertex, 2 face, 3 other */

	memset(h, 0, sizeof(*h));
	h->vertex_first = 1;
	for (;;) {
		if (pos >= len)
			return asph_error_set_at(err, -EINVAL, source, lineno, 1, NULL,
						 "PLY header without end_header");
		size_t end = pos;
		while (end < len && text[end] != '\n')
			end++;
		char line[256];
		size_t ll = end - pos;
		if (ll >= sizeof(line))
			return asph_error_set_at(err, -EINVAL, source, lineno + 1, 1, NULL,
						 "PLY header line too long");
		memcpy(line, text + pos, ll);
		line[ll] = '\0';
		if (ll && line[ll - 1] == '\r')
			line[--ll] = '\0';
		lineno++;
		pos = end + 1;
		char w1[32] = "", w2[32] = "", w3[32] = "", w4[32] = "", w5[32] = "";
		int nw = sscanf(line, "%31s %31s %31s %31s %31s", w1, w2, w3, w4, w5);
		if (lineno == 1) {
			if (strcmp(line, "ply"))
				return asph_error_set_at(err, -EINVAL, source, 1, 1, NULL,
							 "not a PLY file (no 'ply' magic)");
			continue;
		}
		if (nw <= 0 || !strcmp(w1, "comment") || !strcmp(w1, "obj_info"))
			continue;
		if (!strcmp(w1, "format")) {
			if (!strcmp(w2, "ascii"))
				h->binary = 0;
			else if (!strcmp(w2, "binary_little_endian"))
				h->binary = 1;
			else
				return asph_error_set_at(err, -ENOTSUP, source, lineno, 8, "format",
							 "PLY format '%s' not supported (ascii, binary_little_endian)",
							 w2);
		} else if (!strcmp(w1, "element")) {
			char *stop;
			unsigned long long count = strtoull(w3, &stop, 10);
			if (nw < 3 || *stop || count > POINTS_MAX)
				return asph_error_set_at(err, -EINVAL, source, lineno, 9, "element",
							 "bad element count '%s'", w3);
			if (!strcmp(w2, "vertex")) {
				in = 1;
				h->n_vertex = count;
			} else if (!strcmp(w2, "face")) {
				if (h->n_vertex == 0 && h->n_props == 0)
					h->vertex_first = 0;
				in = 2;
				h->n_face = count;
			} else {
				if (count)
					return asph_error_set_at(err, -ENOTSUP, source, lineno, 9,
								 w2,
								 "PLY element '%s' not supported",
								 w2);
				in = 3;
			}
		} else if (!strcmp(w1, "property")) {
			if (in == 1) {
				if (h->n_props == PLY_MAX_PROPS)
					return asph_error_set_at(err, -EINVAL, source, lineno, 1,
								 NULL, "too many properties");
				h->prop_type[h->n_props] = ply_type_of(w2);
				if (h->prop_type[h->n_props] == PLY_NONE || nw < 3)
					return asph_error_set_at(err, -EINVAL, source, lineno, 10,
								 w3,
								 "bad vertex property type '%s'",
								 w2);
				snprintf(h->prop_name[h->n_props], 32, "%s", w3);
				h->n_props++;
			} else if (in == 2) {
				if (strcmp(w2, "list") || nw < 5)
					return asph_error_set_at(err, -EINVAL, source, lineno, 10,
								 NULL,
								 "face property must be 'list <count type> <index type> vertex_indices'");
				h->face_count_type = ply_type_of(w3);
				h->face_index_type = ply_type_of(w4);
				if (!h->face_count_type || !h->face_index_type)
					return asph_error_set_at(err, -EINVAL, source, lineno, 15,
								 NULL, "bad face list types");
			}
		} else if (!strcmp(w1, "end_header")) {
			/* A header ending without a newline leaves pos past
			 * the text. */
			h->data_offset = pos < len ? pos : len;
			h->data_line = lineno + 1;
			break;
		} else {
			return asph_error_set_at(err, -EINVAL, source, lineno, 1, NULL,
						 "unexpected PLY header line '%s'", line);
		}
	}
	if (!h->vertex_first && h->n_face)
		return asph_error_set_at(err, -ENOTSUP, source, 0, 0, NULL,
					 "faces before vertices are not supported");
	return 0;
}

static double ply_get_binary(const unsigned char *p, enum ply_type t)
{
	switch (t) {
	case PLY_I8: return (int8_t)p[0];
	case PLY_U8: return p[0];
	case PLY_I16: { int16_t v; memcpy(&v, p, 2); return v; }
	case PLY_U16: { uint16_t v; memcpy(&v, p, 2); return v; }
	case PLY_I32: { int32_t v; memcpy(&v, p, 4); return v; }
	case PLY_U32: { uint32_t v; memcpy(&v, p, 4); return v; }
	case PLY_F32: { float v; memcpy(&v, p, 4); return v; }
	case PLY_F64: { double v; memcpy(&v, p, 8); return v; }
	case PLY_NONE: break;
	}
	return NAN;
}

/* Reads the next number of the ASCII body; tracks lines for errors. */
struct ply_cursor {
	const char *text;
	size_t len, pos;
	int line;
	size_t line_start;
};

static void ply_skip_space(struct ply_cursor *c)
{
	while (c->pos < c->len && (c->text[c->pos] == ' ' || c->text[c->pos] == '\t' ||
				   c->text[c->pos] == '\r' || c->text[c->pos] == '\n')) {
		if (c->text[c->pos] == '\n') {
			c->line++;
			c->line_start = c->pos + 1;
		}
		c->pos++;
	}
}

static int ply_next(struct ply_cursor *c, double *v)
{
	ply_skip_space(c);
	if (c->pos >= c->len)
		return -ENODATA;
	size_t e = c->pos;
	while (e < c->len && !strchr(" \t\r\n", c->text[e]))
		e++;
	/* strchr() finds the NUL too: a NUL byte is an empty token here. */
	if (e == c->pos || e - c->pos >= 64 ||
	    parse_double(c->text + c->pos, e - c->pos, v) != e - c->pos)
		return -EINVAL;
	c->pos = e;
	return 0;
}

/* Data past the elements the header announces means the counts are wrong:
 * refused rather than dropped. */
static int ply_check_end(const struct ply_header *h, struct ply_cursor *c,
			 size_t avail, const char *source, struct asph_error *err)
{
	if (h->binary) {
		if (avail == 0)
			return 0;
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "element",
					 "%zu bytes after the %zu vertices and %zu faces the header announces",
					 avail, h->n_vertex, h->n_face);
	}
	ply_skip_space(c);
	if (c->pos >= c->len)
		return 0;
	return asph_error_set_at(err, -EINVAL, source, c->line, (int)(c->pos - c->line_start) + 1,
				 "element",
				 "data after the %zu vertices and %zu faces the header announces",
				 h->n_vertex, h->n_face);
}

static int ply_read_body(const char *text, size_t len, const char *source,
			 const struct ply_header *h, struct asph_points *p,
			 struct asph_error *err)
{
	int ix = -1, iy = -1, iz = -1, iv = -1;
	size_t stride = 0;

	for (int i = 0; i < h->n_props; i++) {
		if (!strcmp(h->prop_name[i], "x")) ix = i;
		else if (!strcmp(h->prop_name[i], "y")) iy = i;
		else if (!strcmp(h->prop_name[i], "z")) iz = i;
		else if (iv < 0 && h->prop_type[i] >= PLY_F32) iv = i;
		stride += ply_size(h->prop_type[i]);
	}
	if (ix < 0 || iy < 0 || iz < 0)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "PLY vertices lack x, y or z");
	if (iv >= 0 && asph_points_add_value(p, h->prop_name[iv]) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory");

	struct ply_cursor c = { text, len, h->data_offset, h->data_line, h->data_offset };
	const unsigned char *bin = (const unsigned char *)text + h->data_offset;
	size_t avail = len - h->data_offset;
	double prop[PLY_MAX_PROPS];

	for (size_t i = 0; i < h->n_vertex; i++) {
		if (h->binary) {
			if (avail < stride)
				return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
							 "PLY data ends at vertex %zu of %zu", i,
							 h->n_vertex);
			for (int k = 0; k < h->n_props; k++) {
				prop[k] = ply_get_binary(bin, h->prop_type[k]);
				bin += ply_size(h->prop_type[k]);
			}
			avail -= stride;
		} else {
			for (int k = 0; k < h->n_props; k++) {
				int r = ply_next(&c, &prop[k]);
				if (r < 0)
					return asph_error_set_at(err, -EINVAL, source, c.line,
								 (int)(c.pos - c.line_start) + 1,
								 h->prop_name[k],
								 r == -ENODATA ? "PLY data ends at vertex %zu" : "not a number at vertex %zu",
								 i);
			}
		}
		for (int k = 0; k < 3; k++) {
			int idx = k == 0 ? ix : k == 1 ? iy : iz;
			if (!isfinite(prop[idx]))
				return asph_error_set_at(err, -EINVAL, source,
							 h->binary ? 0 : c.line, 0,
							 h->prop_name[idx],
							 "vertex %zu: not a finite number", i);
			p->xyz[3 * i + k] = prop[idx];
		}
		if (iv >= 0)
			p->value[i] = prop[iv];
	}
	if (h->n_face == 0)
		return ply_check_end(h, &c, avail, source, err);
	p->triangles = malloc(3 * h->n_face * sizeof(uint32_t));
	if (!p->triangles)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t f = 0; f < h->n_face; f++) {
		double cnt, idx[3];
		if (h->binary) {
			size_t cs = ply_size(h->face_count_type), is = ply_size(h->face_index_type);
			if (avail < cs)
				return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
							 "PLY data ends at face %zu", f);
			cnt = ply_get_binary(bin, h->face_count_type);
			bin += cs;
			avail -= cs;
			if (cnt != 3)
				return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
							 "face %zu has %g vertices; only triangles are supported",
							 f, cnt);
			if (avail < 3 * is)
				return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
							 "PLY data ends at face %zu", f);
			for (int k = 0; k < 3; k++) {
				idx[k] = ply_get_binary(bin, h->face_index_type);
				bin += is;
			}
			avail -= 3 * is;
		} else {
			if (ply_next(&c, &cnt) < 0 || cnt != 3)
				return asph_error_set_at(err, -EINVAL, source, c.line, 1, NULL,
							 "face %zu: expected '3 i j k' (triangles only)",
							 f);
			for (int k = 0; k < 3; k++)
				if (ply_next(&c, &idx[k]) < 0)
					return asph_error_set_at(err, -EINVAL, source, c.line, 1,
								 NULL, "face %zu: bad vertex index",
								 f);
		}
		for (int k = 0; k < 3; k++) {
			if (!(idx[k] >= 0 && idx[k] < (double)h->n_vertex) || idx[k] != floor(idx[k]))
				return asph_error_set_at(err, -EINVAL, source,
							 h->binary ? 0 : c.line, 0, NULL,
							 "face %zu: vertex index %g out of range",
							 f, idx[k]);
			p->triangles[3 * f + k] = (uint32_t)idx[k];
		}
	}
	p->n_triangles = h->n_face;
	return ply_check_end(h, &c, avail, source, err);
}

static int read_ply(const char *text, size_t len, const char *source,
		    struct asph_points **out, struct asph_error *err)
{
	struct ply_header h;
	int r = ply_parse_header(text, len, source, &h, err);
	if (r < 0)
		return r;
	/* Every vertex property and face entry takes at least one byte, so
	 * counts the data cannot hold are refused before they are allocated. */
	size_t avail = len - h.data_offset;
	size_t per_vertex = h.n_props > 0 ? (size_t)h.n_props : 1;
	if (h.n_vertex > avail / per_vertex ||
	    h.n_face > (avail - h.n_vertex * per_vertex) / 4)
		return asph_error_set_at(err, -EINVAL, source, h.data_line, 1, "element",
					 "PLY header announces %zu vertices and %zu faces, more than the %zu bytes of data hold",
					 h.n_vertex, h.n_face, avail);
	_cleanup_(asph_points_freep) struct asph_points *p = asph_points_alloc(h.n_vertex);
	if (!p)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = ply_read_body(text, len, source, &h, p, err);
	if (r < 0)
		return r;
	*out = steal_ptr(p);
	return 0;
}

/* ---- JSON ---- */

/* Member i of the array list, three numbers: finite coordinates, or with
 * indices, vertex indices below n_points. */
static int json_triple(json_t *list, const char *name, size_t i, bool indices,
		       size_t n_points, const char *source, double v[3],
		       struct asph_error *err)
{
	json_t *e = json_array_get(list, i);
	char field[48];

	snprintf(field, sizeof(field), "%s[%zu]", name, i);
	if (!json_is_array(e) || json_array_size(e) != 3)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, field, "expected %s",
					 indices ? "[i, j, k]" : "[x, y, z]");
	for (size_t k = 0; k < 3; k++) {
		json_t *x = json_array_get(e, k);
		if (!indices && !(json_is_number(x) && isfinite(json_number_value(x))))
			return asph_error_set_at(err, -EINVAL, source, 0, 0, field,
						 "coordinate %zu is not a finite number", k);
		if (indices && (!json_is_integer(x) || json_integer_value(x) < 0 ||
				 (json_int_t)n_points <= json_integer_value(x)))
			return asph_error_set_at(err, -EINVAL, source, 0, 0, field,
						 "vertex index out of range");
		v[k] = json_number_value(x);
	}
	return 0;
}

static int read_json(const char *text, size_t len, const char *source,
		     struct asph_points **out, struct asph_error *err)
{
	json_error_t jerr;
	_cleanup_(json_decrefp) json_t *root = json_loadb(text, len, 0, &jerr);

	if (!root)
		return asph_error_set_at(err, -EINVAL, source, jerr.line, jerr.column, NULL, "%s",
					 jerr.text);
	json_t *pts = json_object_get(root, "points");
	if (!json_is_array(pts))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "points",
					 "expected an array \"points\" of [x,y,z]");
	size_t n = json_array_size(pts);
	_cleanup_(asph_points_freep) struct asph_points *p = asph_points_alloc(n);
	if (!p)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < n; i++) {
		int r = json_triple(pts, "points", i, false, 0, source, p->xyz + 3 * i, err);
		if (r < 0)
			return r;
	}
	json_t *tris = json_object_get(root, "triangles");
	if (json_is_array(tris) && json_array_size(tris) > 0) {
		size_t nt = json_array_size(tris);
		p->triangles = malloc(3 * nt * sizeof(uint32_t));
		if (!p->triangles)
			return asph_error_set(err, -ENOMEM, "out of memory");
		for (size_t i = 0; i < nt; i++) {
			double t[3];
			int r = json_triple(tris, "triangles", i, true, n, source, t, err);
			if (r < 0)
				return r;
			for (size_t k = 0; k < 3; k++)
				p->triangles[3 * i + k] = (uint32_t)t[k];
		}
		p->n_triangles = nt;
	}
	json_t *vals = json_object_get(root, "values");
	if (json_is_array(vals)) {
		if (json_array_size(vals) != n)
			return asph_error_set_at(err, -EINVAL, source, 0, 0, "values",
						 "expected one value per point");
		json_t *name = json_object_get(root, "value_name");
		if (asph_points_add_value(p, json_is_string(name) ? json_string_value(name) : "value") < 0)
			return asph_error_set(err, -ENOMEM, "out of memory");
		for (size_t i = 0; i < n; i++) {
			json_t *v = json_array_get(vals, i);
			if (!json_is_number(v))
				return asph_error_set_at(err, -EINVAL, source, 0, 0, "values",
							 "value %zu is not a number", i);
			p->value[i] = json_number_value(v);
		}
	}
	*out = steal_ptr(p);
	return 0;
}

/* The reader of each format; maps, binary formats and containers take
 * bytes, the text formats characters. */
static int read_format(enum asph_points_format f, const void *data, size_t len,
		       const char *source, const struct asph_points_read_options *o,
		       struct asph_points **out, struct asph_points_read_info *info,
		       struct asph_error *err)
{
	switch (f) {
	case ASPH_POINTS_PLY:
		return read_ply(data, len, source, out, err);
	case ASPH_POINTS_JSON:
		return read_json(data, len, source, out, err);
	case ASPH_POINTS_X3P:
		return points_read_x3p(data, len, source, out, info, err);
	case ASPH_POINTS_SDF:
		return points_read_sdf(data, len, source, out, info, err);
	case ASPH_POINTS_METROPRO:
		return points_read_metropro(data, len, source, out, info, err);
	case ASPH_POINTS_DATX:
		return points_read_datx(data, len, source, out, info, err);
	case ASPH_POINTS_AUTO:
	case ASPH_POINTS_TEXT:
		break;
	}
	return points_read_text(data, len, source, o, out, info, err);
}

int asph_points_read_memory_as(const void *data, size_t len, const char *source,
			       const struct asph_points_read_options *o,
			       struct asph_points **out, struct asph_points_read_info *info,
			       struct asph_error *err)
{
	struct asph_points_read_info local;
	enum asph_points_format f = o ? o->format : ASPH_POINTS_AUTO;

	if (!info)
		info = &local;
	memset(info, 0, sizeof(*info));
	*out = NULL;
	if (f == ASPH_POINTS_AUTO)
		f = points_detect(data, len);
	if (o && o->unit_mm != 0 && !(o->unit_mm > 0 && isfinite(o->unit_mm)))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "the unit must be a positive length (mm)");
	info->format = f;
	return read_format(f, data, len, source, o, out, info, err);
}

int asph_points_read_memory(const void *data, size_t len, const char *source,
			    struct asph_points **out, struct asph_error *err)
{
	return asph_points_read_memory_as(data, len, source, NULL, out, NULL, err);
}

int asph_points_read_csv_text(const char *text, size_t len,
			      const char *source, struct asph_points **out,
			      struct asph_error *err)
{
	struct asph_points_read_options o = { .format = ASPH_POINTS_TEXT };

	return asph_points_read_memory_as(text, len, source, &o, out, NULL, err);
}

int asph_points_read_as(const char *path, const struct asph_points_read_options *o,
			struct asph_points **out, struct asph_points_read_info *info,
			struct asph_error *err)
{
	int is_stdin = !strcmp(path, "-");
	_cleanup_free_ char *data = NULL;
	size_t len = 0;

	int r = file_read_all(path, POINTS_FILE_LIMIT, &data, &len, err);
	if (r < 0)
		return r;
	return asph_points_read_memory_as(data, len, is_stdin ? "<stdin>" : path, o, out, info,
					  err);
}

int asph_points_read(const char *path, struct asph_points **out,
		     struct asph_error *err)
{
	return asph_points_read_as(path, NULL, out, NULL, err);
}

/* ---- writing ---- */

static void value_range(const struct asph_points *p,
			const struct asph_points_write_options *o, double *lo,
			double *hi)
{
	*lo = o ? o->colour_lo : 0;
	*hi = o ? o->colour_hi : 0;
	if (*lo != *hi)
		return;
	double m = 0;
	for (size_t i = 0; i < p->n; i++)
		if (isfinite(p->value[i]))
			m = fmax(m, fabs(p->value[i]));
	if (m == 0)
		m = 1;
	*lo = -m;
	*hi = m;
}

/* A CSV line of "%.17g" numbers (the default precision), through
 * format_double_g17(): the bytes fprintf() writes, several times faster. */
static void write_csv_g17(FILE *f, const double *v, int count)
{
	char line[4 * FORMAT_G17_MAX + 1];
	size_t len = 0;

	for (int k = 0; k < count; k++) {
		len += format_double_g17(line + len, v[k]);
		line[len++] = k + 1 < count ? ',' : '\n';
	}
	fwrite(line, 1, len, f);
}

static void write_csv(FILE *f, const struct asph_points *p, int prec)
{
	fprintf(f, "x,y,z%s%s\n", p->value ? "," : "", p->value ? p->value_name : "");
	for (size_t i = 0; i < p->n; i++) {
		const double *q = p->xyz + 3 * i;
		if (prec == 17) {
			double v[4] = { q[0], q[1], q[2], p->value ? p->value[i] : 0 };
			write_csv_g17(f, v, p->value ? 4 : 3);
		} else if (p->value) {
			fprintf(f, "%.*g,%.*g,%.*g,%.*g\n", prec, q[0], prec, q[1], prec, q[2],
				prec, p->value[i]);
		} else {
			fprintf(f, "%.*g,%.*g,%.*g\n", prec, q[0], prec, q[1], prec, q[2]);
		}
	}
}

static void write_ply(FILE *f, const struct asph_points *p, int prec,
		      const struct asph_points_write_options *o)
{
	double lo = 0, hi = 0;

	fprintf(f, "ply\nformat ascii 1.0\ncomment asphd points (mm)\n");
	fprintf(f, "element vertex %zu\nproperty double x\nproperty double y\nproperty double z\n", p->n);
	if (p->value) {
		value_range(p, o, &lo, &hi);
		fprintf(f, "comment colour range %s [%.6g, %.6g]\n", p->value_name, lo, hi);
		fprintf(f, "property double %s\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n",
			p->value_name);
	}
	if (p->n_triangles)
		fprintf(f, "element face %zu\nproperty list uchar int vertex_indices\n", p->n_triangles);
	fprintf(f, "end_header\n");
	for (size_t i = 0; i < p->n; i++) {
		const double *q = p->xyz + 3 * i;
		fprintf(f, "%.*g %.*g %.*g", prec, q[0], prec, q[1], prec, q[2]);
		if (p->value) {
			uint8_t rgb[3];
			colormap_diverging((p->value[i] - lo) / (hi - lo), rgb);
			fprintf(f, " %.*g %u %u %u", prec, p->value[i], rgb[0], rgb[1], rgb[2]);
		}
		fputc('\n', f);
	}
	for (size_t t = 0; t < p->n_triangles; t++)
		fprintf(f, "3 %u %u %u\n", p->triangles[3 * t], p->triangles[3 * t + 1],
			p->triangles[3 * t + 2]);
}

static void write_json(FILE *f, const struct asph_points *p, int prec)
{
	fprintf(f, "{\"units\": \"mm\", \"points\": [");
	for (size_t i = 0; i < p->n; i++) {
		const double *q = p->xyz + 3 * i;
		fprintf(f, "%s[%.*g, %.*g, %.*g]", i ? ",\n" : "\n", prec, q[0], prec, q[1], prec, q[2]);
	}
	fprintf(f, "\n]");
	if (p->value) {
		fprintf(f, ",\n\"value_name\": \"%s\", \"values\": [", p->value_name);
		for (size_t i = 0; i < p->n; i++)
			fprintf(f, "%s%.*g", i ? ", " : "", prec, p->value[i]);
		fprintf(f, "]");
	}
	if (p->n_triangles) {
		fprintf(f, ",\n\"triangles\": [");
		for (size_t t = 0; t < p->n_triangles; t++)
			fprintf(f, "%s[%u, %u, %u]", t ? ",\n" : "\n", p->triangles[3 * t],
				p->triangles[3 * t + 1], p->triangles[3 * t + 2]);
		fprintf(f, "\n]");
	}
	fprintf(f, "}\n");
}

int asph_points_write_stream(FILE *f, const char *name, const struct asph_points *p,
			     const struct asph_points_write_options *opts,
			     struct asph_error *err)
{
	int prec = opts && opts->precision > 0 ? opts->precision : 17;
	const char *dot = name ? strrchr(name, '.') : NULL;

	if (dot && !strcasecmp(dot, ".x3p"))
		return asph_error_set_at(err, -EINVAL, name, 0, 0, NULL,
					 "X3P is a container written by path, not to a stream");
	switch (name ? format_of(name) : FMT_CSV) {
	case FMT_PLY:
		write_ply(f, p, prec, opts);
		break;
	case FMT_JSON:
		write_json(f, p, prec);
		break;
	case FMT_CSV:
		write_csv(f, p, prec);
		break;
	}
	if (fflush(f) != 0 || ferror(f)) {
		int e = errno ? errno : EIO;
		return asph_error_set_at(err, -e, name ? name : "<stream>", 0, 0, NULL,
					 "write error: %s", strerror(e));
	}
	return 0;
}

int asph_points_write(const char *path, const struct asph_points *p,
		      const struct asph_points_write_options *opts,
		      struct asph_error *err)
{
	int is_stdout = !strcmp(path, "-");
	const char *dot = strrchr(path, '.');
	FILE *f;
	int r;

	/* X3P: the list layout of ISO 25178-72 (lib/export/x3p.c). */
	if (!is_stdout && dot && !strcasecmp(dot, ".x3p"))
		return asph_x3p_write_points(path, p->xyz, p->n, opts ? opts->x3p : NULL, err);
	f = is_stdout ? stdout : fopen(path, "we");
	if (!f) {
		int e = -errno;
		return asph_error_set_at(err, e, path, 0, 0, NULL, "cannot create: %s",
					 strerror(-e));
	}
	/* "<stdout>" names no format: CSV, as for stdout before. */
	r = asph_points_write_stream(f, is_stdout ? "<stdout>" : path, p, opts, err);
	if (!is_stdout && fclose(f) != 0 && r == 0) {
		int e = errno;
		return asph_error_set_at(err, -e, path, 0, 0, NULL, "write error: %s", strerror(e));
	}
	return r;
}
