/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What asphctl prints of the daemon's answers is other people's text
 * (labels, reasons, names): control characters in it are shown as
 * escapes, so that it cannot move the cursor, retitle the terminal or
 * reorder what is shown. The daemon keeps the text as it was sent.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "asphctl.h"
#include "util-mem.h"

/*
 * The length of the character at s that must be escaped, and its code
 * point, or 0: C0 controls, DEL, C1 controls (U+0080..U+009F) and the
 * bidirectional overrides and isolates (U+202A..U+202E, U+2066..U+2069).
 */
static size_t control_at(const unsigned char *s, unsigned *cp)
{
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

static bool needs_escape(const char *s)
{
	unsigned cp;

	for (const unsigned char *p = (const unsigned char *)s; *p; p++)
		if (control_at(p, &cp))
			return true;
	return false;
}

char *ctl_escape(const char *s, bool json)
{
	size_t n = strlen(s);
	char *out = malloc(6 * n + 1), *o = out;
	const unsigned char *p = (const unsigned char *)s;
	unsigned cp;

	if (!out)
		return NULL;
	while (*p) {
		size_t len = control_at(p, &cp);
		/* In JSON text a raw C0 character is layout: jansson has
		 * escaped those inside strings. */
		if (!len || (json && cp < 0x20)) {
			*o++ = (char)*p++;
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
		p += len;
	}
	*o = '\0';
	return out;
}

void ctl_escape_json(json_t *j)
{
	const char *key;
	json_t *v;
	size_t i;
	void *tmp;

	if (json_is_array(j)) {
		json_array_foreach(j, i, v) {
			if (json_is_string(v) && needs_escape(json_string_value(v))) {
				_cleanup_free_ char *e = ctl_escape(json_string_value(v), false);
				if (e)
					json_array_set_new(j, i, json_string(e));
			} else {
				ctl_escape_json(v);
			}
		}
		return;
	}
	if (!json_is_object(j))
		return;
	json_object_foreach_safe(j, tmp, key, v) {
		if (json_is_string(v) && needs_escape(json_string_value(v))) {
			_cleanup_free_ char *e = ctl_escape(json_string_value(v), false);
			if (e)
				json_object_set_new(j, key, json_string(e));
		} else {
			ctl_escape_json(v);
		}
		if (needs_escape(key)) {
			_cleanup_free_ char *e = ctl_escape(key, false);
			if (e) {
				json_object_set(j, e, json_object_get(j, key));
				json_object_del(j, key);
			}
		}
	}
}
