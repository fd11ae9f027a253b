/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Files opened so that nobody else can redirect them: relative to a
 * directory descriptor, never through a symlink, never out of that
 * directory; new files created exclusively or renamed into place; and a
 * path from "/" whose every step is checked to be in trusted hands, as
 * systemd checks a StateDirectory= (and stricter). Shared by asphd,
 * asphctl and the driver registry. Internal.
 */
#ifndef ASPH_UTIL_FS_H
#define ASPH_UTIL_FS_H

#include <stdbool.h>
#include <stdio.h>
#include <sys/stat.h>
#include <sys/types.h>

#include "asph/error.h"

/*
 * Opens path (relative, no "..") beneath dirfd without following any
 * symlink: openat2() with RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS |
 * RESOLVE_NO_MAGICLINKS, or where the kernel has no openat2() (before
 * Linux 5.6, or a system call filter without it) fs_open_beneath_walk().
 * O_CLOEXEC is added to flags. Returns the descriptor or -errno: -ELOOP
 * for a symlink on the way, -EXDEV for a path that would leave dirfd.
 */
int fs_open_beneath(int dirfd, const char *path, int flags, mode_t mode);
/* The same, one component at a time with O_NOFOLLOW. */
int fs_open_beneath_walk(int dirfd, const char *path, int flags, mode_t mode);

/* Creates the directory name (one component) in dirfd if missing and
 * opens it (a symlink in its place: -ELOOP; a file: -ENOTDIR). */
int fs_mkdir_beneath(int dirfd, const char *name, mode_t mode);

/*
 * Writes the file name (one component) in dirfd: fn writes f, a
 * temporary file that was created exclusively (O_EXCL | O_NOFOLLOW) in
 * dirfd with mode (the umask applies), which is then flushed, synced and
 * renamed over name (a symlink at name is replaced, never followed).
 * fn returns 0 or -errno with err set. On failure nothing is left behind.
 */
typedef int (*fs_write_fn)(FILE *f, void *data, struct asph_error *err);
int fs_write_file_at(int dirfd, const char *name, mode_t mode, fs_write_fn fn, void *data,
		     struct asph_error *err);

/* Whom a path may belong to besides root. */
struct fs_owners {
	uid_t uid;
	gid_t gid;              /* a directory may be writable by this group */
};

/*
 * Opens the absolute path after checking every step of it from "/": each
 * directory passed and each symlink followed belongs to root or to
 * owners->uid; no directory passed may be written by others or by a group
 * other than root's and owners->gid, unless it is sticky (such as /tmp);
 * and ownership never passes from a user to another (a directory of
 * owners->uid holding one of root's that it could replace). The last
 * component must belong to root or owners->uid as well; its mode is the
 * caller's to judge. Returns the descriptor (opened with flags, O_CLOEXEC
 * added) or -errno with err naming the step: -EPERM not trusted, -ENOENT,
 * -ENOTDIR, -ELOOP (more than 40 symlinks), -EINVAL (a relative path, "..").
 */
int fs_open_trusted(const char *path, const struct fs_owners *owners, int flags,
		    struct asph_error *err);

#endif
