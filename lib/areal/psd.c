/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Power spectral densities (profile, radial, areal) and band-limited RMS. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <gsl/gsl_errno.h>
#include <gsl/gsl_fft_complex.h>

#include "asph/areal.h"
#include "areal-internal.h"
#include "util-mem.h"

/* Fewest valid samples a profile needs to count. */
#define MIN_PROFILE_SAMPLES 8

struct areal_fft {
	size_t n;
	gsl_fft_complex_wavetable *wt;
	gsl_fft_complex_workspace *ws;
};

size_t areal_fft_size(size_t n)
{
	for (size_t m = n < 1 ? 1 : n;; m++) {
		size_t k = m;
		while (k % 2 == 0)
			k /= 2;
		while (k % 3 == 0)
			k /= 3;
		while (k % 5 == 0)
			k /= 5;
		if (k == 1)
			return m;
	}
}

struct areal_fft *areal_fft_alloc(size_t n)
{
	struct areal_fft *f = calloc(1, sizeof(*f));

	if (!f)
		return NULL;
	f->n = n;
	f->wt = gsl_fft_complex_wavetable_alloc(n);
	f->ws = gsl_fft_complex_workspace_alloc(n);
	if (!f->wt || !f->ws) {
		areal_fft_free(f);
		return NULL;
	}
	return f;
}

void areal_fft_free(struct areal_fft *f)
{
	if (!f)
		return;
	if (f->wt)
		gsl_fft_complex_wavetable_free(f->wt);
	if (f->ws)
		gsl_fft_complex_workspace_free(f->ws);
	free(f);
}

int areal_fft_forward(struct areal_fft *f, double *data, size_t stride)
{
	return gsl_fft_complex_forward(data, stride, f->n, f->wt, f->ws) == GSL_SUCCESS ? 0 : -EINVAL;
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct areal_fft *, areal_fft_free)

double areal_hann(size_t k, size_t n)
{
	double s = sin(M_PI * ((double)k + 0.5) / (double)n);

	return s * s;
}

void asph_psd_free(struct asph_psd *p)
{
	if (!p)
		return;
	free(p->psd);
	free(p);
}

void asph_psd2_free(struct asph_psd2 *p)
{
	if (!p)
		return;
	free(p->psd);
	free(p);
}

static struct asph_psd *psd_new(size_t n, double df)
{
	struct asph_psd *p = calloc(1, sizeof(*p));

	if (!p)
		return NULL;
	p->n = n;
	p->df = df;
	p->psd = calloc(n, sizeof(double));
	if (!p->psd) {
		free(p);
		return NULL;
	}
	return p;
}

/*
 * Adds the one-sided PSD of z (n samples, NaN masked) to acc[0 .. nfft/2]
 * through the FFT f of length nfft; buf holds 2 nfft doubles. Returns 1 when
 * the profile counted, 0 when it has too few valid samples.
 */
static int profile_add(const double *z, size_t n, double dx, struct areal_fft *f,
		       double *buf, double *acc)
{
	size_t nfft = f->n, m = 0;
	double mean = 0, wsum = 0;

	for (size_t k = 0; k < n; k++)
		if (!isnan(z[k])) {
			mean += z[k];
			m++;
		}
	if (m < MIN_PROFILE_SAMPLES)
		return 0;
	mean /= (double)m;
	memset(buf, 0, 2 * nfft * sizeof(double));
	for (size_t k = 0; k < n; k++) {
		if (isnan(z[k]))
			continue;
		double w = areal_hann(k, n);
		buf[2 * k] = (z[k] - mean) * w;
		wsum += w * w;
	}
	areal_fft_forward(f, buf, 1);
	for (size_t k = 0; k <= nfft / 2; k++) {
		double p = (buf[2 * k] * buf[2 * k] + buf[2 * k + 1] * buf[2 * k + 1]) * dx / wsum;
		acc[k] += (k == 0 || 2 * k == nfft) ? p : 2 * p;
	}
	return 1;
}

static int check_profile(size_t n, double dx, struct asph_error *err)
{
	if (n < MIN_PROFILE_SAMPLES || !(dx > 0) || !isfinite(dx))
		return asph_error_set(err, -EINVAL,
				      "a PSD needs at least %d samples and a positive spacing",
				      MIN_PROFILE_SAMPLES);
	return 0;
}

