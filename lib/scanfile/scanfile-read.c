/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Reading recorded scans. The input is untrusted: every length is checked
 * against the format's limits and against what the file holds before it is
 * used, and damage ends the reading with a report instead of an error.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include <jansson.h>

#include "asph/scanfile.h"
#include "crc32c.h"
#include "scanfile-format.h"
#include "util-mem.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile_reader *, asph_scanfile_reader_free)
DEFINE_TRIVIAL_CLEANUP_FUNC(struct asph_scanfile *, asph_scanfile_free)

/* Fuzzers cannot forge checksums, so builds for them skip the comparison
 * to reach the code behind it. */
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
#define CRC_MATCHES(computed, stored) ((void)(computed), (void)(stored), true)
#else
#define CRC_MATCHES(computed, stored) ((computed) == (stored))
#endif

/* What reading one block found. */
enum block_status {
	BLOCK_OK = 0,
	BLOCK_EOF,
	BLOCK_TORN,
	BLOCK_BAD_CHECKSUM,
	BLOCK_CORRUPT,
};

static void header_clear(struct asph_scanfile_header *h)
{
	free(h->json);
	free(h->prescription);
	free(h->plan);
	free(h->instrument);
	free(h->metadata);
	free(h->software_version);
	free(h->created);
	memset(h, 0, sizeof(*h));
}

/* A header member that must be an object, as compact JSON text. Reals are
 * written with 17 significant digits, so they read back bit for bit. */
static int header_object(const struct asph_scanfile_reader *r, json_t *root,
			 const char *key, bool required, char **out,
			 struct asph_error *err)
{
	json_t *v = json_object_get(root, key);

	if (!v && !required) {
		*out = strdup("{}");
		return *out ? 0 : -ENOMEM;
	}
	if (!v)
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, key, "header has no \"%s\"",
					 key);
	if (!json_is_object(v))
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, key,
					 "header member \"%s\" is not an object", key);
	*out = json_dumps(v, JSON_COMPACT | JSON_REAL_PRECISION(17));
	return *out ? 0 : -ENOMEM;
}

static int header_members(struct asph_scanfile_reader *r, json_t *root,
			  struct asph_error *err)
{
	struct asph_scanfile_header *h = &r->header;
	json_t *sw = json_object_get(root, "software");
	json_t *ver = json_object_get(sw, "version");
	json_t *created = json_object_get(root, "created");
	json_t *created_ns = json_object_get(root, "created_ns");
	int ret;

	if (!json_is_object(root))
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, "header",
					 "header is not a JSON object");
	if ((ret = header_object(r, root, "prescription", true, &h->prescription, err)) < 0 ||
	    (ret = header_object(r, root, "plan", true, &h->plan, err)) < 0 ||
	    (ret = header_object(r, root, "instrument", true, &h->instrument, err)) < 0 ||
	    (ret = header_object(r, root, "metadata", false, &h->metadata, err)) < 0)
		return ret;
	if (!json_is_string(ver))
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, "software.version",
					 "header has no software version");
	if (!json_is_string(created) || !json_is_integer(created_ns))
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, "created",
					 "header has no creation time");
	h->software_version = strdup(json_string_value(ver));
	h->created = strdup(json_string_value(created));
	h->created_ns = json_integer_value(created_ns);
	if (!h->software_version || !h->created)
		return -ENOMEM;
	return 0;
}

static int parse_header_json(struct asph_scanfile_reader *r, char *text,
			     uint32_t len, struct asph_error *err)
{
	json_error_t jerr;
	_cleanup_(json_decrefp) json_t *root = json_loadb(text, len, 0, &jerr);

	if (!root)
		return asph_error_set_at(err, -EBADMSG, r->name, jerr.line, jerr.column, "header",
					 "header JSON: %s", jerr.text);
	return header_members(r, root, err);
}

/* The fixed prefix: magic, version, header length. */
static int read_prefix(struct asph_scanfile_reader *r, uint8_t *pre, uint32_t *len,
		       struct asph_error *err)
{
	struct asph_scanfile_header *h = &r->header;
	int64_t n = scanfile_source_read(&r->src, 0, pre, SCANFILE_PREFIX_SIZE);

