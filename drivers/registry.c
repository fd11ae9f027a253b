/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The driver registry: built-in drivers and plugins loaded with dlopen. */
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "asph-driver/instrument.h"
#include "builtin-drivers.h"
#include "drivers-config.h"
#include "options-internal.h"
#include "util-fs.h"
#include "util-mem.h"
#include "util-suggest.h"

struct registry_entry {
	const struct asph_driver *driver;
	char *origin;           /* NULL for built-in */
};

struct asph_registry {
	size_t n, cap;
	struct registry_entry *entries;
	size_t n_handles;
	void **handles;         /* dlopen handles, closed on free */
};

static bool valid_name(const char *name)
{
	if (!name || !*name || strlen(name) > 48)
		return false;
	for (const char *c = name; *c; c++)
		if (!((*c >= 'a' && *c <= 'z') || (*c >= '0' && *c <= '9') ||
		      *c == '_' || *c == '-'))
			return false;
	return true;
}

static int validate_ops(const struct asph_driver *d, struct asph_error *err)
{
	const struct asph_stage_ops *s = d->stage;
	const struct asph_probe_ops *p = d->probe;

	if (d->roles & ASPH_ROLE_STAGE) {
		if (!s || !s->open || !s->close || !s->info || !s->home ||
		    !s->move_to || !s->position || !s->status || !s->stop)
			return asph_error_set(err, -EINVAL,
					      "driver '%s': stage operations missing", d->name);
	}
	if (d->roles & ASPH_ROLE_PROBE) {
		if (!p || !p->open || !p->close || !p->info || !p->read || !p->stop)
			return asph_error_set(err, -EINVAL,
					      "driver '%s': probe operations missing", d->name);
	}
	return 0;
}

/* Whether a driver of ABI version v can be loaded: the same major
 * version, a minor version up to ours. */
static bool abi_loadable(uint32_t v)
{
	return ASPH_DRIVER_ABI_MAJOR_OF(v) == ASPH_DRIVER_ABI_MAJOR &&
	       ASPH_DRIVER_ABI_MINOR_OF(v) <= ASPH_DRIVER_ABI_MINOR;
}

int asph_driver_validate(const struct asph_driver *d, struct asph_error *err)
{
	if (!d)
		return asph_error_set(err, -EINVAL, "driver table has a NULL entry");
	if (!abi_loadable(d->abi_version))
		return asph_error_set(err, -EPROTO,
				      "driver built for driver ABI %u.%u, this program has ABI %u.%u",
				      ASPH_DRIVER_ABI_MAJOR_OF(d->abi_version),
				      ASPH_DRIVER_ABI_MINOR_OF(d->abi_version),
				      ASPH_DRIVER_ABI_MAJOR, ASPH_DRIVER_ABI_MINOR);
	if (!valid_name(d->name))
		return asph_error_set(err, -EINVAL,
				      "driver name '%s' is not valid ([a-z0-9_-]+)",
				      d->name ? d->name : "(null)");
	if (!(d->roles & (ASPH_ROLE_STAGE | ASPH_ROLE_PROBE)) ||
	    (d->roles & ~(unsigned)(ASPH_ROLE_STAGE | ASPH_ROLE_PROBE)))
		return asph_error_set(err, -EINVAL, "driver '%s': roles not valid", d->name);
	int r = validate_ops(d, err);
	if (r < 0)
		return r;
	if (d->n_options && !d->options)
		return asph_error_set(err, -EINVAL, "driver '%s': options missing", d->name);
	for (size_t i = 0; i < d->n_options; i++) {
		r = option_desc_validate(&d->options[i], err);
		if (r < 0) {
			char msg[sizeof(err->message)];
			if (!err)
				return r;
			snprintf(msg, sizeof(msg), "%s", err->message);
			return asph_error_set(err, r, "driver '%s': %s", d->name, msg);
		}
		for (size_t j = 0; j < i; j++)
			if (!strcmp(d->options[i].name, d->options[j].name))
				return asph_error_set(err, -EINVAL,
						      "driver '%s': option '%s' declared twice",
						      d->name, d->options[i].name);
	}
	return 0;
}

static int add_entry(struct asph_registry *r, const struct asph_driver *d,
		     const char *origin, struct asph_error *err)
{
	int ret = asph_driver_validate(d, err);
	if (ret < 0)
		return ret;
	if (asph_registry_find(r, d->name))
		return asph_error_set(err, -EEXIST, "driver '%s' is already registered",
				      d->name);
	if (r->n == r->cap) {
		size_t cap = r->cap ? 2 * r->cap : 8;
		struct registry_entry *e = realloc(r->entries, cap * sizeof(*e));
		if (!e)
			return asph_error_set(err, -ENOMEM, "out of memory");
		r->entries = e;
		r->cap = cap;
	}
	char *o = NULL;
	if (origin && !(o = strdup(origin)))
		return asph_error_set(err, -ENOMEM, "out of memory");
	r->entries[r->n++] = (struct registry_entry){ d, o };
	return 0;
}

