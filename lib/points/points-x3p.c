/* SPDX-License-Identifier: GPL-3.0-or-later */
/* X3P (ISO 25178-72, the openGPS ISO 5436-2 XML format) from any writer:
 * point lists and matrices, data in bindata or inline, every data type with
 * its Increment and Offset, invalid points by NaN or a valid-points file;
 * the MD5 sums are checked. libzip, libxml2 and nettle's MD5. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <libxml/parser.h>
#include <libxml/tree.h>
#include "util-hash.h"
#include <zip.h>

#include "readers.h"
#include "util-mem.h"

#define XML_LIMIT ((zip_uint64_t)64 << 20)
/* a metre in mm: the factor from an X3P's metres to our mm (exact both
 * ways with the writer's division by 1000, lib/export/x3p.c) */
#define M_TO_MM 1000.0

struct x3p_axis {
	char type;          /* 'I' incremental, 'A' absolute */
	char data;          /* 'I' int16, 'L' int32, 'F' float32, 'D' float64 */
	double inc, off;    /* m */
};

struct x3p {
	const char *source;
	zip_t *zip;
	xmlDocPtr doc;
	xmlNodePtr root;
	char root_dir[128];  /* "" or "name/": a container zipped with its folder */
	struct x3p_axis axis[3];
	bool matrix;
	size_t size[3];     /* matrix: SizeX, SizeY, SizeZ; list: n, 1, 1 */
	size_t nodes;
	size_t record;      /* bytes of one point in data.bin */
	struct asph_error *err;
};

static const char *const axis_names[3] = { "CX", "CY", "CZ" };

static int x3p_error(struct x3p *x, int code, const char *element, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));
static int x3p_error(struct x3p *x, int code, const char *element, const char *fmt, ...)
{
	char msg[400];
	va_list ap;

	va_start(ap, fmt);
	vsnprintf(msg, sizeof(msg), fmt, ap);
	va_end(ap);
	return asph_error_set_at(x->err, code, x->source, 0, 0, element, "x3p: %s", msg);
}

/* ---- the container ---- */

/* Where main.xml is: at the top, or (as zipping a folder makes it, and
 * x3ptools' examples are) in one folder, whose members then are the
 * container's. */
static int find_root(struct x3p *x)
{
	zip_int64_t n = zip_get_num_entries(x->zip, 0);
	int found = 0;

	x->root_dir[0] = '\0';
	if (zip_name_locate(x->zip, "main.xml", 0) >= 0)
		return 0;
	for (zip_int64_t i = 0; i < n; i++) {
		const char *name = zip_get_name(x->zip, (zip_uint64_t)i, 0);
		const char *slash = name ? strchr(name, '/') : NULL;
		if (!slash || strcmp(slash, "/main.xml") || !strncmp(name, "__MACOSX/", 9) ||
		    (size_t)(slash - name) + 2 > sizeof(x->root_dir))
			continue;
		snprintf(x->root_dir, sizeof(x->root_dir), "%.*s/", (int)(slash - name), name);
		found++;
	}
	if (found != 1) {
		x->root_dir[0] = '\0';
		return x3p_error(x, -EINVAL, NULL, found ? "main.xml in more than one folder"
							 : "the container has no main.xml");
	}
	return 0;
}

static int member_read(struct x3p *x, const char *member, zip_uint64_t limit, uint8_t **out,
		       size_t *len)
{
	char name[512];
	zip_stat_t st;
	zip_file_t *f;

	snprintf(name, sizeof(name), "%s%s", x->root_dir, member);
	zip_stat_init(&st);
	if (zip_stat(x->zip, name, 0, &st) < 0)
		return -ENOENT;
	if (!(st.valid & ZIP_STAT_SIZE) || st.size > limit)
		return x3p_error(x, -EFBIG, name, "the member is larger than %llu bytes",
				 (unsigned long long)limit);
	uint8_t *buf = malloc(st.size ? st.size : 1);
	if (!buf)
		return asph_error_set(x->err, -ENOMEM, "out of memory");
	f = zip_fopen(x->zip, name, 0);
	zip_int64_t n = f ? zip_fread(f, buf, st.size) : -1;
	const char *why = f ? zip_file_strerror(f) : zip_strerror(x->zip);
	int r = n == (zip_int64_t)st.size ? 0 :
		x3p_error(x, -EINVAL, name, "the member cannot be read: %s", why);
	if (f)
		zip_fclose(f);
	if (r < 0) {
		free(buf);
		return r;
	}
	*out = buf;
	*len = st.size;
	return 0;
}