	if (n < 0)
		return asph_error_set_at(err, (int)n, r->name, 0, 0, NULL, "cannot read: %s",
					 strerror((int)-n));
	if (n == 0)
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "empty file, not a recorded scan");
	if (memcmp(pre, SCANFILE_MAGIC, n < SCANFILE_MAGIC_SIZE ? (size_t)n : SCANFILE_MAGIC_SIZE))
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "not a recorded scan (bad magic)");
	if (n < SCANFILE_PREFIX_SIZE)
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "truncated header: %lld of %d bytes", (long long)n,
					 SCANFILE_PREFIX_SIZE);
	*len = get_le32(pre + 12);
	h->version_major = get_le16(pre + 8);
	h->version_minor = get_le16(pre + 10);
	if (h->version_major == 0)
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "invalid format version 0.%u", h->version_minor);
	if (h->version_major > ASPH_SCANFILE_VERSION_MAJOR)
		return asph_error_set_at(err, -ENOTSUP, r->name, 0, 0, NULL,
					 "format version %u.%u is newer than this reader (%d.%d)",
					 h->version_major, h->version_minor,
					 ASPH_SCANFILE_VERSION_MAJOR, ASPH_SCANFILE_VERSION_MINOR);
	if (*len == 0 || *len > ASPH_SCANFILE_MAX_HEADER)
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "header length %u is outside 1..%u", *len,
					 ASPH_SCANFILE_MAX_HEADER);
	return 0;
}

static int read_header(struct asph_scanfile_reader *r, struct asph_error *err)
{
	uint8_t pre[SCANFILE_PREFIX_SIZE];
	uint32_t len = 0;
	int ret = read_prefix(r, pre, &len, err);

	if (ret < 0)
		return ret;
	_cleanup_free_ char *text = malloc((size_t)len + 1);
	if (!text)
		return asph_error_set_at(err, -ENOMEM, r->name, 0, 0, NULL, "out of memory");
	int64_t n = scanfile_source_read(&r->src, SCANFILE_PREFIX_SIZE, text, len);
	if (n < 0)
		return asph_error_set_at(err, (int)n, r->name, 0, 0, NULL, "cannot read: %s",
					 strerror((int)-n));
	if (n < len)
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "truncated header: %lld of %u bytes", (long long)n, len);
	uint32_t crc = crc32c(crc32c(0, pre, SCANFILE_PREFIX_CRC_OFFSET), text, len);
	if (!CRC_MATCHES(crc, get_le32(pre + SCANFILE_PREFIX_CRC_OFFSET)))
		return asph_error_set_at(err, -EBADMSG, r->name, 0, 0, NULL,
					 "header checksum mismatch");
	text[len] = '\0';
	if ((ret = parse_header_json(r, text, len, err)) < 0)
		return ret;
	r->header.json = steal_ptr(text);
	r->offset = SCANFILE_PREFIX_SIZE + (uint64_t)len;
	r->resume_offset = r->offset;
	return 0;
}

static bool all_zero(const uint8_t *p, size_t n)
{
	for (size_t i = 0; i < n; i++)
		if (p[i])
			return false;
	return true;
}

/* Structure of a block header, before its payload is read. */
static enum block_status check_block_header(const struct block_header *h,
					    uint64_t off, char *detail,
					    size_t dsize)
{
	if (h->payload_len > ASPH_SCANFILE_MAX_PAYLOAD) {
		snprintf(detail, dsize, "block at offset %llu: payload length %u exceeds the limit %u",
			 (unsigned long long)off, h->payload_len, ASPH_SCANFILE_MAX_PAYLOAD);
		return BLOCK_CORRUPT;
	}
	switch (h->type) {
	case BLOCK_POINTS:
	case BLOCK_REFERENCES:
		if (h->record_size < ASPH_SCANFILE_RECORD_SIZE_1_0 ||
		    h->record_size > ASPH_SCANFILE_MAX_RECORD_SIZE || h->count == 0 ||
		    (uint64_t)h->count * h->record_size != h->payload_len) {
			snprintf(detail, dsize,
				 "block at offset %llu: %u records of %u bytes do not make a payload of %u bytes",
				 (unsigned long long)off, h->count, h->record_size, h->payload_len);
			return BLOCK_CORRUPT;
		}
		break;
	case BLOCK_END:
	case BLOCK_RESUME:
		if (h->record_size || h->count || h->payload_len > BLOCK_MAX_JSON) {
			snprintf(detail, dsize, "block at offset %llu: malformed %s block header",
				 (unsigned long long)off, h->type == BLOCK_END ? "end" : "resume");
			return BLOCK_CORRUPT;
		}
		break;
	default:
		/* Unknown types come from newer minor versions: skipped. */
		break;
	}
	return BLOCK_OK;
}