int asph_registry_new(struct asph_registry **out, struct asph_error *err)
{
	struct asph_registry *r = calloc(1, sizeof(*r));

	if (!r)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t i = 0; i < builtin_drivers_count; i++) {
		int ret = add_entry(r, builtin_drivers[i], NULL, err);
		if (ret < 0) {
			asph_registry_free(r);
			return ret;
		}
	}
	*out = r;
	return 0;
}

void asph_registry_free(struct asph_registry *r)
{
	if (!r)
		return;
	for (size_t i = 0; i < r->n; i++)
		free(r->entries[i].origin);
	free(r->entries);
	for (size_t i = 0; i < r->n_handles; i++)
		dlclose(r->handles[i]);
	free(r->handles);
	free(r);
}

static int keep_handle(struct asph_registry *r, void *h, struct asph_error *err)
{
	void **hs = realloc(r->handles, (r->n_handles + 1) * sizeof(*hs));

	if (!hs)
		return asph_error_set(err, -ENOMEM, "out of memory");
	r->handles = hs;
	r->handles[r->n_handles++] = h;
	return 0;
}

static int load_table(struct asph_registry *r, void *h, const char *path,
		      struct asph_error *err)
{
	asph_driver_plugin_fn fn;
	uint32_t abi = 0;
	size_t n = 0, first = r->n;

	*(void **)&fn = dlsym(h, ASPH_DRIVER_PLUGIN_SYMBOL);
	if (!fn)
		return asph_error_set(err, -ENOEXEC, "not a driver plugin: no symbol %s",
				      ASPH_DRIVER_PLUGIN_SYMBOL);
	const struct asph_driver *const *table = fn(&abi, &n);
	if (!abi_loadable(abi))
		return asph_error_set(err, -EPROTO,
				      "plugin built for driver ABI %u.%u, this program has ABI %u.%u: rebuild it against this version's asph-driver/driver.h",
				      ASPH_DRIVER_ABI_MAJOR_OF(abi), ASPH_DRIVER_ABI_MINOR_OF(abi),
				      ASPH_DRIVER_ABI_MAJOR, ASPH_DRIVER_ABI_MINOR);
	if (!table || n == 0)
		return asph_error_set(err, -EINVAL, "plugin has no drivers");
	for (size_t i = 0; i < n; i++) {
		int ret = add_entry(r, table[i], path, err);
		if (ret < 0) {
			while (r->n > first)
				free(r->entries[--r->n].origin);
			return ret;
		}
	}
	return 0;
}

/*
 * A plugin runs as the program that loads it (root, under
 * --check-config too): before dlopen() it must be a regular file of root
 * or of the user running this, writable by nobody else, in directories
 * trusted the same way from / (fs_open_trusted()). Returns the opened
 * file's descriptor, or -EPERM/-errno with err saying why.
 */
static int open_trusted_plugin(const char *path, struct asph_error *err)
{
	struct fs_owners owners = { .uid = geteuid(), .gid = getegid() };
	_cleanup_free_ char *abs = NULL;
	_cleanup_close_ int fd = -1;
	char cwd[PATH_MAX];
	struct stat st;

	if (path[0] != '/') {
		if (!getcwd(cwd, sizeof(cwd)) || asprintf(&abs, "%s/%s", cwd, path) < 0)
			return asph_error_set(err, -ENOMEM, "cannot make the path absolute");
		path = abs;
	}
	fd = fs_open_trusted(path, &owners, O_RDONLY, err);
	if (fd < 0)
		return fd;
	if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode))
		return asph_error_set(err, -ENOEXEC, "not a regular file");
	if (st.st_mode & (S_IWGRP | S_IWOTH))
		return asph_error_set(err, -EPERM, "writable by %s (mode %04o): not loaded",
				      st.st_mode & S_IWOTH ? "every user" : "its group",
				      (unsigned)(st.st_mode & 07777));
	return steal_fd(fd);
}

int asph_registry_load_plugin(struct asph_registry *r, const char *path,
			      struct asph_error *err)
{
	_cleanup_close_ int fd = open_trusted_plugin(path, err);
	void *h = NULL;
	int ret = fd;

	if (fd >= 0) {
		/* By its path (a name such as /proc/self/fd/N would be taken
		 * for another plugin once the number is used again): only the
		 * owners checked above can change what it names. */
		h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
		if (!h) {
			const char *why = dlerror();
			ret = asph_error_set(err, -ENOEXEC, "cannot load: %s",
					     why ? why : "dlopen failed");
		} else {
			ret = load_table(r, h, path, err);
			if (ret == 0)
				ret = keep_handle(r, h, err);
			if (ret < 0)
				dlclose(h);
		}
	}
	if (ret < 0)
		asph_error_locate(err, path, 0, 0, NULL);
	return ret < 0 ? ret : 0;
}

