/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * The line driver's profile parser (drivers/line/profile.c): any bytes are
 * a profile or refused with a reason, a line and, within the text, a
 * column; what it accepts has what its role needs.
 */
#include <string.h>

#include "fuzz.h"
#include "line/profile.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
	static struct line_profile p;
	struct asph_error err;

	asph_error_clear(&err);
	if (line_profile_parse((const char *)data, size, "fuzz.profile", &p, &err) < 0) {
		fuzz_check_error(&err);
		if (strcmp(err.source, "fuzz.profile") || err.line < 0 || err.column < 0)
			fuzz_die("an error without its place: %s:%d:%d", err.source, err.line, err.column);
		return 0;
	}
	if (!p.name[0] || !p.roles || !p.send_terminator[0] || !p.reply_terminator[0])
		fuzz_die("an accepted profile lacks its name, role or terminators");
	if (p.roles == LINE_ROLE_PROBE && !p.ops[LINE_OP_READ].n)
		fuzz_die("an accepted probe profile cannot read");
	for (int i = 0; i < LINE_OP_COUNT; i++)
		if (p.ops[i].n > LINE_MAX_STEPS)
			fuzz_die("operation %d has %u steps", i, p.ops[i].n);
	return 0;
}
