/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * Record2's Instrument and ProbingSystem from the instrument a recorded
 * scan names (docs/characterization.md, "Exports"): the model is the
 * instrument's configured name, the version its drivers', the probing
 * system the probe's driver, version and serial, contacting for a tactile
 * probe.
 */
#include <errno.h>
#include <stdio.h>
#include <string.h>

#include <jansson.h>

#include "x3p-internal.h"
#include "util-mem.h"

static const char *member(const json_t *o, const char *key)
{
	const char *s = json_string_value(json_object_get(o, key));

	return s && s[0] ? s : NULL;
}

/* "mock 1.0.0", or the driver alone when it has no version. */
static void driver_name(const json_t *role, char *buf, size_t size)
{
	const char *driver = member(role, "driver"), *version = member(role, "version");

	snprintf(buf, size, "%s%s%s", driver ? driver : "-", version ? " " : "",
		 version ? version : "");
}

/* The drivers say what kind of probe they drive in an option "probe" (or
 * "probe_kind" on a CAN bus): tactile probes touch. One that does not say
 * is taken as non-contacting. */
static const char *probing_type(const json_t *probe)
{
	const json_t *o = json_object_get(probe, "options");
	const char *kind = member(probe, "type");

	if (!kind)
		kind = member(o, "probe");
	if (!kind)
		kind = member(o, "probe_kind");
	return kind && !strcmp(kind, "tactile") ? "Contacting" : "NonContacting";
}

int x3p_instrument_names(const char *instrument_json, struct x3p_instrument *out)
{
	_cleanup_(json_decrefp) json_t *root = json_loads(instrument_json, 0, NULL);
	const json_t *stage = json_object_get(root, "stage"), *probe = json_object_get(root, "probe");
	const char *name = member(root, "name");
	const char *serial = member(json_object_get(probe, "options"), "serial");
	char s[96], p[96];

	if (!json_is_object(root) || !name)
		return -EINVAL;
	driver_name(stage, s, sizeof(s));
	driver_name(probe, p, sizeof(p));
	snprintf(out->model, sizeof(out->model), "%s", name);
	snprintf(out->version, sizeof(out->version), "stage %s, probe %s", s, p);
	out->probing_type = probing_type(probe);
	snprintf(out->probing_id, sizeof(out->probing_id), "%s%s%s", p, serial ? ", serial " : "",
		 serial ? serial : "");
	return 0;
}
