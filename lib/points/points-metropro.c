/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Zygo MetroPro .dat, as the MetroPro Reference Guide lays it out: a
 * big-endian header (formats 1 and 2: 834 bytes, format 3: 4096), the
 * intensity frames (unsigned 16-bit) and the phase map (signed 32-bit,
 * values from 2147483640 up invalid), row after row from the top. The
 * height of a phase value is value x S x O x wavelength / R: the
 * interferometric scale factor S, the obliquity factor O and the phase
 * resolution R (4096, 32768 or 131072 by the header's phase_res). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "readers.h"
#include "util-mem.h"

#define M_TO_MM 1000.0
#define PHASE_INVALID 2147483640

/* Byte offsets of the header fields read. */
enum {
	OFF_MAGIC = 0, OFF_FORMAT = 4, OFF_SIZE = 6,
	OFF_AC_WIDTH = 52, OFF_AC_HEIGHT = 54, OFF_AC_BUCKETS = 56, OFF_AC_BYTES = 60,
	OFF_CN_WIDTH = 68, OFF_CN_HEIGHT = 70, OFF_CN_BYTES = 72,
	OFF_SCALE = 164, OFF_WAVELENGTH = 168, OFF_OBLIQUITY = 176, OFF_LATERAL = 184,
	OFF_PHASE_RES = 218, OFF_SIGN = 232,
};

static const struct {
	uint32_t magic;
	uint16_t format;
	uint32_t size;
} header_formats[] = {
	{ 0x881B036F, 1, 834 }, { 0x881B0370, 2, 834 }, { 0x881B0371, 3, 4096 },
};

static int mp_error(struct asph_error *err, const char *source, size_t offset, const char *field,
		    const char *what, long long value)
{
	return asph_error_set_at(err, -EINVAL, source, 0, 0, field,
				 "metropro: %s (%lld at byte offset %zu)", what, value, offset);
}

static int check_header(const uint8_t *d, size_t len, const char *source, size_t *header,
			struct asph_error *err)
{
	if (len < 834)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "metropro: %zu bytes, fewer than the 834 of a header", len);
	uint32_t magic = get_be32(d + OFF_MAGIC);
	for (size_t i = 0; i < ARRAY_SIZE(header_formats); i++) {
		if (header_formats[i].magic != magic)
			continue;
		if (get_be16(d + OFF_FORMAT) != header_formats[i].format)
			return mp_error(err, source, OFF_FORMAT, "header_format",
					"the header format does not match the magic number",
					get_be16(d + OFF_FORMAT));
		if (get_be32(d + OFF_SIZE) != header_formats[i].size)
			return mp_error(err, source, OFF_SIZE, "header_size",
					"the header size does not match the header format",
					get_be32(d + OFF_SIZE));
		*header = header_formats[i].size;
		if (len < *header)
			return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
						 "metropro: %zu bytes, fewer than the %zu of a format %u header",
						 len, *header, header_formats[i].format);
		return 0;
	}
	return mp_error(err, source, OFF_MAGIC, "magic_number", "not a MetroPro magic number",
			magic);
}

static int phase_resolution(const uint8_t *d, const char *source, double *res,
			    struct asph_error *err)
{
	static const double factors[] = { 4096, 32768, 131072 };
	uint16_t r = get_be16(d + OFF_PHASE_RES);

	if (r >= ARRAY_SIZE(factors))
		return mp_error(err, source, OFF_PHASE_RES, "phase_res",
				"an unknown phase resolution (0, 1 or 2)", r);
	*res = factors[r];
	return 0;
}

int points_read_metropro(const uint8_t *d, size_t len, const char *source,
			 struct asph_points **out, struct asph_points_read_info *info,
			 struct asph_error *err)
{
	size_t header = 0, nodes, bytes;
	double res = 0;
	int r = check_header(d, len, source, &header, err);

	if (r < 0 || (r = phase_resolution(d, source, &res, err)) < 0)
		return r;
	size_t ac_bytes = get_be32(d + OFF_AC_BYTES);
	size_t ac_expected = (size_t)get_be16(d + OFF_AC_WIDTH) * get_be16(d + OFF_AC_HEIGHT) *
			     get_be16(d + OFF_AC_BUCKETS) * 2;
	if (ac_bytes != ac_expected)
		return mp_error(err, source, OFF_AC_BYTES, "ac_n_bytes",
				"the intensity size is not width x height x buckets x 2",
				(long long)ac_bytes);
	struct points_map m = { .nx = get_be16(d + OFF_CN_WIDTH), .ny = get_be16(d + OFF_CN_HEIGHT) };
	if (points_map_size(m.nx, m.ny, 4, &nodes, &bytes) < 0)
		return mp_error(err, source, OFF_CN_WIDTH, "cn_width",
				"the file holds no phase map (width or height 0)", (long long)m.nx);
	if (get_be32(d + OFF_CN_BYTES) != bytes)
		return mp_error(err, source, OFF_CN_BYTES, "cn_n_bytes",
				"the phase size is not width x height x 4", get_be32(d + OFF_CN_BYTES));
	size_t phase = header + ac_bytes;
	if (phase > len || bytes > len - phase)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, NULL,
					 "metropro: the phase map takes bytes %zu to %zu; the file has %zu",
					 phase, phase + bytes, len);
	double lateral = get_be_float(d + OFF_LATERAL) * M_TO_MM;
	double wavelength = get_be_float(d + OFF_WAVELENGTH);
	double scale = get_be_float(d + OFF_SCALE) * get_be_float(d + OFF_OBLIQUITY);
	if (!(lateral > 0) || !isfinite(lateral))
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "lateral_res",
					 "metropro: no lateral resolution (%g m at byte offset %d): the positions are unknown",
					 lateral / M_TO_MM, OFF_LATERAL);
	if (!(wavelength > 0) || !isfinite(wavelength) || !isfinite(scale) || scale == 0)
		return asph_error_set_at(err, -EINVAL, source, 0, 0, "wavelength_in",
					 "metropro: the wavelength (byte offset %d) or the scale and obliquity factors (%d, %d) do not give heights",
					 OFF_WAVELENGTH, OFF_SCALE, OFF_OBLIQUITY);
	/* metres per phase count, in mm; an inverted sign flips it */
	double q = scale * wavelength / res * M_TO_MM * (get_be16(d + OFF_SIGN) ? -1 : 1);
	_cleanup_free_ double *z = malloc(nodes * sizeof(double));
	if (!z)
		return asph_error_set(err, -ENOMEM, "out of memory");
	for (size_t k = 0; k < nodes; k++) {
		int32_t v = (int32_t)get_be32(d + phase + 4 * k);
		z[k] = v >= PHASE_INVALID ? NAN : v * q;
	}
	m.z = z;
	points_map_centre(&m, lateral, lateral, 1);
	return points_from_map(&m, "metropro", source, out, info, err);
}
