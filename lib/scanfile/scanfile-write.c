/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Writing recorded scans. Points are encoded straight into the block
 * buffer; a block goes to the file with one write() and is synced right
 * after, so the file only ever ends in a whole block or in the one block
 * being written when the power went.
 */
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>

#include <jansson.h>

#include "config.h"
#include "asph/scanfile.h"
#include "crc32c.h"
#include "fileio.h"
#include "scanfile-format.h"
#include "util-mem.h"
#include "util-time.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_reader *, asph_scanfile_reader_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

struct asph_scanfile_writer {
	int fd;
	int dirfd;               /* what path is relative to: AT_FDCWD, or ours */
	char *path;
	uint32_t block_points;
	uint64_t sync_interval_ns;
	asph_scanfile_clock_fn clock;
	void *clock_data;
	uint8_t *buf;            /* block header, pending records, CRC */
	uint32_t pending;
	uint64_t seq;            /* of the next block */
	uint64_t n_points;       /* in blocks written */
	uint64_t n_synced;       /* in blocks written and synced */
	uint64_t offset;         /* end of the last good block */
	uint64_t last_sync;      /* clock */
	uint64_t t_start;        /* clock when elapsed_ns was t_base */
	uint64_t t_base;
	int error;               /* the first write error; sticky */
	char error_msg[256];
};

static void writer_free(struct asph_scanfile_writer *w)
{
	if (!w)
		return;
	if (w->fd >= 0)
		close(w->fd);
	if (w->dirfd >= 0)
		close(w->dirfd);
	free(w->path);
	free(w->buf);
	free(w);
}

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_writer *, writer_free)

/* A failure with the reason from errno, which must still be the call's. */
static int fail_errno(const char *path, struct asph_error *err, const char *what)
{
	/* Never 0, so a caller cannot take the failure for success. */
	int code = errno > 0 ? -errno : -EIO;

	return asph_error_set_at(err, code, path, 0, 0, NULL, "%s: %s", what, strerror(-code));
}

static uint64_t monotonic_ns(void *data)
{
	return now_monotonic_ns();
}

static uint64_t now(const struct asph_scanfile_writer *w)
{
	return w->clock(w->clock_data);
}

/* dirfd: AT_FDCWD, or a directory path is relative to (dup'd here). */
static int writer_alloc(int dirfd, const char *path,
			const struct asph_scanfile_writer_options *opts,
			struct asph_scanfile_writer **out, struct asph_error *err)
{
	struct asph_scanfile_writer_options o = { 0 };

	if (opts)
		o = *opts;
	if (o.block_points > ASPH_SCANFILE_MAX_BLOCK_POINTS)
		return asph_error_set_at(err, -EINVAL, path, 0, 0, "block_points",
					 "at most %u points per block",
					 ASPH_SCANFILE_MAX_BLOCK_POINTS);
	struct asph_scanfile_writer *w = calloc(1, sizeof(*w));
	if (!w)
		return -ENOMEM;
	w->fd = -1;
	w->dirfd = dirfd == AT_FDCWD ? AT_FDCWD : fcntl(dirfd, F_DUPFD_CLOEXEC, 3);
	w->block_points = o.block_points ? o.block_points : ASPH_SCANFILE_DEFAULT_BLOCK_POINTS;
	w->sync_interval_ns = o.sync_interval_ns ? o.sync_interval_ns : ASPH_SCANFILE_DEFAULT_SYNC_NS;
	w->clock = o.clock ? o.clock : monotonic_ns;
	w->clock_data = o.clock_data;
	w->path = strdup(path);
	w->buf = malloc(BLOCK_OVERHEAD + (size_t)w->block_points * ASPH_SCANFILE_RECORD_SIZE);
	if (!w->path || !w->buf || (dirfd != AT_FDCWD && w->dirfd < 0)) {
		writer_free(w);
		return -ENOMEM;
	}
	*out = w;
	return 0;
}

/* Remembers the first error; every later call returns it again. */
static int writer_error(struct asph_scanfile_writer *w, struct asph_error *err,
			int code, const char *what)
{
	if (!w->error) {
		w->error = code;
		snprintf(w->error_msg, sizeof(w->error_msg), "%s: %s", what, strerror(-code));
	}
	return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
}

/* Writes one sealed block and syncs it. A failed write is cut off again
 * so that the file still ends in a whole block. */
