/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The byte layout of recorded scans (docs/scan-format.md) and what the
 * reader and the writer share. Internal.
 */
#ifndef ASPH_SCANFILE_FORMAT_H
#define ASPH_SCANFILE_FORMAT_H

#include <endian.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "asph/scanfile.h"

#define SCANFILE_MAGIC "ASPHSCAN"
#define SCANFILE_MAGIC_SIZE 8
/* magic, major u16, minor u16, header length u32, CRC-32C u32 */
#define SCANFILE_PREFIX_SIZE 20
#define SCANFILE_PREFIX_CRC_OFFSET 16

#define BLOCK_MAGIC "ASPB"
/* magic, type u16, record size u16, sequence u64, first point u64,
 * count u32, payload length u32; then the payload and a CRC-32C u32 */
#define BLOCK_HEADER_SIZE 32
#define BLOCK_CRC_SIZE 4
#define BLOCK_OVERHEAD (BLOCK_HEADER_SIZE + BLOCK_CRC_SIZE)

/* The largest JSON payload of an end or resume block. */
#define BLOCK_MAX_JSON (64u << 10)

enum block_type {
	BLOCK_POINTS = 1,
	BLOCK_END = 2,
	BLOCK_RESUME = 3,
	BLOCK_REFERENCES = 4,   /* 1.1: measurements of drift references */
};

struct block_header {
	uint16_t type;
	uint16_t record_size;
	uint64_t seq;
	uint64_t first_point;
	uint32_t count;
	uint32_t payload_len;
};

static inline void put_le16(uint8_t *p, uint16_t v)
{
	v = htole16(v);
	memcpy(p, &v, sizeof(v));
}

static inline void put_le32(uint8_t *p, uint32_t v)
{
	v = htole32(v);
	memcpy(p, &v, sizeof(v));
}

static inline void put_le64(uint8_t *p, uint64_t v)
{
	v = htole64(v);
	memcpy(p, &v, sizeof(v));
}

static inline uint16_t get_le16(const uint8_t *p)
{
	uint16_t v;
	memcpy(&v, p, sizeof(v));
	return le16toh(v);
}

static inline uint32_t get_le32(const uint8_t *p)
{
	uint32_t v;
	memcpy(&v, p, sizeof(v));
	return le32toh(v);
}

static inline uint64_t get_le64(const uint8_t *p)
{
	uint64_t v;
	memcpy(&v, p, sizeof(v));
	return le64toh(v);
}

/* IEEE 754 binary64, stored as the little-endian integer of its bits. */
static inline void put_f64(uint8_t *p, double d)
{
	uint64_t v;
	memcpy(&v, &d, sizeof(v));
	put_le64(p, v);
}

static inline double get_f64(const uint8_t *p)
{
	uint64_t v = get_le64(p);
	double d;
	memcpy(&d, &v, sizeof(d));
	return d;
}

void scanfile_point_encode(const struct asph_scanfile_point *pt,
			   uint8_t *out);
/* Decodes a record of record_size bytes (56 in 1.0; newer sizes append
 * fields, of which this reader takes the ones it knows). */
void scanfile_point_decode(const uint8_t *in, uint16_t record_size,
			   struct asph_scanfile_point *pt);

void block_header_encode(const struct block_header *h, uint8_t *out);
/* false when the magic is wrong */
bool block_header_decode(const uint8_t *in, struct block_header *h);

/* Fills the header and the CRC of a block whose payload already sits at
 * block + BLOCK_HEADER_SIZE; returns the block's total size. */
size_t block_seal(uint8_t *block, const struct block_header *h);

/* Where bytes come from: a file descriptor or memory. */
struct scanfile_source {
	int fd;                  /* -1 for memory */
	bool own_fd;
	const uint8_t *mem;
	size_t mem_len;
};

/* Reads up to n bytes at off; returns the count (short at the end) or a
 * negative errno. */
int64_t scanfile_source_read(const struct scanfile_source *src, uint64_t off,
			     void *buf, size_t n);
/* Size now (files may grow while read). */
int scanfile_source_size(const struct scanfile_source *src, uint64_t *size);

struct asph_scanfile_reader {
	struct scanfile_source src;
	char name[256];
	struct asph_scanfile_header header;
	uint64_t offset;          /* of the next block */
	uint64_t seq;             /* the next block's expected sequence */
	uint64_t resume_offset;   /* after the last block but the end block */
	uint64_t resume_seq;      /* sequence a writer continues with */
	uint64_t last_t_ns;       /* of the last point read */
	uint8_t *buf;
	size_t buf_size;
	struct asph_scanfile_point *pts;
	size_t pts_cap;
	struct asph_scanfile_point *refs;     /* every reference read */
	size_t n_refs, refs_cap;
	struct asph_scanfile_report report;
	char *reason;
	char **events;
	size_t n_events;
	bool done;
};

int scanfile_reader_open_fd(int fd, bool own_fd, const char *name,
			    struct asph_scanfile_reader **out,
			    struct asph_error *err);

/* Reads every remaining block of r into a new scan; the header, reason and
 * events move from r to it. */
int scanfile_collect(struct asph_scanfile_reader *r,
		     struct asph_scanfile **out, struct asph_error *err);

/* Looks for a block with a valid checksum starting after off; sets
 * *found and returns 1, 0 if none, or a negative errno. */
int scanfile_find_valid_block(const struct scanfile_source *src, uint64_t off,
			      uint64_t *found);

#endif
