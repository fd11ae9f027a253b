/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * HID digital indicators and touch probes: the layout of their reports (a
 * profile), the pure decoding of an input report, and the link to the
 * device through hidapi (hidraw backend). docs/driver-hid.md documents the
 * default profile. Internal.
 */
#ifndef ASPH_HID_PROTOCOL_H
#define ASPH_HID_PROTOCOL_H

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "asph/error.h"

#define HID_REPORT_MAX 64       /* full-speed interrupt report */

enum hid_command_kind {
	HID_COMMAND_NONE = 0,
	HID_COMMAND_OUTPUT,     /* an output report (write()) */
	HID_COMMAND_FEATURE,    /* a feature report (HIDIOCSFEATURE) */
};

/* A command: the whole report, its id first ("output:0201"). */
struct hid_command {
	enum hid_command_kind kind;
	size_t len;
	uint8_t bytes[HID_REPORT_MAX];
};

/*
 * Where the reading is in an input report. Offsets count from the first
 * byte read() returns, which is the report id when the device numbers
 * its reports (report_id != 0).
 */
struct hid_profile {
	uint8_t report_id;      /* 0: the device does not number reports */
	unsigned value_offset;
	unsigned value_size;    /* 1 .. 4 bytes */
	bool value_signed;      /* two's complement */
	bool big_endian;
	double scale;           /* mm per count */
	int status_offset;      /* -1: no status byte */
	uint8_t valid_mask;     /* set when the value is a reading */
	uint8_t range_mask;     /* set when it is out of range */
	uint8_t touch_mask;     /* set while a tactile tip touches */
	uint8_t error_mask;     /* set when the device is in fault */
	struct hid_command request, zero, hold;
};

/* The built-in default profile (docs/driver-hid.md). */
extern const struct hid_profile hid_default_profile;

/* The built-in profiles, in the order of the driver's `profile` choices. */
extern const struct hid_profile *const hid_builtin_profiles[];

enum hid_status {
	HID_STATUS_OUT_OF_RANGE = 1u << 0,
	HID_STATUS_TOUCHED = 1u << 1,
};

struct hid_sample {
	int64_t counts;         /* the raw value */
	double mm;              /* counts * scale */
	unsigned status;        /* enum hid_status */
};

/*
 * Decodes one input report of n bytes with profile p. -EINVAL for a
 * profile hid_profile_check() refuses; -EPROTO with a reason for a report
 * of another id, a report too short for the profile, a reading the device
 * marks invalid or a device in fault; an out-of-range reading decodes
 * (status HID_STATUS_OUT_OF_RANGE). Pure: no I/O, any bytes in.
 */
int hid_decode_report(const struct hid_profile *p, const uint8_t *buf, size_t n,
		      struct hid_sample *out, struct asph_error *err);

/* Checks a profile's own consistency (sizes inside a report, masks). */
int hid_profile_check(const struct hid_profile *p, struct asph_error *err);

/* Parses "none", "output:HEX" or "feature:HEX" (the report, id first). */
int hid_command_parse(const char *text, struct hid_command *out,
		      struct asph_error *err);

/* ------------------------------------------------------ the device */

struct hid_link;

struct hid_link_info {
	char path[128];
	char product[64];
	char serial[64];
};

/*
 * Opens the device at path, or else the one with vendor_id:product_id
 * (and serial when not empty). -ENODEV when there is none, -EACCES when
 * it may not be opened.
 */
int hid_link_open(const char *path, unsigned vendor_id, unsigned product_id,
		  const char *serial, atomic_bool *stop, struct hid_link **out,
		  struct hid_link_info *info, struct asph_error *err);
void hid_link_close(struct hid_link *l);

/* Sends a command (nothing for HID_COMMAND_NONE). */
int hid_link_send(struct hid_link *l, const struct hid_command *c,
		  struct asph_error *err);

/*
 * Reads one input report, waiting at most timeout_ms (0: what is there).
 * Returns its length, -ETIMEDOUT, -ECANCELED (stop raised), -ENODEV
 * (device gone) or -EIO.
 */
int hid_link_read(struct hid_link *l, uint8_t *buf, size_t size,
		  unsigned timeout_ms, struct asph_error *err);

/* Discards the reports queued before now (at most the kernel's queue). */
int hid_link_drain(struct hid_link *l, struct asph_error *err);

#endif