static int emit(struct asph_scanfile_writer *w, const uint8_t *block, size_t len,
		uint32_t n_points, struct asph_error *err)
{
	int r = fd_write_all(w->fd, block, len);

	if (r < 0) {
		if (ftruncate(w->fd, (off_t)w->offset) < 0) {
			/* the reader stops at the torn block instead */
		}
		return writer_error(w, err, r, "writing a block");
	}
	w->offset += len;
	w->seq++;
	w->n_points += n_points;
	if (fdatasync(w->fd) < 0)
		return writer_error(w, err, -errno, "syncing a block");
	w->n_synced = w->n_points;
	w->last_sync = now(w);
	return 0;
}

static int write_pending(struct asph_scanfile_writer *w, struct asph_error *err)
{
	struct block_header h = {
		.type = BLOCK_POINTS,
		.record_size = ASPH_SCANFILE_RECORD_SIZE,
		.seq = w->seq,
		.first_point = w->n_points,
		.count = w->pending,
		.payload_len = w->pending * ASPH_SCANFILE_RECORD_SIZE,
	};
	uint32_t n = w->pending;

	if (n == 0)
		return 0;
	w->pending = 0;
	return emit(w, w->buf, block_seal(w->buf, &h), n, err);
}

/* An end or resume block with a JSON payload. */
static int write_json_block(struct asph_scanfile_writer *w, enum block_type type,
			    json_t *obj, struct asph_error *err)
{
	_cleanup_free_ char *text = json_dumps(obj, JSON_COMPACT | JSON_REAL_PRECISION(17));
	if (!text)
		return -ENOMEM;
	size_t len = strlen(text);
	if (len > BLOCK_MAX_JSON)
		return asph_error_set_at(err, -EINVAL, w->path, 0, 0, NULL,
					 "record of %zu bytes is longer than %u", len,
					 BLOCK_MAX_JSON);
	_cleanup_free_ uint8_t *block = malloc(BLOCK_OVERHEAD + len);
	if (!block)
		return -ENOMEM;
	/* File bytes, not a C string. */
	memcpy(block + BLOCK_HEADER_SIZE, text, len); // NOLINT(bugprone-not-null-terminated-result)
	struct block_header h = {
		.type = (uint16_t)type,
		.seq = w->seq,
		.first_point = w->n_points,
		.payload_len = (uint32_t)len,
	};
	return emit(w, block, block_seal(block, &h), 0, err);
}

static bool sync_due(const struct asph_scanfile_writer *w)
{
	return w->pending > 0 && now(w) - w->last_sync >= w->sync_interval_ns;
}

static int check_points(const struct asph_scanfile_writer *w,
			const struct asph_scanfile_point *pts, size_t n,
			struct asph_error *err)
{
	for (size_t i = 0; i < n; i++) {
		const struct asph_scanfile_point *p = &pts[i];
		if (p->flags & ASPH_SCANFILE_NOT_MEASURED)
			continue;
		if (!isfinite(p->x) || !isfinite(p->y) || !isfinite(p->z))
			return asph_error_set_at(err, -EINVAL, w->path, 0, 0, NULL,
						 "point %zu (plan index %llu) has non-finite coordinates "
						 "and is not flagged out of range or invalid",
						 i, (unsigned long long)p->plan_index);
	}
	return 0;
}

int asph_scanfile_writer_append(struct asph_scanfile_writer *w,
				const struct asph_scanfile_point *pts, size_t n,
				struct asph_error *err)
{
	int r;

	if (w->error)
		return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
	if ((r = check_points(w, pts, n, err)) < 0)
		return r;
	for (size_t i = 0; i < n; i++) {
		uint8_t *rec = w->buf + BLOCK_HEADER_SIZE +
			       (size_t)w->pending * ASPH_SCANFILE_RECORD_SIZE;
		scanfile_point_encode(&pts[i], rec);
		if (++w->pending == w->block_points && (r = write_pending(w, err)) < 0)
			return r;
	}
	return sync_due(w) ? write_pending(w, err) : 0;
}

int asph_scanfile_writer_append_references(struct asph_scanfile_writer *w,
					   const struct asph_scanfile_point *refs, size_t n,
					   struct asph_error *err)
{
	int r;