static int grow_buf(uint8_t **buf, size_t *size, size_t need)
{
	if (*size >= need)
		return 0;
	uint8_t *b = realloc(*buf, need);
	if (!b)
		return -ENOMEM;
	*buf = b;
	*size = need;
	return 0;
}

/*
 * Reads the block at off into *buf and checks its structure and checksum,
 * not its place in the sequence. Returns an enum block_status (with detail
 * filled for damage) or a negative errno for a failed read.
 */
static int read_block(const struct scanfile_source *src, uint64_t off,
		      uint8_t **buf, size_t *buf_size, struct block_header *h,
		      char *detail, size_t dsize)
{
	uint8_t hb[BLOCK_HEADER_SIZE];
	int64_t n = scanfile_source_read(src, off, hb, sizeof(hb));
	unsigned long long o = (unsigned long long)off;

	if (n <= 0)
		return n < 0 ? (int)n : BLOCK_EOF;
	if (all_zero(hb, (size_t)n)) {
		snprintf(detail, dsize, "zero-filled tail at offset %llu", o);
		return BLOCK_TORN;
	}
	if (memcmp(hb, BLOCK_MAGIC, n < 4 ? (size_t)n : 4)) {
		snprintf(detail, dsize, "bad block magic at offset %llu", o);
		return BLOCK_CORRUPT;
	}
	if (n < BLOCK_HEADER_SIZE) {
		snprintf(detail, dsize, "incomplete block header at offset %llu (%lld of %d bytes)",
			 o, (long long)n, BLOCK_HEADER_SIZE);
		return BLOCK_TORN;
	}
	block_header_decode(hb, h);
	enum block_status st = check_block_header(h, off, detail, dsize);
	if (st != BLOCK_OK)
		return st;

	size_t rest = (size_t)h->payload_len + BLOCK_CRC_SIZE;
	int ret = grow_buf(buf, buf_size, BLOCK_HEADER_SIZE + rest);
	if (ret < 0)
		return ret;
	memcpy(*buf, hb, sizeof(hb));
	n = scanfile_source_read(src, off + BLOCK_HEADER_SIZE, *buf + BLOCK_HEADER_SIZE, rest);
	if (n < 0)
		return (int)n;
	if ((size_t)n < rest) {
		snprintf(detail, dsize, "incomplete block at offset %llu (%lld of %zu bytes)",
			 o, (long long)n + BLOCK_HEADER_SIZE, rest + BLOCK_HEADER_SIZE);
		return BLOCK_TORN;
	}
	size_t covered = BLOCK_HEADER_SIZE + (size_t)h->payload_len;
	if (!CRC_MATCHES(crc32c(0, *buf, covered), get_le32(*buf + covered))) {
		snprintf(detail, dsize, "checksum mismatch in block at offset %llu", o);
		return BLOCK_BAD_CHECKSUM;
	}
	return BLOCK_OK;
}

static void stop(struct asph_scanfile_reader *r, enum asph_scanfile_stop why,
		 const char *detail)
{
	struct asph_scanfile_report *rep = &r->report;
	uint64_t size = 0;

	rep->stop = why;
	rep->stop_offset = r->offset;
	rep->valid_bytes = r->offset;
	snprintf(rep->stop_detail, sizeof(rep->stop_detail), "%s", detail);
	/* Past a clean end, bytes are a writer still at work, not damage. */
	if (why == ASPH_SCANFILE_STOP_END || scanfile_source_size(&r->src, &size) < 0 ||
	    size < r->offset)
		size = r->offset;
	rep->file_size = size;
	rep->discarded_bytes = size - r->offset;
	rep->reason = r->reason;
	r->done = true;
}

