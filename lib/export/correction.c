/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Correction tables: z(r) for turned parts and an XY grid, as CSV. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asph/correction.h"
#include "util-mem.h"

#define DEFAULT_AZIMUTHS 360
#define MAX_TABLE_NODES 4097

struct name {
	const char *name;
	int value;
};

static int parse_name(const char *s, const char *what, const struct name *names,
		      int *out, struct asph_error *err)
{
	char list[128] = "";

	for (const struct name *n = names; n->name; n++) {
		if (!strcmp(s, n->name)) {
			*out = n->value;
			return 0;
		}
		snprintf(list + strlen(list), sizeof(list) - strlen(list), "%s%s",
			 n == names ? "" : (n[1].name ? ", " : " or "), n->name);
	}
	return asph_error_set_at(err, -EINVAL, NULL, 0, 0, what, "'%s' is not %s", s, list);
}

#define PARSER(fn, type, ...)                                                       \
	int fn(const char *s, const char *what, type *out, struct asph_error *err) \
	{                                                                           \
		static const struct name names[] = { __VA_ARGS__, { NULL, 0 } };   \
		int v = 0, r = parse_name(s, what, names, &v, err);                \
		if (r == 0)                                                         \
			*out = (type)v;                                             \
		return r;                                                           \
	}

PARSER(asph_correction_kind_parse, enum asph_correction_kind,
       { "radial", ASPH_CORRECTION_RADIAL }, { "grid", ASPH_CORRECTION_GRID })
PARSER(asph_correction_sign_parse, enum asph_correction_sign,
       { "height-error", ASPH_CORRECTION_HEIGHT_ERROR },
       { "material-to-remove", ASPH_CORRECTION_MATERIAL_TO_REMOVE })
PARSER(asph_correction_direction_parse, enum asph_correction_direction,
       { "z", ASPH_CORRECTION_ALONG_Z }, { "normal", ASPH_CORRECTION_ALONG_NORMAL })
PARSER(asph_correction_extension_parse, enum asph_correction_extension,
       { "constant", ASPH_CORRECTION_EXTEND_CONSTANT },
       { "linear", ASPH_CORRECTION_EXTEND_LINEAR })
PARSER(asph_correction_material_parse, enum asph_correction_material,
       { "below", ASPH_CORRECTION_MATERIAL_BELOW }, { "above", ASPH_CORRECTION_MATERIAL_ABOVE })

struct table {
	const struct asph_surface *s;
	const struct asph_scatter *res;
	struct asph_correction_options o;
	double a;                /* aperture radius */
	double step;
	int along_normal;        /* of the residual */
};

static int check_options(struct table *t, struct asph_error *err)
{
	struct asph_correction_options *o = &t->o;

	if (!isfinite(o->step_mm) || o->step_mm < 0)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "step", "%g mm is not a positive spacing",
					 o->step_mm);
	t->step = o->step_mm > 0 ? o->step_mm : asph_scatter_median_edge(t->res);
	if (!(t->step > 0) || 2 * ((t->a + o->extend_mm) / t->step) + 1 > MAX_TABLE_NODES)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "step",
					 "%g mm gives more than %d values across the part", t->step,
					 MAX_TABLE_NODES);
	if (!isfinite(o->extend_mm) || o->extend_mm < 0 || o->extend_mm > t->a)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "extend",
					 "%g mm is not in 0..%g mm (the aperture radius)", o->extend_mm,
					 t->a);
	if (!isfinite(o->smooth_mm) || o->smooth_mm < 0 ||
	    (o->smooth_mm > 0 && o->smooth_mm < 2 * t->step))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "smooth",
					 "cut-off %g mm must be 0 (none) or at least two steps (%g mm)",
					 o->smooth_mm, 2 * t->step);
	if (o->smooth_mm > 2 * t->a)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "smooth",
					 "cut-off %g mm is longer than the part (%g mm)", o->smooth_mm,
					 2 * t->a);
	if (o->n_azimuths < 0 || o->n_azimuths > 36000)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "azimuths",
					 "%d is not in 1..36000", o->n_azimuths);
	if ((unsigned)o->kind > ASPH_CORRECTION_GRID || (unsigned)o->sign > ASPH_CORRECTION_MATERIAL_TO_REMOVE ||
	    (unsigned)o->direction > ASPH_CORRECTION_ALONG_NORMAL ||
	    (unsigned)o->extension > ASPH_CORRECTION_EXTEND_LINEAR ||
	    (unsigned)o->material > ASPH_CORRECTION_MATERIAL_ABOVE)
		return asph_error_set(err, -EINVAL, "unknown correction table option value");
	return 0;
}

