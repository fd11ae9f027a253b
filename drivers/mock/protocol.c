/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The mock instrument's simulated part and pacing. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "asph/prescription.h"
#include "asph/units.h"
#include "protocol.h"
#include "util-mem.h"
#include "util-time.h"

struct mock_part {
	struct asph_surface *surface;
	double a;
	struct asph_pose pose, rotation;       /* rotation: pose without t */
	double coef[ASPH_ZERNIKE_MAX_J];
	int n_coef;
	double noise_mm;
	double tip;
	bool nominal;           /* no pose, form error or tip: z = S(r) */
	uint64_t seed;
};

int mock_parse_form(const char *text, double *coef, int *n,
		    struct asph_error *err)
{
	const char *c = text;

	*n = 0;
	while (*c) {
		char *end;
		long j = strtol(c, &end, 10);
		if (end == c || *end != ':' || j < 1 || j > ASPH_ZERNIKE_MAX_J)
			return asph_error_set(err, -EINVAL,
					      "form: expected NOLL:NM pairs separated by ';' (Noll 1..%d) at '%s'",
					      ASPH_ZERNIKE_MAX_J, c);
		c = end + 1;
		double nm = strtod(c, &end);
		if (end == c || !isfinite(nm) || (*end && *end != ';'))
			return asph_error_set(err, -EINVAL, "form: bad coefficient at '%s'", c);
		while (*n < j)
			coef[(*n)++] = 0.0;
		coef[j - 1] += nm;
		c = *end ? end + 1 : end;
	}
	return 0;
}

void mock_part_free(struct mock_part *p)
{
	if (!p)
		return;
	asph_surface_free(p->surface);
	free(p);
}

int mock_part_new(const struct mock_part_params *pp, struct mock_part **out,
		  struct asph_error *err)
{
	struct asph_prescription pr;
	struct mock_part *p = calloc(1, sizeof(*p));
	int r;

	if (!p)
		return asph_error_set(err, -ENOMEM, "out of memory");
	p->seed = pp->seed;
	/* the host hands the measured lens over as its prescription text */
	if (pp->lens[0] == '{')
		r = asph_prescription_parse(pp->lens, strlen(pp->lens), "the measured lens", &pr, err);
	else
		r = asph_prescription_load(*pp->lens ? pp->lens : "strong", &pr, err);
	if (r == 0)
		r = asph_surface_alloc(&pr, &p->surface, err);
	if (r == 0)
		r = mock_parse_form(pp->form ? pp->form : "", p->coef, &p->n_coef, err);
	if (r < 0) {
		mock_part_free(p);
		return r;
	}
	p->a = asph_surface_aperture_radius(p->surface);
	p->pose = pp->pose;
	p->rotation = (struct asph_pose){ .rx = pp->pose.rx, .ry = pp->pose.ry, .rz = pp->pose.rz };
	p->noise_mm = asph_nm_to_mm((asph_nm){ pp->noise_nm });
	p->tip = pp->tip_radius;
	p->nominal = p->n_coef == 0 && p->tip == 0 && pp->pose.rx == 0 &&
		     pp->pose.ry == 0 && pp->pose.rz == 0 && pp->pose.t[0] == 0 &&
		     pp->pose.t[1] == 0 && pp->pose.t[2] == 0;
	*out = p;
	return 0;
}

/* The contact point C(u, v) for the part point at nominal (u, v): the part
 * surface point itself, or the tip centre P - tip N for a tactile probe. */
static int contact(const struct mock_part *p, double u, double v, double c[3])
{
	double r = hypot(u, v), n[3], q[3], nn[3], e = 0;
	double sag = asph_surface_is_rotational(p->surface) ? asph_surface_sag(p->surface, r)
							     : asph_surface_sag_xy(p->surface, u, v);

	if (!isfinite(sag))
		return -EDOM;
	asph_surface_normal(p->surface, u, v, n);
	if (p->n_coef && asph_surface_is_rotational(p->surface)) {
		e = asph_nm_to_mm((asph_nm){ asph_zernike_series(p->coef, p->n_coef, r / p->a,
								 atan2(v, u), NULL) });
	} else if (p->n_coef) {
		double o[2], R;
		asph_surface_aperture_disk(p->surface, o, &R);
		e = asph_nm_to_mm((asph_nm){ asph_zernike_series(p->coef, p->n_coef,
								 hypot(u - o[0], v - o[1]) / R,
								 atan2(v - o[1], u - o[0]), NULL) });
	}
	q[0] = u + e * n[0];
	q[1] = v + e * n[1];
	q[2] = sag + e * n[2];
	asph_pose_apply(&p->pose, q, c);
	if (p->tip > 0) {
		asph_pose_apply(&p->rotation, n, nn);
		for (int k = 0; k < 3; k++)
			c[k] -= p->tip * nn[k];
	}
	return 0;
}