static enum asph_scanfile_stop stop_kind(enum block_status st)
{
	switch (st) {
	case BLOCK_TORN:
		return ASPH_SCANFILE_STOP_TORN;
	case BLOCK_BAD_CHECKSUM:
		return ASPH_SCANFILE_STOP_CHECKSUM;
	case BLOCK_EOF:
	case BLOCK_OK:
		return ASPH_SCANFILE_STOP_END;
	default:
		return ASPH_SCANFILE_STOP_CORRUPT;
	}
}

/* The end block: {"outcome": ..., "reason": ..., "points": N, ...}. */
static int parse_end(struct asph_scanfile_reader *r, const uint8_t *payload,
		     uint32_t len, char *detail, size_t dsize)
{
	_cleanup_(json_decrefp) json_t *root = json_loadb((const char *)payload, len, 0, NULL);
	json_t *outcome = json_object_get(root, "outcome");
	json_t *reason = json_object_get(root, "reason");
	json_t *points = json_object_get(root, "points");
	enum asph_scanfile_outcome o;

	if (!json_is_string(outcome) ||
	    asph_scanfile_outcome_from_name(json_string_value(outcome), &o) < 0 ||
	    o == ASPH_SCANFILE_UNFINISHED || (reason && !json_is_string(reason) && !json_is_null(reason)) ||
	    !json_is_integer(points)) {
		snprintf(detail, dsize, "malformed end block at offset %llu",
			 (unsigned long long)r->offset);
		return -EBADMSG;
	}
	if ((uint64_t)json_integer_value(points) != r->report.n_points) {
		snprintf(detail, dsize, "end block at offset %llu counts %lld points, the blocks hold %llu",
			 (unsigned long long)r->offset, (long long)json_integer_value(points),
			 (unsigned long long)r->report.n_points);
		return -EBADMSG;
	}
	if (json_is_string(reason)) {
		r->reason = strdup(json_string_value(reason));
		if (!r->reason)
			return -ENOMEM;
	}
	r->report.ended = true;
	r->report.outcome = o;
	r->report.ended_ns = json_integer_value(json_object_get(root, "time_ns"));
	return 0;
}

static int add_event(struct asph_scanfile_reader *r, const uint8_t *payload,
		     uint32_t len, char *detail, size_t dsize)
{
	_cleanup_(json_decrefp) json_t *root = json_loadb((const char *)payload, len, 0, NULL);

	if (!json_is_object(root)) {
		snprintf(detail, dsize, "malformed resume block at offset %llu",
			 (unsigned long long)r->offset);
		return -EBADMSG;
	}
	char **ev = realloc(r->events, (r->n_events + 1) * sizeof(*ev));
	if (!ev)
		return -ENOMEM;
	r->events = ev;
	ev[r->n_events] = json_dumps(root, JSON_COMPACT | JSON_REAL_PRECISION(17));
	if (!ev[r->n_events])
		return -ENOMEM;
	r->n_events++;
	r->report.n_resumes++;
	return 0;
}

static int decode_points(struct asph_scanfile_reader *r, const struct block_header *h)
{
	const uint8_t *p = r->buf + BLOCK_HEADER_SIZE;

	if (r->pts_cap < h->count) {
		struct asph_scanfile_point *np = realloc(r->pts, h->count * sizeof(*np));
		if (!np)
			return -ENOMEM;
		r->pts = np;
		r->pts_cap = h->count;
	}
	for (uint32_t i = 0; i < h->count; i++)
		scanfile_point_decode(p + (size_t)i * h->record_size, h->record_size, &r->pts[i]);
	r->last_t_ns = r->pts[h->count - 1].t_ns;
	r->report.n_points += h->count;
	return 0;
}

