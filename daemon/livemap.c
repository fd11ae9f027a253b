/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The live map's points, read on a task's thread (livemap.h). */
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jansson.h>

#include "asph/prescription.h"
#include "asph/scanfile.h"
#include "livemap.h"
#include "util-mem.h"

struct livemap_surface {
	int64_t job;
	struct asph_surface *s;         /* NULL: the job's scan gives none */
	unsigned refs;
};

struct livemap_surface *livemap_surface_ref(struct livemap_surface *s)
{
	if (s)
		s->refs++;
	return s;
}

void livemap_surface_unref(struct livemap_surface *s)
{
	if (!s || --s->refs)
		return;
	asph_surface_free(s->s);
	free(s);
}

int64_t livemap_surface_job(const struct livemap_surface *s)
{
	return s ? s->job : 0;
}

int livemap_read_new(const char *path, int64_t job, int64_t from,
		     struct livemap_surface *surface, struct livemap_read **out)
{
	struct livemap_read *r = calloc(1, sizeof(*r));

	if (!r || !(r->path = strdup(path))) {
		free(r);
		return -ENOMEM;
	}
	r->job = job;
	r->from = from;
	r->surface = livemap_surface_ref(surface);
	*out = r;
	return 0;
}

void livemap_read_free(void *data)
{
	struct livemap_read *r = data;

	if (!r)
		return;
	livemap_surface_unref(r->surface);
	livemap_surface_unref(r->built);
	free(r->path);
	free(r->text);
	free(r);
}

/* The nominal surface of the job, from its scan's header (the prescription
 * the job measures): kept in r->built, NULL with a warning when it does not
 * build. */
static void build_surface(struct livemap_read *r, const struct asph_scanfile_header *h)
{
	struct asph_prescription pr;
	struct asph_error err;

	r->built = calloc(1, sizeof(*r->built));
	if (!r->built)
		return;
	r->built->job = r->job;
	r->built->refs = 1;
	asph_error_clear(&err);
	if (!h->prescription ||
	    asph_prescription_parse(h->prescription, strlen(h->prescription), "the scan's header",
				    &pr, &err) < 0 ||
	    asph_surface_alloc(&pr, &r->built->s, &err) < 0)
		snprintf(r->warning, sizeof(r->warning), "the live map has no nominal surface: %.200s",
			 err.message[0] ? err.message : "the scan names no prescription");
}

static json_t *number_or_null(double v)
{
	return isfinite(v) ? json_real(v) : json_null();
}

/* One point: x, y (mm), the probe's reading, and the measured z minus the
 * nominal sag at the measured (x, y), in mm: null for a point that is no
 * measurement, or off the surface (past a conic's root). */
static json_t *live_point(const struct asph_scanfile_point *p, const struct asph_surface *s)
{
	double dz = NAN;

	if (s && !(p->flags & ASPH_SCANFILE_NOT_MEASURED))
		dz = p->z - asph_surface_sag_xy(s, p->x, p->y);
	return json_pack("[o,o,o,o]", number_or_null(p->x), number_or_null(p->y),
			 number_or_null(p->raw), number_or_null(dz));
}

static void answer(struct livemap_read *r, unsigned status, json_t *v)
{
	r->status = status;
	r->text = v ? json_dumps(v, JSON_COMPACT) : NULL;
	json_decref(v);
}

int livemap_read_run(void *data, const struct task *task)
{
	struct livemap_read *r = data;
	struct asph_scanfile_reader *rd = NULL;
	const struct asph_scanfile_point *p;
	const struct asph_surface *s;
	_cleanup_(json_decrefp) json_t *pts = json_array();
	struct asph_error err;
	int64_t index = 0;
	size_t n;
	int rc;

	asph_error_clear(&err);
	rc = asph_scanfile_reader_open(r->path, &rd, &err);
	if (rc < 0) {
		char why[300];
		if (rc == -ENOENT)
			snprintf(why, sizeof(why), "job %" PRId64 " has no scan (yet)", r->job);
		else
			snprintf(why, sizeof(why), "%.280s", err.message);
		answer(r, rc == -ENOENT ? 404 : 409, json_pack("{s:s}", "error", why));
		return 0;
	}
	if (!r->surface)
		build_surface(r, asph_scanfile_reader_header(rd));
	s = r->surface ? r->surface->s : r->built ? r->built->s : NULL;
	/* The sag only for the points sent: at most LIVEMAP_POINTS of them. */
	while (pts && json_array_size(pts) < LIVEMAP_POINTS && !task_cancelled(task) &&
	       asph_scanfile_reader_next(rd, &p, &n, &err) > 0)
		for (size_t i = 0; i < n && json_array_size(pts) < LIVEMAP_POINTS; i++, index++)
			if (index >= r->from && json_array_append_new(pts, live_point(&p[i], s)) < 0)
				break;
	asph_scanfile_reader_free(rd);
	answer(r, 200, pts ? json_pack("{s:I, s:O}", "from", (json_int_t)r->from, "points", pts)
			   : NULL);
	return 0;
}