/* The sum (32 hex digits at the start of text) against the data's. */
static int check_md5(struct x3p *x, const char *expected, size_t n, const void *data,
		     size_t len, const char *what, const char *element)
{
	char hex[33];

#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
	/* the fuzzer mutates what the sums guard */
	return 0;
#endif
	md5_hex(data, len, hex);
	if (n < 32 || strncasecmp(expected, hex, 32))
		return x3p_error(x, -EINVAL, element, "%s does not match its MD5 sum (%.*s, computed %s)",
				 what, (int)(n < 32 ? n : 32), expected, hex);
	return 0;
}

/* ---- main.xml ---- */

/* The element child of parent called name, in any namespace. */
static xmlNodePtr child(xmlNodePtr parent, const char *name)
{
	for (xmlNodePtr c = parent ? parent->children : NULL; c; c = c->next)
		if (c->type == XML_ELEMENT_NODE && !strcmp((const char *)c->name, name))
			return c;
	return NULL;
}

/* The text of an element, without the blanks around it, into buf. */
static const char *text_of(xmlNodePtr n, char *buf, size_t size)
{
	xmlChar *t = n ? xmlNodeGetContent(n) : NULL;
	const char *s = t ? (const char *)t : "";
	size_t b = 0, e = strlen(s);

	while (s[b] && strchr(" \t\r\n", s[b]))
		b++;
	while (e > b && strchr(" \t\r\n", s[e - 1]))
		e--;
	snprintf(buf, size, "%.*s", (int)(e - b), s + b);
	xmlFree(t);
	return buf;
}

static int number_of(struct x3p *x, xmlNodePtr n, const char *element, double *v)
{
	char buf[64], *stop;

	text_of(n, buf, sizeof(buf));
	*v = strtod(buf, &stop);
	if (!buf[0] || *stop || !isfinite(*v))
		return x3p_error(x, -EINVAL, element, "not a finite number: '%s'", buf);
	return 0;
}

static int size_of(struct x3p *x, xmlNodePtr n, const char *element, size_t *v)
{
	char buf[64], *stop;

	text_of(n, buf, sizeof(buf));
	unsigned long long u = strtoull(buf, &stop, 10);
	if (!n || !buf[0] || *stop || buf[0] == '-' || u == 0 || u > POINTS_MAX)
		return x3p_error(x, -EINVAL, element, "expected a count from 1 to %zu, found '%s'",
				 POINTS_MAX, buf);
	*v = (size_t)u;
	return 0;
}

/* The element, or NULL when it is absent or empty (<Offset/>, as some
 * writers put it for "not given"). */
static xmlNodePtr given(xmlNodePtr parent, const char *name)
{
	char buf[8];
	xmlNodePtr n = child(parent, name);

	return n && text_of(n, buf, sizeof(buf))[0] ? n : NULL;
}

