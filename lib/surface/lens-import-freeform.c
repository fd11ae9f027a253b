/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The table of the OpticStudio surface types that are imported, and the
 * freeform ones as prescriptions: Biconic
 * (BICONICX), Toroidal (TOROIDAL, with its optional Zernike Standard
 * terms), Extended Polynomial (XPOLYNOM) and Zernike Standard Sag
 * (SZERNSAG). docs/prescriptions.md gives the layout of their PARM and
 * XDAT lines and where it is documented.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "aperture.h"
#include "lens-import-zmx.h"

/* The extra data of the types that have terms: XDAT 1 the count of terms,
 * XDAT 2 the normalization radius, XDAT 3 .. 2 + count the terms. */
#define XDAT_COUNT 1
#define XDAT_NORM 2
#define XDAT_FIRST_TERM 3

/* The imported types. Their names are 8 characters, as OpticStudio writes
 * them (ODDASPH, one short, is read as ODDASPHE). */
static const struct zmx_type types[] = {
	{ "STANDARD", "Standard", ZMX_STANDARD, ASPH_SURFACE_EVEN_ASPHERE, 0, 0 },
	/* PARM 1 .. 8 multiply r^2 .. r^16 */
	{ "EVENASPH", "Even Asphere", ZMX_EVENASPH, ASPH_SURFACE_EVEN_ASPHERE, 0x1fe, 0 },
	/* PARM 1 .. 8 multiply r^1 .. r^8 */
	{ "ODDASPHE", "Odd Asphere", ZMX_ODDASPH, ASPH_SURFACE_ODD_ASPHERE, 0x1fe, 0 },
	{ "ODDASPH", "Odd Asphere", ZMX_ODDASPH, ASPH_SURFACE_ODD_ASPHERE, 0x1fe, 0 },
	/* XDAT 1 Qbfs (0) or Qcon (1), 2 the number of terms, 3 the
	 * normalization radius, 4 .. the terms a_0 .. */
	{ "QED_TYPE", "Q-Type Asphere", ZMX_QTYPE, ASPH_SURFACE_QBFS, 0, ASPH_SURFACE_MAX_Q + 1 },
	/* PARM 1 x radius, PARM 2 x conic */
	{ "BICONICX", "Biconic", ZMX_FREEFORM, ASPH_SURFACE_BICONIC, 0x6, 0 },
	/* PARM 0 extrapolate, 1 radius of rotation, 2..8 y^2 .. y^14 */
	{ "TOROIDAL", "Toroidal", ZMX_FREEFORM, ASPH_SURFACE_TOROIDAL, 0x1ff,
	  ASPH_SURFACE_MAX_ZERNIKE },
	/* no parameters; the terms x, y, x^2, x y, y^2, x^3, ... */
	{ "XPOLYNOM", "Extended Polynomial", ZMX_FREEFORM, ASPH_SURFACE_XY_POLYNOMIAL, 0,
	  ASPH_SURFACE_XY_TERMS - 1 },
	/* PARM 0 extrapolate, 1..8 r^2 .. r^16, 9 and 10 the terms' x and y decenter */
	{ "SZERNSAG", "Zernike Standard Sag", ZMX_FREEFORM, ASPH_SURFACE_ZERNIKE_SAG, 0x7ff,
	  ASPH_SURFACE_MAX_ZERNIKE },
};

const struct zmx_type *zmx_type_of(const char *name)
{
	for (size_t i = 0; i < sizeof(types) / sizeof(types[0]); i++)
		if (!strcmp(name, types[i].name))
			return &types[i];
	return NULL;
}

void zmx_type_names(char *buf, size_t size)
{
	size_t len = 0;

	buf[0] = '\0';
	for (size_t i = 0; i < sizeof(types) / sizeof(types[0]) && len < size; i++)
		len += (size_t)snprintf(buf + len, size - len, "%s%s", i ? ", " : "", types[i].name);
}

/* OpticStudio writes a plane as curvature 0, and a radius parameter of 0
 * means an infinite radius. */
static double radius_of_curvature(double c)
{
	return c == 0 ? INFINITY : 1.0 / c;
}

static double radius_or_plane(double R)
{
	return R == 0 ? INFINITY : R;
}

/* Where a datum stands, or the TYPE line when the file has none. */
static void where(const struct zsurf *z, const struct zmx_value *v, int *line, int *col)
{
	*line = v->line ? v->line : z->type_line;
	*col = v->line ? v->col : z->type_col;
}

int zmx_check_unknown_data(const struct zsurf *z, const struct zmx_type *t, const char *file,
			   struct asph_error *err)
{
	char field[16];

	for (int i = 0; i <= ZMX_MAX_PARM; i++) {
		const struct zmx_value *v = &z->parm[i];
		if (!v->line || v->v == 0 || (i < 32 && (t->parms >> i & 1)))
			continue;
		snprintf(field, sizeof(field), "PARM %d", i);
		return zmx_refuse(err, file, v->line, v->col, field,
				  "surface %d: the %s surface has no parameter %d (its value %g "
				  "is not imported)", z->number, t->title, i, v->v);
	}
	for (int i = 1; i <= ZMX_MAX_XDAT && t->max_terms == 0; i++) {
		const struct zmx_value *v = &z->xdat[i];
		if (!v->line || v->v == 0)
			continue;
		snprintf(field, sizeof(field), "XDAT %d", i);
		return zmx_refuse(err, file, v->line, v->col, field,
				  "surface %d: the %s surface has no extra data (its value %g "
				  "is not imported)", z->number, t->title, v->v);
	}
	return 0;
}

/* The count of terms (XDAT 1) and the terms into terms[0 .. count - 1];
 * OpticStudio ignores the terms past the count, and so does this. */
