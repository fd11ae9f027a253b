/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Line profile files: finding one by name, listing them all. */
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "drivers-config.h"
#include "fileio.h"
#include "files.h"
#include "util-mem.h"

#define SUFFIX ".profile"
#define MAX_DIRS 16
#define ENV_PATH "ASPH_LINE_PROFILE_PATH"

/* A directory searched before the built-in profiles. One the user named
 * in $ASPH_LINE_PROFILE_PATH must be there; the lab's may be absent. */
struct profile_dir {
	const char *path;
	bool named;             /* in $ASPH_LINE_PROFILE_PATH */
};

/* The directories searched, in order, as pointers into buf. */
static size_t search_dirs(char *buf, size_t size, struct profile_dir dirs[MAX_DIRS])
{
	const char *env = getenv(ENV_PATH);
	char *save = NULL;
	size_t n = 0;

	snprintf(buf, size, "%s", env ? env : "");
	for (char *d = strtok_r(buf, ":", &save); d && n < MAX_DIRS - 1; d = strtok_r(NULL, ":", &save))
		dirs[n++] = (struct profile_dir){ d, true };
	dirs[n++] = (struct profile_dir){ ASPH_LINE_PROFILE_ETC_DIR, false };
	return n;
}

/* 1 when dir can be searched, 0 when the lab's directory is absent (it
 * holds none then), or an error that names the directory and what to
 * change. */
static int check_dir(const struct profile_dir *dir, struct asph_error *err)
{
	struct stat st;
	int r = 0;

	if (stat(dir->path, &st) < 0)
		r = -errno;
	else if (!S_ISDIR(st.st_mode))
		r = -ENOTDIR;
	else if (access(dir->path, R_OK | X_OK) < 0)
		r = -errno;
	if (r == 0)
		return 1;
	if (r == -ENOENT && !dir->named)
		return 0;
	if (dir->named)
		return asph_error_set_at(err, r, NULL, 0, 0, "profile",
					 "%s names %s: %s (set it to directories of profile files, or "
					 "unset it for the lab's and the built-in profiles)",
					 ENV_PATH, dir->path, strerror(-r));
	return asph_error_set_at(err, r, NULL, 0, 0, "profile",
				 "%s: %s (the lab's profile directory: make it a directory this user "
				 "can read, or remove it)", dir->path, strerror(-r));
}

static int load_file(const char *path, struct line_profile *p, struct asph_error *err)
{
	_cleanup_free_ char *text = NULL;
	size_t len = 0;
	int r = file_read_all(path, 1u << 20, &text, &len, err);

	return r < 0 ? r : line_profile_parse(text, len, path, p, err);
}

/* NAME when file is NAME.profile and NAME fits an entry, else false. */
static bool profile_name(const char *file, char name[64])
{
	size_t len = strlen(file);

	if (len <= strlen(SUFFIX) || len - strlen(SUFFIX) >= 64 ||
	    strcmp(file + len - strlen(SUFFIX), SUFFIX))
		return false;
	snprintf(name, 64, "%.*s", (int)(len - strlen(SUFFIX)), file);
	return true;
}

/* "a, b, c": the built-in profiles' names, in buf. */
static const char *builtin_names(char *buf, size_t size)
{
	char name[64];
	size_t used = 0;

	buf[0] = '\0';
	for (size_t i = 0; i < line_builtin_profiles_count && used < size; i++)
		if (profile_name(line_builtin_profiles[i].name, name))
			used += snprintf(buf + used, size - used, "%s%s", used ? ", " : "", name);
	return buf;
}

/* The built-in profile NAME.profile, or NULL. */
static const struct embedded_file *builtin(const char *name)
{
	char file[128];

	snprintf(file, sizeof(file), "%s" SUFFIX, name);
	return embedded_file_find(line_builtin_profiles, line_builtin_profiles_count, file);
}

static int load_builtin(const struct embedded_file *f, struct line_profile *p,
			struct asph_error *err)
{
	char source[160];

	snprintf(source, sizeof(source), "%s (built in)", f->name);
	return line_profile_parse((const char *)f->data, f->size, source, p, err);
}


