/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_AREAL_H
#define ASPH_AREAL_H

#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/units.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Spatial analysis of a residual measured at scattered points
 * (docs/characterization.md, "Spatial-frequency analysis"): linear
 * interpolation on the Delaunay triangulation of the points, resampling onto
 * a regular grid, slope deviation, the ISO 16610-21 Gaussian filter, power
 * spectral densities, band-limited RMS and profile traces.
 *
 * Nothing is invented: a position is inside the measured region only when it
 * lies in a triangle of the measured points whose edges are all at most
 * max_edge long; everywhere else the value is NaN (masked). Long edges are
 * gaps (and the concave parts of the hull), never bridged.
 */

/* ------------------------------------------------------------ interpolant */

struct asph_scatter;

struct asph_scatter_options {
	double max_edge_mm;      /* longest edge of a triangle still inside;
				    0 = max_edge_factor x the median edge */
	double max_edge_factor;  /* 0 = 3 */
};

/* Triangulates the n points xy (mm) carrying value (any unit). The arrays
 * are copied. -EINVAL for a non-finite input, fewer than three points not on
 * a line, bad options; -ENOMEM. */
int asph_scatter_alloc(const double *xy, const double *value, size_t n,
		       const struct asph_scatter_options *opts,
		       struct asph_scatter **out, struct asph_error *err);
void asph_scatter_free(struct asph_scatter *s);
/* Gives the same points other values (n of them, in the points' order), as
 * if the scatter had been made with these: the triangulation, which depends
 * on xy alone, is kept. -EINVAL for a non-finite value. */
int asph_scatter_set_values(struct asph_scatter *s, const double *value,
			    struct asph_error *err);

size_t asph_scatter_n_points(const struct asph_scatter *s);
/* The scatter's copies of xy (x, y pairs) and of the values, in the order
 * given: a caller may let its own arrays go. */
const double *asph_scatter_xy(const struct asph_scatter *s);
const double *asph_scatter_values(const struct asph_scatter *s);
double asph_scatter_median_edge(const struct asph_scatter *s);
double asph_scatter_max_edge(const struct asph_scatter *s);

/*
 * The linear interpolant at (x, y): 0 and *value inside the measured region,
 * -EDOM (value NaN) outside it. idx and w (may be NULL) receive the three
 * points and barycentric weights the value is made of. *hint is a triangle
 * to start the search from (0 at first) and is updated, so that nearby
 * positions in sequence cost a few steps each.
 */
int asph_scatter_eval(const struct asph_scatter *s, double x, double y,
		      uint32_t *hint, double *value, uint32_t idx[3],
		      double w[3]);

/* ------------------------------------------------------------------ grid */

/* A regular grid: z[j * nx + i] at (x0 + i dx, y0 + j dx); NaN = masked. */
struct asph_grid {
	size_t nx, ny;
	double x0, y0, dx;
	double *z;
};

/* NaN-filled. NULL when out of memory or nx * ny is 0 or too big. */
struct asph_grid *asph_grid_alloc(size_t nx, size_t ny);
void asph_grid_free(struct asph_grid *g);

/* The largest grid asph_grid_resample makes: nodes across. */
#define ASPH_GRID_MAX_NODES 4097

/*
 * The interpolant on a square grid of spacing dx centred on the axis,
 * covering the disc of radius `radius`; nodes outside the disc or the
 * measured region are NaN. -EINVAL for a spacing that is not positive or
 * gives more than ASPH_GRID_MAX_NODES across.
 */
int asph_grid_resample(const struct asph_scatter *s, double radius, double dx,
		       struct asph_grid **out, struct asph_error *err);

/* ------------------------------------------------------- slope deviation */

struct asph_slope {
	double length_mm;        /* evaluation length */
	asph_urad rms, max;      /* of the slope magnitude sqrt(sr^2 + st^2) */
	asph_urad rms_radial, max_radial;
	asph_urad rms_azimuthal, max_azimuthal;
	size_t n;                /* positions evaluated */
	asph_urad u_rms, u_max;  /* expanded (k = 2) uncertainties from noise
				    (NaN with a NaN noise level) */
};

/*
 * Slope of the residual (nm) of s over the evaluation length L, as the
 * difference quotient (F(p + L/2 e) - F(p - L/2 e)) / L along the radial
 * direction e_r and along the tangent e_t at the nodes p of a grid of
 * spacing `spacing` inside the disc of radius `radius`. A position counts
 * when both stencils lie in the measured region and the disc. noise_nm > 0
 * propagates independent noise of that standard deviation.
 * -EINVAL: bad arguments; -EDOM: no position could be evaluated.
 */
int asph_slope_compute(const struct asph_scatter *s, double radius,
		       double length_mm, double spacing, double noise_nm,
		       struct asph_slope *out, struct asph_error *err);

/* ------------------------------------------ ISO 16610-21 Gaussian filter */

/* alpha = sqrt(ln 2 / pi): the mean line transmits exp(-pi (alpha lc / l)^2)
 * of a sinusoid of wavelength l, 50 % at the cut-off lc. */