static int extra_terms(const struct zsurf *z, const struct zmx_type *t, const char *file,
		       double *terms, struct asph_error *err)
{
	const struct zmx_value *n = &z->xdat[XDAT_COUNT];
	int line, col;

	if (!(n->v >= 0 && n->v <= t->max_terms && n->v == floor(n->v))) {
		where(z, n, &line, &col);
		return zmx_refuse(err, file, line, col, "XDAT 1",
				  "surface %d: %g terms: the %s surface has a whole number from 0 "
				  "to %d", z->number, n->v, t->title, t->max_terms);
	}
	for (int i = 0; i < (int)n->v; i++)
		terms[i] = z->xdat[XDAT_FIRST_TERM + i].v;
	return (int)n->v;
}

/* The normalization radius (XDAT 2), which the terms need. */
static int norm_radius(const struct zsurf *z, const struct zmx_type *t, const char *file,
		       double *out, struct asph_error *err)
{
	const struct zmx_value *v = &z->xdat[XDAT_NORM];
	int line, col;

	*out = v->v;
	if (v->v > 0)
		return 0;
	where(z, v, &line, &col);
	return zmx_refuse(err, file, line, col, "XDAT 2",
			  "surface %d: the %s surface's normalization radius is %g: its terms "
			  "need a positive length", z->number, t->title, v->v);
}

static int any_nonzero(const double *v, int n)
{
	for (int i = 0; i < n; i++)
		if (v[i] != 0)
			return 1;
	return 0;
}

/*
 * With Extrapolate (PARM 0) at 0, OpticStudio drops the Zernike terms
 * outside their normalization radius; the prescription continues them.
 * The two agree when the aperture stays inside that circle. A file
 * without PARM 0 reads as OpticStudio's default, which extrapolates.
 */
static int check_extrapolate(const struct zsurf *z, const struct zmx_type *t, const char *file,
			     const struct asph_prescription *p, struct asph_error *err)
{
	const struct zmx_value *flag = &z->parm[0];
	struct asph_aperture ap;

	if (!flag->line || flag->v != 0 || !any_nonzero(p->Zernike, ASPH_SURFACE_MAX_ZERNIKE))
		return 0;
	aperture_resolve(p, &ap);
	ap.offset[0] -= p->zernike_decenter[0];
	ap.offset[1] -= p->zernike_decenter[1];
	double reach = aperture_max_radius(&ap);
	if (reach <= p->norm_radius)
		return 0;
	return zmx_refuse(err, file, flag->line, flag->col, "PARM 0",
			  "surface %d: Extrapolate is 0, so the %s surface drops its Zernike terms "
			  "outside their normalization radius %g mm, and the aperture reaches %.6g mm "
			  "from their centre; the prescription continues the terms (set Extrapolate "
			  "to 1, or a normalization radius that holds the aperture)",
			  z->number, t->title, p->norm_radius, reach);
}

static int zernike_terms(const struct zsurf *z, const struct zmx_type *t, const char *file,
			 struct asph_prescription *p, struct asph_error *err)
{
	int n = extra_terms(z, t, file, p->Zernike, err), r;

	if (n < 0)
		return n;
	/* a toroid's terms are optional, and their radius with them */
	if (t->type == ASPH_SURFACE_TOROIDAL && !any_nonzero(p->Zernike, n))
		return 0;
	if ((r = norm_radius(z, t, file, &p->norm_radius, err)) < 0)
		return r;
	return check_extrapolate(z, t, file, p, err);
}

int zmx_freeform(const struct zsurf *z, const char *file, struct asph_prescription *p,
		 struct asph_error *err)
{
	const struct zmx_type *t = zmx_type_of(z->type);
	double terms[ASPH_SURFACE_XY_TERMS - 1];
	int r, n;

	if (!t || t->kind != ZMX_FREEFORM)
		return zmx_refuse(err, file, z->type_line, z->type_col, "TYPE",
				  "surface %d: type %s is not a freeform type", z->number, z->type);
	if ((r = zmx_check_unknown_data(z, t, file, err)) < 0)
		return r;
	p->type = t->type;
	switch (t->type) {
	case ASPH_SURFACE_BICONIC:
		p->Ry = radius_of_curvature(z->curv.v);
		p->ky = z->coni.v;
		p->Rx = radius_or_plane(z->parm[1].v);
		p->kx = z->parm[2].v;
		return 0;
	case ASPH_SURFACE_TOROIDAL:
		p->R = radius_of_curvature(z->curv.v);
		p->k = z->coni.v;
		p->R_rotation = radius_or_plane(z->parm[1].v);
		for (int i = 1; i <= 7; i++)
			p->A[2 * i] = z->parm[1 + i].v;
		return zernike_terms(z, t, file, p, err);
	case ASPH_SURFACE_XY_POLYNOMIAL:
		p->R = radius_of_curvature(z->curv.v);
		p->k = z->coni.v;
		if ((n = extra_terms(z, t, file, terms, err)) < 0 ||
		    (r = norm_radius(z, t, file, &p->norm_radius, err)) < 0)
			return n < 0 ? n : r;
		/* term i is the monomial at asph_xy_index() = i */
		for (int i = 1; i <= n; i++)
			p->C[i] = terms[i - 1];
		return 0;
	case ASPH_SURFACE_ZERNIKE_SAG:
		p->R = radius_of_curvature(z->curv.v);
		p->k = z->coni.v;
		for (int i = 1; i <= 8; i++)
			p->A[2 * i] = z->parm[i].v;
		p->zernike_decenter[0] = z->parm[9].v;
		p->zernike_decenter[1] = z->parm[10].v;
		return zernike_terms(z, t, file, p, err);
	default:
		return 0;
	}
}