static int by_name(const struct dirent **a, const struct dirent **b)
{
	return strcmp((*a)->d_name, (*b)->d_name);
}

static int is_plugin_name(const struct dirent *e)
{
	size_t n = strlen(e->d_name);
	return e->d_name[0] != '.' && n > 3 && !strcmp(e->d_name + n - 3, ".so");
}

int asph_registry_load_dir(struct asph_registry *r, const char *dir,
			   asph_registry_warn_fn warn, void *data,
			   struct asph_error *err)
{
	struct dirent **list = NULL;
	int n = scandir(dir, &list, is_plugin_name, by_name), loaded = 0;

	if (n < 0) {
		if (errno == ENOENT)
			return 0;
		int e = -errno;
		return asph_error_set_at(err, e, dir, 0, 0, NULL,
					 "cannot read plugin directory: %s", strerror(-e));
	}
	for (int i = 0; i < n; i++) {
		_cleanup_free_ char *path = NULL;
		struct asph_error perr;

		asph_error_clear(&perr);
		if (asprintf(&path, "%s/%s", dir, list[i]->d_name) < 0)
			path = NULL;
		if (path && asph_registry_load_plugin(r, path, &perr) == 0)
			loaded++;
		else if (warn)
			warn(&perr, data);
		free(list[i]);
	}
	free(list);
	return loaded;
}

int asph_registry_load_default_dirs(struct asph_registry *r,
				    asph_registry_warn_fn warn, void *data,
				    struct asph_error *err)
{
	const char *env = getenv("ASPH_DRIVER_PATH");
	int total = 0;

	if (!env)
		return asph_registry_load_dir(r, ASPH_PLUGIN_DIR, warn, data, err);
	_cleanup_free_ char *copy = strdup(env);
	if (!copy)
		return asph_error_set(err, -ENOMEM, "out of memory");
	char *save = NULL;
	for (char *d = strtok_r(copy, ":", &save); d; d = strtok_r(NULL, ":", &save)) {
		int n = asph_registry_load_dir(r, d, warn, data, err);
		if (n < 0)
			return n;
		total += n;
	}
	return total;
}

size_t asph_registry_count(const struct asph_registry *r)
{
	return r->n;
}

const struct asph_driver *asph_registry_get(const struct asph_registry *r,
					    size_t i)
{
	return i < r->n ? r->entries[i].driver : NULL;
}

const char *asph_registry_origin(const struct asph_registry *r, size_t i)
{
	if (i >= r->n)
		return NULL;
	return r->entries[i].origin ? r->entries[i].origin : "built-in";
}

int asph_registry_profiles(const struct asph_registry *r, size_t i,
			   struct asph_driver_profile **out, size_t *n,
			   struct asph_error *err)
{
	*out = NULL;
	*n = 0;
	if (i >= r->n)
		return asph_error_set(err, -EINVAL, "no driver %zu in the registry", i);
	/* a plugin's table is its own: only built-in drivers list files */
	for (size_t k = 0; !r->entries[i].origin && k < builtin_profile_lists_count; k++)
		if (builtin_profile_lists[k].driver == r->entries[i].driver)
			return builtin_profile_lists[k].list(out, n, err);
	return 0;
}

const struct asph_driver *asph_registry_find(const struct asph_registry *r,
					     const char *name)
{
	for (size_t i = 0; i < r->n; i++)
		if (!strcmp(r->entries[i].driver->name, name))
			return r->entries[i].driver;
	return NULL;
}

const char *driver_hint(const struct asph_registry *reg, const char *name, char *buf,
			size_t size)
{
	struct suggest s;

	suggest_init(&s, name);
	for (size_t i = 0; i < asph_registry_count(reg); i++)
		suggest_offer(&s, asph_registry_get(reg, i)->name);
	return suggest_hint(&s, buf, size);
}

const char *asph_option_type_name(enum asph_option_type t)
{
	switch (t) {
	case ASPH_OPTION_BOOL: return "bool";
	case ASPH_OPTION_INT: return "int";
	case ASPH_OPTION_DOUBLE: return "double";
	case ASPH_OPTION_STRING: return "string";
	case ASPH_OPTION_ENUM: return "enum";
	}
	return "unknown";
}

const char *asph_kinematics_name(enum asph_kinematics k)
{
	return k == ASPH_KINEMATICS_RTZ ? "r-theta-z" : "xyz";
}

const char *asph_probe_type_name(enum asph_probe_type t)
{
	return t == ASPH_PROBE_OPTICAL ? "optical" : "tactile";
}