	if (w->error)
		return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
	if (n == 0)
		return 0;
	if (n > ASPH_SCANFILE_MAX_BLOCK_POINTS)
		return asph_error_set_at(err, -EINVAL, w->path, 0, 0, NULL,
					 "%zu reference measurements in one block: at most %u", n,
					 ASPH_SCANFILE_MAX_BLOCK_POINTS);
	if ((r = check_points(w, refs, n, err)) < 0)
		return r;
	/* in the order measured: the points before them first */
	if ((r = write_pending(w, err)) < 0)
		return r;
	_cleanup_free_ uint8_t *block = malloc(BLOCK_OVERHEAD + n * ASPH_SCANFILE_RECORD_SIZE);
	if (!block)
		return asph_error_set_at(err, -ENOMEM, w->path, 0, 0, NULL, "out of memory");
	for (size_t i = 0; i < n; i++)
		scanfile_point_encode(&refs[i], block + BLOCK_HEADER_SIZE + i * ASPH_SCANFILE_RECORD_SIZE);
	struct block_header h = {
		.type = BLOCK_REFERENCES,
		.record_size = ASPH_SCANFILE_RECORD_SIZE,
		.seq = w->seq,
		.first_point = w->n_points,
		.count = (uint32_t)n,
		.payload_len = (uint32_t)(n * ASPH_SCANFILE_RECORD_SIZE),
	};
	return emit(w, block, block_seal(block, &h), 0, err);
}

int asph_scanfile_writer_flush(struct asph_scanfile_writer *w, struct asph_error *err)
{
	if (w->error)
		return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
	return write_pending(w, err);
}

int asph_scanfile_writer_tick(struct asph_scanfile_writer *w, struct asph_error *err)
{
	if (w->error)
		return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
	return sync_due(w) ? write_pending(w, err) : 0;
}

uint64_t asph_scanfile_writer_n_points(const struct asph_scanfile_writer *w)
{
	return w->n_points + w->pending;
}

uint64_t asph_scanfile_writer_n_synced(const struct asph_scanfile_writer *w)
{
	return w->n_synced;
}

uint64_t asph_scanfile_writer_elapsed_ns(const struct asph_scanfile_writer *w)
{
	return w->t_base + (now(w) - w->t_start);
}

static int close_fd(struct asph_scanfile_writer *w, struct asph_error *err)
{
	int fd = steal_fd(w->fd);

	if (close(fd) < 0 && errno != EINTR)
		return writer_error(w, err, -errno, "closing the file");
	return 0;
}

int asph_scanfile_writer_finish(struct asph_scanfile_writer *writer,
				enum asph_scanfile_outcome outcome,
				const char *reason, struct asph_error *err)
{
	_cleanup_(writer_freep) struct asph_scanfile_writer *w = writer;
	char when[ISO8601_SIZE];
	int r;

	if (outcome == ASPH_SCANFILE_UNFINISHED ||
	    !strcmp(asph_scanfile_outcome_name(outcome), "unknown"))
		return asph_error_set_at(err, -EINVAL, w->path, 0, 0, "outcome",
					 "invalid outcome %d", (int)outcome);
	if (w->error)
		return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
	if ((r = write_pending(w, err)) < 0)
		return r;

	int64_t t = now_realtime_ns();
	iso8601_utc(t, 9, when, sizeof(when));
	_cleanup_(json_decrefp) json_t *end = json_pack("{s:s, s:s?, s:I, s:s, s:I, s:I}",
		"outcome", asph_scanfile_outcome_name(outcome), "reason", reason,
		"points", (json_int_t)w->n_points, "time", when, "time_ns", (json_int_t)t,
		"elapsed_ns", (json_int_t)asph_scanfile_writer_elapsed_ns(w));
	if (!end)
		return asph_error_set_at(err, -EINVAL, w->path, 0, 0, "reason",
					 "reason is not valid UTF-8");
	if ((r = write_json_block(w, BLOCK_END, end, err)) < 0)
		return r;
	return close_fd(w, err);
}

int asph_scanfile_writer_close(struct asph_scanfile_writer *writer, struct asph_error *err)
{
	_cleanup_(writer_freep) struct asph_scanfile_writer *w = writer;
	int r;

	if (!w)
		return 0;
	if (w->error)
		return asph_error_set_at(err, w->error, w->path, 0, 0, NULL, "%s", w->error_msg);
	if ((r = write_pending(w, err)) < 0)
		return r;
	return close_fd(w, err);
}

/* ---------------------------------------------------------------- create */