static int read_axis(struct x3p *x, xmlNodePtr axes, int k)
{
	char element[64], buf[16];
	xmlNodePtr a = child(axes, axis_names[k]), n;
	struct x3p_axis *ax = &x->axis[k];

	snprintf(element, sizeof(element), "Record1/Axes/%s", axis_names[k]);
	if (!a)
		return x3p_error(x, -EINVAL, element, "the axis is missing");
	snprintf(element, sizeof(element), "Record1/Axes/%s/AxisType", axis_names[k]);
	text_of(child(a, "AxisType"), buf, sizeof(buf));
	if (strcmp(buf, "I") && strcmp(buf, "A"))
		return x3p_error(x, -EINVAL, element, "expected I or A, found '%s'", buf);
	ax->type = buf[0];
	if (k == 2 && ax->type != 'A')
		return x3p_error(x, -EINVAL, element, "the Z axis must be absolute (A)");
	ax->data = 0;
	if (ax->type == 'A') {
		snprintf(element, sizeof(element), "Record1/Axes/%s/DataType", axis_names[k]);
		text_of(child(a, "DataType"), buf, sizeof(buf));
		if (strlen(buf) != 1 || !strchr("ILFD", buf[0]))
			return x3p_error(x, -EINVAL, element, "expected I, L, F or D, found '%s'", buf);
		ax->data = buf[0];
	}
	ax->inc = 1;
	ax->off = 0;
	snprintf(element, sizeof(element), "Record1/Axes/%s/Increment", axis_names[k]);
	if ((n = given(a, "Increment")) && number_of(x, n, element, &ax->inc) < 0)
		return -EINVAL;
	if (ax->type == 'I' && !n)
		return x3p_error(x, -EINVAL, element, "an incremental axis needs its Increment");
	snprintf(element, sizeof(element), "Record1/Axes/%s/Offset", axis_names[k]);
	if ((n = given(a, "Offset")) && number_of(x, n, element, &ax->off) < 0)
		return -EINVAL;
	return 0;
}

static size_t type_size(char t)
{
	return t == 'I' ? 2 : t == 'L' || t == 'F' ? 4 : t == 'D' ? 8 : 0;
}

static int read_layout(struct x3p *x)
{
	xmlNodePtr r1 = child(x->root, "Record1"), r3 = child(x->root, "Record3"), md, n;
	char buf[16];

	if (!r1 || !r3)
		return x3p_error(x, -EINVAL, r1 ? "Record3" : "Record1", "the record is missing");
	text_of(child(r1, "FeatureType"), buf, sizeof(buf));
	if (strcmp(buf, "SUR") && strcmp(buf, "PRF") && strcmp(buf, "PCL"))
		return x3p_error(x, -EINVAL, "Record1/FeatureType", "expected SUR, PRF or PCL, found '%s'",
				 buf);
	for (int k = 0; k < 3; k++)
		if (read_axis(x, child(r1, "Axes"), k) < 0)
			return -EINVAL;
	if ((md = child(r3, "MatrixDimension"))) {
		x->matrix = true;
		if (size_of(x, child(md, "SizeX"), "Record3/MatrixDimension/SizeX", &x->size[0]) < 0 ||
		    size_of(x, child(md, "SizeY"), "Record3/MatrixDimension/SizeY", &x->size[1]) < 0 ||
		    size_of(x, child(md, "SizeZ"), "Record3/MatrixDimension/SizeZ", &x->size[2]) < 0)
			return -EINVAL;
	} else if ((n = child(r3, "ListDimension"))) {
		if (size_of(x, n, "Record3/ListDimension", &x->size[0]) < 0)
			return -EINVAL;
		x->size[1] = x->size[2] = 1;
	} else {
		return x3p_error(x, -EINVAL, "Record3", "neither MatrixDimension nor ListDimension");
	}
	size_t xy;
	if (points_map_size(x->size[0], x->size[1], 0, &xy, NULL) < 0 ||
	    points_map_size(xy, x->size[2], 0, &x->nodes, NULL) < 0)
		return x3p_error(x, -EFBIG, "Record3/MatrixDimension", "more than %zu points",
				 POINTS_MAX);
	x->record = 0;
	for (int k = 0; k < 3; k++)
		x->record += x->axis[k].type == 'A' ? type_size(x->axis[k].data) : 0;
	return 0;
}

/* ---- the points ---- */

/* The coordinate (m) of axis k at node index i (incremental) or of raw. */
static double coordinate(const struct x3p_axis *ax, double raw)
{
	double v = raw;

	/* applied only when they change it: 0 + 1 v would turn -0 into +0 */
	if (ax->inc != 1)
		v *= ax->inc;
	if (ax->off != 0)
		v += ax->off;
	return v;
}

static double raw_value(char type, const uint8_t *p)
{
	switch (type) {
	case 'I': return (int16_t)get_le16(p);
	case 'L': return (int32_t)get_le32(p);
	case 'F': return get_le_float(p);
	default: return get_le_double(p);
	}
}

