/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The safe file helpers (lib/util/util-fs.c) against planted symlinks,
 * escapes with "..", and paths with a step in other hands; both the
 * openat2() path and the walk that stands in for it where the kernel has
 * none. The ownership cases need root (files given to uid 65534); without
 * it they are skipped and say so.
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "util-fs.h"
#include "rmtree.h"

#define OTHER_UID 65534

struct fixture {
	char dir[64];
	int fd;
};

static int setup(void **state)
{
	struct fixture *f = calloc(1, sizeof(*f));

	snprintf(f->dir, sizeof(f->dir), "/tmp/asph-test-fs-XXXXXX");
	assert_non_null(mkdtemp(f->dir));
	assert_int_equal(chmod(f->dir, 0755), 0);
	f->fd = open(f->dir, O_RDONLY | O_DIRECTORY);
	assert_true(f->fd >= 0);
	*state = f;
	return 0;
}

static int teardown(void **state)
{
	struct fixture *f = *state;
	close(f->fd);
	assert_int_equal(rmtree(f->dir), 0);
	free(f);
	return 0;
}

static void put(int dirfd, const char *name, const char *text)
{
	int fd = openat(dirfd, name, O_WRONLY | O_CREAT | O_TRUNC, 0600);

	assert_true(fd >= 0);
	assert_int_equal(write(fd, text, strlen(text)), (ssize_t)strlen(text));
	close(fd);
}

static void expect_content(int dirfd, const char *name, const char *text)
{
	char buf[256] = "";
	int fd = openat(dirfd, name, O_RDONLY | O_NOFOLLOW);
	ssize_t n;

	assert_true(fd >= 0);
	n = read(fd, buf, sizeof(buf) - 1);
	close(fd);
	assert_true(n >= 0);
	buf[n] = '\0';
	assert_string_equal(buf, text);
}

typedef int (*open_fn)(int dirfd, const char *path, int flags, mode_t mode);

static void check_beneath(struct fixture *f, open_fn open_beneath)
{
	int fd;

	assert_int_equal(mkdirat(f->fd, "sub", 0755), 0);
	put(f->fd, "sub/file", "inside");
	put(f->fd, "secret", "outside");
	assert_int_equal(symlinkat("../secret", f->fd, "sub/link"), 0);
	assert_int_equal(symlinkat(".", f->fd, "dirlink"), 0);

	fd = open_beneath(f->fd, "sub/file", O_RDONLY, 0);
	assert_true(fd >= 0);
	close(fd);
	fd = open_beneath(f->fd, "./sub//file", O_RDONLY, 0);
	assert_true(fd >= 0);
	close(fd);
	/* A symlink last or on the way, .. or an absolute path: refused. */
	assert_int_equal(open_beneath(f->fd, "sub/link", O_RDONLY, 0), -ELOOP);
	assert_int_equal(open_beneath(f->fd, "dirlink/secret", O_RDONLY, 0), -ELOOP);
	assert_int_equal(open_beneath(f->fd, "sub/link", O_RDONLY | O_DIRECTORY, 0), -ELOOP);
	assert_int_equal(open_beneath(f->fd, "sub/../secret", O_RDONLY, 0), -EXDEV);
	assert_int_equal(open_beneath(f->fd, "/etc/passwd", O_RDONLY, 0), -EXDEV);
	/* O_CREAT through a planted symlink creates nothing outside. */
	assert_int_equal(symlinkat("../new-outside", f->fd, "sub/plant"), 0);
	assert_int_equal(open_beneath(f->fd, "sub/plant", O_WRONLY | O_CREAT, 0600), -ELOOP);
	assert_int_equal(faccessat(f->fd, "new-outside", F_OK, 0), -1);
	expect_content(f->fd, "secret", "outside");
}

static void test_open_beneath(void **state)
{
	check_beneath(*state, fs_open_beneath);
}

static void test_open_beneath_walk(void **state)
{
	check_beneath(*state, fs_open_beneath_walk);
}

static void test_mkdir_beneath(void **state)
{
	struct fixture *f = *state;
	struct stat st;
	int fd;

	fd = fs_mkdir_beneath(f->fd, "jobs", 0750);
	assert_true(fd >= 0);
	assert_int_equal(fstat(fd, &st), 0);
	assert_true(S_ISDIR(st.st_mode));
	close(fd);
	fd = fs_mkdir_beneath(f->fd, "jobs", 0750);     /* there already */
	assert_true(fd >= 0);
	close(fd);
	assert_int_equal(mkdirat(f->fd, "elsewhere", 0755), 0);
	assert_int_equal(symlinkat("elsewhere", f->fd, "7"), 0);
	assert_int_equal(fs_mkdir_beneath(f->fd, "7", 0750), -ELOOP);
	put(f->fd, "8", "a file");
	assert_int_equal(fs_mkdir_beneath(f->fd, "8", 0750), -ENOTDIR);
	assert_int_equal(fs_mkdir_beneath(f->fd, "..", 0750), -EINVAL);
	assert_int_equal(fs_mkdir_beneath(f->fd, "a/b", 0750), -EINVAL);
}

static int write_text(FILE *fp, void *data, struct asph_error *err)
{
	fputs(data, fp);
	return 0;
}

static int write_then_fail(FILE *fp, void *data, struct asph_error *err)
{
	fputs("half", fp);
	return asph_error_set(err, -EIO, "failed on purpose");
}

/* The names in dir, one string. */
static void listing(const char *dir, char *buf, size_t size)
{
	DIR *d = opendir(dir);
	struct dirent *e;
	size_t n = 0;

	assert_non_null(d);
	buf[0] = '\0';
	while ((e = readdir(d)))
		n += (size_t)snprintf(buf + n, n < size ? size - n : 0, "%s ", e->d_name);
	closedir(d);
}