/* A block of reference measurements: kept all (a scan holds few). */
static int decode_references(struct asph_scanfile_reader *r, const struct block_header *h)
{
	const uint8_t *p = r->buf + BLOCK_HEADER_SIZE;

	if (r->n_refs + h->count > r->refs_cap) {
		size_t cap = r->refs_cap ? r->refs_cap : 64;
		while (cap < r->n_refs + h->count)
			cap *= 2;
		struct asph_scanfile_point *np = realloc(r->refs, cap * sizeof(*np));
		if (!np)
			return -ENOMEM;
		r->refs = np;
		r->refs_cap = cap;
	}
	for (uint32_t i = 0; i < h->count; i++)
		scanfile_point_decode(p + (size_t)i * h->record_size, h->record_size,
				      &r->refs[r->n_refs + i]);
	r->n_refs += h->count;
	r->last_t_ns = r->refs[r->n_refs - 1].t_ns > r->last_t_ns ? r->refs[r->n_refs - 1].t_ns
								  : r->last_t_ns;
	r->report.n_references += h->count;
	return 0;
}

/* Takes the verified block in r->buf; -EBADMSG (detail set) for a block
 * whose checksum is right but whose content does not fit. */
static int accept_block(struct asph_scanfile_reader *r, const struct block_header *h,
			char *detail, size_t dsize)
{
	const uint8_t *payload = r->buf + BLOCK_HEADER_SIZE;
	int ret = 0;

	if (h->seq != r->seq || h->first_point != r->report.n_points) {
		snprintf(detail, dsize,
			 "block at offset %llu is out of sequence (block %llu from point %llu, expected block %llu from point %llu)",
			 (unsigned long long)r->offset, (unsigned long long)h->seq,
			 (unsigned long long)h->first_point, (unsigned long long)r->seq,
			 (unsigned long long)r->report.n_points);
		return -EBADMSG;
	}
	if (h->type == BLOCK_POINTS)
		ret = decode_points(r, h);
	else if (h->type == BLOCK_REFERENCES)
		ret = decode_references(r, h);
	else if (h->type == BLOCK_END)
		ret = parse_end(r, payload, h->payload_len, detail, dsize);
	else if (h->type == BLOCK_RESUME)
		ret = add_event(r, payload, h->payload_len, detail, dsize);
	if (ret < 0)
		return ret;
	r->offset += BLOCK_OVERHEAD + (uint64_t)h->payload_len;
	r->seq++;
	r->report.n_blocks++;
	if (h->type != BLOCK_END) {
		r->resume_offset = r->offset;
		r->resume_seq = r->seq;
	}
	return 0;
}

static int io_error(struct asph_scanfile_reader *r, int code, struct asph_error *err)
{
	return asph_error_set_at(err, code, r->name, 0, 0, NULL, "cannot read at offset %llu: %s",
				 (unsigned long long)r->offset, strerror(-code));
}

int asph_scanfile_reader_next(struct asph_scanfile_reader *r,
			      const struct asph_scanfile_point **pts,
			      size_t *n, struct asph_error *err)
{
	char detail[sizeof(r->report.stop_detail)];
	struct block_header h;

	while (!r->done) {
		if (r->report.ended) {
			uint8_t byte;
			int64_t got = scanfile_source_read(&r->src, r->offset, &byte, 1);
			if (got < 0)
				return io_error(r, (int)got, err);
			snprintf(detail, sizeof(detail), "data after the end block at offset %llu",
				 (unsigned long long)r->offset);
			stop(r, got ? ASPH_SCANFILE_STOP_CORRUPT : ASPH_SCANFILE_STOP_END,
			     got ? detail : "");
			break;
		}
		int st = read_block(&r->src, r->offset, &r->buf, &r->buf_size, &h,
				    detail, sizeof(detail));
		if (st == -ENOMEM)
			return asph_error_set_at(err, st, r->name, 0, 0, NULL, "out of memory");
		if (st < 0)
			return io_error(r, st, err);
		if (st != BLOCK_OK) {
			stop(r, stop_kind(st), st == BLOCK_EOF ? "" : detail);
			break;
		}
		int ret = accept_block(r, &h, detail, sizeof(detail));
		if (ret == -EBADMSG) {
			stop(r, ASPH_SCANFILE_STOP_CORRUPT, detail);
			break;
		}
		if (ret < 0)
			return asph_error_set_at(err, ret, r->name, 0, 0, NULL, "out of memory");
		if (h.type == BLOCK_POINTS) {
			*pts = r->pts;
			*n = h.count;
			return 1;
		}
	}
	*pts = NULL;
	*n = 0;
	return 0;
}

