/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The daemon's directories: the state directory, the job folders in it and
 * the checks that keep other users from writing where the daemon does.
 * The state directory is checked from "/" down (every directory on the way
 * in trusted hands, as systemd checks a StateDirectory=) and then only
 * used through its descriptor: a job folder is opened beneath it without
 * following symlinks (util-fs.h), and so is every file in a job folder.
 * What the daemon creates is private: folders 0750, files 0640, whatever
 * the umask. Each function logs why it refuses. Event loop thread.
 */
#ifndef ASPHD_DIRS_H
#define ASPHD_DIRS_H

#include <stdbool.h>
#include <stdint.h>
#include <sys/stat.h>

#include "asph/error.h"

/* The modes of what the daemon creates in its state directory. */
#define DIRS_DIR_MODE 0750
#define DIRS_FILE_MODE 0640

/*
 * Refuses (-EPERM) a directory that a user other than the daemon's (and
 * root) can write: another owner, a group other than the daemon's, or
 * everyone; a sticky directory (such as /tmp) is accepted with sticky_ok.
 * st is dir's stat; what says in the log what was refused.
 */
int dirs_check_private(const char *dir, const struct stat *st, bool sticky_ok,
		       const char *what);

/*
 * Opens the state directory, creating it (0750) when its parent exists and
 * is trusted. Refuses a path with a step in untrusted hands (-EPERM), one
 * that is not a directory (-ENOTDIR), not private (-EPERM) or read-only
 * (-EROFS). Others' access to it is taken away (mode & 0750) when the
 * daemon owns it. Returns the descriptor (O_DIRECTORY) or -errno.
 */
int dirs_open_state(const char *dir);

/* The directory of the socket at path: trusted from "/" and private
 * (sticky allowed); created 0755 if missing. 0 or -errno. */
int dirs_check_socket_dir(const char *socket_path);

/* The folder of job id: "STATE_DIR/jobs/ID" (malloc'd), or NULL. */
char *dirs_job_path(const char *state_dir, int64_t id);

/* Opens the folder of job id beneath the state directory, with create
 * making it (and jobs/ above it) if missing; a symlink in place of either
 * is refused (-ELOOP). Returns the descriptor or -errno. */
int dirs_open_job(int state_fd, int64_t id, bool create);

/*
 * The web page's files (http_root): the directory trusted from "/", not
 * writable by anyone but root and the daemon's user (its group's members
 * included), and each file in it a regular file of root or the daemon's
 * user that no one else may write: what the page's users run in their
 * browsers comes from nobody else. 0, or -EPERM / -errno with err saying
 * which and why.
 */
int dirs_check_page(const char *root, struct asph_error *err);

/* The highest id among the job folders in jobs/ (0: none), or -errno:
 * a job store put back from a backup may be older than the folders. */
int64_t dirs_last_job(int state_fd);

/* MiB free for the daemon on the file system of fd; 0 or -errno. */
int dirs_free_mb(int fd, uint64_t *mb);

#endif