/* The index of node k along axis a (X fastest, then Y, then Z). */
static size_t node_index(const struct x3p *x, size_t k, int a)
{
	if (a == 0)
		return k % x->size[0];
	return a == 1 ? (k / x->size[0]) % x->size[1] : k / (x->size[0] * x->size[1]);
}

/* Node k's x, y, z in mm from the raw values of its absolute axes; false
 * when it is invalid (NaN). */
static bool node_point(const struct x3p *x, size_t k, const double raw[3], double xyz[3])
{
	for (int a = 0; a < 3; a++) {
		const struct x3p_axis *ax = &x->axis[a];
		double v = coordinate(ax, ax->type == 'I' ? (double)node_index(x, k, a) : raw[a]);
		xyz[a] = v * M_TO_MM;
		if (!isfinite(xyz[a]))
			return false;
	}
	return true;
}

struct collected {
	struct asph_points *p;
	size_t n;
};

static void collect(struct collected *c, const double xyz[3])
{
	memcpy(c->p->xyz + 3 * c->n, xyz, 3 * sizeof(double));
	c->n++;
}

static int collect_alloc(struct x3p *x, struct collected *c)
{
	c->p = asph_points_alloc(x->nodes);
	c->n = 0;
	return c->p ? 0 : asph_error_set(x->err, -ENOMEM, "out of memory");
}

static int read_binary(struct x3p *x, xmlNodePtr link, const uint8_t *valid, size_t valid_len,
		       struct collected *c)
{
	char name[256], sum[64];
	_cleanup_free_ uint8_t *data = NULL;
	size_t len;

	text_of(child(link, "PointDataLink"), name, sizeof(name));
	if (!name[0])
		return x3p_error(x, -EINVAL, "Record3/DataLink/PointDataLink", "no file named");
	int r = member_read(x, name, POINTS_FILE_LIMIT, &data, &len);
	if (r == -ENOENT)
		return x3p_error(x, -EINVAL, "Record3/DataLink/PointDataLink",
				 "the container has no member %s", name);
	if (r < 0)
		return r;
	text_of(child(link, "MD5ChecksumPointData"), sum, sizeof(sum));
	if (sum[0] && check_md5(x, sum, strlen(sum), data, len, name,
				"Record3/DataLink/MD5ChecksumPointData") < 0)
		return -EINVAL;
	if (len != x->nodes * x->record)
		return x3p_error(x, -EINVAL, "Record3/DataLink/PointDataLink",
				 "%s holds %zu bytes; %zu points of %zu bytes take %zu", name, len,
				 x->nodes, x->record, x->nodes * x->record);
	if ((r = collect_alloc(x, c)) < 0)
		return r;
	const uint8_t *p = data;
	for (size_t k = 0; k < x->nodes; k++) {
		double raw[3] = { 0, 0, 0 }, xyz[3];
		for (int a = 0; a < 3; a++)
			if (x->axis[a].type == 'A') {
				raw[a] = raw_value(x->axis[a].data, p);
				p += type_size(x->axis[a].data);
			}
		bool ok = !valid || (k / 8 < valid_len && (valid[k / 8] >> (k % 8) & 1));
		if (ok && node_point(x, k, raw, xyz))
			collect(c, xyz);
	}
	return 0;
}

/* A Datum: the values of the absolute axes, ';' separated (some writers
 * put all three, the incremental ones as placeholders); empty: invalid. */
