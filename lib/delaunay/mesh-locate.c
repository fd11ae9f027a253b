/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Point location in a triangle mesh by a remembering walk. */
#include <errno.h>
#include <math.h>

#include "asph/delaunay.h"

/* Barycentric coordinates of q in triangle t (counter-clockwise). */
static void barycentric(const double *xy, const uint32_t *v, const double q[2], double b[3])
{
	const double *p0 = xy + 2 * (size_t)v[0], *p1 = xy + 2 * (size_t)v[1];
	const double *p2 = xy + 2 * (size_t)v[2];
	double d = (p1[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (p1[1] - p0[1]);

	b[1] = ((q[0] - p0[0]) * (p2[1] - p0[1]) - (p2[0] - p0[0]) * (q[1] - p0[1])) / d;
	b[2] = ((p1[0] - p0[0]) * (q[1] - p0[1]) - (q[0] - p0[0]) * (p1[1] - p0[1])) / d;
	b[0] = 1.0 - b[1] - b[2];
}

/* The coordinate of the vertex opposite edge k (from vertex k to k + 1). */
static int opposite(int k)
{
	return (k + 2) % 3;
}

int asph_mesh_locate(const double *xy, const uint32_t *tri, const uint32_t *nb,
		     size_t ntri, uint32_t *t, const double q[2], double bary[3])
{
	uint32_t cur = *t < ntri ? *t : 0, from = UINT32_MAX;
	const double tol = -1e-12;

	/* A walk in a mesh that is not Delaunay may circle: it never steps
	 * back across the edge it came in by, starts its search of the edges
	 * at a different one each step, and gives up after ntri steps for a
	 * scan of every triangle. */
	for (size_t step = 0; step <= ntri; step++) {
		int moved = 0;
		barycentric(xy, tri + 3 * (size_t)cur, q, bary);
		for (int j = 0; j < 3 && !moved; j++) {
			int k = (int)((step + (size_t)j) % 3);
			uint32_t o = nb[3 * (size_t)cur + (size_t)k];
			if (!(bary[opposite(k)] < tol) || o == from)
				continue;
			if (o == UINT32_MAX) {
				*t = cur;
				return -ENOENT;
			}
			from = cur;
			cur = o;
			moved = 1;
		}
		if (!moved) {
			*t = cur;
			return 0;
		}
	}
	for (size_t c = 0; c < ntri; c++) {
		barycentric(xy, tri + 3 * c, q, bary);
		if (bary[0] >= tol && bary[1] >= tol && bary[2] >= tol) {
			*t = (uint32_t)c;
			return 0;
		}
	}
	return -ENOENT;
}
