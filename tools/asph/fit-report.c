/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What asph fit --report says of the part, the operator and the time. */
#include <pwd.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include <jansson.h>

#include "fit-report.h"
#include "util-time.h"

/* A member of the scan's metadata (asphd records the job's there), or of
 * an object in it. */
static const char *meta_string(const json_t *meta, const char *object, const char *key)
{
	if (object)
		meta = json_object_get(meta, object);
	return json_string_value(json_object_get(meta, key));
}

/* The login name of the user running asph, or "uid N". */
static void running_user(char *buf, size_t size)
{
	struct passwd pw, *res = NULL;
	char tmp[1024];

	if (getpwuid_r(geteuid(), &pw, tmp, sizeof(tmp), &res) == 0 && res)
		snprintf(buf, size, "%s", res->pw_name);
	else
		snprintf(buf, size, "uid %u", (unsigned)geteuid());
}

static const char *first(const char *a, const char *b)
{
	return a ? a : b;
}

void fit_report_who(const struct fit_cli *c, const struct asph_scanfile *scan,
		    struct fit_report_who *w)
{
	memset(w, 0, sizeof(*w));
	if (scan)
		w->meta = json_loads(scan->header.metadata, 0, NULL);
	running_user(w->user, sizeof(w->user));
	w->part = first(c->part, meta_string(w->meta, NULL, "part"));
	w->lot = first(c->lot, meta_string(w->meta, NULL, "lot"));
	w->serial = first(c->serial, meta_string(w->meta, NULL, "serial"));
	w->label = meta_string(w->meta, NULL, "label");
	w->job = json_integer_value(json_object_get(w->meta, "job"));
	w->operator_name = first(c->operator_name, meta_string(w->meta, "submitted_by", "name"));
	if (!w->operator_name)
		w->operator_name = w->user;
	if (c->measured_ns) {
		w->measured_ns = c->measured_ns;
	} else if (scan) {
		w->measured_ns = scan->header.created_ns;
		w->measured_end_ns = scan->report.ended_ns;
	}
}

void fit_report_who_release(struct fit_report_who *w)
{
	json_decref(w->meta);
	w->meta = NULL;
}

int fit_report_parse_measured(const char *arg, int64_t *ns)
{
	if (iso8601_parse_zoned(arg, ns) == 0)
		return 0;
	fprintf(stderr, "asph fit: --measured: '%s' is not an ISO 8601 time with its zone, "
			"e.g. 2027-01-31T14:05:00+01:00 or 2027-01-31T13:05:00Z\n", arg);
	return -1;
}
