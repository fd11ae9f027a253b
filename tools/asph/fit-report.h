/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What asph fit --report (asph replay, asph report) says of the part, the
 * operator and the time of the measurement: the options given (--part,
 * --lot, --serial, --operator, --measured), else what the recorded scan
 * holds (asphd records the job's part, lot, serial, label and submitter in
 * the scan's metadata; its header and end block the times), else, for the
 * operator, the user running asph.
 */
#ifndef ASPH_TOOL_FIT_REPORT_H
#define ASPH_TOOL_FIT_REPORT_H

#include <stdint.h>

#include <jansson.h>

#include "asph/scanfile.h"
#include "fit-tool.h"

struct fit_report_who {
	json_t *meta;           /* the scan's metadata; the texts point into it */
	const char *part, *lot, *serial, *operator_name, *label;
	int64_t job, measured_ns, measured_end_ns;   /* 0: not known */
	char user[256];
};

/* scan may be NULL (a points file). */
void fit_report_who(const struct fit_cli *c, const struct asph_scanfile *scan,
		    struct fit_report_who *w);
void fit_report_who_release(struct fit_report_who *w);

/* --measured TIME: 0, or -1 after saying why. */
int fit_report_parse_measured(const char *arg, int64_t *ns);

#endif
