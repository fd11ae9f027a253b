/* SPDX-License-Identifier: GPL-3.0-or-later */
#ifndef ASPH_SCANFILE_H
#define ASPH_SCANFILE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"
#include "asph/points.h"

#ifdef __cplusplus
extern "C" {
#endif

/*
 * Recorded scans: an append-only file with a self-describing header (lens,
 * plan parameters, instrument, software version, creation time, caller
 * metadata) followed by checksummed blocks of measured points and, when the
 * scan ended cleanly, an end block with the outcome. The byte layout, the
 * flush policy and the recovery rules are in docs/scan-format.md.
 *
 * A reader keeps every block before the first torn or damaged one and
 * reports how much it kept and why it stopped.
 */

#define ASPH_SCANFILE_VERSION_MAJOR 1
#define ASPH_SCANFILE_VERSION_MINOR 1

/* Bytes of one point record as this version writes it (1.1); version 1.0
 * wrote the first 56 of them. */
#define ASPH_SCANFILE_RECORD_SIZE 88
#define ASPH_SCANFILE_RECORD_SIZE_1_0 56

/* Limits every reader enforces on untrusted files. */
#define ASPH_SCANFILE_MAX_HEADER (1u << 20)        /* header JSON bytes */
#define ASPH_SCANFILE_MAX_PAYLOAD (4u << 20)       /* block payload bytes */
#define ASPH_SCANFILE_MAX_RECORD_SIZE 4096u

/* Writer flush policy defaults and the largest block a writer makes. */
#define ASPH_SCANFILE_DEFAULT_BLOCK_POINTS 10000u
#define ASPH_SCANFILE_DEFAULT_SYNC_NS 1000000000ull
#define ASPH_SCANFILE_MAX_BLOCK_POINTS 47662u  /* 4 MiB of 88-byte records */

/* Per-point status flags. */
enum asph_scanfile_point_flags {
	/* x, y, z are corrected for the tactile tip radius. */
	ASPH_SCANFILE_POINT_TIP_COMPENSATED = 1u << 0,
	/* The probe reading was outside its range: x, y, z are not a
	 * measurement (they may be NaN) and export leaves the point out. */
	ASPH_SCANFILE_POINT_OUT_OF_RANGE = 1u << 1,
	/* The probe flagged a weak signal (optical probes). */
	ASPH_SCANFILE_POINT_LOW_SIGNAL = 1u << 2,
	/* Measured again after a failed attempt at the same plan point. */
	ASPH_SCANFILE_POINT_RETRIED = 1u << 3,
	/* 1.1: the position is the one the stage was sent to, not one it
	 * measured (a driver without measured positions). */
	ASPH_SCANFILE_POINT_COMMANDED = 1u << 4,
	/* 1.1: the probe got no valid reading (a dropout): x, y, z are not a
	 * measurement (they may be NaN); export leaves the point out. */
	ASPH_SCANFILE_POINT_INVALID = 1u << 5,
};

/* The flags whose points are not measurements. */
#define ASPH_SCANFILE_NOT_MEASURED (ASPH_SCANFILE_POINT_OUT_OF_RANGE | ASPH_SCANFILE_POINT_INVALID)

/* Where a point's position came from (1.1; the values of the driver ABI's
 * enum asph_position_source). */
enum asph_scanfile_position_source {
	ASPH_SCANFILE_POSITION_UNKNOWN = 0,     /* a 1.0 file, or a replayed point */
	ASPH_SCANFILE_POSITION_LATCHED,
	ASPH_SCANFILE_POSITION_READ_BACK,
	ASPH_SCANFILE_POSITION_INTERPOLATED,
	ASPH_SCANFILE_POSITION_COMMANDED,
};

/* "unknown", "latched", "read-back", "interpolated", "commanded"; NULL
 * past them. */
const char *asph_scanfile_position_source_name(uint32_t source);

/* "tip-compensated", "out-of-range", "low-signal", "retried",
 * "commanded-position", "invalid"; NULL for a bit that is not a known
 * flag. */
const char *asph_scanfile_flag_name(uint32_t flag);
/* A comma-separated list of those names to a mask; -EINVAL names the
 * unknown one in err. */
int asph_scanfile_flags_parse(const char *list, uint32_t *out,
			      struct asph_error *err);

/* One measured point, or one measurement of a drift reference (whose
 * plan_index is its number in the header's reference set). */
struct asph_scanfile_point {
	uint64_t plan_index;   /* index of the plan point it measures */
	double x, y, z;        /* mm, in the frame of the plan points */
	double raw;            /* the probe's own reading (probe units) */
	uint64_t t_ns;         /* ns since the scan started */
	uint32_t flags;        /* enum asph_scanfile_point_flags */
	/* 1.1 (a 1.0 file reads as NaN and UNKNOWN) */
	uint32_t position_source;       /* enum asph_scanfile_position_source */
	double stage[3];       /* the stage's position the point was
				  computed from, in its axes */
};

enum asph_scanfile_outcome {
	ASPH_SCANFILE_UNFINISHED = 0,   /* no end block: the scan was cut off */
	ASPH_SCANFILE_COMPLETED,
	ASPH_SCANFILE_ABORTED,
	ASPH_SCANFILE_FAILED,
};

/* "unfinished", "completed", "aborted", "failed"; and back (-EINVAL). */
const char *asph_scanfile_outcome_name(enum asph_scanfile_outcome o);
int asph_scanfile_outcome_from_name(const char *name,
				    enum asph_scanfile_outcome *out);

/*
 * What the header describes, each a JSON object as text. prescription,
 * plan and instrument are required; metadata (job id, operator, ...) may be
 * NULL. The writer adds the software version and the creation time.
 */
struct asph_scanfile_header_info {
	const char *prescription;  /* asph_prescription_to_json() text */
	const char *plan;          /* method, density, spacing, points, ...;
	                            * asphd adds "for_tolerance" (how a plan
	                            * for a tolerance was chosen) */
	const char *instrument;    /* drivers, options, versions */
	const char *metadata;      /* or NULL */
};

/* The header as read back. Each member is compact JSON text. */
struct asph_scanfile_header {
	unsigned version_major, version_minor;
	char *json;                /* the whole header as stored */
	char *prescription;
	char *plan;
	char *instrument;
	char *metadata;            /* "{}" when none was given */
	char *software_version;    /* libasph version that wrote the file */
	char *created;             /* ISO 8601 UTC, e.g. 2026-11-21T08:16:41.5Z */
	int64_t created_ns;        /* the same, ns since the Unix epoch */
};

/* ---------------------------------------------------------------- writer */

/* Writer flags. */
enum {
	/* create: replace an existing file instead of failing with -EEXIST */
	ASPH_SCANFILE_OVERWRITE = 1u << 0,
	/* resume: also continue a scan that ended aborted or failed (its end
	 * block is removed and kept in the resume record) */
	ASPH_SCANFILE_REOPEN_ENDED = 1u << 1,
};

/* A monotonic clock in ns (tests inject one). */
typedef uint64_t (*asph_scanfile_clock_fn)(void *data);

/* All zero (or a NULL pointer) gives the defaults. */
struct asph_scanfile_writer_options {
	unsigned flags;
	uint32_t block_points;        /* points per block, 0 = 10,000 */
	uint64_t sync_interval_ns;    /* 0 = 1 s */
	asph_scanfile_clock_fn clock; /* NULL = CLOCK_MONOTONIC */
	void *clock_data;
};

struct asph_scanfile_writer;

/*
 * Creates path and writes and syncs the header (file and directory).
 * -EEXIST if path exists (unless ASPH_SCANFILE_OVERWRITE), -EINVAL for a
 * missing or malformed header member (err names it), -EBUSY if another
 * writer holds the file.
 */
int asph_scanfile_writer_create(const char *path,
				const struct asph_scanfile_header_info *info,
				const struct asph_scanfile_writer_options *opts,
				struct asph_scanfile_writer **out,
				struct asph_error *err);

/*
 * The same with path relative to the directory dirfd (which may be
 * closed once this returns): the file is never opened through a symbolic
 * link (O_NOFOLLOW), and the directory synced is dirfd itself.
 */
int asph_scanfile_writer_create_at(int dirfd, const char *path,
				   const struct asph_scanfile_header_info *info,
				   const struct asph_scanfile_writer_options *opts,
				   struct asph_scanfile_writer **out,
				   struct asph_error *err);

struct asph_scanfile;

/*
 * Reopens an interrupted scan to continue it: validates every block, cuts
 * off a torn or damaged tail, records the resumption in the file and
 * continues the block sequence. When recovered is not NULL it receives the
 * scan as read (header, the points kept, the report), which tells exactly
 * which plan points were measured. -EALREADY for a scan that has ended
 * (see ASPH_SCANFILE_REOPEN_ENDED; a completed scan is never reopened),
 * -EBADMSG when valid blocks follow the damage (nothing is cut then).
 */
int asph_scanfile_writer_resume(const char *path,
				const struct asph_scanfile_writer_options *opts,
				struct asph_scanfile **recovered,
				struct asph_scanfile_writer **out,
				struct asph_error *err);
/* The same relative to dirfd, never through a symbolic link. */
int asph_scanfile_writer_resume_at(int dirfd, const char *path,
				   const struct asph_scanfile_writer_options *opts,
				   struct asph_scanfile **recovered,
				   struct asph_scanfile_writer **out,
				   struct asph_error *err);

/*
 * Appends n measurements of drift references (1.1): the points pending are
 * written first, then the references as a block of their own, synced.
 */
int asph_scanfile_writer_append_references(struct asph_scanfile_writer *w,
					   const struct asph_scanfile_point *refs, size_t n,
					   struct asph_error *err);

/*
 * Appends n points. They are buffered; a block is written and synced when
 * block_points are pending or sync_interval_ns has passed since the last
 * sync (the clock is read once per call). -EINVAL for a point without the
 * OUT_OF_RANGE flag whose coordinates are not finite. After a write error
 * every call returns that first error.
 */
int asph_scanfile_writer_append(struct asph_scanfile_writer *w,
				const struct asph_scanfile_point *pts, size_t n,
				struct asph_error *err);

/* Writes the pending points as a block and syncs, now. */
int asph_scanfile_writer_flush(struct asph_scanfile_writer *w,
			       struct asph_error *err);

/* Applies the time part of the policy without a new point; call it while a
 * scan waits (pause, long moves) so buffered points still reach the disk. */
int asph_scanfile_writer_tick(struct asph_scanfile_writer *w,
			      struct asph_error *err);

/* Points in the file including the pending ones, and the durable ones. */
uint64_t asph_scanfile_writer_n_points(const struct asph_scanfile_writer *w);
uint64_t asph_scanfile_writer_n_synced(const struct asph_scanfile_writer *w);

/* ns since the scan started (across resumptions): the t_ns of a point
 * measured now. */
uint64_t asph_scanfile_writer_elapsed_ns(const struct asph_scanfile_writer *w);

/*
 * Ends the scan: writes the pending points and the end block with the
 * outcome and reason (may be NULL), syncs, closes and frees w. Returns the
 * first error (w is freed either way; the file then has no end block).
 */
int asph_scanfile_writer_finish(struct asph_scanfile_writer *w,
				enum asph_scanfile_outcome outcome,
				const char *reason, struct asph_error *err);

/* Writes the pending points, syncs, closes and frees w without an end
 * block: the scan stays resumable. NULL is allowed. */
int asph_scanfile_writer_close(struct asph_scanfile_writer *w,
			       struct asph_error *err);

/* ---------------------------------------------------------------- reader */

/* Why a reader stopped. */
enum asph_scanfile_stop {
	ASPH_SCANFILE_STOP_END = 0,     /* clean end of the file */
	ASPH_SCANFILE_STOP_TORN,        /* the last block is incomplete */
	ASPH_SCANFILE_STOP_CHECKSUM,    /* a block's checksum does not match */
	ASPH_SCANFILE_STOP_CORRUPT,     /* bad magic, impossible sizes, a
					 * block out of sequence, data after
					 * the end block */
};

/* "end", "torn", "checksum", "corrupt" */
const char *asph_scanfile_stop_name(enum asph_scanfile_stop s);

struct asph_scanfile_report {
	uint64_t n_points;         /* points recovered */
	uint64_t n_blocks;         /* valid blocks (all kinds) */
	uint64_t file_size;
	uint64_t valid_bytes;      /* header and valid blocks */
	uint64_t discarded_bytes;  /* file_size - valid_bytes */
	enum asph_scanfile_stop stop;
	uint64_t stop_offset;      /* where reading stopped */
	char stop_detail[192];     /* e.g. "checksum mismatch in block 12 at
				    * offset 560468"; "" for a clean end */
	uint64_t n_references;     /* reference measurements recovered */
	bool ended;                /* the end block was present */
	enum asph_scanfile_outcome outcome;
	const char *reason;        /* of the end block, or NULL */
	unsigned n_resumes;        /* times the scan was resumed */
	int64_t ended_ns;          /* when the end block was written, realtime
				    * ns since the Unix epoch; 0: no end block */
};

struct asph_scanfile_reader;

/*
 * Opens a scan and reads its header. -EBADMSG for a file that is not a
 * scan (empty, bad magic, torn or corrupt header, malformed header JSON),
 * -ENOTSUP for a newer major version; err says which.
 */
/* asph_scanfile_reader_open_at(): relative to dirfd, never through a
 * symbolic link. */
int asph_scanfile_reader_open_at(int dirfd, const char *path,
				 struct asph_scanfile_reader **out,
				 struct asph_error *err);
int asph_scanfile_reader_open(const char *path,
			      struct asph_scanfile_reader **out,
			      struct asph_error *err);
/* The same over bytes in memory (kept by the caller while r lives). */
int asph_scanfile_reader_open_memory(const void *data, size_t len,
				     const char *source,
				     struct asph_scanfile_reader **out,
				     struct asph_error *err);

const struct asph_scanfile_header *
asph_scanfile_reader_header(const struct asph_scanfile_reader *r);

/*
 * Next block of points: returns 1 and sets *pts (valid until the next call)
 * and *n, or 0 when reading stopped (see the report). Damage is not an
 * error; a failing read() is (negative errno).
 */
int asph_scanfile_reader_next(struct asph_scanfile_reader *r,
			      const struct asph_scanfile_point **pts,
			      size_t *n, struct asph_error *err);

/* The reference measurements read so far (valid until the next call of
 * next()). */
size_t asph_scanfile_reader_references(const struct asph_scanfile_reader *r,
				       const struct asph_scanfile_point **refs);

/* The resume records read so far (JSON texts, valid while r lives). */
size_t asph_scanfile_reader_events(const struct asph_scanfile_reader *r,
				   const char *const **events);

/* Complete once next() returned 0. */
const struct asph_scanfile_report *
asph_scanfile_reader_report(const struct asph_scanfile_reader *r);

void asph_scanfile_reader_free(struct asph_scanfile_reader *r);

/* ------------------------------------------------------- a whole scan */

struct asph_scanfile {
	struct asph_scanfile_header header;
	size_t n;
	struct asph_scanfile_point *points;   /* in recording order */
	size_t n_references;
	struct asph_scanfile_point *references; /* drift references, in order */
	struct asph_scanfile_report report;
	size_t n_events;
	char **events;     /* JSON text of each resume record, in order */
};

int asph_scanfile_read(const char *path, struct asph_scanfile **out,
		       struct asph_error *err);
int asph_scanfile_read_memory(const void *data, size_t len,
			      const char *source, struct asph_scanfile **out,
			      struct asph_error *err);
void asph_scanfile_free(struct asph_scanfile *s);

/*
 * The measured points as a point set, in recording order, leaving out the
 * points with any of exclude_flags (the points that are no measurement,
 * out of range or invalid, are always left out). -EBADMSG (err names the point) for a kept point whose
 * coordinates are not finite. This is the one conversion export and replay
 * share, so both see the same points.
 */
int asph_scanfile_to_points(const struct asph_scanfile *s,
			    uint32_t exclude_flags, struct asph_points **out,
			    struct asph_error *err);

/* Reads scan_path and writes its points to out_path (format by extension,
 * as asph_points_write, full precision). report (may be NULL) receives the
 * recovery report, with reason set to NULL. */
int asph_scanfile_export(const char *scan_path, const char *out_path,
			 uint32_t exclude_flags,
			 struct asph_scanfile_report *report,
			 struct asph_error *err);

#ifdef __cplusplus
}
#endif

#endif
