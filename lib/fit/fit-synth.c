/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Synthetic measurements of a part with misalignment, form error, noise. */
#include <errno.h>
#include <math.h>

#include <gsl/gsl_randist.h>
#include <gsl/gsl_rng.h>

#include "asph/fit.h"
#include "asph/zernike.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(gsl_rng *, gsl_rng_free)

static int check_terms(const struct asph_synth_options *o, double *coef,
		       int *n_coef, struct asph_error *err)
{
	*n_coef = 0;
	for (size_t t = 0; t < o->n_terms; t++) {
		int j = o->terms[t].j;
		if (j < 1 || j > ASPH_ZERNIKE_MAX_J || !isfinite(o->terms[t].nm))
			return asph_error_set(err, -EINVAL,
					      "form error term %zu: Noll index %d or coefficient not valid (1..%d)",
					      t + 1, j, ASPH_ZERNIKE_MAX_J);
		while (*n_coef < j)
			coef[(*n_coef)++] = 0.0;
		coef[j - 1] += o->terms[t].nm;
	}
	if (!(o->noise_nm >= 0) || !isfinite(o->noise_nm))
		return asph_error_set(err, -EINVAL, "noise must be finite and >= 0");
	return 0;
}

int asph_fit_synthesize(const struct asph_surface *s,
			const double *xyz_nominal, size_t n,
			const struct asph_synth_options *opts, double *xyz_out,
			struct asph_error *err)
{
	_cleanup_(gsl_rng_freep) gsl_rng *rng = gsl_rng_alloc(gsl_rng_mt19937);
	double coef[ASPH_ZERNIKE_MAX_J], a = asph_surface_aperture_radius(s), c[2], disk_r;
	int n_coef, r, rot = asph_surface_is_rotational(s);

	asph_surface_aperture_disk(s, c, &disk_r);

	if (!rng)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r = check_terms(opts, coef, &n_coef, err);
	if (r < 0)
		return r;
	gsl_rng_set(rng, opts->seed);
	for (size_t i = 0; i < n; i++) {
		double x = xyz_nominal[3 * i], y = xyz_nominal[3 * i + 1];
		double rr = hypot(x, y), nrm[3], q[3], e_nm = 0;

		if (rot && !(rr <= a * (1 + 1e-12)))
			return asph_error_set(err, -EINVAL,
					      "point %zu at radius %.17g mm is outside the aperture (%.17g mm)",
					      i + 1, rr, a);
		if (!rot && !asph_surface_contains(s, x, y, 1e-12 * a))
			return asph_error_set(err, -EINVAL,
					      "point %zu at (%.17g, %.17g) mm is outside the aperture",
					      i + 1, x, y);
		if (n_coef > 0)
			e_nm = rot ? asph_zernike_series(coef, n_coef, rr / a, atan2(y, x), NULL)
				   : asph_zernike_series(coef, n_coef, hypot(x - c[0], y - c[1]) / disk_r,
							 atan2(y - c[1], x - c[0]), NULL);
		/* One draw per point at any noise level: a seed gives the same
		 * sequence whatever the level. */
		e_nm += opts->noise_nm * gsl_ran_gaussian_ziggurat(rng, 1.0);
		asph_surface_normal(s, x, y, nrm);
		double e = asph_nm_to_mm((asph_nm){ e_nm });
		q[0] = x + e * nrm[0];
		q[1] = y + e * nrm[1];
		q[2] = (rot ? asph_surface_sag(s, rr) : asph_surface_sag_xy(s, x, y)) + e * nrm[2];
		asph_pose_apply(&opts->pose, q, xyz_out + 3 * i);
	}
	return 0;
}