int scanfile_reader_open_fd(int fd, bool own_fd, const char *name,
			    struct asph_scanfile_reader **out,
			    struct asph_error *err)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r =
		calloc(1, sizeof(*r));

	if (!r) {
		if (own_fd)
			close(fd);
		return -ENOMEM;
	}
	r->src.fd = fd;
	r->src.own_fd = own_fd;
	snprintf(r->name, sizeof(r->name), "%s", name ? name : "<scan>");
	int ret = read_header(r, err);
	if (ret < 0)
		return ret;
	*out = steal_ptr(r);
	return 0;
}

int asph_scanfile_reader_open(const char *path,
			      struct asph_scanfile_reader **out,
			      struct asph_error *err)
{
	return asph_scanfile_reader_open_at(AT_FDCWD, path, out, err);
}

int asph_scanfile_reader_open_at(int dirfd, const char *path,
				 struct asph_scanfile_reader **out,
				 struct asph_error *err)
{
	int fd = openat(dirfd, path, O_RDONLY | O_CLOEXEC | (dirfd == AT_FDCWD ? 0 : O_NOFOLLOW));

	if (fd < 0) {
		int code = -errno;
		return asph_error_set_at(err, code, path, 0, 0, NULL, "cannot open: %s",
					 strerror(-code));
	}
	return scanfile_reader_open_fd(fd, true, path, out, err);
}

int asph_scanfile_reader_open_memory(const void *data, size_t len,
				     const char *source,
				     struct asph_scanfile_reader **out,
				     struct asph_error *err)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r =
		calloc(1, sizeof(*r));

	if (!r)
		return -ENOMEM;
	r->src.fd = -1;
	r->src.mem = data;
	r->src.mem_len = len;
	snprintf(r->name, sizeof(r->name), "%s", source ? source : "<memory>");
	int ret = read_header(r, err);
	if (ret < 0)
		return ret;
	*out = steal_ptr(r);
	return 0;
}

const struct asph_scanfile_header *
asph_scanfile_reader_header(const struct asph_scanfile_reader *r)
{
	return &r->header;
}

size_t asph_scanfile_reader_references(const struct asph_scanfile_reader *r,
				       const struct asph_scanfile_point **refs)
{
	*refs = r->refs;
	return r->n_refs;
}

size_t asph_scanfile_reader_events(const struct asph_scanfile_reader *r,
				   const char *const **events)
{
	*events = (const char *const *)r->events;
	return r->n_events;
}

const struct asph_scanfile_report *
asph_scanfile_reader_report(const struct asph_scanfile_reader *r)
{
	return &r->report;
}

static void free_events(char **events, size_t n)
{
	for (size_t i = 0; i < n; i++)
		free(events[i]);
	free(events);
}

void asph_scanfile_reader_free(struct asph_scanfile_reader *r)
{
	if (!r)
		return;
	if (r->src.own_fd && r->src.fd >= 0)
		close(r->src.fd);
	header_clear(&r->header);
	free(r->buf);
	free(r->pts);
	free(r->refs);
	free(r->reason);
	free_events(r->events, r->n_events);
	free(r);
}

/* Room for need points in s, *cap of them now: at least need, doubling. */
static int reserve_points(struct asph_scanfile *s, size_t *cap, size_t need)
{
	size_t nc = *cap ? *cap : need > 1024 ? need : 1024;

	if (need <= *cap)
		return 0;
	while (nc < need)
		nc *= 2;
	if (nc > SIZE_MAX / sizeof(*s->points))
		return -ENOMEM;
	struct asph_scanfile_point *np = realloc(s->points, nc * sizeof(*np));
	if (!np)
		return -ENOMEM;
	s->points = np;
	*cap = nc;
	mem_advise_huge(np, nc * sizeof(*np));
	return 0;
}

static int append_points(struct asph_scanfile *s, size_t *cap,
			 const struct asph_scanfile_point *pts, size_t n)
{
	/* Nothing to copy, and s->points may still be NULL (memcpy's
	 * arguments must not be, even for 0 bytes). */
	if (n == 0)
		return 0;
	int r = reserve_points(s, cap, s->n + n);
	if (r < 0)
		return r;
	memcpy(s->points + s->n, pts, n * sizeof(*pts));
	s->n += n;
	return 0;
}

