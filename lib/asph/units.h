/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_UNITS_H
#define ASPH_UNITS_H

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Inside the library lengths are plain doubles in mm and angles in radians.
 * Where a value crosses into nm or microradians (human-facing summaries) it
 * travels in one of these wrappers, so that passing mm where nm is expected
 * does not compile.
 */
typedef struct { double v; } asph_nm;
typedef struct { double v; } asph_urad;

static inline asph_nm asph_nm_from_mm(double mm)
{
	asph_nm nm = { mm * 1e6 };
	return nm;
}
static inline double asph_nm_to_mm(asph_nm nm)
{
	return nm.v * 1e-6;
}
static inline asph_urad asph_urad_from_rad(double rad)
{
	asph_urad u = { rad * 1e6 };
	return u;
}
static inline double asph_urad_to_rad(asph_urad u)
{
	return u.v * 1e-6;
}

#ifdef __cplusplus
}
#endif

#endif