/* The residual at radius r in the table's direction and sign. */
static double convert(const struct table *t, double r, double v)
{
	double d[3], k;

	asph_surface_sag_derivs(t->s, r, d);
	k = sqrt(1 + d[1] * d[1]);   /* along z = along the normal x k */
	if (t->along_normal && t->o.direction == ASPH_CORRECTION_ALONG_Z)
		v *= k;
	else if (!t->along_normal && t->o.direction == ASPH_CORRECTION_ALONG_NORMAL)
		v /= k;
	/* Material below: material above the nominal is height above it. */
	if (t->o.sign == ASPH_CORRECTION_MATERIAL_TO_REMOVE &&
	    t->o.material == ASPH_CORRECTION_MATERIAL_ABOVE)
		v = -v;
	return v;
}

/* Values of a profile v[0..n-1] at spacing step past its last valid one,
 * up to index n_total - 1: constant, or linear with the slope of a line
 * fitted to the last five valid values. */
static void extend_profile(double *v, size_t n_valid_end, size_t n_total, double step,
			   enum asph_correction_extension how)
{
	size_t last = n_valid_end;
	double sx = 0, sy = 0, sxx = 0, sxy = 0, slope = 0;
	int m = 0;

	while (last > 0 && isnan(v[last - 1]))
		last--;
	if (last == 0)
		return;
	for (size_t k = last; k-- > 0 && m < 5;) {
		if (isnan(v[k]))
			break;
		double x = (double)k * step;
		sx += x;
		sy += v[k];
		sxx += x * x;
		sxy += x * v[k];
		m++;
	}
	if (how == ASPH_CORRECTION_EXTEND_LINEAR && m >= 2)
		slope = (m * sxy - sx * sy) / (m * sxx - sx * sx);
	for (size_t k = last; k < n_total; k++)
		v[k] = v[last - 1] + slope * (double)(k - (last - 1)) * step;
}

static const char *sign_text(const struct table *t)
{
	if (t->o.sign == ASPH_CORRECTION_HEIGHT_ERROR)
		return "height error = measured - nominal; positive where the surface stands above the nominal (towards +z)";
	return t->o.material == ASPH_CORRECTION_MATERIAL_BELOW
		       ? "material to remove; positive where material stands above the nominal surface, negative where it is missing (material on the -z side)"
		       : "material to remove; positive where material stands above the nominal surface, negative where it is missing (material on the +z side)";
}

static void header(FILE *f, const struct table *t, const char *lens, size_t n_masked)
{
	const struct asph_correction_options *o = &t->o;

	fprintf(f, "# asphd correction table: %s\n",
		o->kind == ASPH_CORRECTION_RADIAL ? "z(r), sag error of a turned part (mean over azimuth)"
						  : "XY grid");
	fprintf(f, "# lens: %s; aperture radius %.6g mm\n", lens ? lens : "-", t->a);
	fprintf(f, "# value (nm): %s\n", sign_text(t));
	fprintf(f, "# direction: %s\n", o->direction == ASPH_CORRECTION_ALONG_Z
						? "along z (the sag of the surface)"
						: "along the surface normal");
	if (o->smooth_mm > 0)
		fprintf(f, "# smoothing: Gaussian filter (ISO 16610-21), cut-off %g mm\n", o->smooth_mm);
	else
		fprintf(f, "# smoothing: none\n");
	if (o->extend_mm > 0)
		fprintf(f, "# extension: %s beyond the aperture radius to %g mm\n",
			o->extension == ASPH_CORRECTION_EXTEND_LINEAR ? "linear (the rim's value and slope)"
								       : "constant (the rim's value)",
			t->a + o->extend_mm);
	else
		fprintf(f, "# extension: none\n");
	fprintf(f, "# step %g mm; unmeasured values (nan): %zu\n", t->step, n_masked);
}

/* The symmetric profile e(|r|) from -R to R, smoothed, is what a turned
 * part's error is; its r >= 0 half is the table. */
static int radial_table(FILE *f, const struct table *t, const char *lens,
			struct asph_error *err)
{
	size_t n_in = (size_t)floor(t->a / t->step) + 1;
	size_t n = (size_t)floor((t->a + t->o.extend_mm) / t->step + 1e-9) + 1, masked = 0;
	_cleanup_free_ double *half = malloc(n * sizeof(double));
	_cleanup_free_ double *full = malloc((2 * n - 1) * sizeof(double));
	_cleanup_free_ double *smooth = malloc((2 * n - 1) * sizeof(double));
	int az = t->o.n_azimuths ? t->o.n_azimuths : DEFAULT_AZIMUTHS, r;

	if (!half || !full || !smooth)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t k = 0; k < n; k++)
		half[k] = NAN;
	r = asph_profile_azimuthal_mean(t->res, t->step, n_in, az, half, err);
	if (r < 0)
		return r;
	for (size_t k = 0; k < n_in; k++)
		if (!isnan(half[k]))
			half[k] = convert(t, (double)k * t->step, half[k]);
	if (t->o.smooth_mm > 0) {
		for (size_t k = 0; k < n; k++)
			full[n - 1 + k] = full[n - 1 - k] = half[k];
		r = asph_gaussian_profile(full, 2 * n - 1, t->step, t->o.smooth_mm, smooth, err);
		if (r < 0)
			return r;
		memcpy(half, smooth + n - 1, n * sizeof(double));
	}
	if (n > n_in)
		extend_profile(half, n_in, n, t->step, t->o.extension);
	for (size_t k = 0; k < n; k++)
		masked += isnan(half[k]);
	header(f, t, lens, masked);
	fprintf(f, "r_mm,%s_nm\n", t->o.sign == ASPH_CORRECTION_HEIGHT_ERROR ? "height_error" : "material_to_remove");
	for (size_t k = 0; k < n; k++)
		fprintf(f, "%.9g,%.6f\n", (double)k * t->step, half[k]);
	return 0;
}

