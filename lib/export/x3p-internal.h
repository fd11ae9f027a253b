/* SPDX-License-Identifier: GPL-3.0-or-later */
/* Record2's instrument and probing system named from a recorded scan's
 * instrument. Internal. */
#ifndef ASPH_X3P_INTERNAL_H
#define ASPH_X3P_INTERNAL_H

struct x3p_instrument {
	char model[128];                /* the instrument's name */
	char version[256];              /* its drivers and their versions */
	const char *probing_type;       /* "Contacting", "NonContacting" */
	char probing_id[256];           /* the probe's driver, version, serial */
};

/* The names of the instrument JSON text (asph_instrument_config_to_json(),
 * as a scan's header holds it). -EINVAL for text that is no instrument. */
int x3p_instrument_names(const char *instrument_json, struct x3p_instrument *out);

#endif