#define ASPH_GAUSSIAN_ALPHA 0.4697186393498257

/*
 * The mean line (low-pass, cut-off `cutoff`) of a profile z[0 .. n-1] of
 * spacing dx: convolution with s(x) = exp(-pi (x / (alpha lc))^2) / (alpha
 * lc), truncated at |x| <= lc and normalised over the valid (non-NaN)
 * samples at each position. Masked samples stay NaN. The roughness profile
 * is z - mean_line. -EINVAL for bad arguments, -ENOMEM.
 */
int asph_gaussian_profile(const double *z, size_t n, double dx, double cutoff,
			  double *mean_line, struct asph_error *err);

/* The areal filter (ISO 16610-61, the separable Gaussian of the same
 * cut-off along x and y), normalised over the valid nodes; out has g's
 * geometry (it may be g itself). */
int asph_gaussian_areal(const struct asph_grid *g, double cutoff,
			struct asph_grid *out, struct asph_error *err);

/* ------------------------------------------------------------------- PSD */

/*
 * One-sided power spectral densities, in value^2 mm (profile) or value^2
 * mm^2 (areal), of the data with its mean removed, multiplied by a Hann
 * window (and the mask), and normalised by the window's power, so that the
 * sum of psd x df is the (window-weighted) mean square. Zero-padded to a
 * size with factors 2, 3, 5 only.
 */
struct asph_psd {
	size_t n;                /* frequencies f[k] = k df, k = 0 .. n-1 */
	double df;               /* 1/mm */
	double *psd;
	size_t n_profiles;       /* averaged (profile PSD) */
};

void asph_psd_free(struct asph_psd *p);

/* The PSD of one profile (NaN = masked). */
int asph_psd_profile(const double *z, size_t n, double dx,
		     struct asph_psd **out, struct asph_error *err);

/*
 * The radial PSD: the average of the PSDs of n_profiles diameters through
 * the axis at angles k pi / n_profiles, sampled at spacing ds by the
 * interpolant (masked outside the measured region).
 */
int asph_psd_radial(const struct asph_scatter *s, double radius, double ds,
		    int n_profiles, struct asph_psd **out,
		    struct asph_error *err);

/* The diameters asph_psd_residual() averages. */
#define ASPH_PSD_DIAMETERS 18

/*
 * The PSD of a residual map, the one the report draws and the daemon's
 * psd.csv holds: asph_psd_radial() over ASPH_PSD_DIAMETERS diameters,
 * sampled at half the median edge of the points, no finer than
 * radius / 2000. Its errors: asph_psd_radial()'s (-EDOM: no diameter
 * holds enough measured samples).
 */
int asph_psd_residual(const struct asph_scatter *s, double radius,
		      struct asph_psd **out, struct asph_error *err);

/* The areal PSD of a grid (2-D FFT), fx fastest, frequencies wrapped as
 * an FFT returns them: psd2[l * nfx + k] at (kk dfx, ll dfy), kk = k for
 * k < nfx / 2 else k - nfx (the same for l). */
struct asph_psd2 {
	size_t nfx, nfy;
	double dfx, dfy;
	double *psd;             /* two-sided, value^2 mm^2 */
};

void asph_psd2_free(struct asph_psd2 *p);
int asph_psd_areal(const struct asph_grid *g, struct asph_psd2 **out,
		   struct asph_error *err);

/* The areal PSD averaged over annuli of width df (= dfx): a radial
 * one-sided PSD in value^2 mm (2 pi f times the annulus mean). */
int asph_psd2_radial(const struct asph_psd2 *p, struct asph_psd **out,
		     struct asph_error *err);

/*
 * Band-limited RMS from the areal PSD, bands by spatial wavelength
 * (mm): form, wavelengths longer than form_mm; mid-spatial, from high_mm to
 * form_mm; high, shorter than high_mm. total is all but the mean.
 */
struct asph_bands {
	double form_mm, high_mm;
};

struct asph_band_rms {
	double form, mid, high, total;   /* in the value's unit */
};

int asph_band_rms(const struct asph_psd2 *p, const struct asph_bands *b,
		  struct asph_band_rms *out, struct asph_error *err);

/* -------------------------------------------------------- profile traces */

/*
 * The interpolant along the diameter at angle `angle` (rad from +x):
 * z[k] at s_k = -radius + k ds, k = 0 .. n-1, n = 2 floor(radius / ds) + 1
 * (asph_profile_length()), NaN outside the measured region.
 */
size_t asph_profile_length(double radius, double ds);
int asph_profile_sample(const struct asph_scatter *s, double angle,
			double radius, double ds, double *z,
			struct asph_error *err);

/* The mean over n_angles azimuths of the interpolant at radii r_k = k dr,
 * k = 0 .. n-1 (NaN where no azimuth is measured). */
int asph_profile_azimuthal_mean(const struct asph_scatter *s, double dr,
				size_t n, int n_angles, double *z,
				struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