/* Parses one header member; it must be a JSON object. */
static int member(const char *path, json_t *hdr, const char *key, const char *text,
		  bool required, struct asph_error *err)
{
	json_error_t jerr;

	if (!text && !required)
		return json_object_set_new(hdr, key, json_object()) ? -ENOMEM : 0;
	if (!text)
		return asph_error_set_at(err, -EINVAL, path, 0, 0, key, "the header needs the %s",
					 key);
	json_t *v = json_loads(text, 0, &jerr);
	if (!v) {
		return asph_error_set_at(err, -EINVAL, path, jerr.line, jerr.column, key,
					 "%s is not valid JSON: %s", key, jerr.text);
	}
	if (!json_is_object(v)) {
		json_decref(v);
		return asph_error_set_at(err, -EINVAL, path, 0, 0, key, "%s must be a JSON object",
					 key);
	}
	return json_object_set_new(hdr, key, v) ? -ENOMEM : 0;
}

static int header_text(const char *path, const struct asph_scanfile_header_info *info,
		       char **out, struct asph_error *err)
{
	char when[ISO8601_SIZE];
	int64_t t = now_realtime_ns();
	int r;

	iso8601_utc(t, 9, when, sizeof(when));
	_cleanup_(json_decrefp) json_t *hdr = json_pack("{s:s, s:{s:s, s:s}, s:s, s:I}",
		"format", "asph-scan", "software", "name", "libasph", "version", ASPH_VERSION,
		"created", when, "created_ns", (json_int_t)t);
	if (!hdr)
		return -ENOMEM;
	if ((r = member(path, hdr, "prescription", info->prescription, true, err)) < 0 ||
	    (r = member(path, hdr, "plan", info->plan, true, err)) < 0 ||
	    (r = member(path, hdr, "instrument", info->instrument, true, err)) < 0 ||
	    (r = member(path, hdr, "metadata", info->metadata, false, err)) < 0)
		return r;
	*out = json_dumps(hdr, JSON_INDENT(2) | JSON_REAL_PRECISION(17));
	if (!*out)
		return -ENOMEM;
	if (strlen(*out) > ASPH_SCANFILE_MAX_HEADER)
		return asph_error_set_at(err, -EINVAL, path, 0, 0, NULL,
					 "header of %zu bytes is longer than %u", strlen(*out),
					 ASPH_SCANFILE_MAX_HEADER);
	return 0;
}

static int write_header(struct asph_scanfile_writer *w, const char *json,
			struct asph_error *err)
{
	size_t len = strlen(json);
	_cleanup_free_ uint8_t *b = malloc(SCANFILE_PREFIX_SIZE + len);

	if (!b)
		return -ENOMEM;
	/* File bytes, not C strings: the magic and the JSON go unterminated. */
	memcpy(b, SCANFILE_MAGIC, SCANFILE_MAGIC_SIZE); // NOLINT(bugprone-not-null-terminated-result)
	put_le16(b + 8, ASPH_SCANFILE_VERSION_MAJOR);
	put_le16(b + 10, ASPH_SCANFILE_VERSION_MINOR);
	put_le32(b + 12, (uint32_t)len);
	memcpy(b + SCANFILE_PREFIX_SIZE, json, len); // NOLINT(bugprone-not-null-terminated-result)
	put_le32(b + SCANFILE_PREFIX_CRC_OFFSET,
		 crc32c(crc32c(0, b, SCANFILE_PREFIX_CRC_OFFSET), json, len));
	int r = fd_write_all(w->fd, b, SCANFILE_PREFIX_SIZE + len);
	if (r == 0 && fsync(w->fd) < 0)
		r = -errno;
	if (r < 0)
		return asph_error_set_at(err, r, w->path, 0, 0, NULL, "writing the header: %s",
					 strerror(-r));
	w->offset = SCANFILE_PREFIX_SIZE + len;
	return 0;
}

/* Makes the new directory entry durable too. */
static int sync_dir(const struct asph_scanfile_writer *w, struct asph_error *err)
{
	_cleanup_free_ char *copy = strdup(w->path);
	_cleanup_close_ int dfd = -1;

	if (!copy)
		return -ENOMEM;
	if (w->dirfd != AT_FDCWD && !strchr(w->path, '/'))
		dfd = fcntl(w->dirfd, F_DUPFD_CLOEXEC, 3);
	else
		dfd = openat(w->dirfd, dirname(copy), O_RDONLY | O_DIRECTORY | O_CLOEXEC |
			     (w->dirfd == AT_FDCWD ? 0 : O_NOFOLLOW));
	if (dfd < 0 || (fsync(dfd) < 0 && errno != EINVAL))
		return fail_errno(w->path, err, "syncing the directory");
	return 0;
}

