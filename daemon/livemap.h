/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The web page's live map: the points a job's scan holds from the Nth on,
 * at most LIVEMAP_POINTS an answer, each with its deviation from the
 * nominal surface. Reading a scan of millions of points and building a
 * freeform surface take time: a task's thread does it (tasks.h), and the
 * loop keeps the surface of the job asked for last, for the next answer
 * (the page asks twice a second). Each function says which thread runs it.
 */
#ifndef ASPHD_LIVEMAP_H
#define ASPHD_LIVEMAP_H

#include <stdint.h>

#include "asph/surface.h"
#include "tasks.h"

/* The most points one answer carries (the page asks again). */
#define LIVEMAP_POINTS 20000

/* A job's nominal surface, kept while answers use it (loop). */
struct livemap_surface;
/* Loop: a reference to s (may be NULL), and its end. */
struct livemap_surface *livemap_surface_ref(struct livemap_surface *s);
void livemap_surface_unref(struct livemap_surface *s);
/* Loop: whether s is the surface of job (NULL: none kept). */
int64_t livemap_surface_job(const struct livemap_surface *s);

struct livemap_read {
	/* what to read */
	char *path;                     /* the job's scan */
	int64_t job, from;
	struct livemap_surface *surface; /* the job's, a reference; NULL: built here */
	/* what came of it */
	unsigned status;                /* HTTP: 200, 404 no scan yet, 409 unreadable */
	char *text;                     /* the answer's body: JSON */
	struct livemap_surface *built;  /* the surface made here (its job's), or NULL */
	char warning[256];              /* why the map has no nominal surface, or "" */
};

/* Loop: the read of job's scan at path from point from on; surface (a new
 * reference is taken) may be NULL. 0 or -ENOMEM. */
int livemap_read_new(const char *path, int64_t job, int64_t from,
		     struct livemap_surface *surface, struct livemap_read **out);
/* A task's run(): worker thread. Always 0 (the outcome is in status). */
int livemap_read_run(void *read, const struct task *task);
/* A task's free(): loop. */
void livemap_read_free(void *read);

#endif