static void test_write_file_at(void **state)
{
	struct fixture *f = *state;
	struct asph_error err;
	char names[256];
	struct stat st;

	mode_t mask = umask(0);

	umask(mask);
	asph_error_clear(&err);
	assert_int_equal(fs_write_file_at(f->fd, "result.json", 0640, write_text, "{}\n", &err), 0);
	expect_content(f->fd, "result.json", "{}\n");
	assert_int_equal(fstatat(f->fd, "result.json", &st, 0), 0);
	assert_int_equal(st.st_mode & 0777, 0640 & ~mask);
	/* A symlink planted at the name is replaced, its target untouched. */
	put(f->fd, "victim", "precious");
	assert_int_equal(symlinkat("victim", f->fd, "residuals.csv"), 0);
	assert_int_equal(fs_write_file_at(f->fd, "residuals.csv", 0640, write_text, "x,y,z\n",
					  &err), 0);
	expect_content(f->fd, "victim", "precious");
	assert_int_equal(fstatat(f->fd, "residuals.csv", &st, AT_SYMLINK_NOFOLLOW), 0);
	assert_true(S_ISREG(st.st_mode));
	expect_content(f->fd, "residuals.csv", "x,y,z\n");
	/* A writer that fails leaves neither the file nor its temporary. */
	assert_int_equal(fs_write_file_at(f->fd, "map.png", 0640, write_then_fail, NULL, &err),
			 -EIO);
	assert_string_equal(err.message, "failed on purpose");
	listing(f->dir, names, sizeof(names));
	assert_null(strstr(names, "map.png"));
	assert_int_equal(fs_write_file_at(f->fd, "../x", 0640, write_text, "", &err), -EINVAL);
}

static bool am_root(void)
{
	if (geteuid() == 0)
		return true;
	print_message("not root: the cases with files of another user are left out\n");
	return false;
}

static int open_trusted(struct fixture *f, const char *rel, struct asph_error *err)
{
	struct fs_owners o = { .uid = geteuid(), .gid = getegid() };
	char path[160];

	snprintf(path, sizeof(path), "%s/%s", f->dir, rel);
	asph_error_clear(err);
	return fs_open_trusted(path, &o, O_RDONLY | O_DIRECTORY, err);
}

static void test_open_trusted(void **state)
{
	struct fixture *f = *state;
	struct asph_error err;
	int fd;

	assert_int_equal(mkdirat(f->fd, "a", 0755), 0);
	assert_int_equal(mkdirat(f->fd, "a/state", 0750), 0);
	fd = open_trusted(f, "a/state", &err);
	assert_true(fd >= 0);
	close(fd);
	/* .. and a symlink of the same owner are followed, and checked. */
	assert_int_equal(symlinkat("a/state", f->fd, "link"), 0);
	fd = open_trusted(f, "link/../state", &err);
	assert_true(fd >= 0);
	close(fd);
	assert_int_equal(open_trusted(f, "a/none", &err), -ENOENT);
	/* A directory on the way that others may write: refused. */
	assert_int_equal(fchmodat(f->fd, "a", 0777, 0), 0);
	assert_int_equal(open_trusted(f, "a/state", &err), -EPERM);
	assert_non_null(strstr(err.message, "/a: other users may write it"));
	/* Sticky, as /tmp: accepted. */
	assert_int_equal(fchmodat(f->fd, "a", 01777, 0), 0);
	fd = open_trusted(f, "a/state", &err);
	assert_true(fd >= 0);
	close(fd);
	assert_int_equal(fchmodat(f->fd, "a", 0755, 0), 0);
	if (!am_root())
		return;
	/* Group-writable by a group other than ours or root's: refused. */
	assert_int_equal(fchownat(f->fd, "a", 0, OTHER_UID, 0), 0);
	assert_int_equal(fchmodat(f->fd, "a", 0775, 0), 0);
	assert_int_equal(open_trusted(f, "a/state", &err), -EPERM);
	assert_int_equal(fchmodat(f->fd, "a", 0755, 0), 0);
	/* A directory of another user on the way, or as the last step. */
	assert_int_equal(fchownat(f->fd, "a", OTHER_UID, 0, 0), 0);
	assert_int_equal(open_trusted(f, "a/state", &err), -EPERM);
	assert_non_null(strstr(err.message, "belongs to another user"));
	assert_int_equal(fchownat(f->fd, "a", 0, 0, 0), 0);
	assert_int_equal(fchownat(f->fd, "a/state", OTHER_UID, 0, 0), 0);
	assert_int_equal(open_trusted(f, "a/state", &err), -EPERM);
	assert_int_equal(fchownat(f->fd, "a/state", 0, 0, 0), 0);
	/* A symlink that another user planted is not followed. */
	assert_int_equal(symlinkat("a/state", f->fd, "planted"), 0);
	assert_int_equal(fchownat(f->fd, "planted", OTHER_UID, 0, AT_SYMLINK_NOFOLLOW), 0);
	assert_int_equal(open_trusted(f, "planted", &err), -EPERM);
}

int main(void)
{
	const struct CMUnitTest tests[] = {
		cmocka_unit_test_setup_teardown(test_open_beneath, setup, teardown),
		cmocka_unit_test_setup_teardown(test_open_beneath_walk, setup, teardown),
		cmocka_unit_test_setup_teardown(test_mkdir_beneath, setup, teardown),
		cmocka_unit_test_setup_teardown(test_write_file_at, setup, teardown),
		cmocka_unit_test_setup_teardown(test_open_trusted, setup, teardown),
	};

	return cmocka_run_group_tests(tests, NULL, NULL);
}
