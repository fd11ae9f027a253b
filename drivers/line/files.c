/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Line profile files: finding one by name, listing them all. */
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "drivers-config.h"
#include "fileio.h"
#include "files.h"
#include "util-mem.h"

#define SUFFIX ".profile"
#define MAX_DIRS 16

/* The directories searched, in order, as pointers into buf. */
static size_t search_dirs(char *buf, size_t size, const char *dirs[MAX_DIRS])
{
	const char *env = getenv("ASPH_LINE_PROFILE_PATH");
	size_t n = 0;

	snprintf(buf, size, "%s%s" ASPH_LINE_PROFILE_ETC_DIR ":" ASPH_LINE_PROFILE_DIR,
		 env ? env : "", env && *env ? ":" : "");
	char *save = NULL;
	for (char *d = strtok_r(buf, ":", &save); d && n < MAX_DIRS; d = strtok_r(NULL, ":", &save))
		dirs[n++] = d;
	return n;
}

static int load_file(const char *path, struct line_profile *p, struct asph_error *err)
{
	_cleanup_free_ char *text = NULL;
	size_t len = 0;
	int r = file_read_all(path, 1u << 20, &text, &len, err);

	return r < 0 ? r : line_profile_parse(text, len, path, p, err);
}

int line_profile_load(const char *name, struct line_profile *p, struct asph_error *err)
{
	char buf[4096], path[PATH_MAX], searched[1024] = "";
	const char *dirs[MAX_DIRS];

	if (strchr(name, '/'))
		return load_file(name, p, err);
	if (!*name || strlen(name) > 64)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "profile",
					 "profile: give a profile name or a file's path");
	size_t n = search_dirs(buf, sizeof(buf), dirs);
	for (size_t i = 0; i < n; i++) {
		snprintf(path, sizeof(path), "%s/%s" SUFFIX, dirs[i], name);
		if (access(path, F_OK) == 0)
			return load_file(path, p, err);
		size_t used = strlen(searched);
		snprintf(searched + used, sizeof(searched) - used, "%s%s", i ? ", " : "", dirs[i]);
	}
	return asph_error_set_at(err, -ENOENT, NULL, 0, 0, "profile",
				 "no line profile '%s' (looked in %s; asph drivers lists those found)",
				 name, searched);
}

/* ------------------------------------------------------------ listing */

struct listing {
	struct asph_driver_profile *v;
	size_t n, cap;
};

static bool listed(const struct listing *l, const char *name)
{
	for (size_t i = 0; i < l->n; i++)
		if (!strcmp(l->v[i].name, name))
			return true;
	return false;
}

static int add_entry(struct listing *l, const char *name, const char *path)
{
	struct line_profile p;
	struct asph_error e;

	if (l->n == l->cap) {
		size_t cap = l->cap ? 2 * l->cap : 16;
		struct asph_driver_profile *v = realloc(l->v, cap * sizeof(*v));
		if (!v)
			return -ENOMEM;
		l->v = v;
		l->cap = cap;
	}
	struct asph_driver_profile *dp = &l->v[l->n++];
	memset(dp, 0, sizeof(*dp));
	snprintf(dp->name, sizeof(dp->name), "%s", name);
	snprintf(dp->path, sizeof(dp->path), "%s", path);
	asph_error_clear(&e);
	if (load_file(path, &p, &e) < 0) {
		asph_error_format(&e, dp->error, sizeof(dp->error));
		return 0;
	}
	dp->roles = (p.roles & LINE_ROLE_STAGE ? ASPH_ROLE_STAGE : 0) |
		    (p.roles & LINE_ROLE_PROBE ? ASPH_ROLE_PROBE : 0);
	snprintf(dp->description, sizeof(dp->description), "%s", p.description);
	snprintf(dp->reference, sizeof(dp->reference), "%s", p.reference);
	return 0;
}

/* The *.profile files of dir whose names an earlier directory did not
 * take; a directory that is not there holds none. */
static int list_dir(struct listing *l, const char *dir)
{
	DIR *d = opendir(dir);
	char path[PATH_MAX];
	int r = 0;

	if (!d)
		return 0;
	for (struct dirent *de; r == 0 && (de = readdir(d));) {
		size_t len = strlen(de->d_name);
		if (len <= strlen(SUFFIX) || len - strlen(SUFFIX) >= sizeof(l->v->name) ||
		    strcmp(de->d_name + len - strlen(SUFFIX), SUFFIX))
			continue;
		char name[sizeof(l->v->name)];
		snprintf(name, sizeof(name), "%.*s", (int)(len - strlen(SUFFIX)), de->d_name);
		snprintf(path, sizeof(path), "%s/%s", dir, de->d_name);
		if (!listed(l, name))
			r = add_entry(l, name, path);
	}
	closedir(d);
	return r;
}

static int by_name(const void *a, const void *b)
{
	return strcmp(((const struct asph_driver_profile *)a)->name,
		      ((const struct asph_driver_profile *)b)->name);
}

int line_profiles_list(struct asph_driver_profile **out, size_t *n, struct asph_error *err)
{
	char buf[4096];
	const char *dirs[MAX_DIRS];
	struct listing l = { 0 };
	size_t nd = search_dirs(buf, sizeof(buf), dirs);

	for (size_t i = 0; i < nd; i++) {
		if (list_dir(&l, dirs[i]) < 0) {
			free(l.v);
			return asph_error_set(err, -ENOMEM, "out of memory");
		}
	}
	if (l.n)
		qsort(l.v, l.n, sizeof(*l.v), by_name);
	*out = l.v;
	*n = l.n;
	return 0;
}