int line_profile_load(const char *name, struct line_profile *p, struct asph_error *err)
{
	char buf[4096], path[PATH_MAX], searched[1024] = "", names[512];
	struct profile_dir dirs[MAX_DIRS];

	if (strchr(name, '/'))
		return load_file(name, p, err);
	if (!*name || strlen(name) > 64)
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "profile",
					 "profile: give a profile name or a file's path");
	size_t n = search_dirs(buf, sizeof(buf), dirs);
	for (size_t i = 0; i < n; i++) {
		int r = check_dir(&dirs[i], err);
		if (r < 0)
			return r;
		if (r == 0)
			continue;
		snprintf(path, sizeof(path), "%s/%s" SUFFIX, dirs[i].path, name);
		if (access(path, F_OK) == 0)
			return load_file(path, p, err);
		size_t used = strlen(searched);
		snprintf(searched + used, sizeof(searched) - used, "%s%s", used ? ", " : "none in ",
			 dirs[i].path);
	}
	const struct embedded_file *f = builtin(name);
	if (f)
		return load_builtin(f, p, err);
	return asph_error_set_at(err, -ENOENT, NULL, 0, 0, "profile",
				 "no line profile '%s' (%s%sbuilt in: %s; a lab's own go in %s; asph "
				 "drivers lists those found)", name, searched, *searched ? "; " : "",
				 builtin_names(names, sizeof(names)), ASPH_LINE_PROFILE_ETC_DIR);
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

/* An entry for name, loaded from the file at path, or from f when f is
 * not NULL (a built-in profile, whose path is "built-in"). */
static int add_entry(struct listing *l, const char *name, const char *path,
		     const struct embedded_file *f)
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
	snprintf(dp->path, sizeof(dp->path), "%s", f ? "built-in" : path);
	asph_error_clear(&e);
	if ((f ? load_builtin(f, &p, &e) : load_file(path, &p, &e)) < 0) {
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
 * take. */
static int list_dir(struct listing *l, const char *dir)
{
	DIR *d = opendir(dir);
	char path[PATH_MAX], name[64];
	int r = 0;

	if (!d)
		return -errno;
	for (struct dirent *de; r == 0 && (de = readdir(d));) {
		if (!profile_name(de->d_name, name) || listed(l, name))
			continue;
		snprintf(path, sizeof(path), "%s/%s", dir, de->d_name);
		r = add_entry(l, name, path, NULL);
	}
	closedir(d);
	return r;
}

static int by_name(const void *a, const void *b)
{
	return strcmp(((const struct asph_driver_profile *)a)->name,
		      ((const struct asph_driver_profile *)b)->name);
}

/* The directories' profiles, then the built-in ones no directory
 * replaces. */
static int list_all(struct listing *l, struct asph_error *err)
{
	char buf[4096], name[64];
	struct profile_dir dirs[MAX_DIRS];
	size_t nd = search_dirs(buf, sizeof(buf), dirs);
	int r;

	for (size_t i = 0; i < nd; i++) {
		r = check_dir(&dirs[i], err);
		if (r > 0 && (r = list_dir(l, dirs[i].path)) < 0)
			return asph_error_set(err, r, "%s: %s", dirs[i].path, strerror(-r));
		if (r < 0)
			return r;
	}
	for (size_t i = 0; i < line_builtin_profiles_count; i++) {
		const struct embedded_file *f = &line_builtin_profiles[i];
		if (profile_name(f->name, name) && !listed(l, name) &&
		    (r = add_entry(l, name, NULL, f)) < 0)
			return asph_error_set(err, r, "out of memory");
	}
	return 0;
}

int line_profiles_list(struct asph_driver_profile **out, size_t *n, struct asph_error *err)
{
	struct listing l = { 0 };
	int r = list_all(&l, err);

	if (r < 0) {
		free(l.v);
		return r;
	}
	if (l.n)
		qsort(l.v, l.n, sizeof(*l.v), by_name);
	*out = l.v;
	*n = l.n;
	return 0;
}
