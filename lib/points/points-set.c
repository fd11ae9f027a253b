/* SPDX-License-Identifier: GPL-3.0-or-later */
/* A point set's storage: its points, a value per point, and freeing it;
 * below the readers and writers of every format. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>

#include "asph/points.h"
#include "readers.h"
#include "util-mem.h"

struct asph_points *asph_points_alloc(size_t n)
{
	struct asph_points *p = calloc(1, sizeof(*p));

	if (!p || n > POINTS_MAX) {
		free(p);
		return NULL;
	}
	p->n = n;
	p->xyz = calloc(n ? 3 * n : 1, sizeof(double));
	if (!p->xyz) {
		free(p);
		return NULL;
	}
	mem_advise_huge(p->xyz, 3 * n * sizeof(double));
	return p;
}

int asph_points_add_value(struct asph_points *p, const char *name)
{
	free(p->value);
	p->value = calloc(p->n ? p->n : 1, sizeof(double));
	if (!p->value)
		return -ENOMEM;
	mem_advise_huge(p->value, p->n * sizeof(double));
	snprintf(p->value_name, sizeof(p->value_name), "%s", name);
	return 0;
}

void asph_points_free(struct asph_points *p)
{
	if (!p)
		return;
	free(p->xyz);
	free(p->value);
	free(p->triangles);
	free(p);
}
