/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Where a measured point lies on the fitted surface: its foot, and the
 * foot in polar coordinates over the aperture's disk, which the residual's
 * statistics and the form's map both use. */
#include <math.h>

#include "asph/fit.h"
#include "fit-internal.h"

/* A profile is fitted in its trace's frame: back to the part's. */
void fit_frame_to_part(const struct asph_fit *w, double xy[2])
{
	double x = xy[0];

	if (!w->traces.single)
		return;
	xy[0] = w->traces.ca * x - w->traces.sa * xy[1];
	xy[1] = w->traces.sa * x + w->traces.ca * xy[1];
}

void fit_point_foot(const struct asph_fit *w, size_t i, double xy[2])
{
	struct asph_pose pose = {
		{ w->full[0], w->full[1], w->full[2] },
		w->full[ASPH_FIT_RX], w->full[ASPH_FIT_RY], w->full[ASPH_FIT_RZ],
	};
	double q[3], r = w->r_foot[i], rq;

	if (!w->model.rotational) {
		xy[0] = w->foot[i].x;
		xy[1] = w->foot[i].y;
		return;
	}
	asph_pose_apply_inverse(&pose, w->xyz + 3 * i, q);
	rq = hypot(q[0], q[1]);
	/* on q's meridian, across the axis when r < 0 */
	double t = w->opt.residual == ASPH_FIT_RESIDUAL_SAG || !(rq > 0) ? 1.0 : r / rq;
	xy[0] = t * q[0];
	xy[1] = t * q[1];
	fit_frame_to_part(w, xy);
}

void fit_point_polar(const struct asph_fit *w, size_t i, double *rho,
		     double *theta)
{
	struct asph_pose pose = {
		{ w->full[0], w->full[1], w->full[2] },
		w->full[ASPH_FIT_RX], w->full[ASPH_FIT_RY], w->full[ASPH_FIT_RZ],
	};
	double q[3], r = w->r_foot[i], rq, xy[2], c[2], R;

	if (!w->model.centred) {
		/* the foot (or the point, for sag residuals) over the disk
		 * about the aperture's centre */
		fit_point_foot(w, i, xy);
		asph_surface_aperture_disk(w->model.s, c, &R);
		*rho = hypot(xy[0] - c[0], xy[1] - c[1]) / R;
		*theta = atan2(xy[1] - c[1], xy[0] - c[0]);
		return;
	}
	asph_pose_apply_inverse(&pose, w->xyz + 3 * i, q);
	rq = hypot(q[0], q[1]);
	fit_frame_to_part(w, q);
	if (w->opt.residual == ASPH_FIT_RESIDUAL_SAG || !(rq > 0)) {
		*rho = rq / w->model.a;
		*theta = atan2(q[1], q[0]);
		return;
	}
	/* The foot lies on q's meridian, across the axis when r < 0. */
	*rho = fabs(r) / w->model.a;
	*theta = atan2(r * q[1] / rq, r * q[0] / rq);
}
