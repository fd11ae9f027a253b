/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Recorded scans: the layout helpers both sides share, and names. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "asph/scanfile.h"
#include "crc32c.h"
#include "scanfile-format.h"
#include "util-mem.h"

static const char *const outcome_names[] = {
	[ASPH_SCANFILE_UNFINISHED] = "unfinished",
	[ASPH_SCANFILE_COMPLETED] = "completed",
	[ASPH_SCANFILE_ABORTED] = "aborted",
	[ASPH_SCANFILE_FAILED] = "failed",
};

const char *asph_scanfile_outcome_name(enum asph_scanfile_outcome o)
{
	if ((unsigned)o >= ARRAY_SIZE(outcome_names))
		return "unknown";
	return outcome_names[o];
}

int asph_scanfile_outcome_from_name(const char *name,
				    enum asph_scanfile_outcome *out)
{
	for (size_t i = 0; i < ARRAY_SIZE(outcome_names); i++) {
		if (!strcmp(name, outcome_names[i])) {
			*out = (enum asph_scanfile_outcome)i;
			return 0;
		}
	}
	return -EINVAL;
}

static const char *const flag_names[] = {
	"tip-compensated", "out-of-range", "low-signal", "retried", "commanded-position",
	"invalid",
};

static const char *const source_names[] = {
	"unknown", "latched", "read-back", "interpolated", "commanded",
};

const char *asph_scanfile_position_source_name(uint32_t source)
{
	return source < ARRAY_SIZE(source_names) ? source_names[source] : NULL;
}

const char *asph_scanfile_flag_name(uint32_t flag)
{
	for (size_t i = 0; i < ARRAY_SIZE(flag_names); i++)
		if (flag == 1u << i)
			return flag_names[i];
	return NULL;
}

int asph_scanfile_flags_parse(const char *list, uint32_t *out,
			      struct asph_error *err)
{
	uint32_t mask = 0;

	for (const char *p = list; *p;) {
		size_t len = strcspn(p, ",");
		size_t i = 0;
		while (i < ARRAY_SIZE(flag_names) &&
		       (strlen(flag_names[i]) != len || strncmp(p, flag_names[i], len)))
			i++;
		if (i == ARRAY_SIZE(flag_names))
			return asph_error_set(err, -EINVAL, "unknown point flag '%.*s' (known: "
					      "tip-compensated, out-of-range, low-signal, retried, "
					      "commanded-position, invalid)",
					      (int)len, p);
		mask |= 1u << i;
		p += len + (p[len] == ',');
	}
	*out = mask;
	return 0;
}

static const char *const stop_names[] = {
	[ASPH_SCANFILE_STOP_END] = "end",
	[ASPH_SCANFILE_STOP_TORN] = "torn",
	[ASPH_SCANFILE_STOP_CHECKSUM] = "checksum",
	[ASPH_SCANFILE_STOP_CORRUPT] = "corrupt",
};

const char *asph_scanfile_stop_name(enum asph_scanfile_stop s)
{
	if ((unsigned)s >= ARRAY_SIZE(stop_names))
		return "unknown";
	return stop_names[s];
}

/* Record layout (version 1.1), all little-endian:
 * plan index u64, x y z raw f64, t_ns u64, flags u32, position source u32,
 * then the stage's position f64 x 3. Version 1.0 wrote the first 56 bytes,
 * with 0 where the source is. */
void scanfile_point_encode(const struct asph_scanfile_point *pt, uint8_t *out)
{
	put_le64(out + 0, pt->plan_index);
	put_f64(out + 8, pt->x);
	put_f64(out + 16, pt->y);
	put_f64(out + 24, pt->z);
	put_f64(out + 32, pt->raw);
	put_le64(out + 40, pt->t_ns);
	put_le32(out + 48, pt->flags);
	put_le32(out + 52, pt->position_source);
	put_f64(out + 56, pt->stage[0]);
	put_f64(out + 64, pt->stage[1]);
	put_f64(out + 72, pt->stage[2]);
	put_le64(out + 80, 0);
}

void scanfile_point_decode(const uint8_t *in, uint16_t record_size,
			   struct asph_scanfile_point *pt)
{
	pt->plan_index = get_le64(in + 0);
	pt->x = get_f64(in + 8);
	pt->y = get_f64(in + 16);
	pt->z = get_f64(in + 24);
	pt->raw = get_f64(in + 32);
	pt->t_ns = get_le64(in + 40);
	pt->flags = get_le32(in + 48);
	if (record_size < ASPH_SCANFILE_RECORD_SIZE) {
		/* 1.0: the word after the flags was reserved (0) */
		pt->position_source = ASPH_SCANFILE_POSITION_UNKNOWN;
		pt->stage[0] = pt->stage[1] = pt->stage[2] = NAN;
		return;
	}
	pt->position_source = get_le32(in + 52);
	pt->stage[0] = get_f64(in + 56);
	pt->stage[1] = get_f64(in + 64);
	pt->stage[2] = get_f64(in + 72);
}

void block_header_encode(const struct block_header *h, uint8_t *out)
{
	memcpy(out, BLOCK_MAGIC, 4); // NOLINT(bugprone-not-null-terminated-result): file bytes
	put_le16(out + 4, h->type);
	put_le16(out + 6, h->record_size);
	put_le64(out + 8, h->seq);
	put_le64(out + 16, h->first_point);
	put_le32(out + 24, h->count);
	put_le32(out + 28, h->payload_len);
}

bool block_header_decode(const uint8_t *in, struct block_header *h)
{
	if (memcmp(in, BLOCK_MAGIC, 4))
		return false;
	h->type = get_le16(in + 4);
	h->record_size = get_le16(in + 6);
	h->seq = get_le64(in + 8);
	h->first_point = get_le64(in + 16);
	h->count = get_le32(in + 24);
	h->payload_len = get_le32(in + 28);
	return true;
}

size_t block_seal(uint8_t *block, const struct block_header *h)
{
	size_t len = BLOCK_HEADER_SIZE + (size_t)h->payload_len;

	block_header_encode(h, block);
	put_le32(block + len, crc32c(0, block, len));
	return len + BLOCK_CRC_SIZE;
}

int64_t scanfile_source_read(const struct scanfile_source *src, uint64_t off,
			     void *buf, size_t n)
{
	size_t done = 0;

	if (src->fd < 0) {
		if (off >= src->mem_len)
			return 0;
		done = src->mem_len - off < n ? src->mem_len - off : n;
		memcpy(buf, src->mem + off, done);
		return (int64_t)done;
	}
	while (done < n) {
		ssize_t r = pread(src->fd, (uint8_t *)buf + done, n - done,
				  (off_t)(off + done));
		if (r < 0 && errno == EINTR)
			continue;
		if (r < 0)
			return -errno;
		if (r == 0)
			break;
		done += (size_t)r;
	}
	return (int64_t)done;
}

int scanfile_source_size(const struct scanfile_source *src, uint64_t *size)
{
	struct stat st;

	if (src->fd < 0) {
		*size = src->mem_len;
		return 0;
	}
	if (fstat(src->fd, &st) < 0)
		return -errno;
	*size = (uint64_t)st.st_size;
	return 0;
}
