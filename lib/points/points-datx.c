/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Zygo .datx (HDF5, libhdf5): the first map of the group /Data/Surface,
 * a rows x columns dataset whose attributes give its invalid value ("No
 * Data") and its converters: "X Converter" and "Y Converter" the spacing
 * (Parameters[1] in their BaseUnit), "Z Converter" the unit of the values
 * (a length, or Fringes: Parameters[1] the wavelength, [2] the
 * interferometric scale factor, [3] the obliquity factor). Row 0 is the
 * top one. */
#include <errno.h>
#include <stdarg.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include <hdf5.h>

#include "readers.h"
#include "util-mem.h"

#define M_TO_MM 1000.0
#define SURFACE_GROUP "/Data/Surface"
/* No HDF5 filter that Zygo's writers use packs more than about 1000
 * values into a byte: a map announcing more is refused before it is read. */
#define MAX_VALUES_PER_BYTE 1100

struct datx {
	const char *source;
	struct asph_error *err;
	hid_t file, set;
	char name[128];     /* the map's dataset, for messages */
};

static int datx_error(struct datx *x, int code, const char *field, const char *fmt, ...)
	__attribute__((format(printf, 4, 5)));
static int datx_error(struct datx *x, int code, const char *field, const char *fmt, ...)
{
	char msg[400];
	va_list ap;

	va_start(ap, fmt);
	vsnprintf(msg, sizeof(msg), fmt, ap);
	va_end(ap);
	return asph_error_set_at(x->err, code, x->source, 0, 0, field, "datx: %s", msg);
}

/* The first dataset of the group, by name. */
static herr_t first_dataset(hid_t group, const char *name, const H5L_info_t *info, void *data)
{
	char *out = data;
	hid_t d;

	/* soft and external links could name other files: not followed */
	if (info->type != H5L_TYPE_HARD || (d = H5Dopen2(group, name, H5P_DEFAULT)) < 0)
		return 0;
	H5Dclose(d);
	snprintf(out, 128, "%s", name);
	return 1;
}

static int open_map(struct datx *x)
{
	char first[128] = "";
	hsize_t idx = 0;

	if (H5Lexists(x->file, "/Data", H5P_DEFAULT) <= 0 ||
	    H5Lexists(x->file, SURFACE_GROUP, H5P_DEFAULT) <= 0)
		return datx_error(x, -EINVAL, SURFACE_GROUP, "the file has no group %s (not a Zygo .datx)",
				  SURFACE_GROUP);
	hid_t g = H5Gopen2(x->file, SURFACE_GROUP, H5P_DEFAULT);
	if (g < 0)
		return datx_error(x, -EINVAL, SURFACE_GROUP, "the group cannot be opened");
	H5Literate(g, H5_INDEX_NAME, H5_ITER_INC, &idx, first_dataset, first);
	if (first[0])
		x->set = H5Dopen2(g, first, H5P_DEFAULT);
	H5Gclose(g);
	snprintf(x->name, sizeof(x->name), "%s/%s", SURFACE_GROUP, first);
	if (!first[0] || x->set < 0)
		return datx_error(x, -EINVAL, SURFACE_GROUP, "the group holds no map");
	/* a dataset may keep its values in other files (external storage, a
	 * virtual dataset): only the file's own are read */
	hid_t dcpl = H5Dget_create_plist(x->set);
	bool outside = dcpl < 0 || H5Pget_external_count(dcpl) != 0 ||
		       H5Pget_layout(dcpl) == H5D_VIRTUAL;
	if (dcpl >= 0)
		H5Pclose(dcpl);
	if (outside)
		return datx_error(x, -EINVAL, x->name, "the map keeps its values outside the file");
	return 0;
}

/* A converter's BaseUnit and Parameters (up to 4). */
struct converter {
	char unit[32];
	double p[4];
	size_t np;
};

/* The member of a compound type called name: its index, or -1. */
static int member(hid_t type, const char *name)
{
	return H5Tget_member_index(type, name);
}

static int read_string_member(struct datx *x, hid_t attr, hid_t ftype, const char *attr_name,
			      char *out, size_t size)
{
	int i = member(ftype, "BaseUnit");
	hid_t mt = i >= 0 ? H5Tget_member_type(ftype, (unsigned)i) : -1;
	int r = 0;

	if (mt < 0 || H5Tget_class(mt) != H5T_STRING) {
		if (mt >= 0)
			H5Tclose(mt);
		return datx_error(x, -EINVAL, attr_name, "no string member BaseUnit");
	}
	hid_t st = H5Tcopy(H5T_C_S1);
	if (H5Tis_variable_str(mt) > 0) {
		char *s = NULL;
		H5Tset_size(st, H5T_VARIABLE);
		hid_t ct = H5Tcreate(H5T_COMPOUND, sizeof(char *));
		H5Tinsert(ct, "BaseUnit", 0, st);
		if (H5Aread(attr, ct, &s) < 0)
			r = datx_error(x, -EINVAL, attr_name, "BaseUnit cannot be read");
		else
			snprintf(out, size, "%s", s ? s : "");
		if (s) {
			hid_t space = H5Screate(H5S_SCALAR);
			H5Dvlen_reclaim(ct, space, H5P_DEFAULT, &s);
			H5Sclose(space);
		}
		H5Tclose(ct);
	} else {
		size_t n = H5Tget_size(mt);
		char *buf = n < 4096 ? calloc(1, n + 1) : NULL;
		H5Tset_size(st, n);
		hid_t ct = H5Tcreate(H5T_COMPOUND, n);
		H5Tinsert(ct, "BaseUnit", 0, st);
		if (!buf || H5Aread(attr, ct, buf) < 0)
			r = datx_error(x, -EINVAL, attr_name, "BaseUnit cannot be read");
		else
			snprintf(out, size, "%s", buf);
		free(buf);
		H5Tclose(ct);
	}
	H5Tclose(st);
	H5Tclose(mt);
	return r;
}

static int read_parameters(struct datx *x, hid_t attr, hid_t ftype, const char *attr_name,
			   struct converter *c)
{
	int i = member(ftype, "Parameters");
	hid_t mt = i >= 0 ? H5Tget_member_type(ftype, (unsigned)i) : -1;
	hsize_t dim = 0;
	int r = 0;

	c->np = 0;
	if (mt < 0)
		return 0;
	if (H5Tget_class(mt) == H5T_ARRAY && H5Tget_array_ndims(mt) == 1)
		H5Tget_array_dims2(mt, &dim);
	H5Tclose(mt);
	if (dim == 0)
		return datx_error(x, -EINVAL, attr_name, "Parameters is not an array of numbers");
	hsize_t n = dim < 4 ? dim : 4, full = dim;
	double *p = full <= 64 ? calloc(full, sizeof(double)) : NULL;
	hid_t at = H5Tarray_create2(H5T_NATIVE_DOUBLE, 1, &full);
	hid_t ct = H5Tcreate(H5T_COMPOUND, full * sizeof(double));
	H5Tinsert(ct, "Parameters", 0, at);
	if (!p || H5Aread(attr, ct, p) < 0)
		r = datx_error(x, -EINVAL, attr_name, "Parameters cannot be read as numbers");
	else
		memcpy(c->p, p, n * sizeof(double));
	c->np = r == 0 ? n : 0;
	free(p);
	H5Tclose(ct);
	H5Tclose(at);
	return r;
}

static int read_converter(struct datx *x, const char *name, struct converter *c)
{
	if (H5Aexists(x->set, name) <= 0)
		return datx_error(x, -EINVAL, name, "the map %s has no attribute '%s'", x->name, name);
	hid_t attr = H5Aopen(x->set, name, H5P_DEFAULT);
	hid_t ftype = attr >= 0 ? H5Aget_type(attr) : -1;
	int r;

	if (ftype < 0 || H5Tget_class(ftype) != H5T_COMPOUND)
		r = datx_error(x, -EINVAL, name, "not a converter (a compound with BaseUnit and Parameters)");
	else if ((r = read_string_member(x, attr, ftype, name, c->unit, sizeof(c->unit))) == 0)
		r = read_parameters(x, attr, ftype, name, c);
	if (ftype >= 0)
		H5Tclose(ftype);
	if (attr >= 0)
		H5Aclose(attr);
	return r;
}

/* A converter's unit in mm; 0 for one that is not a length. */
static double unit_mm(const char *unit)
{
	static const struct { const char *name; double mm; } units[] = {
		{ "Meters", 1000 }, { "MilliMeters", 1 }, { "MicroMeters", 1e-3 },
		{ "NanoMeters", 1e-6 }, { "Angstroms", 1e-7 }, { "Inches", 25.4 },
	};
	for (size_t i = 0; i < ARRAY_SIZE(units); i++)
		if (!strcasecmp(unit, units[i].name))
			return units[i].mm;
	return 0;
}

static int lateral_spacing(struct datx *x, const char *name, double *mm)
{
	struct converter c;
	int r = read_converter(x, name, &c);

	if (r < 0)
		return r;
	double u = unit_mm(c.unit);
	if (u == 0 || c.np < 2 || !(c.p[1] > 0) || !isfinite(c.p[1] * u))
		return datx_error(x, -EINVAL, name,
				  "no lateral resolution (BaseUnit '%s', Parameters[1] %g): the positions are unknown",
				  c.unit, c.np >= 2 ? c.p[1] : NAN);
	*mm = c.p[1] * u;
	return 0;
}

static int height_scale(struct datx *x, double *mm)
{
	struct converter c;
	int r = read_converter(x, "Z Converter", &c);

	if (r < 0)
		return r;
	if (!strcasecmp(c.unit, "Fringes")) {
		if (c.np < 4)
			return datx_error(x, -EINVAL, "Z Converter",
					  "Fringes need the wavelength, scale and obliquity factors in Parameters[1..3]");
		*mm = c.p[1] * c.p[2] * c.p[3] * M_TO_MM;
	} else {
		*mm = unit_mm(c.unit);
	}
	if (*mm == 0 || !isfinite(*mm))
		return datx_error(x, -EINVAL, "Z Converter", "the unit '%s' is not a length", c.unit);
	return 0;
}

static double no_data(struct datx *x)
{
	double v = INFINITY;

	if (H5Aexists(x->set, "No Data") <= 0)
		return v;
	hid_t a = H5Aopen(x->set, "No Data", H5P_DEFAULT);
	hid_t s = a >= 0 ? H5Aget_space(a) : -1;
	hssize_t n = s >= 0 ? H5Sget_simple_extent_npoints(s) : 0;
	double *buf = n >= 1 && n <= 64 ? calloc((size_t)n, sizeof(double)) : NULL;
	if (buf && H5Aread(a, H5T_NATIVE_DOUBLE, buf) >= 0)
		v = buf[0];
	free(buf);
	if (s >= 0)
		H5Sclose(s);
	if (a >= 0)
		H5Aclose(a);
	return v;
}

static int read_map(struct datx *x, size_t file_len, struct asph_points **out,
		    struct asph_points_read_info *info)
{
	hid_t space = H5Dget_space(x->set);
	hsize_t dims[2];
	size_t nodes;
	double dx = 0, dy = 0, zs = 0;

	int nd = space >= 0 ? H5Sget_simple_extent_ndims(space) : -1;
	if (nd == 2)
		H5Sget_simple_extent_dims(space, dims, NULL);
	if (space >= 0)
		H5Sclose(space);
	if (nd != 2)
		return datx_error(x, -EINVAL, x->name, "the map has %d dimensions, not 2", nd);
	H5T_class_t cls = H5T_NO_CLASS;
	hid_t t = H5Dget_type(x->set);
	if (t >= 0) {
		cls = H5Tget_class(t);
		H5Tclose(t);
	}
	if (cls != H5T_FLOAT && cls != H5T_INTEGER)
		return datx_error(x, -EINVAL, x->name, "the map's values are not numbers");
	if (points_map_size((size_t)dims[1], (size_t)dims[0], sizeof(double), &nodes, NULL) < 0 ||
	    nodes / MAX_VALUES_PER_BYTE > file_len)
		return datx_error(x, -EFBIG, x->name, "a map of %llu x %llu is too large for the file",
				  (unsigned long long)dims[1], (unsigned long long)dims[0]);
	int r = lateral_spacing(x, "X Converter", &dx);
	if (r == 0)
		r = lateral_spacing(x, "Y Converter", &dy);
	if (r == 0)
		r = height_scale(x, &zs);
	if (r < 0)
		return r;
	_cleanup_free_ double *z = malloc(nodes * sizeof(double));
	if (!z)
		return asph_error_set(x->err, -ENOMEM, "out of memory");
	if (H5Dread(x->set, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, z) < 0)
		return datx_error(x, -EINVAL, x->name, "the map's values cannot be read");
	double nd_value = no_data(x);
	for (size_t k = 0; k < nodes; k++)
		z[k] = z[k] >= nd_value || !isfinite(z[k]) ? NAN : z[k] * zs;
	struct points_map m = { .nx = (size_t)dims[1], .ny = (size_t)dims[0], .z = z };
	points_map_centre(&m, dx, dy, 1);
	return points_from_map(&m, "datx", x->source, out, info, x->err);
}

int points_read_datx(const uint8_t *data, size_t len, const char *source,
		     struct asph_points **out, struct asph_points_read_info *info,
		     struct asph_error *err)
{
	struct datx x = { .source = source, .err = err, .file = -1, .set = -1 };
	H5E_auto2_t old_func;
	void *old_data;
	int r;

	/* HDF5 prints its error stack by default: the library stays quiet */
	H5Eget_auto2(H5E_DEFAULT, &old_func, &old_data);
	H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
	hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
	if (fapl >= 0 && H5Pset_fapl_core(fapl, 1 << 20, 0) >= 0 &&
	    H5Pset_file_image(fapl, (void *)data, len) >= 0)
		/* the core driver refuses a name that exists as a file: one
		 * under /dev/null never does (nothing is opened by it) */
		x.file = H5Fopen("/dev/null/asph-datx-image", H5F_ACC_RDONLY, fapl);
	if (fapl >= 0)
		H5Pclose(fapl);
	if (x.file < 0)
		r = datx_error(&x, -EINVAL, NULL, "not a readable HDF5 file");
	else if ((r = open_map(&x)) == 0)
		r = read_map(&x, len, out, info);
	if (x.set >= 0)
		H5Dclose(x.set);
	if (x.file >= 0)
		H5Fclose(x.file);
	H5Eset_auto2(H5E_DEFAULT, old_func, old_data);
	return r;
}