/* Newton on C_xy(u, v) = (x, y) with a forward-difference Jacobian. */
static int solve_contact(const struct mock_part *p, double x, double y, double c[3])
{
	double u = x - p->pose.t[0], v = y - p->pose.t[1];
	const double h = 1e-7;

	for (int it = 0; it < 60; it++) {
		double cu[3], cv[3];
		if (contact(p, u, v, c) < 0)
			return -EDOM;
		double fx = c[0] - x, fy = c[1] - y;
		if (fabs(fx) < 1e-13 && fabs(fy) < 1e-13)
			return 0;
		if (contact(p, u + h, v, cu) < 0 || contact(p, u, v + h, cv) < 0)
			return -EDOM;
		double j11 = (cu[0] - c[0]) / h, j21 = (cu[1] - c[1]) / h;
		double j12 = (cv[0] - c[0]) / h, j22 = (cv[1] - c[1]) / h;
		double det = j11 * j22 - j12 * j21;
		if (!(fabs(det) > 1e-12))
			return -EDOM;
		u -= (j22 * fx - j12 * fy) / det;
		v -= (j11 * fy - j21 * fx) / det;
	}
	return -EDOM;
}

static uint64_t splitmix64(uint64_t *state)
{
	uint64_t z = (*state += 0x9e3779b97f4a7c15u);
	z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9u;
	z = (z ^ (z >> 27)) * 0x94d049bb133111ebu;
	return z ^ (z >> 31);
}

/* A standard Gaussian that depends only on (seed, plan index): a point
 * measured again, or after a resumption, gets the same noise. */
static double point_gaussian(uint64_t seed, uint64_t index)
{
	uint64_t st = seed * 0xd1342543de82ef95u + index;
	double u1 = ((double)(splitmix64(&st) >> 11) + 0.5) * 0x1p-53;
	double u2 = (double)(splitmix64(&st) >> 11) * 0x1p-53;
	return sqrt(-2 * log(u1)) * cos(2 * M_PI * u2);
}

int mock_part_probe_z(struct mock_part *p, double x, double y, uint64_t index, double *z)
{
	double c[3];

	if (p->nominal) {
		c[2] = asph_surface_is_rotational(p->surface)
			       ? asph_surface_sag(p->surface, sqrt(x * x + y * y))
			       : asph_surface_sag_xy(p->surface, x, y);
		if (!isfinite(c[2]))
			return -EDOM;
	} else if (solve_contact(p, x, y, c) < 0) {
		return -EDOM;
	}
	*z = c[2];
	if (p->noise_mm > 0)
		*z += p->noise_mm * point_gaussian(p->seed, index);
	return 0;
}

int mock_wait(atomic_bool *stop, double seconds, unsigned timeout_ms)
{
	double limit = timeout_ms / 1000.0, left = seconds < limit ? seconds : limit;
	bool timed_out = seconds > limit;

	if (atomic_load_explicit(stop, memory_order_relaxed))
		return -ECANCELED;
	while (left > 0) {
		double slice = left < 0.01 ? left : 0.01;
		sleep_ns((uint64_t)(slice * 1e9));
		left -= slice;
		if (atomic_load_explicit(stop, memory_order_relaxed))
			return -ECANCELED;
	}
	return timed_out ? -ETIMEDOUT : 0;
}

double mock_part_slope(const struct mock_part *p, double x, double y)
{
	double d[3];

	/* the nominal surface where the part lies: its slope changes with the
	 * tilt by far less than the bias this feeds */
	asph_surface_sag_derivs(p->surface, hypot(x - p->pose.t[0], y - p->pose.t[1]), d);
	return atan(fabs(d[1]));
}
