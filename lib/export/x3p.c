/* SPDX-License-Identifier: GPL-3.0-or-later */
/* X3P (ISO 25178-72) with libzip, libxml2 and nettle's MD5. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <libxml/tree.h>
#include "util-hash.h"
#include <zip.h>

#include "asph/x3p.h"
#include "util-mem.h"
#include "x3p-internal.h"
#include "util-time.h"

#define NS "http://www.opengps.eu/2008/ISO5436_2"
#define DATA_NAME "bindata/data.bin"
#define MM_TO_M 1e-3
#define NM_TO_M 1e-9

/* The schema's elements below the root are unqualified (no namespace):
 * xmlNewChild() would give them the parent's. */
static xmlNodePtr element(xmlNodePtr parent, const char *name)
{
	xmlNodePtr n = xmlNewNode(NULL, BAD_CAST name);

	return xmlAddChild(parent, n);
}

static xmlNodePtr text_child(xmlNodePtr parent, const char *name, const char *text)
{
	xmlNodePtr n = element(parent, name);

	xmlAddChild(n, xmlNewText(BAD_CAST(text ? text : "")));
	return n;
}

static void number_child(xmlNodePtr parent, const char *name, double v)
{
	char buf[40];

	snprintf(buf, sizeof(buf), "%.17g", v);
	text_child(parent, name, buf);
}

/* An axis: incremental (the coordinate of index i is offset + i increment,
 * in metres) or absolute (the data hold the coordinate). */
static void axis(xmlNodePtr axes, const char *name, int incremental, double increment,
		 double offset)
{
	xmlNodePtr a = element(axes, name);

	text_child(a, "AxisType", incremental ? "I" : "A");
	text_child(a, "DataType", "D");
	number_child(a, "Increment", increment);
	number_child(a, "Offset", offset);
}

/* xsd:dateTime with an explicit zone, of ns since 1970 (0: now). */
static void date_child(xmlNodePtr parent, const char *name, int64_t ns)
{
	char date[64];

	iso8601_utc(ns ? ns : now_realtime_ns(), 3, date, sizeof(date));
	if (date[0] && date[strlen(date) - 1] == 'Z') {
		date[strlen(date) - 1] = '\0';
		strncat(date, "+00:00", sizeof(date) - strlen(date) - 1);
	}
	text_child(parent, name, date);
}

/* The members not given from the instrument that measured. */
static void name_instrument(struct asph_x3p_info *info, const struct x3p_instrument *n)
{
	if (!info->manufacturer)
		info->manufacturer = "-";
	if (!info->model)
		info->model = n->model;
	if (!info->version)
		info->version = n->version;
	if (!info->probing_type)
		info->probing_type = n->probing_type;
	if (!info->probing_id)
		info->probing_id = n->probing_id;
}

/* Record2 in the order of ISO 5436-2:2008, which requires the
 * CalibrationDate that the 2017 amendment makes optional. */
static void record2(xmlNodePtr root, const struct asph_x3p_info *in)
{
	struct asph_x3p_info info = { 0 };
	struct x3p_instrument named;
	xmlNodePtr r = element(root, "Record2"), ins, ps;

	if (in)
		info = *in;
	if (info.instrument_json && x3p_instrument_names(info.instrument_json, &named) == 0)
		name_instrument(&info, &named);
	if (!info.date_ns)
		info.date_ns = now_realtime_ns();
	date_child(r, "Date", info.date_ns);
	if (info.creator)
		text_child(r, "Creator", info.creator);
	ins = element(r, "Instrument");
	text_child(ins, "Manufacturer", info.manufacturer ? info.manufacturer : "asphd");
	text_child(ins, "Model", info.model ? info.model : "asph");
	text_child(ins, "Serial", info.serial ? info.serial : "-");
	text_child(ins, "Version", info.version ? info.version : "-");
	date_child(r, "CalibrationDate",
		   info.calibration_date_ns ? info.calibration_date_ns : info.date_ns);
	ps = element(r, "ProbingSystem");
	text_child(ps, "Type", info.probing_type ? info.probing_type : "Software");
	text_child(ps, "Identification", info.probing_id ? info.probing_id : "-");
	if (info.comment)
		text_child(r, "Comment", info.comment);
}

struct layout {
	const char *feature;        /* PCL or SUR */
	int incremental_xy;
	double dx;                  /* m, incremental axes */
	double x0, y0;              /* m, the first node of incremental axes */
	size_t nx, ny, list;        /* list > 0: ListDimension */
};

