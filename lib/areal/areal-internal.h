/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The interpolant's insides, shared by the files of lib/areal. Internal. */
#ifndef ASPH_AREAL_INTERNAL_H
#define ASPH_AREAL_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "asph/areal.h"

struct asph_scatter {
	size_t n;
	double *xy;
	double *value;
	uint32_t *tri;           /* 3 per triangle, counter-clockwise */
	uint32_t *adj;           /* neighbour across edge k -> k+1 */
	size_t n_tri;
	uint8_t *kept;           /* all edges <= max_edge */
	double median_edge, max_edge;
};

/* The smallest size >= n with no prime factor above 5 (FFT lengths). */
size_t areal_fft_size(size_t n);

/* A complex FFT of one length (GSL's mixed radix), reused across rows. */
struct areal_fft;
struct areal_fft *areal_fft_alloc(size_t n);
void areal_fft_free(struct areal_fft *f);
/* In place, n complex points interleaved (re, im), stride in complex
 * elements. 0 or -EINVAL. */
int areal_fft_forward(struct areal_fft *f, double *data, size_t stride);

/* Hann window value at sample k of n. */
double areal_hann(size_t k, size_t n);

#endif
