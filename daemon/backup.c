/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Event loop thread, but for copy_thread() and what it calls, which run on
 * a copy's own thread and touch only the atomics of its struct backup and
 * what the loop does not read until `finished` is set.
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "backup.h"
#include "dirs.h"
#include "log.h"
#include "mailbox.h"
#include "util-hash.h"
#include "store.h"
#include "util-mem.h"
#include "util-time.h"

#define COPY_PREFIX "copy-"
#define COPY_SUFFIX ".sqlite"

struct backup {
	struct backups *set;
	struct backup *next;
	const void *owner;              /* NULL: released, removed once settled */
	char who[64];
	char name[64];
	char *path;
	enum backup_state state;
	pthread_t thread;
	bool joined;
	int fd;                         /* the finished copy, read back */
	int64_t started_ns, finished_ns;

	/* Written by the thread; read by the loop once finished is set. */
	atomic_llong pages_done, pages_total;
	atomic_bool cancel;
	atomic_bool finished;
	int result;                     /* 0 or -errno */
	char error[sizeof(((struct asph_error *)0)->message)];
	int64_t size;
	char sha256[65];
};

struct backups {
	sd_event *event;
	char *store_path;
	char *dir;                      /* STATE_DIR/backup, once made */
	int state_fd;
	const struct settings_limits *limits;
	struct mailbox *mailbox;        /* a copy's thread is done */
	struct backup *list;
	unsigned serial;
};

static const char *const state_names[] = {
	[BACKUP_COPYING] = "copying",
	[BACKUP_DONE] = "done",
	[BACKUP_FAILED] = "failed",
};

const char *backup_state_name(enum backup_state s)
{
	return (unsigned)s < ARRAY_SIZE(state_names) ? state_names[s] : "unknown";
}

/* ------------------------------------------------------------ the thread */

static int on_step(int64_t done, int64_t total, void *data)
{
	struct backup *bk = data;

	atomic_store(&bk->pages_done, done);
	atomic_store(&bk->pages_total, total);
	return atomic_load(&bk->cancel);
}

/* The size and SHA-256 of the finished copy, which the client checks
 * what it received against. */