/* Files opened through a directory descriptor never follow a symlink. */
static int writer_open(const struct asph_scanfile_writer *w, int flags, mode_t mode)
{
	if (w->dirfd == AT_FDCWD)
		return open(w->path, flags, mode);
	return openat(w->dirfd, w->path, flags | O_NOFOLLOW, mode);
}

static int lock_file(int fd, const char *path, struct asph_error *err)
{
	if (flock(fd, LOCK_EX | LOCK_NB) == 0)
		return 0;
	if (errno == EWOULDBLOCK)
		return asph_error_set_at(err, -EBUSY, path, 0, 0, NULL,
					 "another writer has the scan open");
	return fail_errno(path, err, "cannot lock");
}

static int open_new(struct asph_scanfile_writer *w, bool overwrite, bool *created,
		    struct asph_error *err)
{
	struct stat st;
	int flags = O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC | (overwrite ? 0 : O_EXCL);

	/* Not O_TRUNC: the file is cut only once its lock is ours. */
	w->fd = writer_open(w, flags, 0644);
	if (w->fd < 0)
		return fail_errno(w->path, err, "cannot create");
	*created = !overwrite;
	int r = lock_file(w->fd, w->path, err);
	if (r < 0)
		return r;
	if (fstat(w->fd, &st) == 0 && S_ISREG(st.st_mode) && ftruncate(w->fd, 0) < 0)
		return fail_errno(w->path, err, "cannot truncate");
	return 0;
}

static int writer_create(int dirfd, const char *path,
			 const struct asph_scanfile_header_info *info,
			 const struct asph_scanfile_writer_options *opts,
			 struct asph_scanfile_writer **out, struct asph_error *err)
{
	_cleanup_(writer_freep) struct asph_scanfile_writer *w = NULL;
	_cleanup_free_ char *json = NULL;
	bool created = false;
	int r;

	if ((r = writer_alloc(dirfd, path, opts, &w, err)) < 0)
		return r;
	if ((r = header_text(path, info, &json, err)) < 0)
		return r;
	r = open_new(w, opts && (opts->flags & ASPH_SCANFILE_OVERWRITE), &created, err);
	if (r == 0)
		r = write_header(w, json, err);
	if (r == 0)
		r = sync_dir(w, err);
	if (r < 0) {
		/* A file without a whole header holds nothing worth keeping. */
		if (created)
			unlinkat(w->dirfd, path, 0);
		return r;
	}
	w->t_start = w->last_sync = now(w);
	*out = steal_ptr(w);
	return 0;
}

int asph_scanfile_writer_create(const char *path,
				const struct asph_scanfile_header_info *info,
				const struct asph_scanfile_writer_options *opts,
				struct asph_scanfile_writer **out,
				struct asph_error *err)
{
	return writer_create(AT_FDCWD, path, info, opts, out, err);
}

int asph_scanfile_writer_create_at(int dirfd, const char *path,
				   const struct asph_scanfile_header_info *info,
				   const struct asph_scanfile_writer_options *opts,
				   struct asph_scanfile_writer **out,
				   struct asph_error *err)
{
	return writer_create(dirfd, path, info, opts, out, err);
}

/* ---------------------------------------------------------------- resume */

static int check_resumable(const char *path, const struct asph_scanfile *s, unsigned flags,
			   struct asph_error *err)
{
	const struct asph_scanfile_report *rep = &s->report;
	const char *name = asph_scanfile_outcome_name(rep->outcome);

	if (!rep->ended)
		return 0;
	if (rep->outcome == ASPH_SCANFILE_COMPLETED)
		return asph_error_set_at(err, -EALREADY, path, 0, 0, NULL,
					 "the scan has completed");
	if (!(flags & ASPH_SCANFILE_REOPEN_ENDED))
		return asph_error_set_at(err, -EALREADY, path, 0, 0, NULL,
					 "the scan has ended (%s%s%s)", name,
					 rep->reason ? ": " : "", rep->reason ? rep->reason : "");
	return 0;
}

/* Cutting must not lose a valid block that follows the damage. */
static int check_damage(struct asph_scanfile_reader *r, const struct asph_scanfile_report *rep,
			const char *path, struct asph_error *err)
{
	uint64_t found;

	if (rep->stop != ASPH_SCANFILE_STOP_CHECKSUM && rep->stop != ASPH_SCANFILE_STOP_CORRUPT)
		return 0;
	int ret = scanfile_find_valid_block(&r->src, rep->stop_offset + 1, &found);
	if (ret < 0)
		return asph_error_set_at(err, ret, path, 0, 0, NULL, "cannot read: %s",
					 strerror(-ret));
	if (ret > 0)
		return asph_error_set_at(err, -EBADMSG, path, 0, 0, NULL,
					 "%s, and a valid block follows at offset %llu; not cutting the file",
					 rep->stop_detail, (unsigned long long)found);
	return 0;
}

