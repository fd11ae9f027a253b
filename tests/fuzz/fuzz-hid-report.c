/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The HID probe's report decoding (drivers/hid): the first 8 bytes choose
 * a profile (report id, value offset and size, sign, byte order, status
 * byte, masks), the rest is the input report. A report is decoded or
 * refused with a reason; a decoded value fits its size and is finite.
 */
#include <math.h>
#include <stdint.h>

#include "fuzz.h"
#include "hid/protocol.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	struct hid_profile p = hid_default_profile;
	struct hid_sample s;
	struct asph_error err;

	if (size < 8)
		return 0;
	p.report_id = data[0];
	p.value_offset = data[1] % 64;
	p.value_size = 1 + data[2] % 4;
	p.value_signed = data[3] & 1;
	p.big_endian = data[3] & 2;
	p.status_offset = (int)(data[4] % 65) - 1;
	p.valid_mask = data[5];
	p.range_mask = data[6];
	p.error_mask = data[7];
	p.scale = (data[3] & 4 ? -1 : 1) * ldexp(1.0, -(data[3] >> 3));
	asph_error_clear(&err);
	if (hid_profile_check(&p, &err) < 0) {
		fuzz_check_error(&err);
		return 0;
	}
	asph_error_clear(&err);
	if (hid_decode_report(&p, data + 8, size - 8, &s, &err) < 0) {
		fuzz_check_error(&err);
		return 0;
	}
	double lim = ldexp(1.0, 8 * (int)p.value_size);
	if (!((double)s.counts < lim && (double)s.counts >= (p.value_signed ? -lim / 2 : 0)))
		fuzz_die("counts %lld outside a %u-byte value", (long long)s.counts, p.value_size);
	if (!isfinite(s.mm))
		fuzz_die("a non-finite reading");
	return 0;
}