/* A node past the aperture: along its ray, from the rim inwards. */
static double grid_extension(const struct table *t, double x, double y)
{
	double rr = hypot(x, y), ux = x / rr, uy = y / rr, v[3];
	uint32_t hint = 0;
	int m = 0;

	/* Steps counted, not summed: the radii stay exact multiples. */
	for (int k = 0; t->a - k * t->step > 0 && m < 3; k++) {
		double r = t->a - k * t->step;
		if (asph_scatter_eval(t->res, r * ux, r * uy, &hint, &v[m], NULL, NULL) == 0)
			v[m] = convert(t, r, v[m]), m++;
		else if (m)
			break;
	}
	if (m == 0)
		return NAN;
	/* v[0] at the outermost measured radius; the slope over two steps. */
	double slope = 0;

	if (t->o.extension == ASPH_CORRECTION_EXTEND_LINEAR && m == 3)
		slope = (v[0] - v[2]) / (2 * t->step);
	return v[0] + slope * (rr - t->a);
}

static int grid_table(FILE *f, const struct table *t, const char *lens,
		      struct asph_error *err)
{
	double R = t->a + t->o.extend_mm;
	size_t half = (size_t)floor(R / t->step + 1e-9), n = 2 * half + 1, masked = 0;
	struct asph_grid *g = asph_grid_alloc(n, n);
	uint32_t hint = 0;
	int r = 0;

	if (!g)
		return asph_error_set(err, -ENOMEM, "out of memory for a %zu x %zu table", n, n);
	g->dx = t->step;
	g->x0 = g->y0 = -(double)half * t->step;
	for (size_t j = 0; j < n; j++)
		for (size_t i = 0; i < n; i++) {
			double x = g->x0 + (double)i * g->dx, y = g->y0 + (double)j * g->dx, v;
			double rr = hypot(x, y);
			if (rr <= t->a && asph_scatter_eval(t->res, x, y, &hint, &v, NULL, NULL) == 0)
				g->z[j * n + i] = convert(t, rr, v);
		}
	if (t->o.smooth_mm > 0)
		r = asph_gaussian_areal(g, t->o.smooth_mm, g, err);
	for (size_t j = 0; r == 0 && j < n; j++)
		for (size_t i = 0; i < n; i++) {
			double x = g->x0 + (double)i * g->dx, y = g->y0 + (double)j * g->dx;
			double rr = hypot(x, y);
			if (rr > t->a && rr <= R)
				g->z[j * n + i] = grid_extension(t, x, y);
		}
	if (r == 0) {
		for (size_t k = 0; k < n * n; k++)
			masked += isnan(g->z[k]);
		header(f, t, lens, masked);
		fprintf(f, "x_mm,y_mm,%s_nm\n",
			t->o.sign == ASPH_CORRECTION_HEIGHT_ERROR ? "height_error" : "material_to_remove");
		for (size_t j = 0; j < n; j++)
			for (size_t i = 0; i < n; i++)
				fprintf(f, "%.9g,%.9g,%.6f\n", g->x0 + (double)i * g->dx,
					g->y0 + (double)j * g->dx, g->z[j * n + i]);
	}
	asph_grid_free(g);
	return r;
}

int asph_correction_write(const char *path, const struct asph_surface *s,
			  const char *lens, const struct asph_scatter *residual,
			  int residual_along_normal,
			  const struct asph_correction_options *opts,
			  struct asph_error *err)
{
	struct table t = { .s = s, .res = residual, .a = asph_surface_aperture_radius(s),
			   .along_normal = residual_along_normal };
	_cleanup_fclose_ FILE *f = NULL;
	int r;

	if (opts)
		t.o = *opts;
	r = check_options(&t, err);
	if (r < 0)
		return r;
	f = fopen(path, "we");
	if (!f)
		return asph_error_set(err, -errno, "cannot create %s: %s", path, strerror(errno));
	r = t.o.kind == ASPH_CORRECTION_RADIAL ? radial_table(f, &t, lens, err)
					       : grid_table(f, &t, lens, err);
	if (r == 0 && (fflush(f) != 0 || ferror(f)))
		r = asph_error_set(err, -EIO, "cannot write %s: %s", path, strerror(errno));
	if (r == 0 && fclose(steal_ptr(f)) != 0)
		r = asph_error_set(err, -EIO, "cannot write %s: %s", path, strerror(errno));
	return r;
}