static int write_resume_record(struct asph_scanfile_writer *w, const struct asph_scanfile *s,
			       uint64_t cut, struct asph_error *err)
{
	const struct asph_scanfile_report *rep = &s->report;
	char when[ISO8601_SIZE];
	int64_t t = now_realtime_ns();

	iso8601_utc(t, 9, when, sizeof(when));
	_cleanup_(json_decrefp) json_t *ev = json_pack("{s:s, s:s, s:I, s:I, s:I, s:s, s:s}",
		"event", "resume", "time", when, "time_ns", (json_int_t)t,
		"points", (json_int_t)w->n_points, "discarded_bytes", (json_int_t)cut,
		"stop", asph_scanfile_stop_name(rep->stop), "stop_detail", rep->stop_detail);
	if (!ev)
		return -ENOMEM;
	if (rep->ended &&
	    (json_object_set_new(ev, "previous_outcome",
				 json_string(asph_scanfile_outcome_name(rep->outcome))) ||
	     json_object_set_new(ev, "previous_reason",
				 rep->reason ? json_string(rep->reason) : json_null())))
		return -ENOMEM;
	return write_json_block(w, BLOCK_RESUME, ev, err);
}

/* Times continue from the later of the last point and the wall clock
 * since the scan was created. */
static uint64_t resumed_time_base(const struct asph_scanfile_reader *r,
				  const struct asph_scanfile *s)
{
	int64_t since = now_realtime_ns() - s->header.created_ns;

	return since > 0 && (uint64_t)since > r->last_t_ns ? (uint64_t)since : r->last_t_ns;
}

static int open_existing(struct asph_scanfile_writer *w, struct asph_scanfile_reader **r,
			 struct asph_error *err)
{
	w->fd = writer_open(w, O_RDWR | O_APPEND | O_CLOEXEC, 0);
	if (w->fd < 0)
		return fail_errno(w->path, err, "cannot open");
	int ret = lock_file(w->fd, w->path, err);
	if (ret < 0)
		return ret;
	return scanfile_reader_open_fd(w->fd, false, w->path, r, err);
}

static int writer_resume(int dirfd, const char *path,
			 const struct asph_scanfile_writer_options *opts,
			 struct asph_scanfile **recovered,
			 struct asph_scanfile_writer **out,
			 struct asph_error *err)
{
	_cleanup_(writer_freep) struct asph_scanfile_writer *w = NULL;
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = NULL;
	int ret;

	if ((ret = writer_alloc(dirfd, path, opts, &w, err)) < 0 ||
	    (ret = open_existing(w, &r, err)) < 0 ||
	    (ret = scanfile_collect(r, &s, err)) < 0 ||
	    (ret = check_resumable(path, s, opts ? opts->flags : 0, err)) < 0 ||
	    (ret = check_damage(r, &s->report, path, err)) < 0)
		return ret;

	/* r is set: open_existing() returned 0. */
	uint64_t cut = s->report.file_size - r->resume_offset; // NOLINT(clang-analyzer-core.NullDereference)
	if (cut && ftruncate(w->fd, (off_t)r->resume_offset) < 0)
		return fail_errno(path, err, "cannot cut the damaged tail");
	w->offset = r->resume_offset;
	w->seq = r->resume_seq;
	w->n_points = w->n_synced = s->report.n_points;
	w->t_base = resumed_time_base(r, s);
	w->t_start = w->last_sync = now(w);
	if ((ret = write_resume_record(w, s, cut, err)) < 0)
		return ret;
	if (recovered)
		*recovered = steal_ptr(s);
	*out = steal_ptr(w);
	return 0;
}

int asph_scanfile_writer_resume(const char *path,
				const struct asph_scanfile_writer_options *opts,
				struct asph_scanfile **recovered,
				struct asph_scanfile_writer **out,
				struct asph_error *err)
{
	return writer_resume(AT_FDCWD, path, opts, recovered, out, err);
}

int asph_scanfile_writer_resume_at(int dirfd, const char *path,
				   const struct asph_scanfile_writer_options *opts,
				   struct asph_scanfile **recovered,
				   struct asph_scanfile_writer **out,
				   struct asph_error *err)
{
	return writer_resume(dirfd, path, opts, recovered, out, err);
}