int scanfile_collect(struct asph_scanfile_reader *r, struct asph_scanfile **out,
		     struct asph_error *err)
{
	_cleanup_(asph_scanfile_freep) struct asph_scanfile *s = calloc(1, sizeof(*s));
	const struct asph_scanfile_point *pts;
	size_t n, cap = 0;
	uint64_t size;
	int ret;

	if (!s)
		return -ENOMEM;
	/* As many points as the rest of the file holds records, at most (its
	 * blocks' headers and references take some): read without copying
	 * them as the array doubles. */
	if (scanfile_source_size(&r->src, &size) == 0 && size > r->offset &&
	    (size - r->offset) / ASPH_SCANFILE_RECORD_SIZE < SIZE_MAX / sizeof(*s->points) &&
	    reserve_points(s, &cap, (size_t)((size - r->offset) / ASPH_SCANFILE_RECORD_SIZE)) < 0)
		return asph_error_set(err, -ENOMEM, "out of memory reading a scan of %llu bytes",
				      (unsigned long long)size);
	while ((ret = asph_scanfile_reader_next(r, &pts, &n, err)) > 0)
		if ((ret = append_points(s, &cap, pts, n)) < 0)
			return asph_error_set(err, ret, "out of memory reading %zu points", s->n);
	if (ret < 0)
		return ret;
	s->header = r->header;
	memset(&r->header, 0, sizeof(r->header));
	s->report = r->report;
	r->reason = NULL;
	r->report.reason = NULL;
	s->references = steal_ptr(r->refs);
	s->n_references = r->n_refs;
	r->n_refs = r->refs_cap = 0;
	s->events = steal_ptr(r->events);
	s->n_events = r->n_events;
	r->n_events = 0;
	*out = steal_ptr(s);
	return 0;
}

int asph_scanfile_read(const char *path, struct asph_scanfile **out,
		       struct asph_error *err)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;
	int ret = asph_scanfile_reader_open(path, &r, err);

	return ret < 0 ? ret : scanfile_collect(r, out, err);
}

int asph_scanfile_read_memory(const void *data, size_t len, const char *source,
			      struct asph_scanfile **out, struct asph_error *err)
{
	_cleanup_(asph_scanfile_reader_freep) struct asph_scanfile_reader *r = NULL;
	int ret = asph_scanfile_reader_open_memory(data, len, source, &r, err);

	return ret < 0 ? ret : scanfile_collect(r, out, err);
}

void asph_scanfile_free(struct asph_scanfile *s)
{
	if (!s)
		return;
	header_clear(&s->header);
	free(s->points);
	free(s->references);
	free((char *)s->report.reason);
	free_events(s->events, s->n_events);
	free(s);
}

int scanfile_find_valid_block(const struct scanfile_source *src, uint64_t off,
			      uint64_t *found)
{
	enum { CHUNK = 1 << 20 };
	_cleanup_free_ uint8_t *chunk = malloc(CHUNK);
	_cleanup_free_ uint8_t *buf = NULL;
	size_t buf_size = 0;
	struct block_header h;
	char detail[192];

	if (!chunk)
		return -ENOMEM;
	for (;;) {
		int64_t n = scanfile_source_read(src, off, chunk, CHUNK);
		if (n < 0)
			return (int)n;
		if (n < 4)
			return 0;
		for (const uint8_t *p = chunk; p; p++) {
			size_t left = (size_t)n - (size_t)(p - chunk);
			p = memmem(p, left, BLOCK_MAGIC, 4);
			if (!p)
				break;
			uint64_t at = off + (uint64_t)(p - chunk);
			int st = read_block(src, at, &buf, &buf_size, &h, detail, sizeof(detail));
			if (st < 0)
				return st;
			if (st == BLOCK_OK) {
				*found = at;
				return 1;
			}
		}
		if (n < CHUNK)
			return 0;
		off += (uint64_t)n - 3;   /* a magic may straddle chunks */
	}
}