int asph_psd_profile(const double *z, size_t n, double dx,
		     struct asph_psd **out, struct asph_error *err)
{
	_cleanup_(areal_fft_freep) struct areal_fft *f = NULL;
	_cleanup_free_ double *buf = NULL;
	struct asph_psd *p;
	size_t nfft;
	int r = check_profile(n, dx, err);

	if (r < 0)
		return r;
	nfft = areal_fft_size(n);
	f = areal_fft_alloc(nfft);
	buf = malloc(2 * nfft * sizeof(double));
	p = psd_new(nfft / 2 + 1, 1.0 / ((double)nfft * dx));
	if (!f || !buf || !p) {
		asph_psd_free(p);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	if (!profile_add(z, n, dx, f, buf, p->psd)) {
		asph_psd_free(p);
		return asph_error_set(err, -EDOM, "the profile has fewer than %d valid samples",
				      MIN_PROFILE_SAMPLES);
	}
	p->n_profiles = 1;
	*out = p;
	return 0;
}

int asph_psd_radial(const struct asph_scatter *s, double radius, double ds,
		    int n_profiles, struct asph_psd **out,
		    struct asph_error *err)
{
	_cleanup_(areal_fft_freep) struct areal_fft *f = NULL;
	_cleanup_free_ double *buf = NULL, *z = NULL;
	size_t n = asph_profile_length(radius, ds), nfft;
	struct asph_psd *p;
	int r = check_profile(n, ds, err);

	if (r < 0)
		return r;
	if (n_profiles < 1 || n_profiles > 3600)
		return asph_error_set(err, -EINVAL, "%d profiles is not in 1..3600", n_profiles);
	nfft = areal_fft_size(n);
	f = areal_fft_alloc(nfft);
	buf = malloc(2 * nfft * sizeof(double));
	z = malloc(n * sizeof(double));
	p = psd_new(nfft / 2 + 1, 1.0 / ((double)nfft * ds));
	if (!f || !buf || !z || !p) {
		asph_psd_free(p);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	for (int k = 0; k < n_profiles; k++) {
		asph_profile_sample(s, M_PI * k / n_profiles, radius, ds, z, NULL);
		p->n_profiles += (size_t)profile_add(z, n, ds, f, buf, p->psd);
	}
	if (p->n_profiles == 0) {
		asph_psd_free(p);
		return asph_error_set(err, -EDOM, "no profile has %d valid samples",
				      MIN_PROFILE_SAMPLES);
	}
	for (size_t k = 0; k < p->n; k++)
		p->psd[k] /= (double)p->n_profiles;
	*out = p;
	return 0;
}

int asph_psd_residual(const struct asph_scatter *s, double radius,
		      struct asph_psd **out, struct asph_error *err)
{
	/* Half the points' spacing resolves what they carry; the floor keeps
	 * a dense scan's profiles to a few thousand samples. */
	double ds = fmax(asph_scatter_median_edge(s) / 2, radius / 2000);

	return asph_psd_radial(s, radius, ds, ASPH_PSD_DIAMETERS, out, err);
}

/* The grid, mean removed, times the 2-D Hann window and the mask, into the
 * zero-padded complex buffer; returns the window power sum(w^2 m). */
static double load_windowed(const struct asph_grid *g, size_t nfx, double *buf)
{
	double mean = 0, wsum = 0;
	size_t m = 0;

	for (size_t i = 0; i < g->nx * g->ny; i++)
		if (!isnan(g->z[i])) {
			mean += g->z[i];
			m++;
		}
	mean /= m ? (double)m : 1.0;
	for (size_t j = 0; j < g->ny; j++)
		for (size_t i = 0; i < g->nx; i++) {
			double v = g->z[j * g->nx + i];
			if (isnan(v))
				continue;
			double w = areal_hann(i, g->nx) * areal_hann(j, g->ny);
			buf[2 * (j * nfx + i)] = (v - mean) * w;
			wsum += w * w;
		}
	return wsum;
}

int asph_psd_areal(const struct asph_grid *g, struct asph_psd2 **out,
		   struct asph_error *err)
{
	_cleanup_(areal_fft_freep) struct areal_fft *fx = NULL;
	_cleanup_(areal_fft_freep) struct areal_fft *fy = NULL;
	_cleanup_free_ double *buf = NULL;
	struct asph_psd2 *p;
	size_t nfx, nfy;
	double wsum;

