/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Best fit of 1e6 points (5 DOF) to convergence, against one pass of sag
 * evaluation over the same points. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include <gsl/gsl_errno.h>

#include "asph/fit.h"
#include "asph/prescription.h"
#include "asph/surface.h"
#include "bench-common.h"

#define TARGET_RATIO 60.0

struct ctx {
	const struct asph_surface *s;
	const double *xyz;
	size_t n;
	struct asph_fit *w;
	struct asph_fit_result res;
	double sink;
	int failed;
};

static void sag_pass(void *p)
{
	struct ctx *c = p;
	double sum = 0;

	for (size_t i = 0; i < c->n; i++)
		sum += asph_surface_sag(c->s, hypot(c->xyz[3 * i], c->xyz[3 * i + 1]));
	c->sink += sum;
}

/* Only the fit: the residual statistics (Zernike decomposition) are a
 * separate, one-off cost. */
static void fit_run(void *p)
{
	struct ctx *c = p;
	struct asph_error err;
	int r = asph_fit_init(c->w, c->xyz, c->n, &err);

	while (r == 0 && !asph_fit_test(c->w))
		r = asph_fit_iterate(c->w, &err);
	if (r < 0) {
		fprintf(stderr, "fit failed: %s\n", err.message);
		c->failed = 1;
	}
}

static double *measured_points(const struct asph_surface *s, size_t n)
{
	double a = asph_surface_aperture_radius(s), *xyz = malloc(3 * n * sizeof(double));
	struct asph_synth_options so = {
		.pose = { { 0.043, -0.071, 0.027 }, 6.3e-4, -3.7e-4 },
		.noise_nm = 2.0, .seed = 5,
	};

	if (!xyz)
		return NULL;
	for (size_t i = 0; i < n; i++) {
		double r = a * sqrt((i + 0.5) / (double)n), t = 2.399963229728653 * (double)i;
		xyz[3 * i] = r * cos(t);
		xyz[3 * i + 1] = r * sin(t);
		xyz[3 * i + 2] = 0;
	}
	if (asph_fit_synthesize(s, xyz, n, &so, xyz, NULL) < 0) {
		free(xyz);
		return NULL;
	}
	return xyz;
}

static int bench_lens(const char *name, size_t n)
{
	struct asph_prescription p;
	struct asph_surface *s = NULL;
	struct ctx c = { 0 };
	double t_sag, t_fit;
	int miss;

	if (asph_prescription_preset(name, &p) < 0 || asph_surface_alloc(&p, &s, NULL) < 0)
		return 1;
	c.s = s;
	c.n = n;
	c.xyz = measured_points(s, n);
	if (!c.xyz || asph_fit_alloc(s, n, NULL, &c.w, NULL) < 0)
		return 1;
	t_sag = bench_median(sag_pass, &c, 7);
	t_fit = bench_median(fit_run, &c, 3);
	if (c.failed || asph_fit_get_result(c.w, &c.res, NULL) < 0)
		return 1;
	printf("%s: %zu points, %d iterations, %d passes, converged %d, rms %.3f nm, "
	       "tx %.3e mm, ry %.3e rad\n", name, n, c.res.iterations, c.res.passes,
	       c.res.converged, c.res.rms.v, c.res.value[ASPH_FIT_TX], c.res.value[ASPH_FIT_RY]);
	printf("sag pass: %.4f s\n", t_sag);
	char label[64];
	snprintf(label, sizeof(label), "fit 5 DOF (%s)", name);
	miss = bench_report(label, t_fit, t_sag, TARGET_RATIO);
	asph_fit_free(c.w);
	free((void *)c.xyz);
	asph_surface_free(s);
	return miss;
}

int main(void)
{
	size_t n = bench_size(1000000);
	int miss = 0;

	gsl_set_error_handler_off();
	miss |= bench_lens("turning-point", n);
	miss |= bench_lens("weak", n);
	return miss;
}