static int read_datum(struct x3p *x, xmlNodePtr d, size_t k, double raw[3], bool *valid)
{
	char buf[256], element[64], *s = buf, *stop;
	double v[3];
	int n = 0, absolute = 0;

	snprintf(element, sizeof(element), "Record3/DataList/Datum[%zu]", k);
	text_of(d, buf, sizeof(buf));
	*valid = buf[0] != '\0';
	if (!*valid)
		return 0;
	for (;;) {
		if (n == 3)
			return x3p_error(x, -EINVAL, element, "more than three values: '%s'", buf);
		v[n] = strtod(s, &stop);
		while (*stop == ' ' || *stop == '\t')
			stop++;
		if (stop == s || (*stop && *stop != ';'))
			return x3p_error(x, -EINVAL, element, "not a list of numbers: '%s'", buf);
		n++;
		if (!*stop)
			break;
		s = stop + 1;
	}
	for (int a = 0; a < 3; a++)
		absolute += x->axis[a].type == 'A';
	for (int a = 0, i = 0; a < 3; a++) {
		if (x->axis[a].type != 'A')
			continue;
		/* one value per absolute axis, or X;Y;Z with placeholders */
		raw[a] = n == absolute ? v[i++] : n == 3 ? v[a] : NAN;
	}
	if (n != absolute && n != 3)
		return x3p_error(x, -EINVAL, element, "%d values for %d absolute axes: '%s'", n,
				 absolute, buf);
	return 0;
}

static bool is_datum(xmlNodePtr d)
{
	return d->type == XML_ELEMENT_NODE && !strcmp((const char *)d->name, "Datum");
}

static int read_inline(struct x3p *x, xmlNodePtr list, struct collected *c)
{
	size_t k = 0;
	int r;

	/* as many Datum as points before the points are allocated */
	for (xmlNodePtr d = list->children; d; d = d->next)
		k += is_datum(d);
	if (k != x->nodes)
		return x3p_error(x, -EINVAL, "Record3/DataList", "%zu points; the dimensions give %zu",
				 k, x->nodes);
	if ((r = collect_alloc(x, c)) < 0)
		return r;
	k = 0;
	for (xmlNodePtr d = list->children; d; d = d->next) {
		if (!is_datum(d))
			continue;
		double raw[3] = { 0, 0, 0 }, xyz[3];
		bool valid;
		if (read_datum(x, d, k, raw, &valid) < 0)
			return -EINVAL;
		if (valid && node_point(x, k, raw, xyz))
			collect(c, xyz);
		k++;
	}
	return 0;
}

/* bindata/valid.bin: one bit per point, least significant first, set for a
 * valid one. */
static int read_valid(struct x3p *x, xmlNodePtr link, uint8_t **valid, size_t *len)
{
	char name[256], sum[64];
	xmlNodePtr n = child(link, "ValidPointsLink");

	*valid = NULL;
	if (!n)
		return 0;
	text_of(n, name, sizeof(name));
	int r = member_read(x, name, POINTS_FILE_LIMIT, valid, len);
	if (r == -ENOENT)
		return x3p_error(x, -EINVAL, "Record3/DataLink/ValidPointsLink",
				 "the container has no member %s", name);
	if (r < 0)
		return r;
	text_of(child(link, "MD5ChecksumValidPoints"), sum, sizeof(sum));
	if (sum[0] && check_md5(x, sum, strlen(sum), *valid, *len, name,
				"Record3/DataLink/MD5ChecksumValidPoints") < 0)
		return -EINVAL;
	if (*len < (x->nodes + 7) / 8)
		return x3p_error(x, -EINVAL, "Record3/DataLink/ValidPointsLink",
				 "%s holds %zu bytes; %zu points take %zu", name, *len, x->nodes,
				 (x->nodes + 7) / 8);
	return 0;
}

static int read_points(struct x3p *x, struct asph_points **out, struct asph_points_read_info *info)
{
	xmlNodePtr r3 = child(x->root, "Record3"), link = child(r3, "DataLink");
	xmlNodePtr list = child(r3, "DataList");
	_cleanup_free_ uint8_t *valid = NULL;
	size_t valid_len = 0;
	struct collected c = { NULL, 0 };
	int r;

	if (!link && !list)
		return x3p_error(x, -EINVAL, "Record3", "neither DataLink nor DataList");
	if (link) {
		r = read_valid(x, link, &valid, &valid_len);
		if (r == 0)
			r = read_binary(x, link, valid, valid_len, &c);
	} else {
		r = read_inline(x, list, &c);
	}
	if (r == 0 && c.n == 0)
		r = x3p_error(x, -EINVAL, "Record3", "all %zu points are invalid", x->nodes);
	if (r < 0) {
		asph_points_free(c.p);
		return r;
	}
	c.p->n = c.n;
	if (x->matrix) {
		info->nx = x->size[0];
		info->ny = x->size[1] * x->size[2];
	}
	info->n_invalid = x->nodes - c.n;
	*out = c.p;
	return 0;
}

