/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * What asph fit --report (asph replay, asph report) says of the part, the
 * operator and the time of the measurement: the options given (--part,
 * --lot, --serial, --operator, --measured), else what the recorded scan
 * holds (asphd records the job's part, lot, serial, label and submitter in
 * the scan's metadata; its header and end block the times: the
 * characterization reads them), else, for the operator, the user running
 * asph.
 */
#ifndef ASPH_TOOL_FIT_REPORT_H
#define ASPH_TOOL_FIT_REPORT_H

#include <stddef.h>
#include <stdint.h>

#include "asph/characterize.h"
#include "fit-tool.h"

/* The options' part, lot, serial, operator and time into run, and the
 * user running asph (into user, size bytes) as its default operator. */
void fit_report_run(const struct fit_cli *c, char *user, size_t size,
		    struct asph_characterize_run *run);

/* --measured TIME: 0, or -1 after saying why. */
int fit_report_parse_measured(const char *arg, int64_t *ns);

#endif
