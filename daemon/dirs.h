/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The daemon's directories: the state directory, the job folders in it and
 * the checks that keep other users from writing where the daemon does.
 * Each function logs why it refuses. Event loop thread.
 */
#ifndef ASPHD_DIRS_H
#define ASPHD_DIRS_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/stat.h>

/*
 * Refuses (-EPERM) a directory that a user other than the daemon's (and
 * root) can write: another owner, a group other than the daemon's, or
 * everyone; a sticky directory (such as /tmp) is accepted with sticky_ok.
 * st is dir's stat; what says in the log what was refused.
 */
int dirs_check_private(const char *dir, const struct stat *st, bool sticky_ok,
		       const char *what);

/* Creates the state directory if missing; refuses one that is not a
 * directory (-ENOTDIR), not private (-EPERM) or read-only (-EROFS). */
int dirs_make_state(const char *dir);

/* The folder of job id: "STATE_DIR/jobs/ID" (malloc'd), or NULL. */
char *dirs_job_path(const char *state_dir, int64_t id);

/* Creates the folder of job id (and jobs/ above it) if missing; a symlink
 * in place of either is refused (-ENOTDIR). Returns 0 or -errno. */
int dirs_make_job(const char *state_dir, int64_t id);

#endif
