/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What asph fit --report says of the part, the operator and the time. */
#include <pwd.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "fit-report.h"
#include "util-time.h"

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

void fit_report_run(const struct fit_cli *c, char *user, size_t size,
		    struct asph_characterize_run *run)
{
	running_user(user, size);
	run->part = c->part;
	run->lot = c->lot;
	run->serial = c->serial;
	run->operator_name = c->operator_name;
	run->default_operator = user;
	run->measured_ns = c->measured_ns;
}

int fit_report_parse_measured(const char *arg, int64_t *ns)
{
	if (iso8601_parse_zoned(arg, ns) == 0)
		return 0;
	fprintf(stderr, "asph fit: --measured: '%s' is not an ISO 8601 time with its zone, "
			"e.g. 2027-01-31T14:05:00+01:00 or 2027-01-31T13:05:00Z\n", arg);
	return -1;
}