static int digest(struct backup *bk)
{
	_cleanup_close_ int fd = open(bk->path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
	static const size_t chunk = 1 << 16;
	_cleanup_free_ unsigned char *buf = malloc(chunk);
	struct sha256_ctx h;
	ssize_t n;

	if (fd < 0 || !buf)
		return fd < 0 ? -errno : -ENOMEM;
	sha256_init(&h);
	bk->size = 0;
	while ((n = read(fd, buf, chunk)) > 0) {
		if (atomic_load(&bk->cancel))
			return -ECANCELED;
		sha256_update(&h, (size_t)n, buf);
		bk->size += n;
	}
	if (n < 0)
		return -errno;
	sha256_hex_of(&h, bk->sha256);
	return 0;
}

static void *copy_thread(void *data)
{
	struct backup *bk = data;
	struct asph_error err;

	asph_error_clear(&err);
	bk->result = store_backup(bk->set->store_path, bk->path, on_step, bk, &err);
	if (bk->result == 0)
		bk->result = digest(bk);
	if (bk->result < 0)
		snprintf(bk->error, sizeof(bk->error), "%s",
			 err.message[0] ? err.message : strerror(-bk->result));
	atomic_store(&bk->finished, true);
	/* (when the note is lost for want of memory, the next look at the
	 * copy settles it: settle()) */
	mailbox_post(bk->set->mailbox, &bk);
	return NULL;
}

/* --------------------------------------------------------------- copies */

static void remove_copy(struct backups *b, struct backup *bk)
{
	struct backup **p;

	for (p = &b->list; *p; p = &(*p)->next)
		if (*p == bk) {
			*p = bk->next;
			break;
		}
	if (bk->fd >= 0)
		close(bk->fd);
	if (bk->path)
		unlink(bk->path);
	free(bk->path);
	free(bk);
}

/* A copy whose thread has finished: joined, its outcome taken, and
 * removed when nobody wants it any more. */
static void settle(struct backups *b, struct backup *bk)
{
	double seconds;

	if (bk->joined || !atomic_load(&bk->finished))
		return;
	pthread_join(bk->thread, NULL);
	bk->joined = true;
	bk->finished_ns = now_realtime_ns();
	seconds = (double)(bk->finished_ns - bk->started_ns) / 1e9;
	if (bk->result == 0)
		bk->fd = open(bk->path, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
	if (bk->result == 0 && bk->fd < 0) {
		bk->result = -errno;
		snprintf(bk->error, sizeof(bk->error), "%s: %s", bk->path, strerror(errno));
	}
	bk->state = bk->result == 0 ? BACKUP_DONE : BACKUP_FAILED;
	if (bk->state == BACKUP_DONE)
		log_info("backup: the job store copied for %s into %s: %" PRId64 " bytes in %.1f s, "
			 "sha256 %s", bk->who, bk->name, bk->size, seconds, bk->sha256);
	else if (bk->result != -ECANCELED)
		log_warning("backup: the copy of the job store for %s failed: %s", bk->who,
			    bk->error);
	if (!bk->owner)
		remove_copy(b, bk);
}

static void on_note(void *msg, void *data)
{
	struct backup *bk = *(struct backup **)msg;

	settle(data, bk);
}

static struct backup *copy_of(struct backups *b, const void *owner)
{
	for (struct backup *bk = b ? b->list : NULL; bk; bk = bk->next)
		if (bk->owner == owner) {
			settle(b, bk);
			return bk;
		}
	return NULL;
}

/* Room for a copy: the store with its write-ahead log (the most a copy
 * takes), and limits.min_free_disk_mb besides. */
static int check_room(struct backups *b, struct asph_error *err)
{
	static const char *const suffixes[] = { "", "-wal" };
	uint64_t free_mb, need = 0, keep = b->limits->min_free_disk_mb;
	char path[4096];
	struct stat st;

	for (size_t i = 0; i < ARRAY_SIZE(suffixes); i++) {
		snprintf(path, sizeof(path), "%s%s", b->store_path, suffixes[i]);
		if (stat(path, &st) == 0)
			need += (uint64_t)st.st_size;
	}
	need = (need + (1u << 20) - 1) >> 20;
	if (dirs_free_mb(b->state_fd, &free_mb) < 0 || free_mb >= need + keep)
		return 0;
	return asph_error_set(err, -EDQUOT, "the state directory has %" PRIu64 " MiB free: a "
			      "copy of the job store takes up to %" PRIu64 " MiB, and "
			      "limits.min_free_disk_mb keeps %" PRIu64 " MiB free", free_mb, need, keep);
}

int backups_start(struct backups *b, const void *owner, const char *who,
		  struct asph_error *err)
{
	char stamp[ISO8601_SIZE];
	struct backup *bk, *next;
	int r;

	if (!b)
		return asph_error_set(err, -ENOTSUP, "this daemon makes no copies of its store");
	for (bk = b->list; bk; bk = next) {
		next = bk->next;
		settle(b, bk);          /* (may remove bk) */
	}
	for (bk = b->list; bk; bk = bk->next)
		if (bk->state == BACKUP_COPYING)
			return asph_error_set(err, -EBUSY, "a copy of the job store is being made "
					      "for %s: try again when it is done", bk->who);
	r = check_room(b, err);
	if (r == 0 && !b->dir)
		r = store_backup_dir(b->store_path, true, &b->dir, err);
	if (r < 0)
		return r;
	backups_release(b, owner);
	bk = calloc(1, sizeof(*bk));
	if (!bk)
		return asph_error_set(err, -ENOMEM, "out of memory");
	*bk = (struct backup){ .set = b, .owner = owner, .fd = -1,
			       .started_ns = now_realtime_ns() };
	snprintf(bk->who, sizeof(bk->who), "%s", who);
	iso8601_basic_utc(bk->started_ns, stamp, sizeof(stamp));
	snprintf(bk->name, sizeof(bk->name), COPY_PREFIX "%s-%u" COPY_SUFFIX, stamp, ++b->serial);
	if (asprintf(&bk->path, "%s/%s", b->dir, bk->name) < 0) {
		free(bk);
		return asph_error_set(err, -ENOMEM, "out of memory");
	}
	r = -pthread_create(&bk->thread, NULL, copy_thread, bk);
	if (r < 0) {
		free(bk->path);
		free(bk);
		return asph_error_set(err, r, "cannot start the copy's thread: %s", strerror(-r));
	}
	bk->next = b->list;
	b->list = bk;
	log_info("backup: copying the job store for %s into %s", bk->who, bk->name);
	return 0;
}

int backups_get(struct backups *b, const void *owner, struct backup_info *out)
{
	struct backup *bk = copy_of(b, owner);
	bool over;

	if (!bk)
		return -ENOENT;
	over = bk->state != BACKUP_COPYING;
	*out = (struct backup_info){
		.name = bk->name, .state = bk->state,
		.pages_done = atomic_load(&bk->pages_done),
		.pages_total = atomic_load(&bk->pages_total),
		.size = bk->state == BACKUP_DONE ? bk->size : 0,
		.sha256 = bk->state == BACKUP_DONE ? bk->sha256 : NULL,
		.error = bk->state == BACKUP_FAILED ? bk->error : NULL,
		.started_ns = bk->started_ns, .finished_ns = over ? bk->finished_ns : 0,
	};
	return 0;
}

int backups_fd(struct backups *b, const void *owner, int *fd)
{
	struct backup *bk = copy_of(b, owner);

	if (!bk)
		return -ENOENT;
	if (bk->state == BACKUP_COPYING)
		return -EAGAIN;
	if (bk->state == BACKUP_FAILED)
		return -EIO;
	*fd = bk->fd;
	return 0;
}

void backups_release(struct backups *b, const void *owner)
{
	struct backup *bk = copy_of(b, owner);

	if (!bk)
		return;
	bk->owner = NULL;
	if (bk->joined)
		remove_copy(b, bk);
	else
		atomic_store(&bk->cancel, true);        /* removed once settled */
}

/* ---------------------------------------------------------------- setup */

/* The copies a daemon that died left behind. */
static void remove_leftovers(struct backups *b)
{
	_cleanup_free_ char *dir = NULL;
	struct dirent *e;
	DIR *d;
	size_t n;

	if (store_backup_dir(b->store_path, false, &dir, NULL) < 0 || !(d = opendir(dir)))
		return;
	while ((e = readdir(d))) {
		n = strlen(e->d_name);
		if (strncmp(e->d_name, COPY_PREFIX, strlen(COPY_PREFIX)) ||
		    n < strlen(COPY_SUFFIX) || strcmp(e->d_name + n - strlen(COPY_SUFFIX), COPY_SUFFIX))
			continue;
		if (unlinkat(dirfd(d), e->d_name, 0) == 0)
			log_info("backup: removed %s/%s, a copy left by the last run", dir, e->d_name);
	}
	closedir(d);
}

int backups_new(const struct backups_setup *setup, struct backups **out,
		struct asph_error *err)
{
	struct backups *b = calloc(1, sizeof(*b));
	char *slash;
	int r = 0;

	if (!b)
		return asph_error_set(err, -ENOMEM, "out of memory");
	b->event = setup->event;
	b->limits = setup->limits;
	b->state_fd = -1;
	b->store_path = strdup(setup->store_path);
	slash = b->store_path ? strrchr(b->store_path, '/') : NULL;
	if (!slash) {
		r = b->store_path ? asph_error_set(err, -EINVAL, "%s: not a path", setup->store_path)
				  : asph_error_set(err, -ENOMEM, "out of memory");
		backups_free(b);
		return r;
	}
	*slash = '\0';         /* (the state directory, for its free room) */
	b->state_fd = open(b->store_path, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
	*slash = '/';
	if (b->state_fd < 0)
		r = asph_error_set(err, -errno, "%s: %s", b->store_path, strerror(errno));
	if (r == 0)
		r = mailbox_new(&(struct mailbox_setup){
				.event = setup->event, .size = sizeof(struct backup *),
				.deliver = on_note, .data = b }, &b->mailbox);
	if (r < 0) {
		if (!err || !err->message[0])
			asph_error_set(err, r, "backups: %s", strerror(-r));
		backups_free(b);
		return r;
	}
	remove_leftovers(b);
	*out = b;
	return 0;
}

void backups_free(struct backups *b)
{
	if (!b)
		return;
	for (struct backup *bk = b->list; bk; bk = bk->next)
		atomic_store(&bk->cancel, true);
	while (b->list) {
		struct backup *bk = b->list;
		if (!bk->joined) {
			pthread_join(bk->thread, NULL);   /* within a step of 256 pages */
			bk->joined = true;
		}
		remove_copy(b, bk);
	}
	mailbox_free(b->mailbox);
	if (b->state_fd >= 0)
		close(b->state_fd);
	free(b->dir);
	free(b->store_path);
	free(b);
}