static int parse_main(struct x3p *x, const uint8_t *xml, size_t len)
{
	xmlParserCtxtPtr ctx = xmlNewParserCtxt();

	if (!ctx)
		return asph_error_set(x->err, -ENOMEM, "out of memory");
	x->doc = xmlCtxtReadMemory(ctx, (const char *)xml, (int)len, "main.xml", NULL,
				   XML_PARSE_NONET | XML_PARSE_NOERROR | XML_PARSE_NOWARNING);
	if (!x->doc) {
		const xmlError *e = xmlCtxtGetLastError(ctx);
		int r = asph_error_set_at(x->err, -EINVAL, x->source, 0, 0, "main.xml",
					  "x3p: not well-formed XML at line %d: %s", e ? e->line : 0,
					  e && e->message ? e->message : "");
		/* libxml2's messages end with a newline */
		if (x->err && x->err->message[0] &&
		    x->err->message[strlen(x->err->message) - 1] == '\n')
			x->err->message[strlen(x->err->message) - 1] = '\0';
		xmlFreeParserCtxt(ctx);
		return r;
	}
	xmlFreeParserCtxt(ctx);
	x->root = xmlDocGetRootElement(x->doc);
	/* some writers name the root ISO5436, without the namespace */
	if (!x->root || (strcmp((const char *)x->root->name, "ISO5436_2") &&
			 strcmp((const char *)x->root->name, "ISO5436")))
		return x3p_error(x, -EINVAL, "main.xml", "the root element is not ISO5436_2");
	return 0;
}

static int open_container(struct x3p *x, const uint8_t *data, size_t len)
{
	zip_error_t ze;
	zip_source_t *src;
	int r = 0;

	zip_error_init(&ze);
	src = zip_source_buffer_create(data, len, 0, &ze);
	if (src && !(x->zip = zip_open_from_source(src, ZIP_RDONLY | ZIP_CHECKCONS, &ze))) {
		zip_source_free(src);
		src = NULL;
	}
	if (!src)
		r = asph_error_set_at(x->err, zip_error_code_zip(&ze) == ZIP_ER_MEMORY ? -ENOMEM : -EINVAL,
				      x->source, 0, 0, NULL, "x3p: not a readable ZIP container: %s",
				      zip_error_strerror(&ze));
	zip_error_fini(&ze);
	return r;
}

int points_read_x3p(const uint8_t *data, size_t len, const char *source,
		    struct asph_points **out, struct asph_points_read_info *info,
		    struct asph_error *err)
{
	struct x3p x = { .source = source, .err = err };
	_cleanup_free_ uint8_t *xml = NULL, *sums = NULL;
	size_t xml_len, sums_len;
	int r = open_container(&x, data, len);

	if (r == 0)
		r = find_root(&x);
	if (r < 0) {
		zip_discard(x.zip);
		return r;
	}
	r = member_read(&x, "main.xml", XML_LIMIT, &xml, &xml_len);
	if (r == -ENOENT)
		r = x3p_error(&x, -EINVAL, NULL, "the container has no main.xml");
	/* md5checksum.hex: the sum of main.xml, as md5sum writes it */
	if (r == 0) {
		r = member_read(&x, "md5checksum.hex", 4096, &sums, &sums_len);
		if (r == 0)
			r = check_md5(&x, (const char *)sums, sums_len, xml, xml_len, "main.xml",
				      "md5checksum.hex");
		else if (r == -ENOENT)
			r = 0;
	}
	if (r == 0)
		r = parse_main(&x, xml, xml_len);
	if (r == 0)
		r = read_layout(&x);
	if (r == 0)
		r = read_points(&x, out, info);
	if (x.doc)
		xmlFreeDoc(x.doc);
	zip_discard(x.zip);
	return r;
}
