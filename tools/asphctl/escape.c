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
#include "util-text.h"

static bool needs_escape(const char *s)
{
	return text_has_controls(s);
}

char *ctl_escape(const char *s, bool json)
{
	return text_escape_controls(s, json);
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