	if (g->nx < MIN_PROFILE_SAMPLES || g->ny < MIN_PROFILE_SAMPLES || !(g->dx > 0))
		return asph_error_set(err, -EINVAL, "an areal PSD needs at least %d x %d nodes",
				      MIN_PROFILE_SAMPLES, MIN_PROFILE_SAMPLES);
	nfx = areal_fft_size(g->nx);
	nfy = areal_fft_size(g->ny);
	fx = areal_fft_alloc(nfx);
	fy = areal_fft_alloc(nfy);
	buf = calloc(2 * nfx * nfy, sizeof(double));
	p = calloc(1, sizeof(*p));
	if (p)
		p->psd = malloc(nfx * nfy * sizeof(double));
	if (!fx || !fy || !buf || !p || !p->psd) {
		asph_psd2_free(p);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	wsum = load_windowed(g, nfx, buf);
	if (!(wsum > 0)) {
		asph_psd2_free(p);
		return asph_error_set(err, -EDOM, "the grid has no valid node");
	}
	for (size_t j = 0; j < g->ny; j++)
		areal_fft_forward(fx, buf + 2 * j * nfx, 1);
	for (size_t i = 0; i < nfx; i++)
		areal_fft_forward(fy, buf + 2 * i, nfx);
	p->nfx = nfx;
	p->nfy = nfy;
	p->dfx = 1.0 / ((double)nfx * g->dx);
	p->dfy = 1.0 / ((double)nfy * g->dx);
	for (size_t i = 0; i < nfx * nfy; i++)
		p->psd[i] = (buf[2 * i] * buf[2 * i] + buf[2 * i + 1] * buf[2 * i + 1]) *
			    g->dx * g->dx / wsum;
	*out = p;
	return 0;
}

/* |f| of node (k, l) of the areal PSD. */
static double node_frequency(const struct asph_psd2 *p, size_t k, size_t l)
{
	double kk = k < (p->nfx + 1) / 2 ? (double)k : (double)k - (double)p->nfx;
	double ll = l < (p->nfy + 1) / 2 ? (double)l : (double)l - (double)p->nfy;

	return hypot(kk * p->dfx, ll * p->dfy);
}

int asph_psd2_radial(const struct asph_psd2 *p, struct asph_psd **out,
		     struct asph_error *err)
{
	double df = p->dfx < p->dfy ? p->dfx : p->dfy;
	double fmax = 0.5 * hypot((double)p->nfx * p->dfx, (double)p->nfy * p->dfy);
	size_t n = (size_t)floor(fmax / df + 0.5) + 1;
	struct asph_psd *r = psd_new(n, df);

	if (!r)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t l = 0; l < p->nfy; l++)
		for (size_t k = 0; k < p->nfx; k++) {
			size_t bin = (size_t)floor(node_frequency(p, k, l) / df + 0.5);
			if (bin < n)
				r->psd[bin] += p->psd[l * p->nfx + k] * p->dfx * p->dfy / df;
		}
	r->n_profiles = 1;
	*out = r;
	return 0;
}

int asph_band_rms(const struct asph_psd2 *p, const struct asph_bands *b,
		  struct asph_band_rms *out, struct asph_error *err)
{
	double form = 0, mid = 0, high = 0, area = p->dfx * p->dfy;

	if (!(b->form_mm > 0) || !(b->high_mm > 0) || !(b->high_mm < b->form_mm) ||
	    !isfinite(b->form_mm))
		return asph_error_set(err, -EINVAL,
				      "bands: need 0 < high %g mm < form %g mm", b->high_mm,
				      b->form_mm);
	for (size_t l = 0; l < p->nfy; l++)
		for (size_t k = 0; k < p->nfx; k++) {
			double f = node_frequency(p, k, l), v = p->psd[l * p->nfx + k] * area;
			if (k == 0 && l == 0)
				continue;
			if (f < 1.0 / b->form_mm)
				form += v;
			else if (f < 1.0 / b->high_mm)
				mid += v;
			else
				high += v;
		}
	out->form = sqrt(form);
	out->mid = sqrt(mid);
	out->high = sqrt(high);
	out->total = sqrt(form + mid + high);
	return 0;
}