/* main.xml as UTF-8 text (xmlFree it). */
static int main_xml(const struct layout *L, const char *data_md5,
		    const struct asph_x3p_info *info, xmlChar **out, int *len)
{
	xmlDocPtr doc = xmlNewDoc(BAD_CAST "1.0");
	xmlNodePtr root = xmlNewNode(NULL, BAD_CAST "ISO5436_2"), r1, axes, r3, dl, r4;
	xmlNsPtr ns = xmlNewNs(root, BAD_CAST NS, BAD_CAST "p");
	char buf[32];

	xmlSetNs(root, ns);
	xmlDocSetRootElement(doc, root);
	r1 = element(root, "Record1");
	text_child(r1, "Revision", "ISO5436 - 2000");
	text_child(r1, "FeatureType", L->feature);
	axes = element(r1, "Axes");
	axis(axes, "CX", L->incremental_xy, L->incremental_xy ? L->dx : 1, L->x0);
	axis(axes, "CY", L->incremental_xy, L->incremental_xy ? L->dx : 1, L->y0);
	axis(axes, "CZ", 0, 1, 0);
	record2(root, info);
	r3 = element(root, "Record3");
	if (L->list) {
		snprintf(buf, sizeof(buf), "%zu", L->list);
		text_child(r3, "ListDimension", buf);
	} else {
		xmlNodePtr md = element(r3, "MatrixDimension");
		snprintf(buf, sizeof(buf), "%zu", L->nx);
		text_child(md, "SizeX", buf);
		snprintf(buf, sizeof(buf), "%zu", L->ny);
		text_child(md, "SizeY", buf);
		text_child(md, "SizeZ", "1");
	}
	dl = element(r3, "DataLink");
	text_child(dl, "PointDataLink", DATA_NAME);
	text_child(dl, "MD5ChecksumPointData", data_md5);
	r4 = element(root, "Record4");
	text_child(r4, "ChecksumFile", "md5checksum.hex");
	xmlDocDumpFormatMemoryEnc(doc, out, len, "UTF-8", 1);
	xmlFreeDoc(doc);
	return *out ? 0 : -ENOMEM;
}

/* Little-endian doubles whatever the host's order. */
static void put_le_double(uint8_t *p, double v)
{
	uint64_t u;

	memcpy(&u, &v, sizeof(u));
	for (int i = 0; i < 8; i++)
		p[i] = (uint8_t)(u >> (8 * i));
}

static int container_add(zip_t *z, const char *name, const void *data, size_t len,
		   const char *path, struct asph_error *err)
{
	zip_source_t *src = zip_source_buffer(z, data, len, 0);

	if (!src || zip_file_add(z, name, src, ZIP_FL_OVERWRITE | ZIP_FL_ENC_UTF_8) < 0) {
		if (src)
			zip_source_free(src);
		return asph_error_set(err, -EIO, "%s: cannot add %s: %s", path, name,
				      zip_strerror(z));
	}
	return 0;
}

/* The three members into z; on failure z is discarded. */
static int fill_container(zip_t *z, const struct layout *L, const uint8_t *data, size_t len,
			  const struct asph_x3p_info *info, const char *path,
			  struct asph_error *err)
{
	char data_md5[33], xml_md5[33], hexfile[64];
	xmlChar *xml = NULL;
	int xml_len = 0, r;

	md5_hex(data, len, data_md5);
	if (main_xml(L, data_md5, info, &xml, &xml_len) < 0) {
		zip_discard(z);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	md5_hex(xml, (size_t)xml_len, xml_md5);
	snprintf(hexfile, sizeof(hexfile), "%s *main.xml\n", xml_md5);
	r = container_add(z, "main.xml", xml, (size_t)xml_len, path, err);
	if (r == 0)
		r = container_add(z, DATA_NAME, data, len, path, err);
	if (r == 0)
		r = container_add(z, "md5checksum.hex", hexfile, strlen(hexfile), path, err);
	/* zip_close writes (a temporary file renamed over path, or the
	 * buffer): a failure leaves no half-written container. */
	if (r == 0 && zip_close(z) < 0)
		r = asph_error_set(err, -EIO, "cannot write %s: %s", path, zip_strerror(z));
	if (r < 0)
		zip_discard(z);
	xmlFree(xml);
	return r;
}

static int zip_failed(int code, const char *what, const char *path, struct asph_error *err)
{
	zip_error_t ze;
	int r;

	zip_error_init_with_code(&ze, code);
	r = asph_error_set(err, code == ZIP_ER_MEMORY ? -ENOMEM : -EIO, "cannot %s %s: %s", what,
			   path, zip_error_strerror(&ze));
	zip_error_fini(&ze);
	return r;
}

static int write_container(const char *path, const struct layout *L, const uint8_t *data,
			   size_t len, const struct asph_x3p_info *info,
			   struct asph_error *err)
{
	int zerr = 0;
	zip_t *z = zip_open(path, ZIP_CREATE | ZIP_TRUNCATE, &zerr);

