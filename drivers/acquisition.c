/* SPDX-License-Identifier: GPL-3.0-or-later */
/* The acquisition settings of an instrument: settling, drift control,
 * retries (docs/scanning.md). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "asph-driver/instrument.h"

void asph_acquisition_defaults(struct asph_acquisition *a)
{
	memset(a, 0, sizeof(*a));
	a->settle_window = 1e-3;
	a->drift_interval_s = 60;
	a->n_references = 1;    /* the vertex */
	a->retries = 3;
}

void asph_acquisition_advised(struct asph_acquisition *a, const struct asph_stage_info *si)
{
	if (!(a->set & ASPH_ACQUISITION_SET_SETTLE_WINDOW) && si->settle_window > 0 &&
	    isfinite(si->settle_window))
		a->settle_window = si->settle_window;
	if (!(a->set & ASPH_ACQUISITION_SET_SETTLE_DWELL) && si->settle_dwell > 0 &&
	    isfinite(si->settle_dwell))
		a->settle_dwell = si->settle_dwell;
}

bool asph_acquisition_drift(const struct asph_acquisition *a)
{
	return (a->drift_interval_s > 0 || a->drift_interval_points > 0) && a->n_references > 0;
}

/* A finite number with nothing after it. */
static int number(const char *text, double lo, double hi, double *out)
{
	char *end;
	double v = strtod(text, &end);

	if (end == text || *end || !isfinite(v))
		return -EINVAL;
	if (v < lo || v > hi)
		return -ERANGE;
	*out = v;
	return 0;
}

static int interval(struct asph_acquisition *a, const char *text, struct asph_error *err)
{
	char *end;
	double v = strtod(text, &end);

	if (!strcmp(text, "off") || !strcmp(text, "0")) {
		a->drift_interval_s = 0;
		a->drift_interval_points = 0;
		return 0;
	}
	while (*end == ' ')
		end++;
	if (end == text || !isfinite(v) || !(v > 0))
		return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "drift_interval",
					 "drift_interval '%s' is not a time (\"60s\"), a number of "
					 "points (\"5000points\") or \"off\"", text);
	if (!strcmp(end, "s")) {
		if (v > 1e7)
			return asph_error_set_at(err, -ERANGE, NULL, 0, 0, "drift_interval",
						 "drift_interval %g s is longer than 10^7 s", v);
		a->drift_interval_s = v;
		a->drift_interval_points = 0;
		return 0;
	}
	if (!strcmp(end, "points") && v == floor(v) && v <= 1e15) {
		a->drift_interval_points = (uint64_t)v;
		a->drift_interval_s = 0;
		return 0;
	}
	return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "drift_interval",
				 "drift_interval '%s' is not a time (\"60s\"), a whole number of "
				 "points (\"5000points\") or \"off\"", text);
}

static int references(struct asph_acquisition *a, const char *text, struct asph_error *err)
{
	size_t n = 0;

	if (!strcmp(text, "vertex")) {
		a->n_references = 1;
		a->references[0][0] = a->references[0][1] = 0;
		return 0;
	}
	for (const char *c = text; *c;) {
		char *end;
		double x = strtod(c, &end), y;
		if (end == c || *end != ':' || !isfinite(x))
			goto bad;
		c = end + 1;
		y = strtod(c, &end);
		if (end == c || (*end && *end != ';') || !isfinite(y))
			goto bad;
		if (n == ASPH_MAX_REFERENCES)
			return asph_error_set_at(err, -ERANGE, NULL, 0, 0, "drift_references",
						 "at most %d drift references", ASPH_MAX_REFERENCES);
		a->references[n][0] = x;
		a->references[n][1] = y;
		n++;
		c = *end ? end + 1 : end;
	}
	if (n == 0)
		goto bad;
	a->n_references = n;
	return 0;
bad:
	return asph_error_set_at(err, -EINVAL, NULL, 0, 0, "drift_references",
				 "drift_references '%s' is not \"vertex\" or X:Y points in mm "
				 "separated by ';' (e.g. 0:0;8:0;0:8)", text);
}

int asph_acquisition_set(struct asph_acquisition *a, const char *name, const char *text,
			 struct asph_error *err)
{
	double v;
	int r;

	if (!strcmp(name, "settle_window")) {
		r = number(text, 0, 1e6, &v);
		if (r < 0)
			return asph_error_set_at(err, r, NULL, 0, 0, name,
						 "settle_window '%s' is not a distance in um, 0 .. 10^6",
						 text);
		a->settle_window = v * 1e-3;
		a->set |= ASPH_ACQUISITION_SET_SETTLE_WINDOW;
		return 0;
	}
	if (!strcmp(name, "settle_dwell")) {
		r = number(text, 0, 60, &v);
		if (r < 0)
			return asph_error_set_at(err, r, NULL, 0, 0, name,
						 "settle_dwell '%s' is not a time in s, 0 .. 60", text);
		a->settle_dwell = v;
		a->set |= ASPH_ACQUISITION_SET_SETTLE_DWELL;
		return 0;
	}
	if (!strcmp(name, "retries")) {
		r = number(text, 0, 100, &v);
		if (r < 0 || v != floor(v))
			return asph_error_set_at(err, r < 0 ? r : -EINVAL, NULL, 0, 0, name,
						 "retries '%s' is not a whole number, 0 .. 100", text);
		a->retries = (unsigned)v;
		return 0;
	}
	if (!strcmp(name, "drift_interval"))
		return interval(a, text, err);
	if (!strcmp(name, "drift_references"))
		return references(a, text, err);
	return -ENOENT;
}
