/* SPDX-License-Identifier: GPL-3.0-or-later */
/* What asphctl's commands share (asphctl.h): a call of the daemon and how
 * it failed, JSON printed safely, numbers and job ids from the command
 * line. main.c dispatches to the commands, which call these. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "asphctl.h"
#include "util-mem.h"

int ctl_fail(const struct ctl_error *e)
{
	_cleanup_free_ char *message = ctl_escape(e->message, false);
	_cleanup_free_ char *detail = ctl_escape(e->detail, false);

	if (detail && detail[0])
		fprintf(stderr, "asphctl: %s: %s\n", message ? message : "?", detail);
	else
		fprintf(stderr, "asphctl: %s\n", message ? message : "?");
	if (e->code == 0)
		return EXIT_UNREACHABLE;
	if (e->code == PROTO_PERMISSION_DENIED)
		return EXIT_DENIED;
	return EXIT_FAILURE_RUN;
}

int ctl_call(struct ctl *ctl, const char *method, json_t *params, json_t **result)
{
	return ctl_call_fds(ctl, method, params, NULL, 0, result);
}

int ctl_call_fds(struct ctl *ctl, const char *method, json_t *params, const int *fds,
		 size_t n_fds, json_t **result)
{
	struct ctl_error e = { 0 };
	int r;

	if (!ctl->conn && conn_open(ctl->socket, &ctl->conn, &e) < 0) {
		json_decref(params);
		return ctl_fail(&e);
	}
	r = conn_call_fds(ctl->conn, method, params, fds, n_fds, result, &e);
	if (r < 0)
		return ctl_fail(&e);
	if (!ctl->json)
		ctl_escape_json(*result);
	return 0;
}

void ctl_print_json(const json_t *j)
{
	_cleanup_free_ char *s = json_dumps(j, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
	/* jansson escapes C0; DEL, C1 and the bidirectional controls it
	 * leaves as they are, inside strings only (JSON's syntax is ASCII). */
	_cleanup_free_ char *e = s ? ctl_escape(s, true) : NULL;

	if (e)
		puts(e);
}

int ctl_parse_integer(const char *arg, long long min, long long max, long long *v)
{
	char *end;

	errno = 0;
	*v = strtoll(arg, &end, 10);
	if (errno || end == arg || *end || *v < min || *v > max)
		return -EINVAL;
	return 0;
}

int ctl_parse_real(const char *arg, double *v)
{
	char *end;

	errno = 0;
	*v = strtod(arg, &end);
	if (errno || end == arg || *end || !isfinite(*v))
		return -EINVAL;
	return 0;
}

int64_t ctl_job_id(const char *arg)
{
	long long v;

	if (ctl_parse_integer(arg, 1, INT64_MAX, &v) < 0) {
		fprintf(stderr, "asphctl: '%s' is not a job id\n", arg);
		return -1;
	}
	return v;
}

int64_t ctl_job_operand(int argc, char **argv, const char *usage)
{
	if (optind + 1 != argc) {
		fprintf(stderr, "Usage: asphctl %s\n", usage);
		return -1;
	}
	return ctl_job_id(argv[optind]);
}