	if (!z)
		return zip_failed(zerr, "create", path, err);
	return fill_container(z, L, data, len, info, path, err);
}

/* The container built in memory, then copied to f. */
static int stream_container(FILE *f, const char *name, const struct layout *L,
			    const uint8_t *data, size_t len, const struct asph_x3p_info *info,
			    struct asph_error *err)
{
	zip_error_t ze;
	zip_source_t *buf;
	zip_t *z;
	uint8_t chunk[65536];
	zip_int64_t n;
	int r;

	zip_error_init(&ze);
	buf = zip_source_buffer_create(NULL, 0, 0, &ze);
	zip_error_fini(&ze);
	if (!buf)
		return asph_error_set(err, -ENOMEM, "out of memory");
	zip_source_keep(buf);
	zip_error_init(&ze);
	z = zip_open_from_source(buf, ZIP_TRUNCATE, &ze);
	r = z ? 0 : zip_failed(zip_error_code_zip(&ze), "create", name, err);
	zip_error_fini(&ze);
	if (r == 0)
		r = fill_container(z, L, data, len, info, name, err);
	if (r == 0 && zip_source_open(buf) < 0)
		r = asph_error_set(err, -EIO, "cannot read back %s", name);
	if (r == 0) {
		while ((n = zip_source_read(buf, chunk, sizeof(chunk))) > 0)
			if (fwrite(chunk, 1, (size_t)n, f) != (size_t)n)
				break;
		if (n < 0)
			r = asph_error_set(err, -EIO, "cannot read back %s", name);
		else if (n > 0 || fflush(f) != 0)
			r = asph_error_set(err, -errno, "cannot write %s: %s", name, strerror(errno));
		zip_source_close(buf);
	}
	zip_source_free(buf);
	return r;
}

int asph_x3p_write_points(const char *path, const double *xyz, size_t n,
			  const struct asph_x3p_info *info, struct asph_error *err)
{
	_cleanup_free_ uint8_t *data = NULL;
	struct layout L = { .feature = "PCL", .list = n };

	if (n == 0)
		return asph_error_set(err, -EINVAL, "%s: no point to write", path);
	for (size_t i = 0; i < 3 * n; i++)
		if (!isfinite(xyz[i]))
			return asph_error_set(err, -EINVAL, "%s: point %zu has a non-finite coordinate",
					      path, i / 3);
	data = malloc(24 * n);
	if (!data)
		return asph_error_set(err, -ENOMEM, "out of memory");
	/* divided by 1000, not multiplied by 1e-3: the metres read back
	 * (times 1000, lib/points) and written again give the same bits */
	for (size_t i = 0; i < 3 * n; i++)
		put_le_double(data + 8 * i, xyz[i] / 1000.0);
	return write_container(path, &L, data, 24 * n, info, err);
}

/* The matrix layout's binary data: X fastest, then Y, as the grid. */
static int grid_data(const char *name, const struct asph_grid *g, struct layout *L,
		     uint8_t **out, struct asph_error *err)
{
	size_t m = g->nx * g->ny;
	uint8_t *data;

	if (m == 0 || !(g->dx > 0) || !isfinite(g->dx) || !isfinite(g->x0) || !isfinite(g->y0))
		return asph_error_set(err, -EINVAL, "%s: an empty grid or a bad spacing or origin",
				      name);
	/* the grid where it lies in the part frame: node (i, j) at
	 * (x0 + i dx, y0 + j dx) */
	*L = (struct layout){ .feature = "SUR", .incremental_xy = 1, .dx = g->dx * MM_TO_M,
			      .x0 = g->x0 * MM_TO_M, .y0 = g->y0 * MM_TO_M,
			      .nx = g->nx, .ny = g->ny };
	data = malloc(8 * m);
	if (!data)
		return asph_error_set(err, -ENOMEM, "out of memory");
	mem_advise_huge(data, 8 * m);
	for (size_t i = 0; i < m; i++)
		put_le_double(data + 8 * i, isnan(g->z[i]) ? NAN : g->z[i] * NM_TO_M);
	*out = data;
	return 0;
}

int asph_x3p_write_grid(const char *path, const struct asph_grid *g,
			const struct asph_x3p_info *info, struct asph_error *err)
{
	_cleanup_free_ uint8_t *data = NULL;
	struct layout L;
	int r = grid_data(path, g, &L, &data, err);

	if (r < 0)
		return r;
	return write_container(path, &L, data, 8 * g->nx * g->ny, info, err);
}

int asph_x3p_write_grid_stream(FILE *f, const char *name, const struct asph_grid *g,
			       const struct asph_x3p_info *info, struct asph_error *err)
{
	_cleanup_free_ uint8_t *data = NULL;
	struct layout L;
	int r = grid_data(name, g, &L, &data, err);

	if (r < 0)
		return r;
	return stream_container(f, name, &L, data, 8 * g->nx * g->ny, info, err);
}
