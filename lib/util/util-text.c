/* SPDX-License-Identifier: GPL-3.0-or-later */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "util-text.h"

size_t text_control_at(const char *text, unsigned *cp)
{
	const unsigned char *s = (const unsigned char *)text;

	if (s[0] < 0x20 || s[0] == 0x7f) {
		*cp = s[0];
		return 1;
	}
	if (s[0] == 0xc2 && s[1] >= 0x80 && s[1] <= 0x9f) {
		*cp = s[1];
		return 2;
	}
	if (s[0] == 0xe2 && s[1] == 0x80 && s[2] >= 0xaa && s[2] <= 0xae) {
		*cp = 0x202au + (s[2] - 0xaa);
		return 3;
	}
	if (s[0] == 0xe2 && s[1] == 0x81 && s[2] >= 0xa6 && s[2] <= 0xa9) {
		*cp = 0x2066u + (s[2] - 0xa6);
		return 3;
	}
	return 0;
}

bool text_has_controls(const char *s)
{
	unsigned cp;

	for (; *s; s++)
		if (text_control_at(s, &cp))
			return true;
	return false;
}

char *text_escape_controls(const char *s, bool json)
{
	size_t n = strlen(s);
	char *out = malloc(6 * n + 1), *o = out;
	unsigned cp;

	if (!out)
		return NULL;
	while (*s) {
		size_t len = text_control_at(s, &cp);
		if (!len || (json && cp < 0x20)) {
			*o++ = *s++;
			continue;
		}
		if (!json && cp == '\n')
			o += sprintf(o, "\\n");
		else if (!json && cp == '\t')
			o += sprintf(o, "\\t");
		else if (!json && cp < 0x80)
			o += sprintf(o, "\\x%02x", cp);
		else
			o += sprintf(o, "\\u%04x", cp);
		s += len;
	}
	*o = '\0';
	return out;
}
